"""`edge doctor`: try every part the way the service will, and print a checklist (exit 0 only when
all is well). It starts without numpy or OpenCV: the day they are broken it says so, runs the
checks that need neither, and names those it could not run."""

from __future__ import annotations

import argparse
from typing import Any

from edge.cli.common import add_config_options


def add_parser(sub: Any) -> None:
    p = sub.add_parser("doctor", help="check the computer, the rig's parts and the broker, one line each")
    add_config_options(p, example="camera.backend=picamera2")
    p.add_argument("--json", action="store_true", help="print the checklist as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import logging

    from edge.doctor import examine

    if not args.verbose:
        # The checks provoke what the parts log as warnings (a silent unit's retries): the
        # checklist says it once, in its own words.
        logging.getLogger().setLevel(logging.ERROR)
    result = examine(args.config, args.set)
    if args.json:
        print(result.json())
    else:
        kind = "simulated rig" if result.settings.all_simulated else "real parts: " + ", ".join(
            result.settings.real_parts)
        print(f"edge doctor: {result.settings.source} ({kind})")
        print(result.checks.text())
        print(f"edge doctor: {result.checks.summary()} ({result.elapsed_s:.1f} s)")
    return 0 if result.checks.ok else 1
