"""An emulated Directed Perception / FLIR PTU-D46-17 on a pseudo-terminal.

The emulator speaks the unit's ASCII protocol on the slave side of a pty (``Emulator.port``), so
the real driver (``edge.hw.ptu``) talks to it through pyserial exactly as it would to
``/dev/ttyUSB0``. A background thread serves the master side.

What it does like a real unit:

- Power-up state: echo ON (every received character is sent back as it arrives) and VERBOSE
  replies, speed 1000 and acceleration 2000 positions/s(²); a banner is printed.
- Commands end with a space, CR or LF; a blank line does nothing. Replies are one line ending in
  CR LF: ``*`` (plus a value in terse mode, e.g. ``* 1234``; or words in verbose mode, e.g.
  ``* Current Pan position is 1234``), or ``! <words>`` for an error. With echo on the echo and
  the reply share one line (``PP * Current Pan position is 0``), because the command's delimiter
  is a space.
- Resolution 185.1428″/position, pan −3090…3090, tilt −907…604 positions, speeds 57…2900
  positions/s. Each axis moves on the rig's clock (:mod:`edge.clock`) along a trapezoidal profile;
  position queries mid-move report where the axis is now. ``A`` answers only when both axes have
  stopped, and until then the command parser is blocked (later commands wait in the buffer), as on
  the unit. On a simulated clock the driver waiting for that answer is the rig waiting for its
  move: the emulator moves the clock to the move's end and answers at once.
- ``H`` halts, ``R`` recalibrates (echo on and verbose again, back at 0 after ``reset_s``).

Simplifications (traps if you compare with a real head): a new target mid-move replans from the
current position at rest (no blending of velocities); ``H`` stops at once instead of
decelerating; there is no slaved mode (``I`` is accepted and changes nothing); the serial line has
no baud-rate delay.

Faults for tests (``inject``): ``drop`` (swallow the next N replies), ``garble`` (corrupt the next
N replies' bytes: the high bit of every other byte, as line noise at a wrong baud rate looks),
``silence`` (no output at all for S seconds of real time — a fault of the line, which is real;
commands still execute), ``reset`` (power-cycled:
echo on, verbose, default speeds, position lost → 0, a pending await is lost, banner printed),
``hang`` (never answers again), ``notice`` (``!P`` glued in front of the next N replies, as the
unit's asynchronous limit notice arrives).
"""

from __future__ import annotations

import logging
import math
import os
import re
import select
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass

from edge.clock import REAL, Clock
from edge.hw.ptu import trapezoid_s

log = logging.getLogger(__name__)

RESOLUTION_ARCSEC = 185.1428  # PTU-D46-17
BANNER = (
    "Pan-Tilt Controller v2.12.6 (PTU-D46-17.5 emulated by edge)",
    "Initializing...",
)
_TOKEN = re.compile(rb"[ \r\n]*([^ \r\n]+)[ \r\n]")
_AXIS_CMD = re.compile(r"([PT])([RNXULSAPH])(-?\d+)?")
FAULTS = ("drop", "garble", "silence", "reset", "hang", "notice")


@dataclass
class _Axis:
    """One axis: limits, settings and the current trapezoidal move (positions, seconds)."""

    name: str  # "Pan" or "Tilt", as verbose replies say
    lo: int
    hi: int
    speed: int
    accel: int
    start: float = 0.0  # where the current move began
    target: float = 0.0
    t0: float = 0.0
    duration: float = 0.0

    def at(self, t: float) -> float:
        d = self.target - self.start
        tau = t - self.t0
        if tau >= self.duration or d == 0:
            return self.target
        s = math.copysign(1.0, d)
        dist, v, a, total = abs(d), float(self.speed), float(self.accel), self.duration
        ta = min(v / a, total / 2)  # a triangular profile never reaches v
        if tau < ta:
            x = 0.5 * a * tau * tau
        elif tau < total - ta:
            x = 0.5 * a * ta * ta + a * ta * (tau - ta)
        else:
            x = dist - 0.5 * a * (total - tau) ** 2
        return self.start + s * x

    def moving(self, t: float) -> bool:
        return t < self.t0 + self.duration

    def plan(self, target: int, t: float) -> None:
        self.start, self.target, self.t0 = self.at(t), float(target), t
        self.duration = trapezoid_s(abs(self.target - self.start), self.speed, self.accel)

    def stop(self, t: float, where: float | None = None) -> None:
        p = self.at(t) if where is None else where
        self.start = self.target = p
        self.duration = 0.0


