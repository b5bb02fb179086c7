"""The three laser pointers, switched by GPIO through gpiozero — and kept safe.

:class:`Lasers` drives one ``gpiozero.DigitalOutputDevice`` per laser. Everything here errs towards
*off*: the lasers are off at construction, on ``close()`` (idempotent, run at interpreter exit too,
and by ``with``), and a watchdog switches off any laser that has been on continuously for longer
than ``[lasers] max_on_s`` (eye safety: a hung sweep must not leave a beam on). Signals belong to
the service that owns the lasers; for everything that cannot run our ``close()`` — a crash, a
``kill -9``, systemd's ``ExecStopPost`` — :func:`force_all_off` drives every configured pin to its
off level from a fresh process, without needing any state (``edge lasers off``).

The driver never knows which backend it switches: it takes a gpiozero pin factory, as every
gpiozero device does. Without one it uses gpiozero's default (lgpio on a Pi;
``GPIOZERO_PIN_FACTORY`` chooses another); the composition root (:mod:`edge.parts`) passes the
simulator's mock factory for ``[lasers] backend = "sim"``. This module imports nothing heavy (no
numpy, no configuration loader): ``edge lasers off`` runs from it when everything else is broken.
"""

from __future__ import annotations

import atexit
import functools
import logging
import threading
import weakref
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from edge.clock import REAL, Clock
from edge.errors import ConfigError, LaserError
from edge.schema import build, require

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LaserWiring:
    """How one laser is switched: its BCM GPIO pin and the driver's polarity. Wiring, not geometry:
    where the beam points is :class:`edge.rig.Laser`'s business."""

    name: str
    pin: int | None = None  # BCM GPIO number; None: not wired (an error when the lasers open)
    active_high: bool = True  # False for a driver that lights the laser while its input is low

    def __post_init__(self) -> None:
        if self.pin is not None:
            require(0 <= self.pin <= 27, "pin", f"must be a BCM GPIO number 0-27, got {self.pin}")


# README's wiring of geometry.md's default rig.
DEFAULT_WIRING = (LaserWiring("center", 17), LaserWiring("parallel", 27), LaserWiring("sloped", 22))


def wiring_from_table(rig: dict[str, Any], source: str) -> tuple[LaserWiring, ...]:
    """The lasers' wiring from a config file's ``[rig]`` table as read (``[[rig.lasers]]``'s
    `name`, `pin`, `active_high`; the defaults when there are none), for the light commands that
    must not need the whole configuration: a mistake in a laser's geometry must not keep its pin
    from going off."""
    entries = rig.get("lasers")
    if entries is None:
        return DEFAULT_WIRING
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise ConfigError(f"{source}: rig.lasers: expected a list of tables ([[rig.lasers]])")
    return tuple(build(LaserWiring, {k: e[k] for k in ("name", "pin", "active_high") if k in e},
                       source, f"rig.lasers[{i}]") for i, e in enumerate(entries))


@dataclass(frozen=True)
class LasersConfig:
    """How the lasers are switched (``[lasers]``); pins and polarity are in ``[[rig.lasers]]``."""

    backend: Literal["sim", "gpio"] = "sim"  # gpio: gpiozero's default pin factory (lgpio on a Pi)
    max_on_s: float = 2.0  # eye safety: a laser on longer than this is switched off
    settle_ms: float = 1.0  # from the GPIO edge to full (or no) light: driver and diode
    # sim backend only: a file that keeps the simulated pins' levels after the process ends, as
    # real wires do (for testing `edge lasers off` after a kill); empty: the pins die with the process.
    sim_wires: str = ""

    def __post_init__(self) -> None:
        require(0 < self.max_on_s <= 60, "max_on_s", "must be 0-60 s")
        require(0 <= self.settle_ms <= 100, "settle_ms", "must be 0-100 ms")




