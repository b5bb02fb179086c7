"""`edge lasers off`: drive every configured laser pin to its off level — systemd's ExecStopPost.

This is the eye-safety path after a crash or a kill, so it needs nothing but the pins: it reads
only the laser wiring (``[[rig.lasers]]`` name, pin, active_high) and ``[lasers]`` from the
configuration file, through the light table reader, and imports neither numpy nor OpenCV nor any
ranging, mode or simulator module (but the simulator's mock pins when the lasers are simulated).
A mistake anywhere else in the file does not matter; a file that is missing or broken where the
wiring is read makes it switch off the default wiring (GPIO 17, 27, 22) instead, and say so: it
exits 0 once the pins are driven, as systemd expects of a clean-up.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from edge.cli.common import add_config_options


def add_parser(sub: Any) -> None:
    p = sub.add_parser("lasers", help="drive the laser pins: `edge lasers off` switches every laser off")
    p.add_argument("action", choices=["off"], help="off: drive every configured laser pin to its off level")
    add_config_options(p, example="lasers.backend=gpio")
    p.set_defaults(func=run)


def wiring_of(args: argparse.Namespace) -> tuple[tuple[Any, ...], Any]:
    """(the lasers' wiring, the ``[lasers]`` settings) of the configuration the options name;
    ConfigError when either cannot be read."""
    from edge.config_file import apply_overrides, default_config_path, read_table
    from edge.errors import ConfigError
    from edge.hw.lasers import LasersConfig, wiring_from_table
    from edge.schema import build

    file = Path(args.config) if args.config is not None else default_config_path()
    source = str(file)
    data = read_table(file)
    apply_overrides(data, args.set)
    rig = data.get("rig", {})
    if not isinstance(rig, dict):
        raise ConfigError(f"{source}: rig: expected a table")
    wiring = wiring_from_table(rig, source)
    settings = build(LasersConfig, data.get("lasers", {}), source, "lasers")
    return wiring, settings


def _fallback() -> tuple[tuple[Any, ...], Any, str]:
    """The default wiring on the machine's own GPIO, or on mock pins where it has none: a broken
    configuration must not leave a laser lit, and on a device the default pins are the likely ones."""
    from edge.errors import LaserError
    from edge.hw.lasers import DEFAULT_WIRING, LasersConfig, default_factory

    try:
        default_factory()
    except LaserError:
        # No GPIO here (a development machine): the simulator's pins stand in, so the command
        # still says what it would have done.
        return DEFAULT_WIRING, LasersConfig(backend="sim"), "mock pins (no GPIO on this machine)"
    return DEFAULT_WIRING, LasersConfig(backend="gpio"), "GPIO"


def run(args: argparse.Namespace) -> int:
    import sys

    from edge.errors import EdgeError
    from edge.hw.lasers import force_all_off
    from edge.parts import laser_factory

    try:
        wiring, settings = wiring_of(args)
    except EdgeError as exc:
        wiring, settings, where = _fallback()
        pins = ", ".join(f"GPIO{w.pin}" for w in wiring)
        print(f"edge: {exc}; switching off the default wiring ({pins}) on {where} instead", file=sys.stderr)
    for name, pin, level in force_all_off(wiring, laser_factory(settings)):
        print(f"laser {name}: GPIO{pin} driven {'high' if level else 'low'} (off)")
    if settings.backend == "sim":
        where = f"the simulated wires in {settings.sim_wires}" if settings.sim_wires else "mock pins"
        print(f"(lasers.backend is sim: no real pins were touched, only {where})")
    return 0
