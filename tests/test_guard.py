"""The area guard's logic (edge.modes.guard): synthetic sweeps, then the simulated office with a
person walking through it."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from edge.config import load_config
from edge.errors import ConfigError
from edge.modes.guard import CLEARED, INTRUSION, MOVED, Guard, GuardConfig, GuardEvent, glimpse
from edge.ranging import AMBIGUOUS, FAULT, NO_SPOT, OK, OUT_OF_RANGE, ZoneResult
from edge.schema import FieldError, build
from edge.sim.record import scene_for, true_rig
from edge.triangulation import LaserMeasurement

N = 64
STEP = 360.0 / N


def pan_of(k: int) -> float:
    p = k * STEP
    return p - 360.0 if p > 180.0 else p


def room(n: int = N) -> np.ndarray:
    """Background ranges of a synthetic room: 2-4 m, varying smoothly around the turn."""
    k = np.arange(n)
    return 3.0 + 0.8 * np.sin(2 * np.pi * k / n) + 0.2 * np.cos(6 * np.pi * k / n)


def zone(k: int, r: float | None, status: str = OK, sigma_frac: float = 0.003, base: bool = True) -> ZoneResult:
    pan = pan_of(k)
    if status != OK or r is None:
        return ZoneResult(k, pan, 0.0, status)
    point = np.array([r * math.cos(math.radians(pan)), r * math.sin(math.radians(pan)), 0.0])
    return ZoneResult(k, pan, 0.0, OK, r, sigma_frac * r, point_base_m=point if base else None)


def sweep(
    ranges: Sequence[float | None],
    rng: np.random.Generator | None = None,
    noise_frac: float = 0.003,
    statuses: dict[int, str] | None = None,
    base: bool = True,
) -> list[ZoneResult]:
    """A sweep of `ranges` (None: out_of_range) with Gaussian noise and status overrides."""
    out = []
    for k, r in enumerate(ranges):
        status = (statuses or {}).get(k, OK if r is not None else OUT_OF_RANGE)
        if status == OK and rng is not None:
            r = r + rng.normal(0.0, noise_frac * r)
        out.append(zone(k, r, status, base=base))
    return out


def learned(config: GuardConfig = GuardConfig(), background: Sequence[float | None] | None = None,
            seed: int = 0) -> tuple[Guard, np.random.Generator, list]:
    bg = list(room()) if background is None else list(background)
    rng = np.random.default_rng(seed)
    guard = Guard(config, len(bg))
    for s in range(config.learn_sweeps):
        assert guard.learning
        assert guard.update(sweep(bg, rng), s, float(s)) == []
    assert not guard.learning
    return guard, rng, bg


def with_object(bg: Sequence[float | None], zones: dict[int, float]) -> list[float | None]:
    out = list(bg)
    for k, r in zones.items():
        out[k] = r
    return out


# --- configuration ----------------------------------------------------------------------------


def test_config_defaults_and_validation():
    c = GuardConfig()
    assert (c.learn_sweeps, c.k_sigma, c.min_drop_m, c.confirm_sweeps, c.clear_sweeps, c.move_min_m) == (
        5, 4.0, 0.15, 2, 2, 0.2)
    for bad in ({"learn_sweeps": 0}, {"k_sigma": 0.0}, {"min_drop_m": -0.1}, {"confirm_sweeps": 0},
                {"confirm_zones": 1}, {"clear_sweeps": 0}, {"move_min_m": 0.0}, {"min_ok_fraction": 0.0}):
        with pytest.raises(FieldError):
            GuardConfig(**bad)
    # The config loader builds it from a [guard] table and names the key at fault.
    assert build(GuardConfig, {"learn_sweeps": 8, "k_sigma": 3}, "x.toml", "guard").k_sigma == 3.0
    with pytest.raises(ConfigError, match=r"x.toml: guard.confirm_zones: must be 0"):
        build(GuardConfig, {"confirm_zones": 1}, "x.toml", "guard")
    with pytest.raises(ValueError):
        Guard(c, 0)


# --- synthetic sweeps -------------------------------------------------------------------------


def test_noise_only_raises_nothing_and_state_reports_learning():
    guard = Guard(GuardConfig(), N)
    st0 = guard.state()
    assert st0["learning"] and st0["learned_sweeps"] == 0 and st0["tracks"] == []
    rng = np.random.default_rng(1)
    bg = room()
    for s in range(100):
        assert guard.update(sweep(bg, rng), s, 1.5 * s) == []
        if s == 2:
            assert guard.state()["learned_sweeps"] == 3 and guard.learning
    state = guard.state()
    assert not state["learning"] and state["zones_with_background"] == N
    assert state["open_zones"] == [] and state["unlearned_zones"] == [] and state["pending_tracks"] == 0
    json.dumps(state)


def test_single_zone_one_sweep_spike_never_alarms():
    guard, rng, bg = learned()
    s = 10
    for k in range(0, N, 3):  # a big spike somewhere every other sweep, each in one sweep only
        assert guard.update(sweep(with_object(bg, {k: 0.8}), rng), s, float(s)) == []
        assert guard.update(sweep(bg, rng), s + 1, s + 1.0) == []
        s += 2
    # Even a spike over several zones, in one sweep only, does not alarm with the default rule.
    assert guard.update(sweep(with_object(bg, {20: 1.0, 21: 1.0, 22: 1.0}), rng), s, float(s)) == []
    assert guard.update(sweep(bg, rng), s + 1, s + 1.0) == []
    assert guard.tracks == []


def test_persistent_two_zone_object_alarms_once():
    guard, rng, bg = learned()
    obj = with_object(bg, {10: 1.5, 11: 1.5})
    events = []
    for s in range(10, 20):
        events += guard.update(sweep(obj, rng), s, float(s))
    assert [e.event for e in events] == [INTRUSION]
    e = events[0]
    assert e.sweep == 11 and e.id == "t1" and e.zones == (10, 11)
    assert e.range_m == pytest.approx(1.5, abs=0.02)
    assert e.baseline_m == pytest.approx(np.median(bg[10:12]), abs=0.05)
    assert e.bearing_deg == pytest.approx(10.5 * STEP, abs=0.5)
    assert e.velocity_mps is not None and math.hypot(*e.velocity_mps) < 0.1  # standing still
    (track,) = guard.tracks
    assert track.id == "t1" and track.zones == (10, 11) and track.last_seen_sweep == 19


def test_confirm_zones_confirms_a_wide_blob_at_once_but_never_one_zone():
    guard, rng, bg = learned(GuardConfig(confirm_zones=3))
    assert guard.update(sweep(with_object(bg, {30: 1.0}), rng), 10, 10.0) == []
    assert guard.update(sweep(bg, rng), 11, 11.0) == []
    events = guard.update(sweep(with_object(bg, {30: 1.0, 31: 1.0, 32: 1.0}), rng), 12, 12.0)
    assert [(e.event, e.zones) for e in events] == [(INTRUSION, (30, 31, 32))]


def test_moving_object_gives_moved_with_the_right_velocity():
    guard, rng, bg = learned()
    events: list[GuardEvent] = []
    r = 2.5
    # An object at 2.5 m walks to the left (increasing pan) one zone (0.245 m) per sweep, 1 s apart.
    for i, s in enumerate(range(10, 20)):
        events += guard.update(sweep(with_object(bg, {12 + i: r, 13 + i: r}), rng), s, float(s))
    kinds = [e.event for e in events]
    assert kinds[0] == INTRUSION and kinds.count(INTRUSION) == 1
    moved = [e for e in events if e.event == MOVED]
    assert len(moved) == 8 and all(e.id == "t1" for e in moved)
    for e in moved:
        # True velocity: tangential, chord of one zone step per second at 1.5 m, direction +pan.
        a = math.radians(e.bearing_deg)
        tangent = (-math.sin(a), math.cos(a))
        vx, vy = e.velocity_mps
        speed = math.hypot(vx, vy)
        assert speed == pytest.approx(2 * r * math.sin(math.radians(STEP) / 2), rel=0.15)
        assert (vx * tangent[0] + vy * tangent[1]) / speed > 0.95
    # Back the other way: the velocity turns round.
    events = []
    for i, s in enumerate(range(20, 26)):
        events += guard.update(sweep(with_object(bg, {20 - i: r, 21 - i: r}), rng), s, float(s))
    last = [e for e in events if e.event == MOVED][-1]
    a = math.radians(last.bearing_deg)
    assert last.velocity_mps[0] * -math.sin(a) + last.velocity_mps[1] * math.cos(a) < 0


def test_radial_approach_velocity_points_at_the_device():
    guard, rng, bg = learned()
    events = []
    for i, s in enumerate(range(10, 16)):
        r = 2.5 - 0.3 * i
        events += guard.update(sweep(with_object(bg, {40: r, 41: r}), rng), s, float(s))
    moved = [e for e in events if e.event == MOVED]
    assert moved
    for e in moved:
        a = math.radians(e.bearing_deg)
        radial = e.velocity_mps[0] * math.cos(a) + e.velocity_mps[1] * math.sin(a)
        assert radial == pytest.approx(-0.3, abs=0.05)


def test_object_that_leaves_is_cleared():
    guard, rng, bg = learned()
    obj = with_object(bg, {30: 2.0, 31: 2.0, 32: 2.0})
    events = []
    for s in range(10, 14):
        events += guard.update(sweep(obj, rng), s, float(s))
    assert [e.event for e in events] == [INTRUSION]
    assert guard.update(sweep(bg, rng), 14, 14.0) == []  # clear_sweeps = 2: not yet
    (cleared,) = guard.update(sweep(bg, rng), 15, 15.0)
    assert cleared.event == CLEARED and cleared.id == "t1" and cleared.zones == (30, 31, 32)
    assert guard.tracks == [] and guard.state()["tracks"] == []
    # Back again: a new track with a new id.
    events = []
    for s in range(16, 19):
        events += guard.update(sweep(obj, rng), s, float(s))
    assert [(e.event, e.id) for e in events] == [(INTRUSION, "t2")]


def test_relearn_resets():
    guard, rng, bg = learned()
    obj = with_object(bg, {5: 1.2, 6: 1.2})
    for s in range(10, 13):
        guard.update(sweep(obj, rng), s, float(s))
    assert len(guard.tracks) == 1
    (cleared,) = guard.relearn()
    assert cleared.event == CLEARED and cleared.id == "t1" and cleared.sweep == 12
    assert guard.learning and guard.tracks == [] and guard.state()["learned_sweeps"] == 0
    # The object is now part of the background.
    for s in range(13, 40):
        assert guard.update(sweep(obj, rng), s, float(s)) == []
    assert not guard.learning
    # Its removal (the background farther) raises nothing either.
    for s in range(40, 50):
        assert guard.update(sweep(bg, rng), s, float(s)) == []


def test_fault_and_ambiguous_zones_neither_raise_nor_clear():
    guard, rng, bg = learned()
    # Random faults and ambiguities alone: nothing.
    for s in range(10, 60):
        bad = {int(k): (FAULT if rng.random() < 0.5 else AMBIGUOUS) for k in rng.choice(N, 8, replace=False)}
        assert guard.update(sweep(bg, rng, statuses=bad), s, float(s)) == []
    # An object whose zones then fault is held, not cleared, until they read the background.
    obj = with_object(bg, {20: 1.0, 21: 1.0})
    events = []
    for s in range(60, 63):
        events += guard.update(sweep(obj, rng), s, float(s))
    assert [e.event for e in events] == [INTRUSION]
    for s in range(63, 73):
        assert guard.update(sweep(bg, rng, statuses={20: FAULT, 21: AMBIGUOUS}), s, float(s)) == []
    assert len(guard.tracks) == 1
    # Missing zones are unknown too.
    missing = [z for z in sweep(bg, rng) if z.index not in (20, 21)]
    assert guard.update(missing, 73, 73.0) == []
    assert guard.update(sweep(bg, rng), 74, 74.0) == []
    assert [e.event for e in guard.update(sweep(bg, rng), 75, 75.0)] == [CLEARED]


def test_a_fault_between_two_zones_of_an_object_does_not_split_it():
    guard, rng, bg = learned()
    obj = with_object(bg, {40: 1.3, 41: 1.3, 42: 1.3})
    events = []
    for s in range(10, 16):
        events += guard.update(sweep(obj, rng, statuses={41: AMBIGUOUS} if s % 2 else {}), s, float(s))
    assert [e.event for e in events] == [INTRUSION] and len(guard.tracks) == 1


def test_wrap_around_blob_at_zones_63_and_0():
    guard, rng, bg = learned()
    obj = with_object(bg, {63: 1.4, 0: 1.4})
    events = []
    for s in range(10, 14):
        events += guard.update(sweep(obj, rng), s, float(s))
    assert [e.event for e in events] == [INTRUSION]
    assert events[0].zones == (63, 0)
    assert events[0].bearing_deg == pytest.approx(-STEP / 2, abs=0.5)
    # Walking across the turn keeps one track.
    events = []
    for s, zones in zip(range(14, 18), [(62, 63), (61, 62), (62, 63), (63, 0)]):
        events += guard.update(sweep(with_object(bg, {z: 1.4 for z in zones}), rng), s, float(s))
    assert {e.id for e in events} == {"t1"} and INTRUSION not in [e.event for e in events]


def test_doorway_zone_without_background():
    bg = list(room())
    bg[3:6] = [None, None, None]  # a doorway onto a dark corridor: out_of_range while learning
    guard, rng, _ = learned(background=bg)
    state = guard.state()
    assert state["open_zones"] == [3, 4, 5] and state["zones_with_background"] == N - 3
    for s in range(10, 30):  # its usual status is no alarm
        assert guard.update(sweep(bg, rng), s, float(s)) == []
    events = []
    for s in range(30, 33):  # somebody in the doorway
        events += guard.update(sweep(with_object(bg, {4: 2.6, 5: 2.6}), rng), s, float(s))
    assert [e.event for e in events] == [INTRUSION]
    assert events[0].zones == (4, 5) and events[0].baseline_m == GuardConfig().open_max_m
    events = []
    for s in range(33, 36):  # gone: the doorway reads out of range again
        events += guard.update(sweep(bg, rng), s, float(s))
    assert [e.event for e in events] == [CLEARED]


def test_unusual_no_spot_holds_a_track():
    guard, rng, bg = learned()
    obj = with_object(bg, {50: 1.2, 51: 1.2})
    for s in range(10, 13):
        guard.update(sweep(obj, rng), s, float(s))
    assert len(guard.tracks) == 1
    # A dark coat: the spots vanish. Not the zones' usual status, so the track is held.
    for s in range(13, 20):
        assert guard.update(sweep(bg, rng, statuses={50: NO_SPOT, 51: NO_SPOT}), s, float(s)) == []
    assert len(guard.tracks) == 1


def test_zone_flickering_between_two_surfaces_does_not_alarm():
    bg = list(room())
    rng = np.random.default_rng(5)
    guard = Guard(GuardConfig(), N)
    # Zone 25's beam grazes a cabinet's edge: sometimes the cabinet (1.2 m), sometimes the wall.
    pattern = [1.2, 1.2, bg[25], bg[25], bg[25]] + [1.2 if rng.random() < 0.4 else bg[25] for _ in range(200)]
    for s, r in enumerate(pattern):
        assert guard.update(sweep(with_object(bg, {25: r}), rng), s, float(s)) == []


def test_sparse_zone_alarms_only_nearer_than_anything_it_showed():
    bg = list(room())
    guard = Guard(GuardConfig(), N)
    rng = np.random.default_rng(2)
    # A dark armchair in zone 44: a range in one learning sweep out of five, far too high once.
    for s in range(5):
        st_ = {44: NO_SPOT} if s != 2 else {}
        guard.update(sweep(with_object(bg, {44: bg[44] * 1.3}), rng, statuses=st_), s, float(s))
    for s in range(5, 40):
        st_ = {} if s % 3 == 0 else {44: NO_SPOT}
        assert guard.update(sweep(bg, rng, statuses=st_), s, float(s)) == []


def _beside(zone_result: ZoneResult, depths: dict[str, float], snr: float = 35.0) -> ZoneResult:
    """`zone_result` (a no_spot) with the default rig's other lasers' spots at `depths` (m), each
    where its beam meets a surface at that depth, as ranging lists them (`ZoneResult.lasers`)."""
    rig = load_config(None).rig.build()
    spots = {}
    for name, depth in depths.items():
        laser = rig.laser(name)
        along = (depth - laser.origin_m[2]) / laser.direction[2]
        point = np.asarray(laser.origin_m) + np.asarray(laser.direction) * along
        spots[name] = LaserMeasurement(name, np.array([320.0, 240.0]), 0.1, point, depth, 0.03, snr, 1)
    return dataclasses.replace(zone_result, lasers=spots)


def test_a_glimpse_is_another_laser_s_spot_beside_the_reference_s_beam() -> None:
    """The parallel laser lands 4 cm beside the center's beam at every depth; the sloped one 0.35 m
    below it at 2 m, on another surface as likely as not."""
    reference = load_config(None).rig.build().reference
    dim = zone(10, None, NO_SPOT)
    assert glimpse(_beside(dim, {"parallel": 2.28, "sloped": 1.1}), reference) == 2.28
    assert glimpse(_beside(dim, {"sloped": 2.0}), reference) is None
    assert glimpse(_beside(dim, {"sloped": 0.4}), reference) == 0.4  # (7 cm below it)
    assert glimpse(_beside(dim, {"parallel": 2.28}, snr=6.0), reference) is None
    assert glimpse(_beside(zone(10, None, OUT_OF_RANGE), {"parallel": 2.28}), reference) is None


@pytest.mark.parametrize("told", [True, False])
def test_a_zone_too_dim_for_its_reference_spot_is_judged_by_the_spot_beside_it(told: bool) -> None:
    """Zone 10's wall (2.3 m) is too dim for the center laser's spot in every learning sweep, while
    the parallel laser's, beside it, shows: a sparse zone at the parallel's depth, not an open one.
    When the center's spot shows after all, twice in a row, nothing is raised (taken for open, the
    guard raised an intrusion: `told` False, no reference laser given); something nearer still is."""
    config = GuardConfig(learn_sweeps=3)
    reference = load_config(None).rig.build().reference if told else None
    guard = Guard(config, N, reference=reference)
    bg = list(room())
    bg[10] = 2.3
    rng = np.random.default_rng(4)

    def dim_sweep(status: str = NO_SPOT, at: float = 2.3) -> list[ZoneResult]:
        results = sweep(with_object(bg, {10: at}), rng, statuses={10: status} if status != OK else None)
        if status == NO_SPOT:
            results[10] = _beside(results[10], {"parallel": 2.3 + rng.normal(0.0, 0.01)})
        return results

    for s in range(3):
        assert guard.update(dim_sweep(), s, float(s)) == []
    assert (10 in guard.state()["open_zones"]) is not told
    events = []
    for s, status in enumerate([NO_SPOT, OK, OK, NO_SPOT, NO_SPOT, NO_SPOT, OK, NO_SPOT], start=3):
        events += guard.update(dim_sweep(status), s, float(s))
    assert [e.event for e in events] == ([] if told else [INTRUSION, CLEARED])
    events = []
    for s in range(11, 14):  # somebody 1.5 m away in that zone
        events += guard.update(dim_sweep(OK, 1.5), s, float(s))
    assert [e.event for e in events] == [INTRUSION]


def test_background_adapts_to_a_removed_object():
    config = GuardConfig(adapt_window=10)
    near = with_object(room(), {30: 1.0, 31: 1.0})
    guard, rng, _ = learned(config, background=near)
    bg = list(room())
    for s in range(10, 30):  # the box is taken away: farther, never an alarm
        assert guard.update(sweep(bg, rng), s, float(s)) == []
    events = []
    for s in range(30, 33):  # now a box put there is news
        events += guard.update(sweep(near, rng), s, float(s))
    assert [e.event for e in events] == [INTRUSION]
    # Without adaptation the old background stays.
    guard, rng, _ = learned(GuardConfig(adapt=False), background=near)
    for s in range(10, 30):
        guard.update(sweep(bg, rng), s, float(s))
    for s in range(30, 33):
        assert guard.update(sweep(near, rng), s, float(s)) == []


def test_position_without_point_base_comes_from_pan_and_range():
    guard, rng, bg = learned()
    events = []
    for s in range(10, 13):
        events += guard.update(sweep(with_object(bg, {16: 1.0}), rng, base=False), s, float(s))
    (e,) = events
    assert e.bearing_deg == pytest.approx(90.0, abs=0.5)
    (track,) = guard.tracks
    assert track.position_m[0] == pytest.approx(0.0, abs=0.02) and track.position_m[1] == pytest.approx(1.0, abs=0.02)


def test_event_json_is_the_alert_payload_without_ts():
    e = GuardEvent(INTRUSION, "t3", (12, 13), 70.31234, 1.80004, 3.9, (0.1234, -0.5), 41)
    out = e.to_json()
    assert out == {"event": "intrusion", "id": "t3", "zones": [12, 13], "bearing_deg": 70.31, "range_m": 1.8,
                   "baseline_m": 3.9, "velocity_mps": [0.123, -0.5], "sweep": 41}
    assert GuardEvent(CLEARED, "t3", (1,), 0.0, 1.0, 2.0, None, 2).to_json()["velocity_mps"] is None
    json.dumps(out)


def test_zone_index_outside_the_sweep_is_an_error():
    guard = Guard(GuardConfig(), 8)
    with pytest.raises(ValueError, match="zone index 8"):
        guard.update([zone(8, 2.0)], 0, 0.0)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.integers(3, 24),
    seed=st.integers(0, 2**32 - 1),
    k_sigma=st.floats(1.0, 6.0),
    min_drop=st.floats(0.0, 0.3),
    sigma_frac=st.floats(0.001, 0.03),
    learn=st.integers(1, 8),
    sweeps=st.integers(5, 40),
    bad_rate=st.floats(0.0, 0.3),
)
def test_property_noise_within_k_sigma_raises_nothing(n, seed, k_sigma, min_drop, sigma_frac, learn, sweeps, bad_rate):
    """Readings within ±k·σ/2 of the truth (so within k·σ of one another, σ the reported sigma_m),
    with any mix of unknown statuses and missing zones, never raise an event."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0.3, 5.0, n)
    guard = Guard(GuardConfig(learn_sweeps=learn, k_sigma=k_sigma, min_drop_m=min_drop), n)
    for s in range(learn + sweeps):
        results = []
        for k in range(n):
            if s > 0 and rng.random() < bad_rate:
                status = rng.choice([FAULT, AMBIGUOUS, NO_SPOT, OUT_OF_RANGE, "missing"])
                if status != "missing":
                    results.append(zone(k, None, str(status)))
                continue
            sigma = sigma_frac * truth[k]
            r = truth[k] + rng.uniform(-0.5, 0.5) * k_sigma * sigma
            results.append(ZoneResult(k, pan_of(k), 0.0, OK, r, sigma))
        rng.shuffle(results)
        assert guard.update(results, s, 1.5 * s) == []


