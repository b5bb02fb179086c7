"""The `edge` command: thin wrappers around the library.

Exit status: 0 success, 1 runtime failure, 2 usage or configuration error. Every expected failure
is one line on stderr (``edge: <what, where, what to do>``), never a traceback; logs go to stderr.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

from edge import __version__
from edge.errors import EdgeError

log = logging.getLogger("edge")


class _Parser(argparse.ArgumentParser):
    """argparse that says `edge: …` in one line and exits 2, as every other error does."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", help="configuration file (default: config/sim.toml)")
    p.add_argument(
        "--set",
        metavar="KEY=VALUE",
        action="append",
        default=[],
        help="change one configuration key, e.g. --set sim.scene=kitchen (repeatable)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log debug messages")


def _config(args: argparse.Namespace):
    from edge.config import load_config

    return load_config(args.config, args.set)


def _progress(label: str):
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
            raise _usage("--frames must be an even number >= 2 (laser-off/laser-on pairs)")
        pairs = args.frames // 2
    if args.zones is not None and args.zones < 1:
        raise _usage("--zones must be >= 1")
    started = time.monotonic()
    if args.target:
        from edge.sim.record import record_targets

        distances = _distances(args.target, "--target")
        out = record_targets(config, distances, Path(args.out), pairs, progress=_progress("recording"))
    else:
        out = record_sweep(config, Path(args.out), args.zones, pairs, _progress("recording"))
    print(f"wrote {out} in {time.monotonic() - started:.1f} s")
    return 0


