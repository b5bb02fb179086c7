"""The laser health on the simulator's frames: a healthy rig where the old judgement called the
sloped laser dark in every sweep, and dead and stuck lasers.

The zones are rendered straight from the scene at the guard's poses, one laser-off/laser-on pair a
zone as the guard takes them, ranged by the rig's Ranger and judged by the service's RigHealth: the
sweep's ranging and judging without the pan-tilt unit and the camera, at eight poses each (a whole
sweep renders 64 views, 15-20 s of a core). The long soak (100 sweeps of every scene) is a
benchmark, not a test.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

import numpy as np
import pytest

from edge.config import load_config
from edge.laserhealth import LaserFault
from edge.ranging import OK, FrameGroup, Ranger, ZoneResult
from edge.service import RigHealth
from edge.sim.record import scene_for, true_rig
from edge.sim.render import Renderer
from edge.sweep import lit_when_off

pytestmark = pytest.mark.slow  # renders views of the scenes: a few seconds each

NAMES = ("center", "parallel", "sloped")
# Eight zones each (the renderer keeps eight views, so passes after the first cost only noise).
OFFICE_DESK = range(16, 24)  # pan 90-129°: the sloped beam meets the desk top, or grazes it unseen
KITCHEN_WORKTOP = range(43, 51)  # pan -118 to -79°: the sloped beam meets the worktop
OFFICE_START = range(33, 41)  # pan -174 to -135°: where a guard sweep from pan 0 starts


class Guard:
    """The guard's zones at some of its poses in a shipped scene, with lasers broken at will."""

    def __init__(self, scene: str, zones: range) -> None:
        config = load_config(None, [f"sim.scene={scene}"])
        self.renderer = Renderer(scene_for(config), true_rig(config), config.sim, config.camera)
        self.ranger = Ranger(config.rig.build(), config.ranging)
        self.poses = [config.sweep.poses()[i] for i in zones]

    def zones(self, passes: int, broken: Mapping[str, str] | None = None,
              seed: int = 0) -> Iterator[tuple[ZoneResult, set[str]]]:
        """Pass over the poses back and forth, as sweeps do; `broken`: laser → "dead" or "stuck"."""
        broken = broken or {}
        on = {n: 1.0 for n in NAMES if broken.get(n) != "dead"}
        off = {n: 1.0 for n, kind in broken.items() if kind == "stuck"}
        k = 0
        for p in range(passes):
            for pan, tilt in self.poses if p % 2 == 0 else self.poses[::-1]:
                rng = np.random.default_rng([seed, k])
                group = FrameGroup([self.renderer.render(pan, tilt, on, 0.0, rng)],
                                   [self.renderer.render(pan, tilt, off, 0.0, rng)], NAMES, (pan, tilt))
                result = self.ranger.range_zone(k, pan, tilt, [group])
                yield result, lit_when_off(self.ranger, result, [group])
                k += 1


def rig_health(changes: list) -> RigHealth:
    return RigHealth(NAMES, "nominal rig", calibrated=False, camera=lambda: None,
                     changed=lambda: changes.append(1))


@pytest.fixture(scope="module")
def office_start() -> Guard:
    return Guard("office", OFFICE_START)


@pytest.mark.parametrize(("scene", "zones"), [("office", OFFICE_DESK), ("kitchen", KITCHEN_WORKTOP)])
def test_a_healthy_rig_where_the_sloped_spot_leaves_the_range_reports_no_laser_fault(scene: str, zones: range) -> None:
    guard = Guard(scene, zones)
    changes: list = []
    health = rig_health(changes)
    unused = longest = 0  # zones in a row the sloped spot was missing from the range's spots
    for result, lit in guard.zones(passes=2):
        health.zone(result, lit)
        assert health.parts["lasers"] == "ok", (result.pan_deg, health.parts["lasers"])
        ranged_without = result.status == OK and "sloped" not in result.lasers
        unused = unused + 1 if ranged_without else 0
        longest = max(longest, unused)
    assert changes == []
    # What the old judgement went by: eight zones in a row without the sloped spot in the range.
    assert longest >= 8


def test_a_spot_on_a_nearer_surface_is_spotted_though_the_range_leaves_it_out(office_start: Guard) -> None:
    """At pan -146° the sloped beam meets the armchair, a metre nearer than the wall the other two
    beams meet: the range is the wall's, and the sloped spot was seen all the same."""
    results = [result for result, _ in office_start.zones(passes=1)]
    step = next(r for r in results if abs(r.pan_deg + 146.25) < 0.01)
    assert step.status == OK and set(step.lasers) == {"center", "parallel"}
    assert step.spotted == frozenset(NAMES)


@pytest.mark.parametrize("laser", NAMES)
@pytest.mark.parametrize(("kind", "fault", "within"), [("dead", LaserFault.DARK, 8), ("stuck", LaserFault.STUCK_ON, 2)])
def test_a_broken_laser_is_reported_within_a_few_zones(office_start: Guard, laser: str, kind: str,
                                                       fault: LaserFault, within: int) -> None:
    """Within `within` zones of evidence in a row. A stray light on a dead laser's path (another
    beam's glint, about one zone in a hundred with one frame pair a zone) looks like its spot and
    starts the count again; and a view twice in a row (where a sweep turns back) counts once."""
    changes: list = []
    health = rig_health(changes)
    since_seen = zones = 0  # zones at a new view since its spot last showed; zones in all
    view = None
    for result, lit in office_start.zones(passes=3, broken={laser: kind}):
        health.zone(result, lit)
        zones += 1
        since_seen += (result.pan_deg, result.tilt_deg) != view
        view = (result.pan_deg, result.tilt_deg)
        if laser in result.spotted and laser not in lit:
            since_seen = 0
        if health.lasers.verdicts():
            break
    verdicts = health.lasers.verdicts()
    assert set(verdicts) == {laser} and verdicts[laser].fault is fault
    assert since_seen <= within and zones <= 2 * within, f"{laser} {kind}: reported after {zones} zones"
    assert health.parts["lasers"].startswith(f"fault: laser {laser} ") and changes == [1]
    if laser == "center":  # the blind aid hears that it cannot see
        assert health.cannot_see("center") is not None
