"""Simulated laser wiring: gpiozero mock pins that remember when they changed, and what that meant
for the light.

The real lasers are switched through gpiozero; in the simulator the very same code drives a
``gpiozero.pins.mock.MockFactory`` whose pins are :class:`LaserPin`. Each pin logs every change of
its output with ``time.monotonic_ns()`` (absolute times, unlike ``MockPin.states``, which keeps
deltas), so that the simulated camera can ask :class:`LaserWiring` how much of each row's exposure
each laser was lit — a rolling shutter sees a switch mid-frame as a brightness step between rows.
"""

from __future__ import annotations

import mmap
import os
import threading
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from gpiozero.pins.mock import MockFactory, MockPin

from edge.errors import LaserError
from edge.rig import Laser

# A pin keeps at most this many changes; older ones are dropped (frames only look back a frame or
# two, and a long simulated run switches the lasers tens of times a second).
_MAX_LOG = 4096


class Wires:
    """The levels on the simulated wires, kept in a small file shared between processes.

    A real pin keeps driving its last level after the process that set it dies (SIGKILL, a
    watchdog kill): that is why systemd runs ``edge lasers off`` after the service stops. Mock pins
    live and die with their process, so a test could never see a laser left on by a killed
    process, nor a fresh process switch it off. With ``[lasers] sim_wires`` set, every simulated
    pin writes its level here (one byte per BCM number: 0 undriven, 1 low, 2 high), and a pin
    created in a later process starts from what the wire still carries. A shared memory map:
    a write is in the page cache the moment it is made, so even SIGKILL cannot lose it.
    """

    SIZE = 64  # BCM 0-53, rounded up
    _LEVELS = (None, False, True)  # by code: 0 undriven, 1 low, 2 high

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise LaserError(f"lasers.sim_wires: cannot open {self.path}: {exc.strerror}") from None
        try:
            size = os.fstat(fd).st_size
            if size == 0:
                os.ftruncate(fd, self.SIZE)
            elif size != self.SIZE:
                raise LaserError(
                    f"lasers.sim_wires: {self.path} is not a wires file ({size} bytes, expected {self.SIZE})")
            self._map = mmap.mmap(fd, self.SIZE)
        finally:
            os.close(fd)
        for code in self._map[:]:
            if code not in (0, 1, 2):
                self._map.close()
                raise LaserError(f"lasers.sim_wires: {self.path} is not a wires file (a byte is {code})")

    def level(self, bcm: int) -> bool | None:
        """What the wire of GPIO `bcm` carries: True high, False low, None undriven."""
        return self._LEVELS[self._map[bcm]]

    def levels(self) -> dict[int, bool | None]:
        """Every driven wire: BCM number → level."""
        return {bcm: self.level(bcm) for bcm in range(self.SIZE) if self._map[bcm]}

    def drive(self, bcm: int, level: bool | None) -> None:
        self._map[bcm] = self._LEVELS.index(level)


def _bcm(info) -> int | None:
    name = str(info.name)
    return int(name[4:]) if name.startswith("GPIO") and name[4:].isdigit() else None


