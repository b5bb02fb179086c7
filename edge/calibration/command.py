"""``edge calibrate``: fit a recording of a flat target offline, or have a running device calibrate
itself through the broker. Command-line parsing only; the work is done by :mod:`.fit`,
:mod:`.file` and :mod:`edge.monitor`."""

from __future__ import annotations

import argparse
import json
from typing import Any

from edge.errors import CommandError, UsageError


def add_parser(sub: Any) -> None:
    """Register `edge calibrate` on an argparse sub-parsers object."""
    p = sub.add_parser(
        "calibrate", help="fit the laser rays from a flat target at known distances",
        description="Either fit a recording offline (--recording, --out), or have a running device "
                    "calibrate itself through the broker while you carry the target (--device).")
    p.add_argument("--recording", metavar="DIR",
                   help="recording whose zone i shows a flat target squarely at distance i")
    p.add_argument("--distances", metavar="D1,D2,...", required=True,
                   help="target distances in metres from the optical centre, one per zone, e.g. 0.5,1,2")
    p.add_argument("--out", metavar="FILE", help="calibration file to write (JSON)")
    p.add_argument("--fit-focal", action="store_true",
                   help="also fit the focal length (laser origins then held at their nominal values)")
    p.add_argument("--device", metavar="ID",
                   help="instead: send cmd/calibrate to this running device and follow it (broker from --config)")
    p.add_argument("--config", metavar="FILE",
                   help="configuration file, for --device's broker (default: config/sim.toml)")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                   help="change one configuration key, e.g. --set mqtt.host=\"broker\" (repeatable)")
    p.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    p.set_defaults(func=run)


def parse_distances(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values:
        raise UsageError(f"--distances: expected metres separated by commas, e.g. 0.5,1,2; got {text!r}")
    return values


def run(args: argparse.Namespace) -> int:
    """`edge calibrate`: read, fit, write, report; or, with --device, over the broker."""
    distances = parse_distances(args.distances)
    if args.device is not None:
        if args.recording or args.out or args.fit_focal:
            raise UsageError("--device calibrates a running device: --recording, --out and --fit-focal "
                             "are for a recording")
        from edge.commands import parse_command
        from edge.config import load_config
        from edge.monitor import calibrate_device

        config = load_config(args.config, args.set)
        # The device would refuse what the command check refuses: say it here, before any wait.
        try:
            parse_command("calibrate", json.dumps({"distances_m": distances}).encode(),
                          max_bytes=config.mqtt.max_payload_bytes, pan_limits=(-180.0, 180.0),
                          tilt_limits=(-90.0, 90.0))
        except CommandError as exc:
            raise UsageError(f"--distances: {str(exc).removeprefix('cmd/calibrate: ')}") from None
        return calibrate_device(config, args.device, distances)
    if not args.recording or not args.out:
        raise UsageError("give --recording and --out (a fit of a recording), or --device (a running device)")
    from edge.calibration.file import write_calibration
    from edge.calibration.fit import fit_calibration
    from edge.calibration.report import report
    from edge.recording import read_recording

    recording = read_recording(args.recording)
    cal = fit_calibration(recording, distances, fit_focal=args.fit_focal)
    write_calibration(args.out, cal)
    print("\n".join(report(cal, recording.rig)))
    print(f"wrote {args.out}")
    return 0
