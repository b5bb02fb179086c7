"""What the simulated lasers' pins meant for the light: when, and for how much of each row's
exposure, each laser was lit — a rolling shutter sees a switch mid-frame as a brightness step
between rows."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from gpiozero.pins.mock import MockFactory

from edge.hw.lasers import LaserWiring
from edge.sim.gpio import LaserPin


class LaserLight:
    """What the simulated lasers did, read from their pins: when and how long each was lit.

    A laser is lit while its pin drives its active level (high, or low for an active-low driver);
    the light follows the wire `settle_ns` later (driver and diode), and an undriven pin (input
    mode, e.g. after ``close()``) is dark — the driver's pull resistor holds it off.
    """

    def __init__(self, lasers: Iterable[LaserWiring], factory: MockFactory, settle_ns: int = 0,
                 broken: dict[str, str] | None = None, lag_ns: dict[str, int] | None = None) -> None:
        self.settle_ns = int(settle_ns)
        self.broken = dict(broken or {})  # laser name → "dead" or "stuck" (simulated faults)
        self.lag_ns = dict(lag_ns or {})  # laser name → its own time to switch, in place of settle_ns
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
        times = np.array([t for t, _ in log], dtype=np.int64) + self.lag_ns.get(name, self.settle_ns)
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
