"""What the `edge` commands share: the configuration options (declared once), loading the
configuration, one-line usage errors, a progress bar, distance lists.

Light on purpose: every command module imports this at start-up, ``edge lasers off`` included.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from edge.errors import UsageError

if TYPE_CHECKING:
    from edge.config import Config


class Parser(argparse.ArgumentParser):
    """argparse that says `edge: …` in one line and exits 2, as every other error does."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def add_config_options(p: argparse.ArgumentParser, example: str = "sim.scene=kitchen") -> None:
    """--config, --set and -v, the options every command that reads the configuration takes."""
    p.add_argument("--config", metavar="FILE", help="configuration file (default: config/sim.toml)")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                   help=f"change one configuration key, e.g. --set {example} (repeatable)")
    add_verbose(p)


def add_verbose(p: argparse.ArgumentParser) -> None:
    p.add_argument("-v", "--verbose", action="store_true", help="log debug messages")


def load(args: argparse.Namespace, *extra: str) -> Config:
    """The configuration the options name, with `extra` overrides applied after --set's."""
    from edge.config import load_config

    return load_config(args.config, [*args.set, *extra])


def usage(message: str) -> UsageError:
    return UsageError(message)


def progress(label: str) -> Callable[[int, int], None] | None:
    """A one-line progress bar on a terminal; nothing when stderr is not one (logs suffice)."""
    if not sys.stderr.isatty():
        return None
    start = time.monotonic()

    def show(done: int, total: int) -> None:
        width = 30
        filled = int(width * done / total)
        rate = done / max(time.monotonic() - start, 1e-6)
        sys.stderr.write(f"\r{label} [{'#' * filled}{'.' * (width - filled)}] {done}/{total} {rate:.1f}/s")
        if done == total:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return show


def distances(text: str, option: str) -> list[float]:
    """Distances in metres separated by commas (``0.5,1,2``), each within 0.05-100 m."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise usage(f"{option}: expected distances in metres separated by commas, e.g. 0.5,1,2") from None
    if not values or any(not (0.05 < v < 100.0) for v in values):
        raise usage(f"{option}: each distance must be between 0.05 and 100 m, got {text!r}")
    return values
