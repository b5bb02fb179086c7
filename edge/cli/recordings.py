"""`edge replay` and `edge sim record|show`: recordings ranged again, made on the simulator, drawn."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from edge.cli.common import Parser, add_config_options, add_verbose, distances, load, progress, usage


def add_parsers(sub: Any) -> None:
    p = sub.add_parser("replay", help="range a recorded sweep again")
    p.add_argument("recording", help="recording folder (edge-sweep/1)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--json", action="store_true", help="print the edge-ranges/1 document only")
    out.add_argument("--score", action="store_true", help="per-zone table and error summary against truth (default)")
    p.add_argument("--estimator", choices=["triangulate", "thesis"], default="triangulate")
    p.add_argument("--calibration", metavar="FILE", help="calibration file from edge calibrate")
    add_config_options(p)
    p.set_defaults(func=cmd_replay)

    sim = sub.add_parser("sim", help="the simulator").add_subparsers(
        dest="sim_command", required=True, parser_class=Parser
    )
    p = sim.add_parser("record", help="write a simulated sweep as an edge-sweep/1 recording")
    add_config_options(p)
    p.add_argument("--scene", help="scene name (config/scenes/NAME.toml) or file")
    p.add_argument("--out", required=True, help="recording folder to write")
    p.add_argument("--zones", type=int, help="number of zones (default: sweep.zones)")
    p.add_argument("--frames", type=int, help="frames per zone, even: off/on pairs (default: 2 × sweep.pairs_per_zone)")
    p.add_argument("--seed", type=int, help="noise and speckle seed (default: sim.seed)")
    p.add_argument(
        "--target",
        metavar="D1,D2,...",
        help="instead of a scene: zone i shows a flat target squarely at distance Di (m), for edge calibrate",
    )
    p.set_defaults(func=cmd_sim_record)

    p = sim.add_parser("show", help="draw a recording's contact sheet (PNG)")
    p.add_argument("recording", help="recording folder")
    p.add_argument("--out", help="PNG to write (default: RECORDING/contact.png)")
    p.add_argument("--columns", type=int, default=8)
    add_verbose(p)
    p.set_defaults(func=cmd_sim_show)


def cmd_replay(args: argparse.Namespace) -> int:
    from edge.recording import read_recording
    from edge.replay import Replayer, format_score, ranging_for, replay_document, score

    recording = read_recording(args.recording)
    rig = recording.rig
    if args.calibration:
        from edge.calibration.file import read_calibration

        rig = read_calibration(args.calibration).apply(rig)
    replayer = Replayer(rig, args.estimator, ranging_for(recording, load(args).ranging))
    results = list(replayer.zones(recording, progress("ranging")))
    if args.json:
        json.dump(replay_document(recording, results), sys.stdout)
        sys.stdout.write("\n")
    else:
        print(format_score(score(recording, results)))
    return 0


def cmd_sim_record(args: argparse.Namespace) -> int:
    from edge.sim.record import record_sweep

    overrides = list(args.set)
    if args.scene:
        overrides.append(f"sim.scene={json.dumps(args.scene)}")
    if args.seed is not None:
        overrides.append(f"sim.seed={args.seed}")
    from edge.config import load_config

    config = load_config(args.config, overrides)
    pairs = None
    if args.frames is not None:
        if args.frames < 2 or args.frames % 2:
            raise usage("--frames must be an even number >= 2 (laser-off/laser-on pairs)")
        pairs = args.frames // 2
    if args.zones is not None and args.zones < 1:
        raise usage("--zones must be >= 1")
    started = time.monotonic()
    if args.target:
        from edge.sim.record import record_targets

        targets = distances(args.target, "--target")
        out = record_targets(config, targets, Path(args.out), pairs, progress=progress("recording"))
    else:
        out = record_sweep(config, Path(args.out), args.zones, pairs, progress("recording"))
    print(f"wrote {out} in {time.monotonic() - started:.1f} s")
    return 0


def cmd_sim_show(args: argparse.Namespace) -> int:
    from edge.contact import contact_sheet
    from edge.errors import UsageError
    from edge.fsutil import check_output, write_png
    from edge.recording import read_recording

    out = Path(args.out) if args.out else Path(args.recording) / "contact.png"
    check_output(out, "--out", error=UsageError)
    recording = read_recording(args.recording)
    write_png(out, contact_sheet(recording, columns=args.columns))
    print(f"wrote {out}")
    return 0