# --- the simulated office -----------------------------------------------------------------------
#
# Ranges are the reference laser's true range (camera z where the `center` beam meets the scene,
# ray-cast), with Gaussian noise of 0.3 % of range (the measured accuracy) and 2 % of the zones
# randomly ambiguous or no_spot. A sweep starts every SWEEP_PERIOD_S and takes SWEEP_DURATION_S:
# zone k is measured at t0 + k·SWEEP_DURATION_S/64 (its own instant, also handed to the guard), so
# a moving person is where they were when each zone looked.

SWEEP_PERIOD_S = 1.5
SWEEP_DURATION_S = 0.6
NOISE_FRAC = 0.003


class OfficeSim:
    def __init__(self) -> None:
        config = load_config(None, ["sim.scene=office-walker"])
        self.scene = scene_for(config)
        rig = true_rig(config)
        self.limits = rig.range_limits_m
        self.walker = self.scene.movers[0]
        self.poses = config.sweep.poses()
        assert len(self.poses) == N
        b2w = self.scene.base_to_world()
        self.w2b = b2w.inverse()
        laser = rig.reference
        self.cam_to_base = [rig.camera_to_base(pan, tilt) for pan, tilt in self.poses]
        self.cam_to_world = [b2w.compose(p) for p in self.cam_to_base]
        self.origins = np.array([p.apply(laser.o) for p in self.cam_to_world])
        self.dirs = np.array([p.rotate(laser.d) for p in self.cam_to_world])
        self.empty = self._cast(self.scene.at(0.0), range(N))  # the walker comes at 40 s

    def _cast(self, geometry, zones) -> dict[int, np.ndarray | None]:
        zones = list(zones)
        hits = geometry.cast(self.origins[zones], self.dirs[zones])
        return {
            k: self.cam_to_world[k].inverse().apply(hits.point[i]) if hits.hit[i] else None
            for i, k in enumerate(zones)
        }

    def zone_times(self, t0: float) -> dict[int, float]:
        return {k: t0 + k * SWEEP_DURATION_S / N for k in range(N)}

    def truth(self, times: dict[int, float]) -> dict[int, np.ndarray | None]:
        """Camera-frame point of the reference beam in each zone at its own time."""
        out = dict(self.empty)
        for k, t in times.items():
            if self.walker.pose_at(t) is not None:
                out.update(self._cast(self.scene.at(t), [k]))
        return out

    def sweep(self, t0: float, rng: np.random.Generator, outlier: tuple[int, float] | None = None):
        times = self.zone_times(t0)
        results = []
        for k, p in self.truth(times).items():
            pan, tilt = self.poses[k]
            if p is None:
                results.append(ZoneResult(k, pan, tilt, NO_SPOT))
                continue
            z = float(p[2])
            z_meas = z + rng.normal(0.0, NOISE_FRAC * z)
            if outlier is not None and outlier[0] == k:
                z_meas = z * outlier[1]
            if not self.limits[0] <= z_meas <= self.limits[1]:
                results.append(ZoneResult(k, pan, tilt, OUT_OF_RANGE))
                continue
            if rng.random() < 0.02:
                results.append(ZoneResult(k, pan, tilt, AMBIGUOUS if rng.random() < 0.5 else NO_SPOT))
                continue
            point = p + np.array([0.0, 0.0, z_meas - z])  # the beam runs along camera z
            results.append(ZoneResult(
                k, pan, tilt, OK, z_meas, NOISE_FRAC * z_meas, point, self.cam_to_base[k].apply(point)
            ))
        return results, times

    def walker_base_xy(self, t: float) -> np.ndarray | None:
        pose = self.walker.pose_at(t)
        return None if pose is None else self.w2b.apply(pose.t)[:2]


