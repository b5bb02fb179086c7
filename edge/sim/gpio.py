"""Simulated laser pins: gpiozero mock pins that remember when they changed.

The real lasers are switched through gpiozero; in the simulator the very same code drives a
``gpiozero.pins.mock.MockFactory`` whose pins are :class:`LaserPin`. Each pin logs every change of
its output with the rig's clock (:mod:`edge.clock`; absolute times, unlike ``MockPin.states``,
which keeps deltas), so that the simulated camera can ask :class:`edge.sim.light.LaserLight` how much of each
row's exposure each laser was lit. Light on purpose (no numpy): ``edge lasers off`` on a simulated
rig loads this and nothing else of the simulator.
"""

from __future__ import annotations

import mmap
import os
import threading
from pathlib import Path

from gpiozero.pins.mock import MockFactory, MockPin

from edge.clock import REAL, Clock
from edge.errors import LaserError

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
        self._clock: Clock = getattr(factory, "clock", REAL)
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
        t = self._clock.now_ns()
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
        """A copy of the changes so far: ``(rig clock ns, True/False driven, None undriven)``."""
        with self._log_lock:
            return list(self._log)


class LaserFactory(MockFactory):
    """gpiozero's mock pin factory with :class:`LaserPin` pins, optionally on shared :class:`Wires`."""

    def __init__(self, wires: Wires | None = None, clock: Clock = REAL) -> None:
        super().__init__(pin_class=LaserPin)
        self.wires = wires
        self.clock = clock  # the pins' changes are timed on it


def laser_factory(wires_file: str | os.PathLike | None = None, clock: Clock = REAL) -> LaserFactory:
    """A mock pin factory for the simulated lasers, timed on `clock`; with `wires_file`, their
    levels outlive the process (see :class:`Wires`)."""
    return LaserFactory(Wires(wires_file) if wires_file else None, clock)