def default_factory() -> Any:
    """gpiozero's default pin factory (what ``Device`` would pick), as a HardwareError if none."""
    import warnings

    from gpiozero import Device

    try:
        # gpiozero warns for each factory it falls back from; one line of our own says it better.
        with warnings.catch_warnings(record=True) as fallbacks:
            warnings.simplefilter("always")
            Device.ensure_pin_factory()
        for w in fallbacks:
            log.info("gpiozero: %s", w.message)
    except Exception as exc:  # gpiozero raises several kinds (BadPinFactory, ImportError, ...)
        raise LaserError(
            f"lasers: no GPIO available ({exc}); on a Raspberry Pi install python3-lgpio, elsewhere "
            "use [lasers] backend = \"sim\""
        ) from None
    return Device.pin_factory


def _wired(lasers: Iterable[LaserWiring]) -> list[LaserWiring]:
    lasers = list(lasers)
    missing = [laser.name for laser in lasers if laser.pin is None]
    if missing:
        raise LaserError(f"lasers: no GPIO pin configured for {', '.join(missing)} (rig.lasers[].pin)")
    return lasers


def _close_if_alive(ref: weakref.ReferenceType) -> None:
    obj = ref()
    if obj is not None:
        obj.close()


class Lasers:
    """A bank of lasers on GPIO pins (implements :class:`edge.hw.base.LaserBank`)."""

    def __init__(
        self, lasers: Sequence[LaserWiring], settings: LasersConfig | None = None, factory: Any = None,
        clock: Clock = REAL,
    ) -> None:
        from gpiozero import DigitalOutputDevice

        wired = _wired(lasers)
        self.names: tuple[str, ...] = tuple(laser.name for laser in wired)
        settings = settings if settings is not None else LasersConfig()
        self.settings = settings
        # gpiozero's default for real GPIO; the composition root (edge.parts) passes the simulator's.
        self.factory = factory if factory is not None else default_factory()
        self.clock = clock  # the rig's: switch times are compared with frame times
        self.settle_ns = int(round(settings.settle_ms * 1e6))
        self.max_on_ns = int(round(settings.max_on_s * 1e9))
        self.watchdog_trips = 0
        self._lock = threading.RLock()
        self._devices: dict[str, Any] = {}
        self._on_since: dict[str, int] = {}  # laser → when it was last switched on (monotonic ns)
        self._closed = False
        # Eye safety: on the real clock a thread of its own, which a hung loop cannot hold up.
        self._watchdog = clock.timer(self._watch, "laser-watchdog")
        try:
            for laser in wired:
                # initial_value=False: configured as an output already at its off level.
                self._devices[laser.name] = DigitalOutputDevice(
                    laser.pin, active_high=laser.active_high, initial_value=False, pin_factory=self.factory
                )
        except Exception as exc:
            self._close_devices()
            if isinstance(exc, LaserError):
                raise
            raise LaserError(f"lasers: cannot set up GPIO: {exc}") from None
        self._last_switch_ns = self.clock.now_ns()
        # Run close() at interpreter exit, without the registry keeping this object alive.
        self._atexit = functools.partial(_close_if_alive, weakref.ref(self))
        atexit.register(self._atexit)
        log.debug("lasers %s ready on %s, all off", ", ".join(self.names), type(self.factory).__name__)

    # --- the LaserBank interface -----------------------------------------------------------------

    def set(self, on: Iterable[str]) -> int:
        """Switch exactly `on` on and the others off. Returns the monotonic time (ns) by which the
        new state has taken effect: the last GPIO write plus the settle time. If nothing changes,
        that is the previous switch's time."""
        wanted = frozenset((on,) if isinstance(on, str) else on)  # set("center") means that laser
        unknown = sorted(wanted - set(self.names))
        if unknown:
            raise ValueError(f"unknown laser {', '.join(map(repr, unknown))} (known: {', '.join(self.names)})")
        with self._lock:
            if self._closed:
                raise LaserError("lasers: already closed")
            changed = False
            # Off before on, so that for a moment fewer lasers are lit, never more.
            for name in self.names:
                if name not in wanted and name in self._on_since:
                    self._devices[name].off()
                    del self._on_since[name]
                    changed = True
            now = self.clock.now_ns()
            for name in self.names:
                if name in wanted and name not in self._on_since:
                    self._devices[name].on()
                    # A laser already on keeps its original time: the watchdog limits continuous
                    # on-time, which repeated set() calls must not extend.
                    self._on_since[name] = now
                    changed = True
            if changed:
                self._last_switch_ns = self.clock.now_ns()
                self._arm_watchdog()
            return self._last_switch_ns + self.settle_ns

    def off(self) -> int:
        return self.set(())

    @property
    def lit(self) -> frozenset[str]:
        with self._lock:
            return frozenset(self._on_since)

    @property
    def last_switch_ns(self) -> int:
        """When the lasers last changed state (the last GPIO write), monotonic ns."""
        return self._last_switch_ns

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Lasers off, then the pins released. Safe to call any number of times, from any thread."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._on_since.clear()
            self._close_devices()
        self._watchdog.close()
        atexit.unregister(self._atexit)

    def __enter__(self) -> Lasers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- internals -----------------------------------------------------------------------------

    def _close_devices(self) -> None:
        for name, device in self._devices.items():
            try:
                device.off()
            except Exception as exc:  # keep going: the other lasers must still go off
                log.error("laser %s: could not switch off: %s", name, exc)
        for device in self._devices.values():
            try:
                device.close()
            except Exception as exc:
                log.error("laser GPIO: could not release: %s", exc)
        self._last_switch_ns = self.clock.now_ns()

    def _arm_watchdog(self) -> None:
        """(Under the lock.) Wake the watchdog when the laser on longest reaches its limit."""
        if self._on_since:
            self._watchdog.arm(min(self._on_since.values()) + self.max_on_ns)
        else:
            self._watchdog.disarm()

    def _watch(self) -> None:
        with self._lock:
            if self._closed:
                return
            now = self.clock.now_ns()
            overdue = [n for n, t in self._on_since.items() if now - t >= self.max_on_ns]
            for name in overdue:
                try:
                    self._devices[name].off()
                except Exception as exc:
                    log.error("laser %s: watchdog could not switch it off: %s", name, exc)
                del self._on_since[name]
            if overdue:
                self._last_switch_ns = self.clock.now_ns()
                self.watchdog_trips += 1
                log.warning(
                    "laser %s on for more than %.3g s: switched off (eye safety, [lasers] max_on_s)",
                    ", ".join(overdue), self.settings.max_on_s,
                )
            self._arm_watchdog()


