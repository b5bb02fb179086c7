"""`edge config` (check a configuration file and summarise it) and `edge bench` (speed figures)."""

from __future__ import annotations

import argparse
from typing import Any

from edge.cli.common import add_config_options, load


def add_parsers(sub: Any) -> None:
    p = sub.add_parser("config", help="check a configuration file and summarise it")
    add_config_options(p)
    p.set_defaults(func=cmd_config)

    p = sub.add_parser("bench", help="measure speed (prints figures, asserts nothing)")
    add_config_options(p)
    p.add_argument("what", choices=["render", "ranging", "blindaid", "rangefinder"], help="what to time")
    p.add_argument("--repeats", type=int,
                   help="runs to take the median of (blindaid: passes of the fan; rangefinder: ranges)")
    p.set_defaults(func=cmd_bench)


def cmd_config(args: argparse.Namespace) -> int:
    config = load(args)
    rig = config.rig.build()
    print(f"{config.source}: ok")
    print(f"  camera {rig.camera.width}x{rig.camera.height} fx={rig.camera.fx:g}")
    for laser, wire in zip(rig.lasers, config.rig.wiring(), strict=True):
        ref = " (reference)" if laser is rig.reference else ""
        low = ", active low" if not wire.active_high else ""
        print(f"  laser {laser.name}: pin {wire.pin}{low}{ref}")
    from edge.calibration.in_use import believed_rig

    print(f"  calibration: {believed_rig(config).health}")
    if not config.rig.calibration:  # the service also looks in its state folder
        print(f"  calibration of edge run: {believed_rig(config, service=True).health}")
    print(f"  sweep {len(config.sweep.poses())} zones, {config.sweep.pairs_per_zone} pairs each")
    print(f"  sim scene {config.sim.scene}")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from edge import bench

    config = load(args)
    run = {"render": bench.bench_render, "ranging": bench.bench_ranging, "blindaid": bench.bench_blindaid,
           "rangefinder": bench.bench_rangefinder}[args.what]
    lines = run(config, **({"repeats": args.repeats} if args.repeats else {}))
    print("\n".join(lines))
    return 0
