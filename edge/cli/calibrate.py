"""`edge calibrate`: fit the laser rays from a recording of a flat target, or have a running device
calibrate itself over MQTT. The work is in :mod:`edge.calibration`; it is imported only when the
command runs (the fit needs OpenCV, which the other commands must not wait for)."""

from __future__ import annotations

import argparse
from typing import Any

from edge.cli.common import add_config_options


def add_parser(sub: Any) -> None:
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
    add_config_options(p, example='mqtt.host="broker"')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from edge.calibration.fit import run as calibrate

    return calibrate(args)
