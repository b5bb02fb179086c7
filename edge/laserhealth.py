"""Is each laser working? Judged from the zones, as they come.

A laser that does not light, and one that does not go off, both vanish from the laser-on minus
laser-off difference: its spot is missing while the other lasers find theirs (the surface is in
range). The two are told apart by the laser-off frames: a laser that stays on shows its spot there.
Pure: zone results (and what the off frames showed) in, a typed verdict per laser out; the words
are made only for people (`LaserVerdict.words`), and nothing decides by them.
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from edge.ranging import ZoneResult


class LaserFault(enum.Enum):
    DARK = "does not light"
    STUCK_ON = "does not go off"


@dataclass(frozen=True)
class LaserVerdict:
    """A broken laser, and the evidence: the last `zones` telling zones, and (for one stuck on)
    how many of them showed its spot in the laser-off frames."""

    laser: str
    fault: LaserFault
    zones: int
    lit_off: int = 0

    def words(self, calibrated: bool = True) -> str:
        """What `state` says of it. On an uncalibrated rig a dark laser has a likelier cause: a
        hand-mounted laser half a degree off puts its spot outside the narrow band the nominal rig
        searches."""
        if self.fault is LaserFault.STUCK_ON:
            return (f"laser {self.laser} does not go off: its spot shows in laser-off frames "
                    f"({self.lit_off} of the last {self.zones} zones); check its driver")
        text = (f"laser {self.laser} does not light: no spot in the last {self.zones} zones where "
                "the other lasers found theirs; check the diode, its supply and wiring")
        if not calibrated:
            text += ("; or, as this rig is not calibrated, its spot may lie where the nominal "
                     "rig does not look: calibrate it (cmd/calibrate)")
        return text


class LaserHealth:
    """Keeps the last `window` telling zones of each laser: zones where another laser found its
    spot, or where it showed in the laser-off frames. Lit when off in at least half of them: it
    does not go off. Missing from all of them: it does not light (one zone that finds its spot
    clears that)."""

    def __init__(self, names: Sequence[str], window: int = 8) -> None:
        self.names = tuple(names)
        self.window = window
        self._seen: dict[str, deque[tuple[bool, bool]]] = {n: deque(maxlen=window) for n in self.names}
        # (found, lit when off)

    def update(self, result: ZoneResult, lit_when_off: Iterable[str] = ()) -> bool:
        """Take one zone; True when a verdict changed (or its evidence, which `state` shows)."""
        before = self.verdicts()
        found = set(result.lasers)
        lit_off = set(lit_when_off)
        for name in self.names:
            # Another laser saw the surface, or this one showed lit when off: the zone tells.
            if found - {name} or name in lit_off:
                self._seen[name].append((name in found, name in lit_off))
        return self.verdicts() != before

    def verdicts(self) -> dict[str, LaserVerdict]:
        """The broken lasers by name (working ones are absent)."""
        out = {}
        for name, seen in self._seen.items():
            if len(seen) < self.window:
                continue
            lit = sum(lit for _, lit in seen)
            if lit * 2 >= len(seen):
                out[name] = LaserVerdict(name, LaserFault.STUCK_ON, len(seen), lit)
            elif not any(found for found, _ in seen):
                out[name] = LaserVerdict(name, LaserFault.DARK, len(seen))
        return out

    def faults(self) -> dict[str, str]:
        """The verdicts in words, by laser."""
        return {name: verdict.words() for name, verdict in self.verdicts().items()}
