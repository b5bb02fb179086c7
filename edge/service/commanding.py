"""Commands in, results out: each command is checked (`edge.commands`), carried out by its handler
and answered on ``cmd/<name>/result``, ok or not, with the request id it came with."""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable, Mapping

from edge.commands import Command, label, parse_command, request_id_of
from edge.errors import CommandError, EdgeError

log = logging.getLogger(__name__)

Limits = tuple[tuple[float, float], tuple[float, float]]  # (pan, tilt) (min, max) in degrees
# (name, ok, error, request id)
PublishResult = Callable[[str, bool, "str | None", "str | None"], None]


class Later:
    """What a handler returns when its result comes later (cmd/calibrate, at the end)."""


LATER = Later()
# A handler returns None when done, why it failed, or LATER.
Handler = Callable[[Command], "str | Later | None"]


class Dispatcher:
    """Routes each command to its handler in `handlers`; `limits()` gives the unit's reach
    (which cmd/point is checked against) and `max_bytes` the largest payload taken."""

    def __init__(self, handlers: Mapping[str, Handler], publish_result: PublishResult,
                 limits: Callable[[], Limits], max_bytes: int) -> None:
        self.handlers = handlers
        self._publish_result = publish_result
        self._limits = limits
        self._max_bytes = max_bytes

    def handle(self, name: str, payload: bytes) -> None:
        """Validate and carry out one command; every command gets a result, ok or not (a LATER
        one when its handler gives it)."""
        (pan, tilt) = self._limits()
        try:
            command = parse_command(name, payload, max_bytes=self._max_bytes, pan_limits=pan, tilt_limits=tilt)
        except CommandError as exc:
            log.warning("command %s refused: %s", label(name), exc)
            self._publish_result(name, False, str(exc), request_id_of(payload))
            return
        try:
            error = self.handlers[command.name](command)
        except EdgeError as exc:
            error = str(exc)
        except Exception as exc:  # noqa: BLE001 - a bug; the sender still gets an answer
            log.exception("command %s failed", name)
            error = f"cmd/{name} failed: internal error ({type(exc).__name__}); see the device's log"
        if isinstance(error, Later):
            log.info("command %s started", name)
            return
        if error:
            log.warning("command %s failed: %s", name, error)
        else:
            log.info("command %s done", name)
        self._publish_result(name, error is None, error, command.request_id)


class CommandQueue:
    """Commands taken from the link (`receive()`) and carried out one by one by `handle`, with
    `progressed()` (the watchdog's food) after each. Once a turn has spent `budget_s` on them, the
    rest wait for the next turn: a burst of slow cmd/point must not starve the mode, nor hold off a
    stop. New commands are taken only when the last ones are done, so that the link's bounded
    queue stays the bound (beyond it the link refuses them). Nothing a sender can send escapes."""

    def __init__(self, receive: Callable[[], list[tuple[str, bytes]]], handle: Callable[[str, bytes], None],
                 progressed: Callable[[], None], budget_s: float = 0.25) -> None:
        self._receive = receive
        self._handle = handle
        self._progressed = progressed
        self._budget_s = budget_s
        self._pending: deque[tuple[str, bytes]] = deque()

    def handle(self, name: str, payload: bytes) -> None:
        """Carry out one command; whatever escapes its handling is logged, never raised."""
        try:
            self._handle(name, payload)
        except Exception:  # noqa: BLE001 - the name and payload came from outside
            log.exception("command %s: failed; the service goes on", label(name))

    def run(self, stopping: Callable[[], bool]) -> None:
        """A turn's worth of the commands received."""
        if not self._pending:
            self._pending.extend(self._receive())
        began = time.monotonic()
        while self._pending and not stopping():
            self.handle(*self._pending.popleft())
            self._progressed()
            if time.monotonic() - began >= self._budget_s:
                break
