"""Driver for a Directed Perception / FLIR PTU-D46 pan-tilt unit on a serial line (``PanTilt``).

Protocol notes (ASCII; a command ends with a space; a reply is one line starting with ``*`` for
success or ``!`` for an error) and the traps this driver is built around:

- The unit powers up with echo ON and VERBOSE replies. ``initialise()`` discards whatever is
  pending, sends ``ED`` (its own echo still comes back: ``ED *``) and ``FT``, and from then on
  expects terse replies (``* 1234``) without echo. An echo or a worded reply later means the unit
  was reset or power-cycled (position lost, speeds back to defaults): the driver logs it,
  re-initialises and repeats the command; a move repeats the whole move.
- Resolution (``PR``/``TR``) is a real number of arc-seconds per position (185.1428 on a D46-17):
  never parse it as an int. Degrees become positions by ``round()``, not truncation.
- Asynchronous limit notices ``!P``/``!T`` arrive unrequested, alone or glued in front of a later
  reply (``!P* 1234``); they are logged as warnings and stripped. ``! <words>`` is an error.
- Replies are read to their line end, never by byte count, and every read has a deadline. A missing
  or garbled reply re-synchronises the line (flush, blank line, wait for silence) and repeats the
  command, at most twice more, pausing longer each time: every command is idempotent (absolute
  positions, settings, queries), so a repeat is safe.
- ``A`` (await) answers only when the move has ended: its deadline follows from the distance
  (trapezoidal profile time × 1.5 plus the reply timeout), never a constant.
- The unit's speed bounds (``PL``/``PU``) are checked against ``ptu.speed_deg_s``: a speed out of
  range is refused, not clamped, so that the configuration says what the head does.
- One lock covers each exchange, and ``A`` is one exchange: while a move is awaited, other threads'
  commands (``position()``, ``halt()``) wait for it, as the unit's own parser would make them.
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from edge.clock import REAL, Clock
from edge.errors import PtuError
from edge.schema import require

log = logging.getLogger(__name__)

TRIES = 3  # one command and at most two repeats
_NOTICES = re.compile(r"^((?:![PT])+)(?=[*!]|$)")
_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")
_POLL_S = 0.02  # serial read granularity; deadlines are kept by the loops around it
_NOTICE = "!notice"  # _classify's answer for a line that held nothing but limit notices


@dataclass(frozen=True)
class PtuConfig:
    """The pan-tilt unit (``[ptu]``): a PTU-D46 on a serial port, or ``sim://`` for the emulator."""

    port: str = "sim://"
    baudrate: int = 9600
    timeout_s: float = 0.5  # for one reply; moves wait as long as their distance needs
    speed_deg_s: float = 60.0
    accel_deg_s2: float = 240.0
    settle_ms: float = 30.0  # let the head stop ringing before a frame is taken

    def __post_init__(self) -> None:
        require(self.baudrate in (600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200),
                "baudrate", f"not a PTU-D46 baud rate: {self.baudrate}")
        require(self.timeout_s > 0, "timeout_s", "must be positive")
        require(self.speed_deg_s > 0, "speed_deg_s", "must be positive")
        require(self.accel_deg_s2 > 0, "accel_deg_s2", "must be positive")
        require(self.settle_ms >= 0, "settle_ms", "must be >= 0")


def _deg(angle: float) -> str:
    """An angle with as many decimals as a position step needs (0.0514°: five), no trailing 0s."""
    return f"{angle:.5f}".rstrip("0").rstrip(".")


def trapezoid_s(distance: float, speed: float, accel: float) -> float:
    """Duration of a rest-to-rest move with a speed cap and a constant acceleration."""
    if distance <= 0:
        return 0.0
    if distance >= speed * speed / accel:
        return distance / speed + speed / accel
    return 2.0 * math.sqrt(distance / accel)


class _UnitReset(Exception):
    """Internal: the unit answers with echo or verbose words although it was set up otherwise."""


