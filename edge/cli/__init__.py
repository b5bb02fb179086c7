"""The `edge` command: thin wrappers around the library, one module per group of commands.

Exit status: 0 success, 1 runtime failure, 2 usage or configuration error. Every expected failure
is one line on stderr (``edge: <what, where, what to do>``), never a traceback; logs go to stderr.

Building the parser imports only the command modules, which import their work when they run: so
``edge lasers off`` (systemd's ExecStopPost, the eye-safety path) loads neither numpy nor OpenCV,
and works when they are broken.
"""

from __future__ import annotations

import logging
import sys

from edge import __version__
from edge.cli import calibrate, doctor, info, lasers, maps, ptu, recordings, running, sweeps
from edge.cli.common import Parser
from edge.errors import EdgeError


def build_parser() -> Parser:
    parser = Parser(prog="edge", description="Structured-light range finder on a pan-tilt unit.")
    parser.add_argument("--version", action="version", version=f"edge {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    sweeps.add_parsers(sub)  # demo, sweep, record
    running.add_parsers(sub)  # run, range
    info.add_parsers(sub)  # config, bench
    recordings.add_parsers(sub)  # replay, sim record|show
    maps.add_parser(sub)  # map
    calibrate.add_parser(sub)
    ptu.add_parser(sub)
    lasers.add_parser(sub)
    doctor.add_parser(sub)
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