class LaserPin(MockPin):
    """A mock pin that logs ``(t_ns, level)`` whenever what it drives changes.

    ``level`` is True/False while the pin is an output driving high/low, and None while it is an
    input (not driven: a closed device, or a pin never set up), which the wiring reads as dark.
    """

    def __init__(self, factory, info) -> None:
        self._log_lock = threading.Lock()
        self._log: list[tuple[int, bool | None]] = []
        super().__init__(factory, info)
        self._wires: Wires | None = getattr(factory, "wires", None)
        self._bcm = _bcm(info)
        if self._wires is not None and self._bcm is not None:
            level = self._wires.level(self._bcm)  # a wire left driven by an earlier process
            if level is not None:
                self._function, self._state = "output", level
        self._record()

    def _driven(self) -> bool | None:
        return bool(self._state) if self._function == "output" else None

    def _record(self) -> None:
        level = self._driven()
        t = time.monotonic_ns()
        if self._wires is not None and self._bcm is not None:
            self._wires.drive(self._bcm, level)
        with self._log_lock:
            if self._log and self._log[-1][1] == level:
                return
            self._log.append((t, level))
            if len(self._log) > _MAX_LOG:
                del self._log[: _MAX_LOG // 2]

    def _change_state(self, value):
        changed = super()._change_state(value)
        self._record()
        return changed

    def _set_function(self, value) -> None:
        super()._set_function(value)
        self._record()

    @property
    def log(self) -> list[tuple[int, bool | None]]:
        """A copy of the changes so far: ``(monotonic ns, True/False driven, None undriven)``."""
        with self._log_lock:
            return list(self._log)


class LaserFactory(MockFactory):
    """gpiozero's mock pin factory with :class:`LaserPin` pins, optionally on shared :class:`Wires`."""

    def __init__(self, wires: Wires | None = None) -> None:
        super().__init__(pin_class=LaserPin)
        self.wires = wires


def laser_factory(wires_file: str | os.PathLike | None = None) -> LaserFactory:
    """A mock pin factory for the simulated lasers; with `wires_file`, their levels outlive the
    process (see :class:`Wires`)."""
    return LaserFactory(Wires(wires_file) if wires_file else None)


class LaserWiring:
    """What the simulated lasers did, read from their pins: when and how long each was lit.

    A laser is lit while its pin drives its active level (high, or low for an active-low driver);
    the light follows the wire `settle_ns` later (driver and diode), and an undriven pin (input
    mode, e.g. after ``close()``) is dark — the driver's pull resistor holds it off.
    """

    def __init__(self, lasers: Iterable[Laser], factory: MockFactory, settle_ns: int = 0,
                 broken: dict[str, str] | None = None) -> None:
        self.settle_ns = int(settle_ns)
        self.broken = dict(broken or {})  # laser name → "dead" or "stuck" (simulated faults)
        self._pins: dict[str, tuple[LaserPin, bool]] = {}
        for laser in lasers:
            if laser.pin is None:
                continue  # no wire: never lit
            pin = factory.pin(laser.pin)
            if not isinstance(pin, LaserPin):
                raise TypeError(
                    f"laser {laser.name!r}: GPIO{laser.pin} is a {type(pin).__name__}, not a LaserPin; "
                    "open the simulated lasers on edge.sim.gpio.laser_factory()"
                )
            self._pins[laser.name] = (pin, laser.active_high)
        self.names = tuple(self._pins)

    def _lit_steps(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Times (ns, int64, already shifted by the settle time) where the light changes, and 0/1
        lit values from each of those times on; before the first time the laser is dark."""
        pin, active_high = self._pins[name]
        log = pin.log
        times = np.array([t for t, _ in log], dtype=np.int64) + self.settle_ns
        lit = np.array([lvl is not None and lvl == active_high for _, lvl in log], dtype=np.float64)
        return times, lit

    def row_fractions(self, row_t0: np.ndarray, exposure_ns: int) -> dict[str, np.ndarray]:
        """For each laser, the fraction of [t0, t0 + exposure] it was lit, per entry of `row_t0`
        (monotonic ns; e.g. each row's exposure start under a rolling shutter)."""
        t0 = np.asarray(row_t0, dtype=np.int64)
        out: dict[str, np.ndarray] = {}
        for name in self._pins:
            times, lit = self._lit_steps(name)
            if exposure_ns <= 0:
                k = np.searchsorted(times, t0, side="right") - 1
                out[name] = np.where(k >= 0, lit[np.maximum(k, 0)], 0.0)
                continue
            # Integrate the step function: cumulative lit time at each change, then interpolate.
            # Times relative to the first change keep the arithmetic exact in float64.
            origin = int(times[0]) if len(times) else 0
            rel = (times - origin).astype(np.float64)
            cum = np.concatenate([[0.0], np.cumsum(lit[:-1] * np.diff(rel))])
            until_end = _lit_time_until(t0 + exposure_ns, origin, rel, cum, lit)
            frac = (until_end - _lit_time_until(t0, origin, rel, cum, lit)) / float(exposure_ns)
            out[name] = np.clip(frac, 0.0, 1.0)
        # A broken laser ignores its wire: a dead diode never lights, a shorted driver never stops.
        for name, kind in self.broken.items():
            if name in out:
                out[name] = np.full(t0.shape, 1.0 if kind == "stuck" else 0.0)
        return out

    def fractions(self, t0_ns: int, t1_ns: int) -> dict[str, float]:
        """For each laser, the fraction of [t0, t1] it was lit (its state at t0 when t1 == t0)."""
        rows = self.row_fractions(np.array([t0_ns], dtype=np.int64), int(t1_ns) - int(t0_ns))
        return {name: float(v[0]) for name, v in rows.items()}

    def lit_at(self, t_ns: int) -> frozenset[str]:
        """The lasers whose light was on at `t_ns`."""
        return frozenset(n for n, f in self.fractions(t_ns, t_ns).items() if f > 0.5)


def _lit_time_until(t: np.ndarray, origin: int, rel: np.ndarray, cum: np.ndarray, lit: np.ndarray) -> np.ndarray:
    """Lit time from the first change to each of `t`: `cum` (the cumulative lit time at each change,
    at times `rel` after `origin`) plus the lit part since the last change before it."""
    tr = (t - origin).astype(np.float64)
    k = np.searchsorted(rel, tr, side="right") - 1
    kk = np.maximum(k, 0)
    return np.where(k >= 0, cum[kk] + lit[kk] * (tr - rel[kk]), 0.0)
