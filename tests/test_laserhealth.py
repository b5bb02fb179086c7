"""The laser verdicts from zone results alone: what counts as evidence, and the hysteresis."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from edge.laserhealth import Hysteresis, LaserFault, LaserHealth, LaserVerdict
from edge.ranging import NO_SPOT, OK, ZoneResult
from edge.triangulation import LaserMeasurement

NAMES = ("center", "parallel", "sloped")
QUICK = Hysteresis(enter_dark=4, enter_stuck=2, leave=2)
_views = itertools.count()


def zone(found: tuple[str, ...], spotted: tuple[str, ...] = (), pan: float | None = None) -> ZoneResult:
    """A zone whose range used the spots of `found`; `spotted` lasers showed spots it left out.
    Each at a view of its own, as a sweep's zones, unless `pan` says where."""
    lasers = {n: LaserMeasurement(n, np.zeros(2), 0.1, np.zeros(3), 2.0, 0.01, 30.0, 1) for n in found}
    pan = next(_views) * 5.625 % 360.0 - 180.0 if pan is None else pan
    return ZoneResult(0, pan, 0.0, OK if "center" in found else NO_SPOT, lasers=lasers,
                      spotted=frozenset(found) | frozenset(spotted))


def test_a_laser_missing_where_the_others_see_is_dark_after_enough_zones_until_it_shows_again() -> None:
    health = LaserHealth(NAMES, QUICK)
    for _ in range(3):
        assert not health.update(zone(("parallel", "sloped")))
    assert health.faults() == {}  # not yet: three zones could be a desk top under the beam
    assert health.update(zone(("parallel", "sloped")))
    assert "does not light" in health.faults()["center"] and set(health.faults()) == {"center"}
    assert not health.update(zone(NAMES))  # one spot could be a stray light on its path
    assert health.verdicts()["center"].fault is LaserFault.DARK
    assert health.update(zone(NAMES)) and health.faults() == {}


def test_runs_of_misses_shorter_than_the_hysteresis_never_make_a_verdict() -> None:
    """A working laser's spot goes missing at the same few views in every sweep (a desk top, a
    doorway's edge): runs of misses, each ended by a zone that finds it."""
    health = LaserHealth(NAMES)
    for _ in range(100):
        for _ in range(health.hysteresis.enter_dark - 1):
            assert not health.update(zone(("center", "parallel")))
        assert not health.update(zone(NAMES))
    assert health.verdicts() == {}


def test_a_spot_the_range_left_out_is_seen() -> None:
    """The cause of the false verdicts: the `sloped` beam meets a desk nearer than the wall the
    other two meet; its spot is found but left out of the range. The laser lit."""
    health = LaserHealth(NAMES)
    for _ in range(50):
        health.update(zone(("center", "parallel"), spotted=("sloped",)))
    assert health.verdicts() == {}


def test_one_view_over_and_over_is_one_piece_of_evidence() -> None:
    """The range finder ranges one view frame after frame: a spot the room hides there (a desk top
    under the beam) stays hidden, and says no more after a thousand frames than after one. Other
    views tell a dead laser from it."""
    health = LaserHealth(NAMES, QUICK)
    for _ in range(1000):
        health.update(zone(("center", "parallel"), pan=12.5))
    assert health.verdicts() == {}
    for k in range(QUICK.enter_dark - 2):
        assert not health.update(zone(("center", "parallel"), pan=20.0 + k))
    assert health.update(zone(("center", "parallel"), pan=12.5))  # back where it began: a view anew
    assert health.verdicts()["sloped"].fault is LaserFault.DARK
    health = LaserHealth(NAMES, QUICK)  # and stuck on alike
    for _ in range(100):
        health.update(zone(("center", "parallel"), pan=12.5), {"sloped"})
    assert health.verdicts() == {}
    assert health.update(zone(("center", "parallel"), pan=13.0), {"sloped"})


def sweep(health: LaserHealth, views: int, missing: set[int], broken: bool = False) -> list[int]:
    """One pass over `views` views: the sloped spot missing at the `missing` ones (everywhere when
    `broken`); the zones (by view) where a verdict changed."""
    changed = []
    for v in range(views):
        gone = broken or v in missing
        if health.update(zone(("center", "parallel") if gone else NAMES, pan=float(v))):
            changed.append(v)
    return changed