@pytest.fixture(scope="module")
def office() -> OfficeSim:
    return OfficeSim()


@pytest.fixture(scope="module")
def walker_run(office):
    """Sweeps every 1.5 s from t = 10 s to 100 s; learning on the empty office."""
    guard = Guard(GuardConfig(), N)
    rng = np.random.default_rng(7)
    log = []  # (event, sweep start, zone times)
    n = 0
    t0 = 10.0
    while t0 <= 100.0 + 1e-9:
        results, times = office.sweep(t0, rng)
        for e in guard.update(results, n, t0, times):
            log.append((e, t0, times))
        n += 1
        t0 = 10.0 + n * SWEEP_PERIOD_S
    return log


def _blob_time(event: GuardEvent, times: dict[int, float]) -> float:
    return float(np.mean([times[k] for k in event.zones]))


def _angle_deg(a, b) -> float:
    d = math.degrees(math.atan2(a[1], a[0]) - math.atan2(b[1], b[0]))
    return abs((d + 180.0) % 360.0 - 180.0)


def test_sim_walker_intrusion_in_the_right_zones(office, walker_run):
    intrusions = [(e, t0, times) for e, t0, times in walker_run if e.event == INTRUSION]
    assert len(intrusions) == 1, [e.to_json() for e, _, _ in walker_run]
    e, t0, times = intrusions[0]
    assert t0 >= office.walker.start_s
    t = _blob_time(e, times)
    xy = office.walker_base_xy(t)
    true_bearing = math.degrees(math.atan2(xy[1], xy[0]))
    assert abs((e.bearing_deg - true_bearing + 180) % 360 - 180) <= 2 * STEP
    assert any(abs((pan_of(k) - true_bearing + 180) % 360 - 180) <= 2 * STEP for k in e.zones)
    # The front of the person, a little nearer than their centre.
    assert e.range_m == pytest.approx(float(np.hypot(*xy)), abs=0.5)
    assert e.range_m < e.baseline_m - 0.15