class Emulator:
    """A PTU-D46-17 on a pseudo-terminal, served from a background thread until ``close()``."""

    def __init__(
        self,
        *,
        resolution_arcsec: float = RESOLUTION_ARCSEC,
        pan_limits: tuple[int, int] = (-3090, 3090),
        tilt_limits: tuple[int, int] = (-907, 604),
        speed_bounds: tuple[int, int] = (57, 2900),
        speed: int = 1000,
        accel: int = 2000,
        accel_max: int = 200_000,
        reset_s: float = 2.0,
        clock: Clock = REAL,
    ) -> None:
        self.clock = clock
        self.resolution_arcsec = resolution_arcsec
        self.speed_bounds = speed_bounds
        self.accel_max = accel_max
        self.reset_s = reset_s
        self._defaults = (speed, accel)
        self.pan = _Axis("Pan", *pan_limits, speed, accel)
        self.tilt = _Axis("Tilt", *tilt_limits, speed, accel)
        self.commands: deque[str] = deque(maxlen=2000)  # every command received, for tests
        self.echo = True
        self.verbose = True
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._pending: str | None = None  # "A" or "R": the parser waits for the motion to end
        self._reset_done = 0.0
        self._buf = bytearray()
        self._drop = self._garble = self._notices = 0
        self._silent_until = 0.0
        self._hung = False
        self._motion = (0.0, 0.0)  # start and end of the latest move (the clock's s)

        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no line discipline between the driver and us: bytes as sent
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._power_up(self._now())
        self._thread = threading.Thread(target=self._run, name=f"ptu-emulator {self.port}", daemon=True)
        self._thread.start()
        log.debug("PTU emulator serving %s", self.port)

    def _now(self) -> float:
        """The unit's time (s): the rig's clock, which its motion follows."""
        return self.clock.now_ns() / 1e9

    # ---- in-process API (the simulated camera, tests) ----

    def pose(self) -> tuple[float, float]:
        """(pan, tilt) in degrees at this instant, mid-move included (not rounded to positions)."""
        with self._lock:
            now = self._now()
            k = self.resolution_arcsec / 3600.0
            return self.pan.at(now) * k, self.tilt.at(now) * k

    def heading(self) -> tuple[float, float]:
        """Where the current move ends (degrees): equal to ``pose()`` once the unit is there."""
        with self._lock:
            k = self.resolution_arcsec / 3600.0
            return self.pan.target * k, self.tilt.target * k

    def positions(self) -> tuple[int, int]:
        """(pan, tilt) in whole positions, as a query would answer now."""
        with self._lock:
            now = self._now()
            return round(self.pan.at(now)), round(self.tilt.at(now))

    @property
    def moving(self) -> bool:
        with self._lock:
            now = self._now()
            return self.pan.moving(now) or self.tilt.moving(now) or self._pending == "R"

    @property
    def last_motion_s(self) -> float:
        """How long the latest move took (or takes) from its first command to both axes at rest."""
        with self._lock:
            return self._motion[1] - self._motion[0]

    def inject(self, mode: str, count: int = 1, seconds: float = 0.0) -> None:
        """Start a fault (see the module notes): ``count`` for drop/garble/notice, ``seconds`` for
        silence; reset and hang act at once."""
        if mode not in FAULTS:
            raise ValueError(f"unknown fault {mode!r} (known: {', '.join(FAULTS)})")
        with self._lock:
            now = self._now()
            if mode == "drop":
                self._drop += count
            elif mode == "garble":
                self._garble += count
            elif mode == "notice":
                self._notices += count
            elif mode == "silence":
                self._silent_until = time.monotonic() + seconds
            elif mode == "hang":
                self._hung = True
            else:
                self._power_up(now)
        log.debug("PTU emulator: fault %s injected", mode)

    def emit(self, data: bytes) -> None:
        """Send bytes unrequested (e.g. a lone ``!T`` limit notice), subject to the faults."""
        with self._lock:
            self._send(data)

    def clear_faults(self) -> None:
        with self._lock:
            self._drop = self._garble = self._notices = 0
            self._silent_until = 0.0
            self._hung = False

    def close(self) -> None:
        """Stop the thread and close both ends of the pty (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=2.0)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> Emulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- the unit ----

    def _power_up(self, now: float) -> None:
        """State after power-on (also the ``reset`` fault): whatever was going on is lost."""
        self.echo = self.verbose = True
        self._pending = None
        self._buf.clear()
        for axis in (self.pan, self.tilt):
            axis.speed, axis.accel = self._defaults
            axis.stop(now, 0.0)
        for line in BANNER:
            self._send(line.encode() + b"\r\n")

    def _run(self) -> None:
        while not self._stop.is_set():
            # Poll fast while an await is pending so that its reply follows the motion's end.
            wait = 0.005 if self._pending else 0.05
            try:
                ready, _, _ = select.select([self._master], [], [], wait)
            except (OSError, ValueError):
                return
            with self._lock:
                if ready:
                    try:
                        data = os.read(self._master, 4096)
                    except BlockingIOError:
                        data = b""
                    except OSError:
                        return
                    if data and not self._hung:
                        if self.echo:
                            self._send(data)
                        self._buf += data
                self._service(self._now())
                waits_for = self._waits_for() if self.clock.simulated else None
            if waits_for is not None:
                # The driver waits for the move's end: on a simulated clock that is the rig's
                # time passing (outside the lock: the camera reads the pose meanwhile).
                self.clock.sleep_until_ns(waits_for)
                with self._lock:
                    self._service(self._now())

    def _waits_for(self) -> int | None:
        """(Under the lock.) When the pending ``A`` or ``R`` will answer (clock ns), if one is."""
        if self._pending == "A":
            end = max(self.pan.t0 + self.pan.duration, self.tilt.t0 + self.tilt.duration)
        elif self._pending == "R":
            end = self._reset_done
        else:
            return None
        return math.ceil(end * 1e9) + 1  # a nanosecond past it: float seconds round

    def _service(self, now: float) -> None:
        if self._pending == "A" and not (self.pan.moving(now) or self.tilt.moving(now)):
            self._pending = None
            self._reply("*")
        elif self._pending == "R" and now >= self._reset_done:
            self._pending = None
            for axis in (self.pan, self.tilt):
                axis.stop(now, 0.0)
            self._reply("*")
        while self._pending is None:
            m = _TOKEN.match(self._buf)
            if m is None:
                if len(self._buf) > 256:  # no delimiter in sight: line noise, forget it
                    self._buf.clear()
                break
            token = m.group(1).decode("ascii", "replace").upper()  # before the buffer changes
            del self._buf[: m.end()]
            self.commands.append(token)
            self._execute(token, now)

    def _execute(self, cmd: str, now: float) -> None:
        simple = {"FT": ("verbose", False), "FV": ("verbose", True), "ED": ("echo", False),
                  "EE": ("echo", True)}
        if cmd in simple:
            setattr(self, *simple[cmd])
            return self._reply("*")
        if cmd == "A":
            if self.pan.moving(now) or self.tilt.moving(now):
                self._pending = "A"
                return None
            return self._reply("*")
        if cmd == "H":
            self.pan.stop(now)
            self.tilt.stop(now)
            return self._reply("*")
        if cmd == "I":
            return self._reply("*")
        if cmd == "V":
            return self._reply("* " + BANNER[0])
        if cmd == "R":
            self.echo = self.verbose = True
            for axis in (self.pan, self.tilt):
                axis.plan(0, now)
            self._pending = "R"
            self._reset_done = now + max(self.reset_s, self.pan.duration, self.tilt.duration)
            return None
        m = _AXIS_CMD.fullmatch(cmd)
        if m is None:
            return self._reply("! Illegal command")
        axis = self.pan if m.group(1) == "P" else self.tilt
        op, arg = m.group(2), m.group(3)
        if arg is not None and op not in "SAP":
            return self._reply("! Illegal argument")
        return self._axis_command(axis, op, None if arg is None else int(arg), now)

    def _axis_command(self, axis: _Axis, op: str, arg: int | None, now: float) -> None:
        n = axis.name
        if op == "H":
            axis.stop(now)
            return self._reply("*")
        if arg is None:
            queries = {
                "R": (f"{self.resolution_arcsec:.4f}", f"seconds arc per {n} position"),
                "N": (axis.lo, f"Minimum {n} position is"),
                "X": (axis.hi, f"Maximum {n} position is"),
                "L": (self.speed_bounds[0], f"Minimum {n} speed is"),
                "U": (self.speed_bounds[1], f"Maximum {n} speed is"),
                "S": (axis.speed, f"Current {n} speed is"),
                "A": (axis.accel, f"Current {n} acceleration is"),
                "P": (round(axis.at(now)), f"Current {n} position is"),
            }
            value, words = queries[op]
            if not self.verbose:
                return self._reply(f"* {value}")
            if op == "R":
                return self._reply(f"* {value} {words}")
            return self._reply(f"* {words} {value}")
        if op == "P":
            if not axis.lo <= arg <= axis.hi:
                return self._reply(f"! Illegal {n} position argument {arg} (limits {axis.lo} to {axis.hi})")
            if not (self.pan.moving(now) or self.tilt.moving(now)):
                self._motion = (now, now)
            axis.plan(arg, now)
            self._motion = (self._motion[0], max(self._motion[1], now + axis.duration))
        elif op == "S":
            lo, hi = self.speed_bounds
            if not lo <= arg <= hi:
                return self._reply(f"! Illegal {n} speed argument {arg} (bounds {lo} to {hi})")
            axis.speed = arg
        else:  # "A"
            if not 1 <= arg <= self.accel_max:
                return self._reply(f"! Illegal {n} acceleration argument {arg} (1 to {self.accel_max})")
            axis.accel = arg
        return self._reply("*")

    def _reply(self, text: str) -> None:
        if self._drop:
            self._drop -= 1
            log.debug("PTU emulator: dropped reply %r", text)
            return
        data = text.encode()
        if self._notices:
            self._notices -= 1
            data = b"!P" + data
        if self._garble:
            self._garble -= 1
            data = bytes(b | 0x80 if i % 2 == 0 else b for i, b in enumerate(data))
        self._send(data + b"\r\n")

    def _send(self, data: bytes) -> None:
        if self._hung or time.monotonic() < self._silent_until:
            return
        while data:
            try:
                written = os.write(self._master, data)
            except (BlockingIOError, OSError):
                # Nobody reads and the pty is full (or gone): drop it, as a UART overrun would.
                log.debug("PTU emulator: output dropped (%d bytes)", len(data))
                return
            data = data[written:]
