"""Is each laser working? Judged from the zones, as they come.

A laser that does not light, and one that does not go off, both vanish from the laser-on minus
laser-off difference. The two are told apart by the laser-off frames: a laser that stays on shows
its spot there.

Missing is not yet broken. A working laser's spot goes missing where the room hides it: on a desk
top or a worktop below the wall the other beams meet (lit at a grazing angle, too faint to find),
through a doorway, on a dark or glossy patch. Those misses come in runs, at the same views, and a
judgement that counted a handful of them flapped between "does not light" and "all working again"
in every sweep of a healthy rig. So the judgement takes only evidence that holds up:

- a laser is *seen* in a zone whenever the frames showed its spot on its path
  (`ZoneResult.spotted`), used in the range or not: a spot on a nearer surface than the wall the
  other beams meet (a step, a desk top) is left out of the range, but the laser lit;
- a zone *tells* that a laser is dark only where it was not seen while another laser's spot was
  (spots are searched for over the working range alone, the same depths for every laser: a
  surface is there, in range and lit enough) and it did not show in the laser-off frames. On the
  thesis rig every laser's path lies in the picture over the whole range, so where the others
  found the surface its spot must be in view too, unless the room hides it;
- a zone tells that a laser is stuck on only where its spot showed in the laser-off frames and
  not in the difference (a red lamp or a glint in the off frame leaves the spot in the difference);
  a zone where it shows in neither, though another laser's spot does, ends such a run (a red thing
  on a dead laser's path, at a view here and there, is not a laser that stays on);
- hysteresis: a verdict needs that evidence in `enter_dark` (or `enter_stuck`) telling zones in a
  row, and goes only after `leave` zones in a row that show the laser working. A run of dark
  evidence ends only where the spot shows in the difference (it lit); zones that tell nothing
  (nothing in range, a part's fault) neither count nor break a run;
- one view is one piece of evidence: the range finder's frames of one view, over and over, count
  once (what the room hides there it hides in every frame); and a view where a working laser's
  spot went missing (it showed again right after) hides it: a miss there tells nothing until the
  spot shows there again (the next sweep meets the same desk top).

Pure: zone results (and what the off frames showed) in, a typed verdict per laser out; the words
are made only for people (`LaserVerdict.words`), and nothing decides by them.
"""

from __future__ import annotations

import enum
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from edge.ranging import ZoneResult


class LaserFault(enum.Enum):
    DARK = "does not light"
    STUCK_ON = "does not go off"


@dataclass(frozen=True)
class Hysteresis:
    """How much evidence a verdict takes, in telling zones in a row.

    `enter_dark` keeps a dead laser reported within eight zones. A working laser's runs of misses
    stay well below it: over the shipped scenes' guard sweeps the longest seen was six views (the
    sloped spot on the office's desk top, and the one view beyond it where the spot is faint),
    three once the views that hid it before tell nothing. A stuck laser's evidence is rarer by far
    in a working one (the off frame showing a spot on its path that the difference does not), so
    two zones do."""

    enter_dark: int = 8
    enter_stuck: int = 2
    leave: int = 2

    def __post_init__(self) -> None:
        if min(self.enter_dark, self.enter_stuck, self.leave) < 1:
            raise ValueError(f"hysteresis counts must be >= 1, got {self}")


@dataclass(frozen=True)
class LaserVerdict:
    """A broken laser, and the evidence: the `zones` telling zones in a row that made the verdict,
    and (for one stuck on) how many of them showed its spot in the laser-off frames."""

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


class _Zone(enum.Enum):
    """What one zone says of one laser."""

    WORKS = enum.auto()  # its spot in the difference, not in the off frame: it switches
    LEAKS = enum.auto()  # in the difference and in the off frame: it lights; stuck or a red glint
    LIT_OFF = enum.auto()  # in the off frame only: it does not go off
    MISSING = enum.auto()  # nowhere, though another laser's spot shows the surface: dark, or hidden
    SILENT = enum.auto()  # nowhere, nor any other laser's: nothing in range, or a part failed

    @staticmethod
    def of(name: str, seen: set[str], lit_off: set[str]) -> _Zone:
        if name in seen:
            return _Zone.LEAKS if name in lit_off else _Zone.WORKS
        if name in lit_off:
            return _Zone.LIT_OFF
        return _Zone.MISSING if seen else _Zone.SILENT  # (`seen` holds only other lasers here)


View = tuple[float, float]  # (pan, tilt) of a zone, degrees
# Views remembered, per laser, as hiding its spot (a sweep has 64, the blind aid's fan 7, each
# cmd/point adds one): the oldest are forgotten past this.
_HIDING_VIEWS = 256