def test_sim_walker_moved_events_follow_the_direction_of_travel(office, walker_run):
    assert {e.id for e, _, _ in walker_run} == {"t1"}
    tracked = [(e, t0, times) for e, t0, times in walker_run if e.event in (INTRUSION, MOVED)]
    moved = [(i, e, times) for i, (e, _, times) in enumerate(tracked) if e.event == MOVED]
    assert len(moved) >= 2
    good = 0
    for i, e, times in moved:
        t_now = _blob_time(e, times)
        prev, _, prev_times = tracked[i - 1]
        t_prev = _blob_time(prev, prev_times) if prev.sweep == e.sweep - 1 else t_now - SWEEP_PERIOD_S
        p0, p1 = office.walker_base_xy(t_prev), office.walker_base_xy(min(t_now, office.walker.end_s))
        assert p0 is not None and p1 is not None
        true_v = (p1 - p0) / (t_now - t_prev)  # the true path's chord over the same interval
        if _angle_deg(e.velocity_mps, true_v) < 45.0:
            good += 1
        assert math.hypot(*e.velocity_mps) < 3 * office.walker.speed_mps
    assert good >= math.ceil(2 * len(moved) / 3), f"{good} of {len(moved)} moved events in the right direction"


def test_sim_walker_cleared_after_leaving(office, walker_run):
    cleared = [(e, t0) for e, t0, _ in walker_run if e.event == CLEARED]
    assert len(cleared) == 1
    e, t0 = cleared[0]
    leave = office.walker.end_s  # path length / speed plus two 15-s stands, after the start
    assert leave == pytest.approx(78.76, abs=0.01)
    assert leave < t0 <= leave + (GuardConfig().clear_sweeps + 1) * SWEEP_PERIOD_S
    assert walker_run[-1][0].event == CLEARED  # nothing after


