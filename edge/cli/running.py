"""`edge run` (the headless service) and `edge range` (its ranges, live from the broker)."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

from edge.cli.common import add_config_options, load, usage

log = logging.getLogger("edge")


def add_parsers(sub: Any) -> None:
    p = sub.add_parser("run", help="the headless service: run the configured mode with MQTT until stopped")
    add_config_options(p)
    p.add_argument("--for", dest="run_for", type=float, metavar="SECONDS",
                   help="stop cleanly after this long on the rig's clock (simulated seconds on a simulated rig)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("range", help="show the range finder's ranges live (from the broker)")
    add_config_options(p)
    p.add_argument("--device", help="device id (default: device.id, else this host's name)")
    p.add_argument("--count", type=int, help="stop after this many ranges")
    p.add_argument("--timeout", type=float, default=10.0, help="stop when nothing came for this long (s)")
    p.set_defaults(func=cmd_range)


def cmd_run(args: argparse.Namespace) -> int:
    """The headless service: the configured mode, MQTT, systemd notifications, until stopped."""
    from edge.service import Service

    if args.run_for is not None and args.run_for <= 0:
        raise usage("--for must be a positive number of seconds")
    config = load(args)
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

    seen = watch(load(args), args.device, args.count, args.timeout)
    return 0 if seen else 1