def test_a_view_where_a_working_lasers_spot_went_missing_tells_nothing_there_again() -> None:
    """Sweep after sweep the desk top hides the sloped spot at the same six views; now and then
    (a weak spot) it goes missing at the two next to them too: eight in a row, which alone would
    make a verdict. The six views hid it while it worked, and a miss there says nothing."""
    health = LaserHealth(NAMES)
    desk = set(range(20, 26))
    for k in range(100):
        assert sweep(health, 64, desk | ({26, 27} if k % 3 == 1 else set())) == []
    assert health.verdicts() == {}


def test_a_laser_that_dies_is_still_reported_though_some_views_hid_its_spot() -> None:
    health = LaserHealth(NAMES)
    desk = set(range(20, 26))
    for _ in range(3):
        sweep(health, 64, desk)
    # It dies as the sweep reaches the desk: the six views there say nothing, the eight after do.
    changed = [v for v in range(18, 64) if health.update(zone(("center", "parallel"), pan=float(v)))]
    assert changed == [18 + 6 + health.hysteresis.enter_dark - 1]
    assert health.verdicts()["sloped"].fault is LaserFault.DARK


def test_a_laser_dead_from_the_start_is_reported_on_a_fan_of_few_views() -> None:
    """The blind aid's fan has seven views, passed back and forth: a laser that never lit leaves no
    view known to hide its spot, and the eighth view (the first of the way back but one) tells."""
    health = LaserHealth(NAMES)
    fan = [float(v) for v in (-30, -20, -10, 0, 10, 20, 30)]
    passes = [fan, fan[::-1], fan, fan[::-1]]
    views = [v for p in passes for v in p]
    changed = [k for k, v in enumerate(views) if health.update(zone(("parallel", "sloped"), pan=v))]
    assert changed == [8]  # the seventh view and its repeat where the fan turns count once
    assert health.verdicts()["center"].fault is LaserFault.DARK


def test_a_stray_light_on_a_dead_lasers_path_hides_no_view() -> None:
    """A glint on a dead laser's path looks like its spot, once: the count starts again, but one
    spot is not a laser that works, and the views it was missing at still tell."""
    health = LaserHealth(NAMES)
    for v in range(5):
        health.update(zone(("center", "parallel"), pan=float(v)))
    health.update(zone(("center", "parallel"), ("sloped",), pan=5.0))  # the stray
    changed = [v for v in range(6, 20) if health.update(zone(("center", "parallel"), pan=float(v)))]
    assert changed == [6 + health.hysteresis.enter_dark - 1]
    health = LaserHealth(NAMES)  # and on the next pass over the same views, they still tell
    for v in range(5):
        health.update(zone(("center", "parallel"), pan=float(v)))
    health.update(zone(("center", "parallel"), ("sloped",), pan=5.0))
    changed = [v for v in range(8) if health.update(zone(("center", "parallel"), pan=float(v)))]
    assert changed == [health.hysteresis.enter_dark - 1]


def test_zones_where_no_laser_sees_anything_say_nothing_and_break_no_run() -> None:
    health = LaserHealth(NAMES, QUICK)
    for _ in range(20):
        health.update(zone(()))  # a doorway: nothing in range
    assert health.faults() == {}
    for _ in range(3):
        health.update(zone(("parallel", "sloped")))
    health.update(zone(()))
    health.update(zone(("parallel", "sloped")))
    assert set(health.verdicts()) == {"center"}
    health.update(zone(NAMES))
    health.update(zone(()))  # nor do they break the run that clears it
    assert health.update(zone(NAMES)) and health.verdicts() == {}