def test_sim_empty_office_200_sweeps_raise_nothing(office):
    guard = Guard(GuardConfig(), N)
    rng = np.random.default_rng(11)
    events = []
    for n in range(200):
        outlier = None
        if n >= 5 and n % 20 == 7:  # one zone in 20 sweeps off by 30 %
            outlier = (int(rng.integers(N)), 0.7 if n % 40 == 7 else 1.3)
        t0 = 10.0 - 1000.0 + n * SWEEP_PERIOD_S  # long before the walker comes
        results, times = office.sweep(t0, rng, outlier)
        events += guard.update(results, n, t0, times)
    assert events == []
    state = guard.state()
    assert state["open_zones"] == [3, 4, 5]  # the doorway
    assert state["zones_with_background"] == N - 3


# --- doorways: the map says where the room ends along a ray -----------------------------------


def test_someone_beyond_a_doorway_is_not_an_intruder_but_someone_in_it_is() -> None:
    """Zones 10-12 look through a doorway onto a dark corridor (no range: open zones); the map
    says the room ends 3 m along them. Someone walking in the corridor at 3.5-4 m raises nothing;
    someone in the doorway (2.5 m) does; without the map the corridor raised an intrusion."""
    bg = with_object(list(room()), {10: None, 11: None, 12: None})
    outside = {10: 3.0, 11: 3.0, 12: 3.0}
    guard, rng, _ = learned(background=bg)
    plain, rng2, _ = learned(background=bg, seed=1)
    s = 10
    for r in (3.5, 3.7, 4.0, 3.6, 3.8):
        walking = sweep(with_object(bg, {10: r, 11: r}), rng)
        assert guard.update(walking, s, float(s), outside_m=outside) == []
        s += 1
    assert any(e.event == INTRUSION for k in range(3)
               for e in plain.update(sweep(with_object(bg, {10: 3.6, 11: 3.6}), rng2), 30 + k, 30.0 + k))
    events = []
    for _ in range(3):
        events += guard.update(sweep(with_object(bg, {11: 2.5, 12: 2.5}), rng), s, float(s), outside_m=outside)
        s += 1
    assert [e.event for e in events] == [INTRUSION] and set(events[0].zones) == {11, 12}
    # Walking out through the door: beyond the room's end it is gone, and cleared.
    events = []
    for _ in range(3):
        events += guard.update(sweep(with_object(bg, {11: 3.5, 12: 3.5}), rng), s, float(s), outside_m=outside)
        s += 1
    assert [e.event for e in events] == [CLEARED]
