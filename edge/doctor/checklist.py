"""The doctor's checklist: one line per check, each ``ok`` or what is wrong and what to do.

A check is a function that returns what it found (its line's detail) or raises what stopped it:
:class:`Problem` (something is wrong: the line fails, with a remedy), :class:`Skip` (the check does
not apply here: simulated parts need no device nodes), :class:`NotRun` (it could not be tried: a
package it needs cannot be imported, or the part it needs failed its own line). Anything else a
check raises is a failure too, never a traceback: the doctor is for the day things are broken.

Light on purpose (no numpy): ``edge doctor`` must start, and say what it could not check, when the
heavy packages are broken.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Literal

log = logging.getLogger(__name__)

Status = Literal["ok", "fail", "skip", "not run"]


class Problem(Exception):
    """What a check found wrong (`detail`) and what to do about it (`remedy`)."""

    def __init__(self, detail: str, remedy: str = "") -> None:
        super().__init__(detail)
        self.detail = detail
        self.remedy = remedy


class Skip(Exception):
    """The check does not apply to this rig (the reason is its detail)."""


class NotRun(Exception):
    """The check could not be tried (the reason is its detail): a missing package or a failed part."""


@dataclass(frozen=True)
class Line:
    check: str
    status: Status
    detail: str
    remedy: str = ""
    seconds: float = 0.0  # what the check took (wall time): a slow part shows here


@dataclass
class Checklist:
    """The lines so far, in the order the checks ran."""

    lines: list[Line] = field(default_factory=list)

    def run(self, name: str, check: Callable[[], str]) -> Line:
        """Run `check` and record its line."""
        started = time.monotonic()
        try:
            line = Line(name, "ok", check())
        except Problem as exc:
            line = Line(name, "fail", exc.detail, exc.remedy)
        except Skip as exc:
            line = Line(name, "skip", str(exc))
        except NotRun as exc:
            line = Line(name, "not run", str(exc))
        except Exception as exc:  # the doctor must report everything and carry on
            log.debug("check %s", name, exc_info=True)
            detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            line = Line(name, "fail", detail, "see `edge doctor -v` for where it came from")
        line = dataclasses.replace(line, seconds=round(time.monotonic() - started, 3))
        self.lines.append(line)
        return line

    def add(self, line: Line) -> Line:
        self.lines.append(line)
        return line

    def status(self, name: str) -> Status | None:
        return next((line.status for line in self.lines if line.check == name), None)

    @property
    def ok(self) -> bool:
        """All is well: nothing failed and nothing was left unchecked (a skip does not apply)."""
        return all(line.status in ("ok", "skip") for line in self.lines)

    def summary(self) -> str:
        failed = sum(line.status == "fail" for line in self.lines)
        not_run = [line.check for line in self.lines if line.status == "not run"]
        if self.ok:
            return f"all {len(self.lines)} checks ok"
        parts = []
        if failed:
            parts.append(f"{failed} of {len(self.lines)} checks failed")
        if not_run:
            parts.append(f"not run: {', '.join(not_run)}")
        return "; ".join(parts)

    def text(self) -> str:
        """The checklist for people: status, check, what was found; the remedy on the next line."""
        width = max((len(line.check) for line in self.lines), default=0)
        out = []
        for line in self.lines:
            mark = {"ok": "ok", "fail": "FAIL", "skip": "skip", "not run": "not run"}[line.status]
            out.append(f"{mark:<8} {line.check:<{width}}  {line.detail}")
            if line.remedy:
                out.append(f"{'':<8} {'':<{width}}  → {line.remedy}")
        return "\n".join(out)

    def json(self, **extra: object) -> str:
        return json.dumps({**extra, "ok": self.ok, "checks": [asdict(line) for line in self.lines]},
                          ensure_ascii=False)