@dataclass
class _Judge:
    """One laser's runs of evidence and its verdict. Each run counts its evidence in a row; a zone
    against it ends the run, one that tells nothing either way leaves it be.

    Evidence from the view the run's last evidence came from counts once: the range finder's
    frames, one view many times over, see the same room, and a spot the room hides there stays
    hidden (a dead laser is told from it by other views: a map sweep's, cmd/point's). And a view
    where the spot went missing while the laser worked (it showed in the zones that followed, twice
    in a row) hides it: a miss there says nothing until the spot shows there again. The guard's
    sweeps pass the same views again and again, and a desk top that hid the spot in the last sweep
    hides it in this one; a laser dead from the start has no such views, and one that dies later
    still misses everywhere else."""

    verdict: LaserVerdict | None = None
    dark: int = 0  # MISSING in a row, at views that do not hide it
    stuck: int = 0  # LIT_OFF in a row
    working: int = 0  # zones in a row that show it working, while a verdict stands
    dark_view: View | None = None  # where the last MISSING came from
    stuck_view: View | None = None  # where the last LIT_OFF came from
    shown: int = 0  # zones in a row that showed its spot
    missed: list[View] = field(default_factory=list)  # MISSING views since it last showed twice
    hiding: OrderedDict[View, None] = field(default_factory=OrderedDict)  # views that hide its spot

    def take(self, zone: _Zone, view: View, name: str, h: Hysteresis) -> None:
        if zone is _Zone.MISSING:
            if view not in self.hiding and view != self.dark_view:
                self.dark += 1
            self.dark_view, self.shown = view, 0
            if len(self.missed) < _HIDING_VIEWS:
                self.missed.append(view)
        elif zone in (_Zone.WORKS, _Zone.LEAKS):
            self.dark, self.dark_view = 0, None  # it lit
            self.hiding.pop(view, None)
            self.shown += 1
            if self.shown >= h.leave:
                if self.verdict is None:  # it worked all along: where it went missing, it was hidden
                    self._hidden_at(self.missed)
                self.missed = []
        elif zone is _Zone.LIT_OFF:
            # Not in the difference: not its spot lighting for the on frame. A stuck laser is told
            # by the stuck run; a red thing on a dead laser's path must not end its dark run.
            self.shown = 0
        if zone is _Zone.LIT_OFF:
            self.stuck += 1 if view != self.stuck_view else 0
            self.stuck_view = view
        elif zone in (_Zone.WORKS, _Zone.MISSING):
            self.stuck, self.stuck_view = 0, None  # it went off, or shows nowhere
        if self.verdict is None:
            if self.stuck >= h.enter_stuck:
                self.verdict = LaserVerdict(name, LaserFault.STUCK_ON, self.stuck, self.stuck)
            elif self.dark >= h.enter_dark:
                self.verdict = LaserVerdict(name, LaserFault.DARK, self.dark)
            self.working = 0
            return
        # A dark laser works again once its spot shows; one stuck on, once it also goes off.
        if self.verdict.fault is LaserFault.STUCK_ON:
            works, against = zone is _Zone.WORKS, zone in (_Zone.LIT_OFF, _Zone.LEAKS)
        else:
            works, against = zone in (_Zone.WORKS, _Zone.LEAKS), zone in (_Zone.MISSING, _Zone.LIT_OFF)
        if works:
            self.working += 1
        elif against:
            self.working = 0
        if self.working >= h.leave:
            self.verdict, self.working, self.dark, self.stuck = None, 0, 0, 0
            self.dark_view = self.stuck_view = None
        elif self.verdict.fault is LaserFault.DARK and self.stuck >= h.enter_stuck:
            self.verdict = LaserVerdict(name, LaserFault.STUCK_ON, self.stuck, self.stuck)
            self.working = 0

    def _hidden_at(self, views: list[View]) -> None:
        for view in views:
            self.hiding[view] = None
            self.hiding.move_to_end(view)
        while len(self.hiding) > _HIDING_VIEWS:
            self.hiding.popitem(last=False)


class LaserHealth:
    """Each laser's verdict from the zones as they come (see the module notes for the evidence)."""

    def __init__(self, names: Sequence[str], hysteresis: Hysteresis = Hysteresis()) -> None:
        self.names = tuple(names)
        self.hysteresis = hysteresis
        self._judges = {name: _Judge() for name in self.names}

    def update(self, result: ZoneResult, lit_when_off: Iterable[str] = ()) -> bool:
        """Take one zone; True when a verdict changed."""
        seen = set(result.spotted) | set(result.lasers)
        lit_off = set(lit_when_off)
        view = (round(result.pan_deg, 2), round(result.tilt_deg, 2))
        before = self.verdicts()
        for name, judge in self._judges.items():
            judge.take(_Zone.of(name, seen, lit_off), view, name, self.hysteresis)
        return self.verdicts() != before

    def verdicts(self) -> dict[str, LaserVerdict]:
        """The broken lasers by name (working ones are absent)."""
        return {name: j.verdict for name, j in self._judges.items() if j.verdict is not None}

    def faults(self) -> dict[str, str]:
        """The verdicts in words, by laser."""
        return {name: verdict.words() for name, verdict in self.verdicts().items()}
