"""Is each laser working? Judged from the zones, as they come.

A laser that does not light, and one that does not go off, both vanish from the laser-on minus
laser-off difference: its spot is missing while the other lasers find theirs (the surface is in
range). The two are told apart by the laser-off frames: a laser that stays on shows its spot there.
Pure: zone results (and what the off frames showed) in, a verdict per laser out.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Sequence

from edge.ranging import ZoneResult


class LaserHealth:
    """Keeps the last `window` telling zones of each laser: zones where another laser found its
    spot, or where it showed in the laser-off frames. Lit when off in at least half of them: it
    does not go off. Missing from all of them: it does not light (one zone that finds its spot
    clears that)."""

    def __init__(self, names: Sequence[str], window: int = 8) -> None:
        self.names = tuple(names)
        self.window = window
        self._seen = {n: deque(maxlen=window) for n in self.names}  # (found, lit when off)

    def update(self, result: ZoneResult, lit_when_off: Iterable[str] = ()) -> bool:
        """Take one zone; True when a verdict changed."""
        before = self.faults()
        found = set(result.lasers)
        lit_off = set(lit_when_off)
        for name in self.names:
            # Another laser saw the surface, or this one showed lit when off: the zone tells.
            if found - {name} or name in lit_off:
                self._seen[name].append((name in found, name in lit_off))
        return self.faults() != before

    def faults(self) -> dict[str, str]:
        out = {}
        for name, seen in self._seen.items():
            if len(seen) < self.window:
                continue
            if sum(lit for _, lit in seen) * 2 >= len(seen):
                out[name] = (f"laser {name} does not go off: its spot shows in laser-off frames "
                             f"({sum(lit for _, lit in seen)} of the last {len(seen)} zones); check its driver")
            elif not any(found for found, _ in seen):
                out[name] = (f"laser {name} does not light: no spot in the last {len(seen)} zones where "
                             "the other lasers found theirs; check the diode, its supply and wiring")
        return out
