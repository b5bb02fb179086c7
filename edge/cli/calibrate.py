"""`edge calibrate`: fit the laser rays from a recording of a flat target, check a calibration on
another such recording (``--check``), or have a running device calibrate itself over MQTT. The work
is in :mod:`edge.calibration` and :mod:`edge.monitor`; it is imported only when the command runs
(the fit needs OpenCV, which the other commands must not wait for)."""

from __future__ import annotations

import argparse
import json
from typing import Any

from edge.cli.common import add_config_options, distances, load
from edge.errors import CommandError, UsageError


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "calibrate", help="fit the laser rays from a flat target at known distances",
        description="Either fit a recording offline (--recording, --out), check a calibration on a "
                    "recording the fit did not use (--check, --calibration), or have a running device "
                    "calibrate itself through the broker while you carry the target (--device).")
    p.add_argument("--recording", metavar="DIR",
                   help="recording whose zone i shows a flat target squarely at distance i")
    p.add_argument("--distances", metavar="D1,D2,...", required=True,
                   help="target distances in metres from the optical centre, one per zone, e.g. 0.5,1,2")
    p.add_argument("--out", metavar="FILE", help="calibration file to write (JSON)")
    p.add_argument("--fit-focal", action="store_true",
                   help="also fit the focal length (laser origins then held at their nominal values)")
    p.add_argument("--check", metavar="RECORDING",
                   help="instead: range this recording (zone i: the target at distance i, not used by the fit) "
                        "with --calibration and print the range errors beside the predicted ones")
    p.add_argument("--calibration", metavar="FILE", help="the calibration file that --check checks")
    p.add_argument("--device", metavar="ID",
                   help="instead: send cmd/calibrate to this running device and follow it (broker from --config)")
    add_config_options(p, example='mqtt.host="broker"')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """`edge calibrate`: read, fit, write, report; or, with --device, over the broker."""
    targets = distances(args.distances, "--distances")
    if args.check is not None:
        if args.recording or args.out or args.fit_focal or args.device:
            raise UsageError("--check ranges a recording with --calibration: --recording, --out, --fit-focal "
                             "and --device are for a fit")
        if not args.calibration:
            raise UsageError("--check needs --calibration FILE: the calibration to check")
        return _check(args.check, targets, args.calibration)
    if args.calibration:
        raise UsageError("--calibration is for --check; a fit writes its calibration to --out")
    if args.device is not None:
        if args.recording or args.out or args.fit_focal:
            raise UsageError("--device calibrates a running device: --recording, --out and --fit-focal "
                             "are for a recording")
        from edge.commands import parse_command
        from edge.monitor import calibrate_device

        config = load(args)
        # The device would refuse what the command check refuses: say it here, before any wait.
        try:
            parse_command("calibrate", json.dumps({"distances_m": targets}).encode(),
                          max_bytes=config.mqtt.max_payload_bytes, pan_limits=(-180.0, 180.0),
                          tilt_limits=(-90.0, 90.0))
        except CommandError as exc:
            raise UsageError(f"--distances: {str(exc).removeprefix('cmd/calibrate: ')}") from None
        return calibrate_device(config, args.device, targets)
    if not args.recording or not args.out:
        raise UsageError("give --recording and --out (a fit of a recording), or --device (a running device)")
    from edge.calibration.file import write_calibration
    from edge.calibration.fit import fit_calibration
    from edge.calibration.report import report
    from edge.fsutil import check_output
    from edge.recording import read_recording

    check_output(args.out, "--out", error=UsageError)  # before the fit, not after it
    recording = read_recording(args.recording)
    cal = fit_calibration(recording, targets, fit_focal=args.fit_focal)
    write_calibration(args.out, cal)
    print("\n".join(report(cal, recording.rig)))
    print(f"wrote {args.out}")
    return 0


def _check(recording_dir: str, targets: list[float], calibration: str) -> int:
    """`edge calibrate --check`: range each laser's spot in each zone with the calibration."""
    from edge.calibration.check import check_calibration, check_lines
    from edge.calibration.file import read_calibration
    from edge.recording import read_recording

    cal = read_calibration(calibration)
    recording = read_recording(recording_dir)
    zones = check_calibration(recording, targets, cal)
    print(f"{calibration} on {recording_dir}: each laser's range error in mm (measured − tape) by distance")
    print("\n".join(check_lines(zones, cal)))
    return 0