def test_a_laser_lit_in_the_off_frames_and_gone_from_the_difference_does_not_go_off() -> None:
    health = LaserHealth(NAMES, QUICK)
    assert not health.update(zone(("parallel", "sloped")), {"center"})
    # Its spot leaks into the difference now and then (flicker): that neither counts nor clears.
    assert not health.update(zone(NAMES), {"center"})
    assert health.update(zone(("parallel", "sloped")), {"center"})
    verdict = health.verdicts()["center"]
    assert verdict == LaserVerdict("center", LaserFault.STUCK_ON, 2, 2)
    assert "does not go off" in health.faults()["center"]
    # It is not dark either, whatever the zones where it shows nowhere say.
    for _ in range(10):
        health.update(zone(("parallel", "sloped")))
    assert health.verdicts()["center"].fault is LaserFault.STUCK_ON
    # It goes off again: its spot in the difference and not in the off frames, twice.
    health.update(zone(NAMES))
    assert health.update(zone(NAMES)) and health.verdicts() == {}


def test_a_glint_in_a_working_lasers_off_frames_is_not_stuck() -> None:
    """A red lamp or a glint on the laser's path in the off frame while its spot is in the
    difference as well: the laser switches; and such glints one zone apart do not add up."""
    health = LaserHealth(NAMES, QUICK)
    for _ in range(20):
        health.update(zone(NAMES), {"parallel"})
        health.update(zone(NAMES))
    assert health.verdicts() == {}
    health.update(zone(("center", "sloped")), {"parallel"})  # its spot lost too (a dark patch)
    health.update(zone(NAMES))
    health.update(zone(("center", "sloped")), {"parallel"})
    assert health.verdicts() == {}


def test_a_red_thing_on_a_dead_lasers_path_here_and_there_does_not_make_it_stuck() -> None:
    """The kitchen has something red on the `parallel` path at two views: a working laser's spot
    shows in the difference there as well; a dead one's does not, and the off frame's red thing
    would be a stuck laser's evidence. Zones between where it shows nowhere end that run."""
    health = LaserHealth(NAMES)
    changed = [k for k in range(60) if health.update(zone(("center", "sloped")), {"parallel"} if k % 17 == 3 else ())]
    # Nor does the red thing end its run of dark evidence: eight misses, and the one zone between.
    assert changed == [health.hysteresis.enter_dark]
    assert health.verdicts()["parallel"].fault is LaserFault.DARK


def test_a_dark_laser_that_shows_in_the_off_frames_turns_stuck() -> None:
    health = LaserHealth(NAMES, QUICK)
    for _ in range(4):
        health.update(zone(("center", "parallel")))
    assert health.verdicts()["sloped"].fault is LaserFault.DARK
    health.update(zone(("center", "parallel")), {"sloped"})
    assert health.update(zone(("center", "parallel")), {"sloped"})
    assert health.verdicts()["sloped"].fault is LaserFault.STUCK_ON


def test_a_standing_verdict_is_one_verdict_however_long_it_stands() -> None:
    """The verdict keeps the evidence that made it: `state` goes out when it comes and goes, not
    at every zone that confirms it."""
    health = LaserHealth(NAMES)
    changes = [health.update(zone(("center", "parallel"))) for _ in range(40)]
    assert changes.count(True) == 1 and changes.index(True) == health.hysteresis.enter_dark - 1
    assert health.verdicts()["sloped"] == LaserVerdict("sloped", LaserFault.DARK, 8)


def test_verdicts_are_typed_and_worded_only_on_demand() -> None:
    health = LaserHealth(NAMES, QUICK)
    for _ in range(4):
        health.update(zone(("center", "sloped")))
    verdict = health.verdicts()["parallel"]
    assert verdict == LaserVerdict("parallel", LaserFault.DARK, 4)
    assert verdict.words().startswith("laser parallel does not light") and "calibrate it" not in verdict.words()
    assert verdict.words(calibrated=False).endswith("calibrate it (cmd/calibrate)")
    stuck = LaserVerdict("center", LaserFault.STUCK_ON, 8, 5)
    assert "(5 of the last 8 zones)" in stuck.words(calibrated=False) and "calibrate it" not in stuck.words(False)


def test_hysteresis_counts_are_checked() -> None:
    with pytest.raises(ValueError):
        Hysteresis(enter_dark=0)
    with pytest.raises(ValueError):
        Hysteresis(leave=0)
