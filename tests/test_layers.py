"""The layers of ../shared/design.md, checked on the source: what each layer may import.

Every import counts, at the top of a module or inside a function (a late import is still a
dependency), and whether guarded by TYPE_CHECKING or not: the source is parsed with `ast`, nothing
is imported. A failure names each offending import by file and line.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from pathlib import Path

EDGE = Path(__file__).resolve().parents[1] / "edge"

# Drivers own their small settings and take them as arguments: none of the core, config, modes
# or simulator.
HW_FORBIDDEN = ("edge.sim", "edge.config", "edge.modes", "edge.ranging", "edge.triangulation", "edge.fusion",
                "edge.vision")

# The pure core: arrays and dataclasses in and out; no driver, MQTT, service or simulator, and no
# clock, thread or process (time is passed in).
CORE = (
    "rig.py",
    "vision.py",
    "paths.py",
    "stuck.py",
    "spotshape.py",
    "spoterror.py",
    "framenoise.py",
    "redsites.py",
    "ranging.py",
    "triangulation.py",
    "tracks.py",
    "fusion.py",
    "mapping.py",
    "grid.py",
    "cloud.py",
    "calibration/fit.py",
    "calibration/spots.py",
    "modes/guard.py",
    "modes/blindaid/logic.py",
    "laserhealth.py",
    "accuracy/conditions.py",
    "isp.py",
    "accuracy/floor.py",
    "accuracy/score.py",
)
CORE_FORBIDDEN = ("edge.hw", "edge.mqtt", "edge.service", "edge.sim", "time", "threading", "subprocess")


def module_name(path: Path) -> str:
    parts = path.relative_to(EDGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> list[tuple[int, str]]:
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    return imports_in(path.read_text(encoding="utf-8"), package, str(path))


def imports_in(source: str, package: str, filename: str = "<source>") -> list[tuple[int, str]]:
    """(line, module) for every import in `source`, anywhere in it, for a module of `package`.
    ``from a import b`` yields both ``a`` and ``a.b`` (b may be a module); relative imports are
    made absolute."""
    out = []
    for node in ast.walk(ast.parse(source, filename=filename)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([node.module] if node.module else []))
            out.append((node.lineno, base))
            out += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
    return out


def offences(paths: Iterable[Path], forbidden: tuple[str, ...]) -> list[str]:
    found = []
    for path in sorted(paths):
        found += offences_in(imports(path), str(path.relative_to(EDGE.parent)), forbidden)
    return found


def offences_in(found: list[tuple[int, str]], where: str, forbidden: tuple[str, ...]) -> list[str]:
    """One line per forbidden module imported, per line of the file."""
    out: dict[tuple[int, str], str] = {}
    for line, name in found:
        for bad in forbidden:
            if (name == bad or name.startswith(bad + ".")) and (line, bad) not in out:
                out[line, bad] = f"{where}:{line} imports {name}"
    return [out[key] for key in sorted(out)]


def hw_modules() -> list[Path]:
    return sorted((EDGE / "hw").rglob("*.py"))


def core_modules() -> list[Path]:
    return [EDGE / name for name in CORE]


def test_the_checker_sees_function_local_and_relative_imports() -> None:
    source = (
        "import os, time as clock\n"
        "from . import base\n"
        "from ..config import LasersConfig\n"
        "def late():\n"
        "    import time\n"
        "    if True:\n"
        "        from edge import sim\n"
    )
    found = imports_in(source, "edge.hw")
    assert (2, "edge.hw.base") in found and (3, "edge.config") in found
    assert (5, "time") in found and (7, "edge.sim") in found
    assert offences_in(found, "probe.py", HW_FORBIDDEN) == [
        "probe.py:3 imports edge.config", "probe.py:7 imports edge.sim",
    ]
    assert offences_in(found, "probe.py", CORE_FORBIDDEN) == [
        "probe.py:1 imports time", "probe.py:2 imports edge.hw", "probe.py:5 imports time",
        "probe.py:7 imports edge.sim",
    ]


def test_the_rules_cover_real_files() -> None:
    missing = [str(p) for p in core_modules() if not p.is_file()]
    assert not missing, f"core modules moved or renamed; update CORE in this test: {missing}"
    assert hw_modules(), "no driver modules found under edge/hw/"


def test_the_pure_core_imports_no_driver_service_or_clock() -> None:
    bad = offences(core_modules(), CORE_FORBIDDEN)
    assert not bad, "the pure core reaches out of its layer:\n" + "\n".join(bad)


def test_drivers_import_no_core_config_modes_or_simulator() -> None:
    bad = offences(hw_modules(), HW_FORBIDDEN)
    assert not bad, "drivers (edge/hw/) reach out of their layer:\n" + "\n".join(bad)
