"""`edge demo`, `edge sweep`, `edge record`: one sweep on the rig, its table, results and map."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from edge.cli.common import add_config_options, load, progress

# Parts that make `edge demo` a simulation whatever the configuration file says.
_SIMULATED_PARTS = ('ptu.port="sim://"', 'camera.backend="sim"', 'lasers.backend="sim"')


def add_parsers(sub: Any) -> None:
    p = sub.add_parser("demo", help="a full simulated sweep of the office: table, error against the room, map")
    add_config_options(p)
    p.add_argument("--out", default="out/demo", help="folder for sweep.json and map.png (default: out/demo)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("sweep", help="run one sweep on the configured rig (simulated by default)")
    add_config_options(p)
    p.add_argument("--out", default="out/sweep", help="folder for sweep.json and map.png")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("record", help="run one sweep on the configured rig and save it as an edge-sweep/1 recording")
    add_config_options(p)
    p.add_argument("recording", help="recording folder to write (must not exist, or be a recording)")
    p.add_argument("--out", default="out/record", help="folder for sweep.json and map.png")
    p.set_defaults(func=cmd_record)


def cmd_demo(args: argparse.Namespace) -> int:
    """A full sweep of the simulated office through the emulated pan-tilt unit on a pty, mock GPIO
    and the simulated camera on its frame clock; the table, the error against the room, the map."""
    # Whatever the file says, a demo simulates (unless --set says otherwise).
    from edge.config import load_config

    config = load_config(args.config, [*_SIMULATED_PARTS, *args.set])
    return _live_sweep(config, Path(args.out), None)


def cmd_sweep(args: argparse.Namespace) -> int:
    """One sweep on the configured rig: a table, the results as JSON and the map as a PNG."""
    return _live_sweep(load(args), Path(args.out), None)


def cmd_record(args: argparse.Namespace) -> int:
    """One sweep on the configured rig, its frames saved as an edge-sweep/1 recording."""
    return _live_sweep(load(args), Path(args.out), Path(args.recording))


def _live_sweep(config, out: Path, recording: Path | None) -> int:
    import contextlib

    from edge.errors import UsageError
    from edge.fsutil import atomic_write_bytes, check_output
    from edge.mapping import map_error, results_document
    from edge.maps import MAP_FILES, build_map, write_map
    from edge.maps import Scan as MapScan
    from edge.recording import RecordingWriter, rig_to_json

    # Refused before the sweep, not after it: a folder of ours, a regular sweep.json and map files.
    check_output(out, "--out", folder=True, error=UsageError)
    for name in ("sweep.json", *MAP_FILES):
        check_output(out / name, "--out", error=UsageError)
    from edge.replay import format_score, score_ranges
    from edge.sweep import run_configured_sweep

    started = time.monotonic()
    device = "sim" if config.camera.backend == "sim" else config.device.resolved_id()
    from edge.calibration.in_use import believed_rig

    # The recording keeps the rig it was ranged with, calibration included, so replay agrees.
    rig = believed_rig(config).rig
    writer = RecordingWriter(recording, rig, device=device, frame_gamma=config.frames_gamma) if recording else None
    with writer or contextlib.nullcontext() as recorder:
        sweep = run_configured_sweep(config, progress("sweep"), recorder=recorder)
    report = sweep.report
    truths = sweep.truth_ranges()
    if sweep.truths:
        print(format_score(score_ranges(report.results, truths)))
    else:
        for r in report.results:
            rng = f"{r.range_m:7.3f} m" if r.range_m is not None else "      -  "
            print(f"{r.index:4d} {r.pan_deg:9.3f} {r.status:<12} {rng} {r.detail}")
    print(sweep_timing(report))
    error = map_error(report.results, truths) if sweep.truths else None
    if error is not None:
        print(f"map error against the true room: mean {100 * error.mean_rel:.2f} %, median "
              f"{100 * error.median_rel:.2f} %, max {100 * error.max_rel:.2f} % over {error.zones} zones")
    out.mkdir(parents=True, exist_ok=True)
    extra: dict[str, object] = {"duration_s": round(report.duration_s, 3), "limit_s": round(report.limit_s, 3),
                                "wall_s": round(report.wall_s, 3), "clock": "simulated" if report.simulated_time
                                else "real", "dropped_frames": report.dropped_frames}
    if error is not None:
        extra["map_error"] = {"zones": error.zones, "mean_rel": round(error.mean_rel, 6),
                              "median_rel": round(error.median_rel, 6), "max_rel": round(error.max_rel, 6)}
    extra["rig"] = rig_to_json(rig)  # what `edge map` needs to cast the rays again
    doc = results_document(report.results, **extra)
    if sweep.truths:
        for zone in doc["zones"]:
            zone["truth_range_m"] = (sweep.truths.get(zone["index"]) or {}).get("range_m")
    atomic_write_bytes(out / "sweep.json", json.dumps(doc, indent=1).encode())
    title = f"{config.sim.scene} (simulated)" if sweep.truths else device
    if error is not None:
        title += f"; mean error {100 * error.mean_rel:.2f} %"
    grid, cloud = build_map(config.map, [MapScan("sweep", rig, report.results)])
    write_map(out, grid, cloud, sweep.room, title)
    print(f"results: {out / 'sweep.json'}; map: {out / 'map.png'} (occupancy grid: map.pgm + map.yaml; "
          f"points: cloud.ply)"
          + (f"; recording: {recording}" if recording else "")
          + f" ({time.monotonic() - started:.1f} s in all)")
    return 0


def sweep_timing(report) -> str:
    """The sweep's time on the rig against its limit, and (on a simulated clock) the computer's
    time apart: what a real rig would take is the first, how fast this machine renders the second."""
    ratio = report.duration_s / report.limit_s if report.limit_s else float("nan")
    if report.simulated_time:
        took = (f"sweep: {report.duration_s:.1f} s of device time (simulated clock); the rig's limit "
                f"{report.limit_s:.1f} s (frames, moves and settling) — {ratio:.2f}× the limit; "
                f"{report.wall_s:.1f} s of wall time rendering it")
    else:
        took = (f"sweep: {report.duration_s:.1f} s; the rig's limit {report.limit_s:.1f} s "
                f"(frames, moves and settling) — {ratio:.2f}× the limit")
    return (f"{took}; {report.faults} zones fault; {report.dropped_frames} frames exposed across a "
            "laser switch, none used")