def force_all_off(wiring: Iterable[LaserWiring], factory: Any = None) -> list[tuple[str, int, bool]]:
    """Drive every configured laser pin to its off level and leave it there; returns
    ``(laser, BCM pin, level driven: True = high)`` for each.

    Keeps no state and needs none: meant for a fresh process after a crash (``edge lasers off``,
    systemd's ``ExecStopPost``). It uses the pins directly rather than devices, so it works even
    while another object in this process holds them. On real GPIO the pins are then detached from
    gpiozero, because gpiozero's exit handler would turn them back into floating inputs; released
    lines keep their output level on Raspberry Pi OS. (Still, give each driver a pull resistor to
    its off level: at boot, before anything runs, the pins are inputs.)
    """
    from gpiozero.pins.mock import MockFactory

    factory = factory if factory is not None else default_factory()
    driven: list[tuple[str, int, bool]] = []
    pins = []
    errors = []
    for laser in wiring:
        if laser.pin is None:
            log.warning("laser %s has no pin configured: cannot switch it off", laser.name)
            continue
        level = not laser.active_high
        try:
            pin = factory.pin(laser.pin)
            if pin.function == "output":
                pin.state = level  # already driven: just the level, no glitch through input
            else:
                pin.output_with_state(level)
        except Exception as exc:  # try every pin before reporting
            errors.append(f"{laser.name} (GPIO{laser.pin}): {exc}")
            continue
        pins.append(pin)
        driven.append((laser.name, laser.pin, level))
    if not isinstance(factory, MockFactory):
        table = getattr(factory, "pins", None)
        if isinstance(table, dict):
            for key in [k for k, p in table.items() if any(p is q for q in pins)]:
                del table[key]
    if errors:
        raise LaserError(f"lasers off: could not drive {'; '.join(errors)}")
    return driven
