"""`edge config` (check a configuration file and summarise it) and `edge bench` (speed figures)."""

from __future__ import annotations

import argparse
from typing import Any

from edge.cli.common import add_config_options, load


def add_parsers(sub: Any) -> None:
    p = sub.add_parser("config", help="check a configuration file and summarise it")
    add_config_options(p)
    p.set_defaults(func=cmd_config)

    p = sub.add_parser("bench", help="measure speed or accuracy (prints figures, asserts nothing)")
    add_config_options(p)
    p.add_argument("what", choices=["render", "ranging", "blindaid", "rangefinder", "accuracy"],
                   help="what to time, or accuracy: ranging on a family of simulated conditions against the floor")
    p.add_argument("--repeats", type=int,
                   help="runs to take the median of (blindaid: passes of the fan; rangefinder: ranges)")
    a = p.add_argument_group("accuracy")
    a.add_argument("--conditions", type=int, help="conditions of the family to run (default 8)")
    a.add_argument("--seed", type=int, help="the first condition's index in its family (default 0)")
    a.add_argument("--zones", type=int, help="zones per condition (default 16)")
    a.add_argument("--family", choices=["tuning", "evaluation"],
                   help="tuning (default) for work on the estimator; evaluation, which no tuning may see, to report")
    a.add_argument("--rig", choices=["true", "calibrated", "nominal"],
                   help="what ranging is given: the simulated rig as built (default), one fitted from a "
                        "simulated calibration, or the nominal one")
    a.add_argument("--jobs", type=int, default=0, help="conditions run at once (default: one per core)")
    a.add_argument("--keep", metavar="DIR", help="keep the recordings in DIR (and their figures, for --replay)")
    a.add_argument("--replay", metavar="DIR",
                   help="range the recordings that --keep kept in DIR again, with the estimator as it is now "
                        "(the family, conditions and zones are DIR's; --config and --set, if given, replace "
                        "the ones it was recorded with)")
    a.add_argument("--json", metavar="FILE", help="also write every zone's result, truth and floor (JSON)")
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
    if args.what == "accuracy":
        return cmd_bench_accuracy(args)
    from edge import bench

    config = load(args)
    run = {"render": bench.bench_render, "ranging": bench.bench_ranging, "blindaid": bench.bench_blindaid,
           "rangefinder": bench.bench_rangefinder}[args.what]
    lines = run(config, **({"repeats": args.repeats} if args.repeats else {}))
    print("\n".join(lines))
    return 0


def cmd_bench_accuracy(args: argparse.Namespace) -> int:
    import json
    import os
    import sys
    from pathlib import Path

    from edge.accuracy.bench import (
        KEPT_FILE,
        KeptFamily,
        condition_line,
        family_document,
        replay_family,
        report,
        run_family,
        software,
        software_line,
    )
    from edge.accuracy.conditions import FAMILY_SIZE, family
    from edge.config import load_config
    from edge.errors import UsageError
    from edge.fsutil import atomic_write_bytes

    if args.json:
        from edge.fsutil import check_output

        check_output(args.json, "--json", error=UsageError)
    if args.replay and args.keep:
        raise UsageError("--replay and --keep: a replay keeps nothing new; give one of them")

    def done(run) -> None:
        print(condition_line(run), file=sys.stderr, flush=True)

    if args.replay:
        given = [f"--{o}" for o in ("family", "conditions", "seed", "zones") if getattr(args, o) is not None]
        if given:
            raise UsageError(f"--replay {args.replay}: the family, its conditions and zones are the kept ones; "
                             f"drop {', '.join(given)}")
        kept = KeptFamily.read(Path(args.replay))
        config_path, overrides = ((args.config, args.set) if args.config or args.set
                                  else (kept.config, list(kept.overrides)))
        load_config(config_path, overrides)  # a bad configuration is reported before any work
        family_name, zones, rig = kept.family, kept.zones, args.rig or kept.rig
        jobs = args.jobs or min(len(kept.conditions), os.cpu_count() or 1)
        runs = replay_family(config_path, overrides, kept, rig, jobs, done)
        rendered_with = kept.rendered_with
    else:
        args.conditions = 8 if args.conditions is None else args.conditions
        args.seed = 0 if args.seed is None else args.seed
        args.zones = 16 if args.zones is None else args.zones
        if not 1 <= args.conditions <= 1000:
            raise UsageError("--conditions: must be 1-1000")
        if not 0 <= args.seed <= FAMILY_SIZE - args.conditions:
            raise UsageError(f"--seed: must be 0-{FAMILY_SIZE - args.conditions}")
        if not 1 <= args.zones <= 1024:
            raise UsageError("--zones: must be 1-1024")
        load(args)  # a bad configuration is reported before any work
        config_path, overrides = args.config, args.set
        family_name, zones, rig = args.family or "tuning", args.zones, args.rig or "true"
        conditions = family(family_name, args.conditions, args.seed)
        jobs = args.jobs or min(len(conditions), os.cpu_count() or 1)
        runs = run_family(config_path, overrides, conditions, zones, rig, jobs,
                          Path(args.keep) if args.keep else None, done)
        rendered_with = software()
    print("\n".join([*report(runs, family_name, zones, rig), software_line(rendered_with)]))
    doc = json.dumps(family_document(runs, family_name, zones, rig, config_path, overrides, rendered_with),
                     indent=1).encode()
    if args.keep:
        atomic_write_bytes(Path(args.keep) / KEPT_FILE, doc)
    if args.json:
        atomic_write_bytes(Path(args.json), doc)
    return 0
