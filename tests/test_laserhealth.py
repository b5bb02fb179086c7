"""The laser verdicts from zone results alone."""

from __future__ import annotations

import numpy as np

from edge.laserhealth import LaserHealth
from edge.ranging import NO_SPOT, OK, LaserMeasurement, ZoneResult

NAMES = ("center", "parallel", "sloped")


def zone(found: tuple[str, ...]) -> ZoneResult:
    lasers = {n: LaserMeasurement(n, np.zeros(2), 0.1, np.zeros(3), 2.0, 0.01, 30.0, 1) for n in found}
    return ZoneResult(0, 0.0, 0.0, OK if "center" in found else NO_SPOT, lasers=lasers)


def test_a_laser_missing_where_the_others_see_is_dead_until_it_shows_again() -> None:
    health = LaserHealth(NAMES, window=4)
    for _ in range(3):
        health.update(zone(("parallel", "sloped")))
    assert health.faults() == {}  # not yet: three zones could be bad luck
    assert health.update(zone(("parallel", "sloped")))
    assert "does not light" in health.faults()["center"] and set(health.faults()) == {"center"}
    assert health.update(zone(NAMES)) and health.faults() == {}


def test_zones_where_no_laser_sees_anything_say_nothing() -> None:
    health = LaserHealth(NAMES, window=4)
    for _ in range(20):
        health.update(zone(()))  # a doorway: nothing in range
    assert health.faults() == {}


def test_a_laser_lit_in_the_off_frames_does_not_go_off() -> None:
    health = LaserHealth(NAMES, window=4)
    for k in range(4):
        # Its spot leaks into the difference now and then (flicker), but shows in every off frame.
        health.update(zone(("center", "parallel", "sloped") if k == 1 else ("parallel", "sloped")), {"center"})
    assert "does not go off" in health.faults()["center"]