def _distances(text: str, option: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise _usage(f"{option}: expected distances in metres separated by commas, e.g. 0.5,1,2") from None
    if not values or any(not (0.05 < v < 100.0) for v in values):
        raise _usage(f"{option}: each distance must be between 0.05 and 100 m, got {text!r}")
    return values


def cmd_sim_show(args: argparse.Namespace) -> int:
    from edge.contact import contact_sheet
    from edge.fsutil import write_png
    from edge.recording import read_recording

    recording = read_recording(args.recording)
    out = Path(args.out) if args.out else Path(args.recording) / "contact.png"
    write_png(out, contact_sheet(recording, columns=args.columns))
    print(f"wrote {out}")
    return 0


# Parts that make `edge demo` a simulation whatever the configuration file says.
_SIMULATED_PARTS = ('ptu.port="sim://"', 'camera.backend="sim"', 'lasers.backend="sim"')


def cmd_demo(args: argparse.Namespace) -> int:
    """A full sweep of the simulated office through the emulated pan-tilt unit on a pty, mock GPIO
    and the simulated camera on its frame clock; the table, the error against the room, the map."""
    from edge.config import load_config

    overrides = list(_SIMULATED_PARTS) + list(args.set)
    return _live_sweep(load_config(args.config, overrides), Path(args.out), None)


def cmd_sweep(args: argparse.Namespace) -> int:
    """One sweep on the configured rig: a table, the results as JSON and the map as a PNG."""
    return _live_sweep(_config(args), Path(args.out), None)


def cmd_record(args: argparse.Namespace) -> int:
    """One sweep on the configured rig, its frames saved as an edge-sweep/1 recording."""
    return _live_sweep(_config(args), Path(args.out), Path(args.recording))


def _live_sweep(config, out: Path, recording: Path | None) -> int:
    import contextlib

    from edge.fsutil import atomic_write_bytes, write_png
    from edge.mapping import draw_map, map_error, results_document
    from edge.recording import RecordingWriter
    from edge.replay import format_score, score_ranges
    from edge.sweep import run_configured_sweep

    started = time.monotonic()
    device = "sim" if config.camera.backend == "sim" else config.device.resolved_id()
    from edge.calibration.in_use import believed_rig

    # The recording keeps the rig it was ranged with, calibration included, so replay agrees.
    writer = RecordingWriter(recording, believed_rig(config).rig, device=device) if recording else None
    with writer or contextlib.nullcontext() as recorder:
        sweep = run_configured_sweep(config, _progress("sweep"), recorder=recorder)
    report = sweep.report
    truths = sweep.truth_ranges()
    if sweep.truths:
        print(format_score(score_ranges(report.results, truths)))
    else:
        for r in report.results:
            rng = f"{r.range_m:7.3f} m" if r.range_m is not None else "      -  "
            print(f"{r.index:4d} {r.pan_deg:9.3f} {r.status:<12} {rng} {r.detail}")
    ratio = report.duration_s / report.limit_s if report.limit_s else float("nan")
    print(f"sweep: {report.duration_s:.1f} s; the rig's limit {report.limit_s:.1f} s "
          f"(frames, moves and settling) — {ratio:.2f}× the limit; {report.faults} zones fault; "
          f"{report.dropped_frames} frames exposed across a laser switch, none used")
    error = map_error(report.results, truths) if sweep.truths else None
    if error is not None:
        print(f"map error against the true room: mean {100 * error.mean_rel:.2f} %, median "
              f"{100 * error.median_rel:.2f} %, max {100 * error.max_rel:.2f} % over {error.zones} zones")
    out.mkdir(parents=True, exist_ok=True)
    extra = {"duration_s": round(report.duration_s, 3), "limit_s": round(report.limit_s, 3),
             "dropped_frames": report.dropped_frames}
    if error is not None:
        extra["map_error"] = {"zones": error.zones, "mean_rel": round(error.mean_rel, 6),
                              "median_rel": round(error.median_rel, 6), "max_rel": round(error.max_rel, 6)}
    doc = results_document(report.results, **extra)
    if sweep.truths:
        for zone in doc["zones"]:
            zone["truth_range_m"] = (sweep.truths.get(zone["index"]) or {}).get("range_m")
    atomic_write_bytes(out / "sweep.json", json.dumps(doc, indent=1).encode())
    title = f"{config.sim.scene} (simulated)" if sweep.truths else device
    if error is not None:
        title += f"; mean error {100 * error.mean_rel:.2f} %"
    picture = draw_map(report.results, sweep.room, range_limit_m=config.rig.range_limits_m[1], title=title)
    write_png(out / "map.png", picture)
    print(f"results: {out / 'sweep.json'}; map: {out / 'map.png'}"
          + (f"; recording: {recording}" if recording else "")
          + f" ({time.monotonic() - started:.1f} s in all)")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    """The headless service: the configured mode, MQTT, systemd notifications, until stopped."""
    from edge.service import Service

    if args.run_for is not None and args.run_for <= 0:
        raise _usage("--for must be a positive number of seconds")
    config = _config(args)
    logging.getLogger().setLevel(logging.DEBUG if args.verbose else config.log_level.upper())
    _dump_threads_on_abort()
    return Service(config, run_for_s=args.run_for).run()


def _dump_threads_on_abort() -> None:
    """systemd's watchdog kills a stuck service with SIGABRT: have Python print every thread's
    stack to stderr first, so the journal says where the loop was stuck."""
    import faulthandler

    if faulthandler.is_enabled():
        return  # already (e.g. under pytest, which has its own)
    try:
        faulthandler.enable(file=sys.stderr, all_threads=True)
    except (AttributeError, ValueError, OSError):  # stderr without a file descriptor
        log.debug("no thread dump on abort: stderr has no file descriptor")


def cmd_range(args: argparse.Namespace) -> int:
    """Show the range finder's ranges live, from the broker."""
    from edge.monitor import watch

    seen = watch(_config(args), args.device, args.count, args.timeout)
    return 0 if seen else 1


def cmd_config(args: argparse.Namespace) -> int:
    config = _config(args)
    rig = config.rig.build()
    print(f"{config.source}: ok")
    print(f"  camera {rig.camera.width}x{rig.camera.height} fx={rig.camera.fx:g}")
    for laser in rig.lasers:
        ref = " (reference)" if laser is rig.reference else ""
        print(f"  laser {laser.name}: pin {laser.pin}{ref}")
    from edge.calibration.in_use import believed_rig

    print(f"  calibration: {believed_rig(config).health}")
    if not config.rig.calibration:  # the service also looks in its state folder
        print(f"  calibration of edge run: {believed_rig(config, service=True).health}")
    print(f"  sweep {len(config.sweep.poses())} zones, {config.sweep.pairs_per_zone} pairs each")
    print(f"  sim scene {config.sim.scene}")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from edge.recording import read_recording
    from edge.replay import Replayer, format_score, replay_document, score

    recording = read_recording(args.recording)
    rig = recording.rig
    if args.calibration:
        from edge.calibration.file import read_calibration

        rig = read_calibration(args.calibration).apply(rig)
    replayer = Replayer(rig, args.estimator, _config(args).ranging)
    results = list(replayer.zones(recording, _progress("ranging")))
    if args.json:
        json.dump(replay_document(recording, results), sys.stdout)
        sys.stdout.write("\n")
    else:
        print(format_score(score(recording, results)))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from edge import bench

    config = _config(args)
    run = {"render": bench.bench_render, "ranging": bench.bench_ranging, "blindaid": bench.bench_blindaid}[args.what]
    lines = run(config, **({"repeats": args.repeats} if args.repeats else {}))
    print("\n".join(lines))
    return 0


def _usage(message: str) -> EdgeError:
    from edge.errors import UsageError

    return UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="edge", description="Structured-light range finder on a pan-tilt unit.")
    parser.add_argument("--version", action="version", version=f"edge {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("demo", help="a full simulated sweep of the office: table, error against the room, map")
    _common(p)
    p.add_argument("--out", default="out/demo", help="folder for sweep.json and map.png (default: out/demo)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("run", help="the headless service: run the configured mode with MQTT until stopped")
    _common(p)
    p.add_argument("--for", dest="run_for", type=float, metavar="SECONDS",
                   help="stop cleanly after this long (for tests and trials)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("range", help="show the range finder's ranges live (from the broker)")
    _common(p)
    p.add_argument("--device", help="device id (default: device.id, else this host's name)")
    p.add_argument("--count", type=int, help="stop after this many ranges")
    p.add_argument("--timeout", type=float, default=10.0, help="stop when nothing came for this long (s)")
    p.set_defaults(func=cmd_range)

    p = sub.add_parser("config", help="check a configuration file and summarise it")
    _common(p)
    p.set_defaults(func=cmd_config)

    p = sub.add_parser("sweep", help="run one sweep on the configured rig (simulated by default)")
    _common(p)
    p.add_argument("--out", default="out/sweep", help="folder for sweep.json and map.png")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("record", help="run one sweep on the configured rig and save it as an edge-sweep/1 recording")
    _common(p)
    p.add_argument("recording", help="recording folder to write (must not exist, or be a recording)")
    p.add_argument("--out", default="out/record", help="folder for sweep.json and map.png")
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("replay", help="range a recorded sweep again")
    p.add_argument("recording", help="recording folder (edge-sweep/1)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--json", action="store_true", help="print the edge-ranges/1 document only")
    out.add_argument("--score", action="store_true", help="per-zone table and error summary against truth (default)")
    p.add_argument("--estimator", choices=["triangulate", "thesis"], default="triangulate")
    p.add_argument("--calibration", metavar="FILE", help="calibration file from edge calibrate")
    _common(p)
    p.set_defaults(func=cmd_replay)

    from edge.calibration import command as calibration
    from edge.hw import lasers, ptu

    calibration.add_parser(sub)
    ptu.add_parser(sub)
    lasers.add_parser(sub)

    p = sub.add_parser("bench", help="measure speed (prints figures, asserts nothing)")
    _common(p)
    p.add_argument("what", choices=["render", "ranging", "blindaid"], help="what to time")
    p.add_argument("--repeats", type=int, help="runs to take the median of")
    p.set_defaults(func=cmd_bench)

    sim = sub.add_parser("sim", help="the simulator").add_subparsers(
        dest="sim_command", required=True, parser_class=_Parser
    )
    p = sim.add_parser("record", help="write a simulated sweep as an edge-sweep/1 recording")
    _common(p)
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
    p.add_argument("-v", "--verbose", action="store_true")
    p.set_defaults(func=cmd_sim_show)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if getattr(args, "verbose", False) else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(args.func(args) or 0)
    except EdgeError as exc:
        print(f"edge: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("edge: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1
