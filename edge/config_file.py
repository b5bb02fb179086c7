"""The configuration file as a plain table: where it is, read as TOML, ``--set`` applied.

Light on purpose (no numpy, no driver, no mode): ``edge lasers off`` reads the laser wiring through
it when nothing else may work. :mod:`edge.config` turns the table into typed objects.
"""

from __future__ import annotations

import os
import sys
import tomllib
from pathlib import Path
from typing import Any

from edge.errors import ConfigError
from edge.fsutil import read_small
from edge.schema import MAX_DEPTH, depth, show

REPO_ROOT = Path(__file__).resolve().parents[1]

# A configuration is a few kB; a scene's or a long poses list's stays well under this.
CONFIG_LIMIT = 1 << 20


def config_dir() -> Path:
    """Where the shipped configuration (``sim.toml``, ``scenes/``) lives: ``$EDGE_CONFIG_DIR``; else
    the checkout's ``config/`` (edge run from its repository, or installed editable); else the
    ``config/`` beside the venv edge is installed in (the README's ``/opt/edge/.venv``, a plain
    ``pip install``, whose package has no ``config/`` next to it)."""
    env = os.environ.get("EDGE_CONFIG_DIR")
    if env:
        return Path(env)
    places = (REPO_ROOT / "config", Path(sys.prefix).resolve().parent / "config")
    for place in places:
        if (place / "sim.toml").is_file():
            return place
    raise ConfigError(f"no shipped configuration: neither {show(str(places[0]))} nor {show(str(places[1]))} "
                      "has sim.toml; give --config FILE, or set EDGE_CONFIG_DIR to the repository's config folder")


def default_config_path() -> Path:
    return config_dir() / "sim.toml"


def read_table(file: Path) -> dict[str, Any]:
    """The TOML file as a plain table; ConfigError with one line if it cannot be read as TOML.

    The file must be a regular file of at most CONFIG_LIMIT bytes (never a FIFO or a device:
    see :func:`edge.fsutil.read_small`), nesting at most MAX_DEPTH levels."""
    name = show(str(file))
    try:
        data = tomllib.loads(read_small(file, CONFIG_LIMIT).decode("utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{name}: no such configuration file") from None
    except OSError as exc:
        raise ConfigError(f"{name}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{name}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{name}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{name}: not usable TOML: nested too deeply") from None
    except ValueError as exc:  # e.g. a whole number of more digits than Python converts
        raise ConfigError(f"{name}: not usable TOML: {str(exc).splitlines()[0]}") from None
    if depth(data) > MAX_DEPTH:
        raise ConfigError(f"{name}: not usable TOML: nested more than {MAX_DEPTH} levels deep")
    return data


def parse_override(text: str) -> tuple[str, Any]:
    """``key.path=value`` → (key path, value); the value is read as TOML, else as a string."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(f"--set {show(text)}: expected KEY=VALUE, e.g. --set sim.scene=kitchen")
    if "\n" in text or "\r" in text:
        raise ConfigError(f"--set {show(text)}: a line break in it; give one KEY=VALUE per --set")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except (tomllib.TOMLDecodeError, ValueError, RecursionError):
        value = raw.strip()
    return key, value


def apply_override(data: dict[str, Any], key: str, value: Any) -> None:
    node = data
    parts = key.split(".")
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"--set {show(key)}: {show(part)} is not a table")
        node = child
    node[parts[-1]] = value


def apply_overrides(data: dict[str, Any], overrides: list[str] | tuple[str, ...]) -> None:
    """Apply ``--set key.path=value`` overrides to the table, in order."""
    for text in overrides:
        key, value = parse_override(text)
        apply_override(data, key, value)