class PanTiltUnit:
    """A PTU-D46 behind the ``PanTilt`` interface: degrees in and out, positive pan left, tilt up."""

    def __init__(self, config: PtuConfig, ser: Any, on_close: Callable[[], None] | None = None,
                 clock: Clock = REAL) -> None:
        # The rig's clock, for the settling after a move; the line's timeouts are real time always.
        self.clock = clock
        self.config = config
        self._ser = ser
        self._ser.timeout = _POLL_S  # every read returns within this; our deadlines do the rest
        self.port = str(getattr(ser, "port", None) or getattr(ser, "name", "?"))
        self._lock = threading.RLock()  # one command/reply exchange at a time
        self._move_lock = threading.Lock()  # PP, TP, A of one move are not interleaved
        self._rx = bytearray()
        self._terse = False  # set once ED and FT were acknowledged
        self._ready = False  # set once initialise() went through: moves are allowed
        self._moving = False  # a move was commanded and not seen to end: close() halts
        self._pos: tuple[int, int] | None = None  # last known position (positions)
        self._on_close = on_close  # what lives and dies with the port (the emulator behind a pty)
        self.resets = 0  # how often the unit was found reset and re-initialised
        self.model = ""
        self.res_arcsec = (0.0, 0.0)
        self.limits = ((0, 0), (0, 0))  # (min, max) positions of pan and tilt
        self.speed_bounds = ((0, 0), (0, 0))  # (lower, upper) positions/s of pan and tilt

    @classmethod
    def open(cls, config: PtuConfig, initialise: bool = True,
             on_close: Callable[[], None] | None = None, clock: Clock = REAL) -> PanTiltUnit:
        """Open ``config.port`` with pyserial (any URL it knows: a device, a pty, ``loop://``).
        `on_close` runs when the unit is closed (or fails to open), after the port is closed."""
        import serial

        if config.port.startswith("sim://"):
            raise PtuError("ptu.port sim:// is the emulator: open it with edge.parts.open_ptu(config)")
        try:
            ser = serial.serial_for_url(config.port, config.baudrate, timeout=_POLL_S)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise PtuError(f"cannot open the pan-tilt unit's port {config.port}: {exc}; "
                                "check ptu.port and the cable") from None
        unit = cls(config, ser, on_close, clock)
        if initialise:
            try:
                unit.initialise()
            except BaseException:
                unit.close()
                raise
        return unit

    # ---- set-up ----

    def initialise(self) -> None:
        """Bring a unit in any state (power-up: echo on, verbose) to terse, no echo, our speeds."""
        with self._lock:
            self._configure()

    def _configure(self) -> None:
        self._terse = self._ready = False
        self._discard_pending()
        self._exchange("ED", recover=False)  # its echo still comes back: stripped by _classify
        self._exchange("FT", recover=False)
        self._terse = True
        self._exchange("I", recover=False)  # immediate mode: PP/TP start moving at once
        try:
            self.model = self._exchange("V", "text", recover=False)
        except PtuError as exc:  # older firmware may not know V; nothing depends on it
            log.debug("%s", exc)
            self.model = "(model unknown)"

        def q(cmd: str, kind: str = "int") -> str:
            return self._exchange(cmd, kind, recover=False)

        self.res_arcsec = (float(q("PR", "float")), float(q("TR", "float")))
        self.limits = ((int(q("PN")), int(q("PX"))), (int(q("TN")), int(q("TX"))))
        self.speed_bounds = ((int(q("PL")), int(q("PU"))), (int(q("TL")), int(q("TU"))))
        if min(self.res_arcsec) <= 0 or any(lo >= hi for lo, hi in self.limits):
            raise PtuError(f"pan-tilt unit on {self.port} reports nonsense (resolution "
                                f"{self.res_arcsec}, limits {self.limits}); reset it and retry")
        speed = self._per_axis(self.config.speed_deg_s)
        if not all(b[0] <= s <= b[1] for s, b in zip(speed, self.speed_bounds)):
            lo, hi = self.speed_range_deg_s
            raise PtuError(f"ptu.speed_deg_s = {self.config.speed_deg_s:g} °/s is outside what "
                                f"the pan-tilt unit allows ({lo:.2f}–{hi:.2f} °/s); set "
                                "ptu.speed_deg_s within that range")
        accel = self._per_axis(self.config.accel_deg_s2)
        for axis, s, a in zip("PT", speed, accel):
            q(f"{axis}S{s}", "ack")
            try:
                q(f"{axis}A{a}", "ack")
            except PtuError as exc:
                raise PtuError(f"{exc}; check ptu.accel_deg_s2") from None
        self._pos = (int(q("PP")), int(q("TP")))
        self._ready = True
        log.info("pan-tilt unit on %s: %s; %.4f″/position; at %s", self.port, self.model,
                 self.res_arcsec[0], self._pos)

    def _per_axis(self, deg: float) -> tuple[int, int]:
        rp, rt = self.resolution_deg
        return round(deg / rp), round(deg / rt)

    # ---- geometry ----

    @property
    def resolution_deg(self) -> tuple[float, float]:
        if self.res_arcsec[0] <= 0:
            raise self._not_ready()
        return self.res_arcsec[0] / 3600.0, self.res_arcsec[1] / 3600.0

    @property
    def limits_deg(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """((pan min, pan max), (tilt min, tilt max)) in degrees."""
        rp, rt = self.resolution_deg
        (pn, px), (tn, tx) = self.limits
        return (pn * rp, px * rp), (tn * rt, tx * rt)

    @property
    def speed_range_deg_s(self) -> tuple[float, float]:
        """The speeds both axes accept, °/s."""
        res = self.resolution_deg
        return (max(b[0] * r for b, r in zip(self.speed_bounds, res)),
                min(b[1] * r for b, r in zip(self.speed_bounds, res)))

    def to_positions(self, pan_deg: float, tilt_deg: float) -> tuple[int, int]:
        """Degrees → whole positions (rounded); HardwareError when outside the unit's limits."""
        if not self._ready:
            raise self._not_ready()
        rp, rt = self.resolution_deg
        target = (round(pan_deg / rp), round(tilt_deg / rt))
        for name, deg, pos, (lo, hi), r in zip(("pan", "tilt"), (pan_deg, tilt_deg), target,
                                               self.limits, (rp, rt)):
            if not lo <= pos <= hi:
                # Enough digits to be true: a limit of 179.99994° shown as 180.00° reads as if
                # 180° were allowed.
                raise PtuError(f"{name} {deg:g}° is outside the pan-tilt unit's limits "
                                    f"{_deg(lo * r)}°…{_deg(hi * r)}°; choose a {name} within them")
        return target

    def move_time_s(self, pan_from: float, tilt_from: float, pan_to: float, tilt_to: float) -> float:
        """Duration of a move with the configured speed and acceleration (the longer axis)."""
        v, a = self.config.speed_deg_s, self.config.accel_deg_s2
        return max(trapezoid_s(abs(pan_to - pan_from), v, a), trapezoid_s(abs(tilt_to - tilt_from), v, a))

    # ---- motion ----

    def move(self, pan_deg: float, tilt_deg: float) -> tuple[float, float]:
        """Go there, wait until the move has ended (plus ``settle_ms``), return where it is."""
        target = self.to_positions(pan_deg, tilt_deg)  # refuses before anything is sent
        with self._move_lock:
            for _ in range(2):
                resets = self.resets
                if self._pos is None:
                    self.position()
                assert self._pos is not None
                (rp, rt), (p0, t0) = self.resolution_deg, self._pos
                t_move = self.move_time_s(p0 * rp, t0 * rt, target[0] * rp, target[1] * rt)
                self._moving = True
                self._pos = None  # unknown until the move is seen to end
                # Every exchange costs a round trip (≈10 ms at 9600 baud): send only what changes.
                if target[0] != p0:
                    self._exchange(f"PP{target[0]}")
                if target[1] != t0:
                    self._exchange(f"TP{target[1]}")
                self._exchange("A", timeout=t_move * 1.5 + self.config.timeout_s)
                if self.resets == resets:
                    break
                # The unit was reset while moving: it is at 0 now, not at the target. Again.
                log.warning("pan-tilt unit on %s was reset during a move; moving again", self.port)
            else:
                raise PtuError(f"pan-tilt unit on {self.port} reset itself twice during one move; "
                                    "check its power supply")
            self._moving = False
            # The await answered: both axes are at the target (a stepper reports the position it
            # was sent to, so asking again would only cost two more round trips).
            self._pos = target
        if self.config.settle_ms > 0:
            self.clock.sleep(self.config.settle_ms / 1000.0)
        rp, rt = self.resolution_deg
        return target[0] * rp, target[1] * rt

    def home(self) -> tuple[float, float]:
        return self.move(0.0, 0.0)

    def halt(self) -> None:
        self._exchange("H")
        self._moving = False
        self._pos = None

    def position(self) -> tuple[float, float]:
        """Where the unit says it is now (degrees)."""
        with self._lock:
            self._pos = (int(self._exchange("PP", "int")), int(self._exchange("TP", "int")))
            rp, rt = self.resolution_deg
            return self._pos[0] * rp, self._pos[1] * rt

    def close(self) -> None:
        """Halt a move that was not seen to end, close the port, then run `on_close`."""
        try:
            if self._moving and self._terse and self._ser.is_open:
                try:  # one try only: a unit that does not answer must not hold up closing
                    self._exchange("H", tries=1)
                except PtuError as exc:
                    log.warning("%s", exc)
        finally:
            self._ser.close()
            on_close, self._on_close = self._on_close, None
            if on_close is not None:
                on_close()

    def __enter__(self) -> PanTiltUnit:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _not_ready(self) -> PtuError:
        return PtuError(f"pan-tilt unit on {self.port} is not initialised; call initialise() first")

    # ---- the line ----

    @property
    def retry_budget_s(self) -> float:
        """Worst case for one short exchange: three reply timeouts, two growing pauses, quiet waits."""
        t = self.config.timeout_s
        return TRIES * t + t * (1 + 2) + 2 * min(0.1, t) + 0.1

    def _exchange(self, cmd: str, kind: str = "ack", timeout: float | None = None, *,
                  recover: bool = True, tries: int = TRIES) -> str:
        """Send one command, return its reply's payload (after ``*``); see the module notes."""
        with self._lock:
            try:
                return self._transact(cmd, kind, timeout, tries)
            except _UnitReset:
                if not recover:
                    raise PtuError(f"pan-tilt unit on {self.port} was reset while being set up; "
                                        "call initialise() again") from None
            log.warning("pan-tilt unit on %s answers with echo or verbose replies: it was reset or "
                        "power-cycled (position lost); initialising it again", self.port)
            self._configure()
            self.resets += 1
            try:
                return self._transact(cmd, kind, timeout, tries)
            except _UnitReset:
                raise PtuError(f"pan-tilt unit on {self.port} keeps resetting; check its power "
                                    "supply, then call initialise()") from None

    def _transact(self, cmd: str, kind: str, timeout: float | None, tries: int) -> str:
        wait = timeout if timeout is not None else self.config.timeout_s
        started, garbled = time.monotonic(), ""
        for attempt in range(tries):
            if attempt:
                self._resync(attempt)
            else:
                self._discard_pending(quiet_s=0.0)
            self._io("write", cmd.encode("ascii") + b" ")
            deadline = time.monotonic() + wait
            while (line := self._read_line(deadline)) is not None:
                result = self._classify(cmd, line, kind)
                if result is None:
                    garbled = line
                    break
                if result is not _NOTICE:
                    return result
            what = f"garbled reply {garbled!r}" if line is not None else "no reply"
            log.warning("pan-tilt unit on %s: %s to %s (try %d of %d); re-synchronising",
                        self.port, what, cmd, attempt + 1, tries)
        spent = time.monotonic() - started
        if garbled:
            raise PtuError(f"pan-tilt unit on {self.port} gives garbled replies to {cmd} (last "
                                f"{garbled!r}); check ptu.baudrate and the cable")
        raise PtuError(f"pan-tilt unit on {self.port} does not answer (no reply to {cmd} in "
                            f"{tries} tries, {spent:.1f} s); check power and cable")

    def _classify(self, cmd: str, line: str, kind: str) -> str | None:
        """A reply's payload; ``_NOTICE`` for a lone limit notice; None for garbage."""
        echoed = line.startswith(cmd)
        if echoed:
            line = line[len(cmd):].lstrip()
        m = _NOTICES.match(line)
        if m:
            log.warning("pan-tilt unit on %s: limit notice %s (an axis hit its limit)", self.port, m.group(1))
            line = line[m.end():].lstrip()
            if not line:
                return _NOTICE
        if "\ufffd" in line or not line.isprintable() or line[:1] not in ("*", "!"):
            return None
        if echoed and self._terse:
            raise _UnitReset
        if line[0] == "!":
            raise PtuError(f"pan-tilt unit on {self.port} refused {cmd}: {line[1:].strip()}")
        payload = line[1:].strip()
        if kind not in ("int", "float"):
            return payload
        if self._terse and not _NUMBER.fullmatch(payload):
            if re.search(r"[A-Za-z]{3}", payload):
                raise _UnitReset  # verbose words where a terse number belongs
            return None
        found = _NUMBER.search(payload)  # verbose (only before FT): the number among the words
        return found.group(0) if found and (kind == "float" or "." not in found.group(0)) else None

    def _io(self, op: str, data: bytes = b"") -> Any:
        """One serial call; pyserial's SerialException/OSError become a one-line HardwareError."""
        try:
            if op == "write":
                return self._ser.write(data)
            waiting = int(self._ser.in_waiting)
            return waiting if op == "waiting" else self._ser.read(max(1, waiting))
        except Exception as exc:
            raise PtuError(f"pan-tilt unit port {self.port} failed: {exc}; check the cable") from None

    def _read_line(self, deadline: float) -> str | None:
        """The next non-empty line (CR or LF ends it), or None at the deadline."""
        while True:
            ends = [i for i in (self._rx.find(b"\r"), self._rx.find(b"\n")) if i >= 0]
            if ends:
                end = min(ends)
                text = self._rx[:end].decode("ascii", "replace").strip()
                del self._rx[: end + 1]
                if text:
                    log.debug("ptu %s ← %r", self.port, text)
                    return text
                continue
            if time.monotonic() >= deadline:
                return None
            self._rx += self._io("read")

    def _discard_pending(self, quiet_s: float = 0.1, pause_s: float = 0.0) -> None:
        """Drop what is pending; with ``quiet_s`` > 0 also wait until the line was quiet that long
        (and at least ``pause_s``), bounded so that a babbling line cannot hold us."""
        now = time.monotonic()
        until, last = now + pause_s, now
        give_up = until + max(1.0, 2 * self.config.timeout_s)
        while True:
            now = time.monotonic()
            if now >= give_up:
                break
            if self._io("waiting"):
                self._rx += self._io("read")
                last = time.monotonic()
                continue
            if quiet_s <= 0 or (now >= until and now - last >= quiet_s):
                break
            chunk = self._io("read")  # waits up to _POLL_S
            if chunk:
                self._rx += chunk
                last = time.monotonic()
        stale = self._rx.decode("ascii", "replace")
        self._rx.clear()
        for notice in re.findall(r"(?:![PT])+(?=[*!\s]|$)", stale):
            log.warning("pan-tilt unit on %s: limit notice %s (an axis hit its limit)", self.port, notice)
        if stale.strip():
            log.debug("ptu %s: discarded %r", self.port, stale)

    def _resync(self, attempt: int) -> None:
        """Forget the line's state: flush, end any half-received command, pause, drain."""
        self._rx.clear()
        try:
            self._ser.reset_input_buffer()
        except Exception:  # a serial-like object without it: the drain below does the job
            pass
        self._io("write", b"\r\n")
        # The pause grows with each try: a unit that is busy or rebooting gets time to come back.
        self._discard_pending(quiet_s=min(0.1, self.config.timeout_s),
                              pause_s=self.config.timeout_s * attempt)
