"""The rig's clock: real time on a device, simulated time for a virtual rig.

Everything that refers to the rig's time reads one :class:`Clock`: frame times, exposures and the
rolling shutter, laser switches and their settling, the pan-tilt unit's motion, the scene's movers,
the laser watchdog, the blind aid's sound, and the service's intervals (``--for``, sweep times).

- :data:`REAL` is ``time.monotonic_ns()``: a device, and the simulator under ``sim.clock = "real"``.
- :class:`SimClock` is simulated time. It stands still while the computer works (rendering a frame,
  ranging it) and jumps when the rig waits (for the next frame, for a move to end, for a laser to
  settle). A simulated run is then a function of its configuration and seed alone, on any machine
  and under any load, and it runs as fast as the computer can render: faster than real time where a
  frame costs less than a frame period, slower, without distortion, where it costs more.
  ``paced=True`` keeps it from running ahead of real time (``sim.clock = "paced"``): for a person
  or a tool that talks to the simulated device live, e.g. carrying the calibration board of the
  ``bench`` scene while ``edge calibrate`` runs; it may still fall behind, without distortion.
  ``pace`` lets it run that many times faster than real time, at most.

Waiting is the one thing that moves simulated time, so the rig's parts wait through the clock:
``sleep_until_ns``/``sleep`` to wait for the rig, :meth:`Clock.timer` for what happens at a time
whoever waits (the laser watchdog, the sound's ticks, ``--for``), and :meth:`Clock.idle` for a loop
that has nothing to do but wait for a person or a broker — that wait stays in real time under both
clocks (a paused simulated device must not run through its ``--for`` before a command can reach
it). A :class:`SimClock`'s timers fire in the thread that moves time past them, in time order, and
the time reads theirs while they run: a watchdog cuts a laser at exactly its limit, never late.

Light: the eye-safety path (``edge lasers off``) imports this.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable
from typing import Protocol

log = logging.getLogger(__name__)

# Where simulated time starts (ns): any fixed value makes runs repeatable; a large one keeps "a time
# before the rig started" positive, as on the monotonic clock.
SIM_START_NS = 1_000_000_000_000


class Timer(Protocol):
    """Calls its function once at the time it is armed for (re-arm it from the function for more)."""

    def arm(self, t_ns: int) -> None:
        """Call at `t_ns` (now if that has passed); replaces an earlier arming."""

    def disarm(self) -> None:
        """Do not call (until armed again)."""

    def close(self) -> None:
        """Never call again; idempotent."""


class Clock(Protocol):
    simulated: bool

    def now_ns(self) -> int: ...

    def sleep_until_ns(self, t_ns: int) -> None: ...

    def sleep(self, seconds: float) -> None: ...

    def idle(self, event: threading.Event, seconds: float) -> bool:
        """Wait up to `seconds` of real time for `event` (a command, a stop); whether it is set."""

    def timer(self, fn: Callable[[], None], name: str) -> Timer: ...


class RealClock:
    """The monotonic clock; a timer is a thread of its own (an eye-safety timer must not wait
    behind a sound card)."""

    simulated = False

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep_until_ns(self, t_ns: int) -> None:
        while (left := t_ns - time.monotonic_ns()) > 0:
            time.sleep(left / 1e9)

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def idle(self, event: threading.Event, seconds: float) -> bool:
        return event.wait(max(seconds, 0.0))

    def timer(self, fn: Callable[[], None], name: str) -> Timer:
        return _ThreadTimer(fn, name)


REAL = RealClock()


class _ThreadTimer:
    """A thread, started at the first arming, that sleeps until the armed time and calls."""

    def __init__(self, fn: Callable[[], None], name: str) -> None:
        self._fn = fn
        self._name = name
        self._cond = threading.Condition()
        self._due: int | None = None
        self._closed = False
        self._thread: threading.Thread | None = None

    def arm(self, t_ns: int) -> None:
        with self._cond:
            if self._closed:
                return
            self._due = int(t_ns)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
                self._thread.start()
            self._cond.notify_all()

    def disarm(self) -> None:
        with self._cond:
            self._due = None
            self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._due = None
            self._cond.notify_all()
            thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed:
                    if self._due is None:
                        self._cond.wait()
                        continue
                    left = self._due - time.monotonic_ns()
                    if left <= 0:
                        break
                    self._cond.wait(left / 1e9)
                if self._closed:
                    return
                self._due = None
            _call(self._fn, self._name)


def _call(fn: Callable[[], None], name: str) -> None:
    try:
        fn()
    except Exception:  # a timer's failure is its owner's to report; the clock keeps going
        log.exception("%s: timer failed", name)


class SimClock:
    """Simulated time (see the module notes). Thread-safe: any thread may wait; waits move time
    forward (never back), one at a time, firing the timers they pass in order."""

    simulated = True

    def __init__(self, start_ns: int = SIM_START_NS, paced: bool = False, pace: float = 1.0) -> None:
        if not pace > 0:
            raise ValueError(f"pace must be positive, not {pace}")
        self._now = int(start_ns)
        self._start = int(start_ns)
        self.paced = paced
        self.pace = float(pace)
        self._wall_start = time.monotonic_ns()
        self._lock = threading.Lock()  # the time and the timers
        # One mover at a time; re-entrant, as a timer's function may itself wait.
        self._moving = threading.RLock()
        self._timers: list[tuple[int, int, _SimTimer, int]] = []  # (due, order, timer, arming)
        self._order = itertools.count()

    def now_ns(self) -> int:
        return self._now

    def sleep_until_ns(self, t_ns: int) -> None:
        with self._moving:
            if self.paced:  # not ahead of real time
                ahead = (int(t_ns) - self._start) / self.pace - (time.monotonic_ns() - self._wall_start)
                if ahead > 0:
                    time.sleep(ahead / 1e9)
            while True:
                with self._lock:
                    due = self._next_due(int(t_ns))
                    if due is None:
                        self._now = max(self._now, int(t_ns))
                        return
                    t, timer = due
                    self._now = max(self._now, t)
                    timer.due = None
                _call(timer.fn, timer.name)

    def sleep(self, seconds: float) -> None:
        self.sleep_until_ns(self._now + max(round(seconds * 1e9), 0))

    def idle(self, event: threading.Event, seconds: float) -> bool:
        began = time.monotonic_ns()
        set_ = event.wait(max(seconds, 0.0))
        self.sleep(min((time.monotonic_ns() - began) / 1e9, max(seconds, 0.0)))
        return set_

    def timer(self, fn: Callable[[], None], name: str) -> Timer:
        return _SimTimer(self, fn, name)

    def _next_due(self, until_ns: int) -> tuple[int, _SimTimer] | None:
        """The earliest live timer due by `until_ns` (under the lock), dropping stale armings."""
        while self._timers:
            t, _, timer, arming = self._timers[0]
            if timer.arming != arming or timer.due is None:
                heapq.heappop(self._timers)
                continue
            if t > until_ns:
                return None
            heapq.heappop(self._timers)
            return t, timer
        return None

    def _arm(self, timer: _SimTimer, t_ns: int) -> None:
        with self._lock:
            timer.arming += 1
            timer.due = max(int(t_ns), self._now)
            heapq.heappush(self._timers, (timer.due, next(self._order), timer, timer.arming))

    def _disarm(self, timer: _SimTimer) -> None:
        with self._lock:
            timer.due = None


class _SimTimer:
    def __init__(self, clock: SimClock, fn: Callable[[], None], name: str) -> None:
        self.clock = clock
        self.fn = fn
        self.name = name
        self.due: int | None = None
        self.arming = 0
        self.closed = False

    def arm(self, t_ns: int) -> None:
        if not self.closed:
            self.clock._arm(self, t_ns)

    def disarm(self) -> None:
        self.clock._disarm(self)

    def close(self) -> None:
        self.closed = True
        self.clock._disarm(self)
