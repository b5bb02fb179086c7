"""`edge ptu status|move|home`: drive the pan-tilt unit by hand (bench checks)."""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from edge.cli.common import add_config_options


def add_parser(sub: Any) -> None:
    p = sub.add_parser("ptu", help="drive the pan-tilt unit: status, move, home")
    p.add_argument("--port", help="serial port, or sim:// for the emulator (default: ptu.port)")
    add_config_options(p, example="ptu.speed_deg_s=30")
    actions = p.add_subparsers(dest="ptu_action", required=True, parser_class=type(p))
    actions.add_parser("status", help="model, resolution, limits and position")
    m = actions.add_parser("move", help="move to PAN TILT (degrees; positive pan left, tilt up)")
    m.add_argument("pan", type=float, help="pan, degrees")
    m.add_argument("tilt", type=float, help="tilt, degrees")
    actions.add_parser("home", help="move to pan 0, tilt 0")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from edge.cli.common import load
    from edge.parts import open_ptu

    settings = load(args).ptu
    if args.port:
        settings = dataclasses.replace(settings, port=args.port)
    unit, emulator = open_ptu(settings)
    with unit:
        if args.ptu_action == "status":
            (pn, px), (tn, tx) = unit.limits_deg
            lo, hi = unit.speed_range_deg_s
            pan, tilt = unit.position()
            print(f"pan-tilt unit on {unit.port}{' (emulator)' if emulator else ''}: {unit.model}")
            (ap, at), (dp, dt) = unit.res_arcsec, unit.resolution_deg
            print(f"resolution: pan {ap:.4f}″, tilt {at:.4f}″ per position ({dp:.6f}°, {dt:.6f}°)")
            print(f"limits: pan {pn:+.5f}°…{px:+.5f}°, tilt {tn:+.5f}°…{tx:+.5f}°")  # 180.00 would hide 179.99994
            print(f"speed: {settings.speed_deg_s:g} °/s (unit allows {lo:.2f}–{hi:.2f} °/s), "
                  f"acceleration {settings.accel_deg_s2:g} °/s²")
            print(f"position: pan {pan:+.4f}°, tilt {tilt:+.4f}°")
        else:
            target = (args.pan, args.tilt) if args.ptu_action == "move" else (0.0, 0.0)
            unit.move(*target)
            pan, tilt = unit.position()  # as the unit reports it
            print(f"position: pan {pan:+.4f}°, tilt {tilt:+.4f}°")
    return 0
