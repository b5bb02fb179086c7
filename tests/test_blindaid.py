"""The blind aid's logic: fan, laws, cue choice, holding and dropping readings, speech."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.errors import ConfigError
from edge.modes.blindaid.logic import (
    BEEP,
    BLIND,
    CANNOT_SEE,
    SILENCE,
    TONE,
    BlindAid,
    BlindAidConfig,
    Cue,
    distance_words,
    fan_poses,
    integer_words,
    pan_gains,
    scan_order,
)
from edge.ranging import AMBIGUOUS, FAULT, NO_SPOT, OK, OUT_OF_RANGE, ZoneResult
from edge.schema import FieldError, build

CFG = BlindAidConfig()
LEFT, AHEAD, RIGHT = 30.0, 0.0, -30.0  # pan of the fan's left edge, centre, right edge


def ok(pan: float, r: float) -> ZoneResult:
    return ZoneResult(0, pan, 0.0, OK, range_m=r, sigma_m=0.01)


def bad(pan: float, status: str) -> ZoneResult:
    return ZoneResult(0, pan, 0.0, status, detail="test")


def quiet(**kw: object) -> BlindAid:
    return BlindAid(BlindAidConfig(speak_new=False, **kw))  # type: ignore[arg-type]


# --- config and fan --------------------------------------------------------------------------


def test_defaults_valid_and_loadable_through_schema() -> None:
    cfg = build(BlindAidConfig, {"fan_zones": 9, "clear_m": 2.5}, "test.toml", "blindaid")
    assert cfg.fan_zones == 9 and cfg.clear_m == 2.5 and cfg.danger_m == 0.5


@pytest.mark.parametrize(("key", "value"), [
    ("fan_zones", 6), ("fan_zones", 1), ("fan_zones", 17), ("danger_m", 3.5), ("danger_m", 0.0),
    ("min_interval_s", 1.5), ("pitch_high_hz", 300.0), ("volume", 1.5), ("sample_rate", 12345),
    ("hold_s", 5.0), ("beep_s", 0.2), ("ahead_deg", 40.0),
])
def test_bad_values_rejected_naming_key(key: str, value: object) -> None:
    with pytest.raises(FieldError) as e:
        BlindAidConfig(**{key: value})  # type: ignore[arg-type]
    assert e.value.key in (key, "clear_m", "max_interval_s", "pitch_high_hz", "beep_s")
    with pytest.raises(ConfigError, match=r"test\.toml: blindaid\."):
        build(BlindAidConfig, {key: value}, "test.toml", "blindaid")


def test_config_is_frozen() -> None:
    with pytest.raises(AttributeError):
        CFG.clear_m = 1.0  # type: ignore[misc]


@pytest.mark.parametrize("n", [3, 5, 7, 9, 15])
def test_fan_poses_symmetric_left_to_right(n: int) -> None:
    cfg = BlindAidConfig(fan_zones=n, fan_half_width_deg=30.0, tilt_deg=-5.0)
    poses = fan_poses(cfg)
    assert len(poses) == n
    pans = [p for p, _ in poses]
    assert pans[0] == pytest.approx(30.0) and pans[-1] == pytest.approx(-30.0)
    assert pans[n // 2] == 0.0  # straight ahead, not -0.0 either
    assert all(a > b for a, b in zip(pans, pans[1:]))  # left (positive pan) to right
    for i in range(n):
        assert pans[i] == pytest.approx(-pans[n - 1 - i])
    assert all(t == -5.0 for _, t in poses)
    order = scan_order(cfg)
    assert sorted(set(order)) == list(range(n))
    assert all(abs(a - b) == 1 for a, b in zip(order + order[:1], order[1:] + order[:1]))


def test_zone_of_by_pan_tolerates_nudges_and_rejects_outside() -> None:
    aid = BlindAid(CFG)
    assert aid.zone_of(ok(30.0, 1.0)) == 0
    assert aid.zone_of(ok(0.05, 1.0)) == 3
    assert aid.zone_of(ok(-19.95, 1.0)) == 5
    assert aid.zone_of(ok(-30.0, 1.0)) == 6
    assert aid.zone_of(ok(40.0, 1.0)) is None
    assert aid.zone_of(ok(-90.0, 1.0)) is None
    assert aid.update(ok(90.0, 1.0), 0.0) is None  # outside the fan: ignored


# --- laws --------------------------------------------------------------------------------------


def test_law_end_points() -> None:
    assert CFG.interval_s(CFG.clear_m) == pytest.approx(CFG.max_interval_s)
    assert CFG.interval_s(CFG.danger_m) == pytest.approx(CFG.min_interval_s)
    assert CFG.pitch_hz(CFG.clear_m) == pytest.approx(CFG.pitch_low_hz)
    assert CFG.pitch_hz(CFG.danger_m) == pytest.approx(CFG.pitch_high_hz)
    # Geometric: the midpoint of the band is the geometric mean.
    mid = (CFG.clear_m + CFG.danger_m) / 2
    assert CFG.interval_s(mid) == pytest.approx(math.sqrt(CFG.min_interval_s * CFG.max_interval_s))
    assert CFG.pitch_hz(mid) == pytest.approx(math.sqrt(CFG.pitch_low_hz * CFG.pitch_high_hz))


def test_nearer_means_shorter_interval_and_higher_pitch() -> None:
    cues = []
    for d in (2.9, 2.5, 2.0, 1.5, 1.0, 0.7, 0.55):
        cue = quiet().update(ok(AHEAD, d), 0.0)
        assert cue is not None and cue.sound == BEEP
        cues.append(cue)
    assert all(a.interval_s > b.interval_s for a, b in zip(cues, cues[1:]))  # type: ignore[operator]
    assert all(a.pitch_hz < b.pitch_hz for a, b in zip(cues, cues[1:]))  # type: ignore[operator]


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 6.0), st.floats(0.0, 6.0))
def test_laws_monotonic_property(d1: float, d2: float) -> None:
    near, far = min(d1, d2), max(d1, d2)
    assert CFG.interval_s(near) <= CFG.interval_s(far)
    assert CFG.pitch_hz(near) >= CFG.pitch_hz(far)
    assert CFG.min_interval_s <= CFG.interval_s(near) <= CFG.max_interval_s
    assert CFG.pitch_low_hz <= CFG.pitch_hz(near) <= CFG.pitch_high_hz
    inside = CFG.danger_m < near and far <= CFG.clear_m and far - near > 1e-6
    if inside:
        assert CFG.interval_s(near) < CFG.interval_s(far)
        assert CFG.pitch_hz(near) > CFG.pitch_hz(far)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0.3, 4.0), min_size=1, max_size=7))
def test_nearest_of_any_fan_drives_cue_property(ranges: list[float]) -> None:
    aid = quiet()
    pans = [p for p, _ in aid.poses]
    for i, r in enumerate(ranges):
        aid.update(ok(pans[i], r), 0.01 * i)
    cue = aid.cue
    near = min(ranges)
    if near > CFG.clear_m:
        assert cue.sound == SILENCE and cue.range_m is None
    else:
        assert cue.range_m == pytest.approx(near, abs=CFG.hysteresis_m + 1e-9)
        assert cue.sound == (TONE if cue.range_m <= CFG.danger_m else BEEP)


def test_inside_danger_tone_beyond_clear_silence() -> None:
    cue = quiet().update(ok(AHEAD, 0.4), 0.0)
    assert cue is not None and cue.sound == TONE and cue.interval_s is None
    assert cue.pitch_hz == CFG.pitch_high_hz
    aid = quiet()
    assert aid.update(ok(AHEAD, 3.5), 0.0) is None  # it was silent already: nothing new
    assert aid.cue.sound == SILENCE and aid.cue.pitch_hz is None and aid.cue.range_m is None


def test_hysteresis_at_danger_and_clear() -> None:
    aid = quiet()
    assert aid.update(ok(AHEAD, 0.45), 0.0).sound == TONE  # type: ignore[union-attr]
    aid.update(ok(AHEAD, 0.53), 0.1)  # within hysteresis: still the tone
    assert aid.cue.sound == TONE
    assert aid.update(ok(AHEAD, 0.6), 0.2).sound == BEEP  # type: ignore[union-attr]
    aid.update(ok(AHEAD, 3.03), 0.3)
    assert aid.cue.sound == BEEP  # just past clear_m: kept
    assert aid.update(ok(AHEAD, 3.2), 0.4).sound == SILENCE  # type: ignore[union-attr]
    assert aid.update(ok(AHEAD, 3.03), 0.5) is None  # coming back needs clear_m itself


def test_small_changes_make_no_new_cue() -> None:
    aid = quiet()
    assert aid.update(ok(AHEAD, 1.50), 0.0) is not None
    assert aid.update(ok(AHEAD, 1.52), 0.1) is None
    assert aid.update(ok(AHEAD, 1.47), 0.2) is None
    cue = aid.update(ok(AHEAD, 1.44), 0.3)
    assert cue is not None and cue.range_m == 1.44


def test_bearing_and_stereo_pan() -> None:
    left = quiet().update(ok(LEFT, 1.0), 0.0)
    right = quiet().update(ok(RIGHT, 1.0), 0.0)
    ahead = quiet().update(ok(AHEAD, 1.0), 0.0)
    assert left is not None and right is not None and ahead is not None
    assert left.bearing_deg == 30.0 and left.pan == -1.0  # positive pan is left (geometry.md)
    assert right.pan == 1.0 and ahead.pan == 0.0
    gl, gr = pan_gains(left.pan)
    assert gl == pytest.approx(1.0) and gr == pytest.approx(0.0, abs=1e-12)
    for p in (-1.0, -0.3, 0.0, 0.5, 1.0):
        a, b = pan_gains(p)
        assert a * a + b * b == pytest.approx(1.0)  # constant power
    assert pan_gains(0.0)[0] == pytest.approx(math.sqrt(0.5))


def test_nearest_zone_wins_and_switching_needs_a_clear_margin() -> None:
    aid = quiet()
    aid.update(ok(LEFT, 2.0), 0.0)
    aid.update(ok(AHEAD, 1.0), 0.1)
    assert aid.cue.zone == 3
    aid.update(ok(RIGHT, 0.98), 0.2)  # nearer by less than the hysteresis: stay ahead
    assert aid.cue.zone == 3
    cue = aid.update(ok(RIGHT, 0.9), 0.3)
    assert cue is not None and cue.zone == 6 and cue.pan == 1.0


def test_stale_readings_dropped() -> None:
    aid = quiet(max_age_s=1.5)
    aid.update(ok(LEFT, 1.0), 0.0)
    aid.update(ok(AHEAD, 2.0), 1.0)
    assert aid.cue.zone == 0
    cue = aid.tick(1.51)  # the left reading is now too old: the one ahead drives the cue
    assert cue is not None and cue.zone == 3 and cue.range_m == 2.0
    aid.update(ok(RIGHT, 3.5), 2.5)  # the rig still sees (nothing near on the right)
    cue = aid.tick(2.6)
    assert cue is not None and cue.sound == SILENCE


def test_ambiguous_holds_then_drops() -> None:
    aid = quiet(hold_s=0.5, max_age_s=1.5)
    aid.update(ok(AHEAD, 1.2), 0.0)
    assert aid.update(bad(AHEAD, AMBIGUOUS), 0.2) is None  # held
    assert aid.cue.sound == BEEP and aid.cue.range_m == 1.2
    assert aid.update(bad(AHEAD, AMBIGUOUS), 0.6) is None  # hold runs from the first one
    cue = aid.tick(0.71)
    assert cue is not None and cue.sound == SILENCE


# --- cannot see ----------------------------------------------------------------------------------


def part_fault(pan: float, part: str | None) -> ZoneResult:
    return ZoneResult(0, pan, 0.0, FAULT, detail="camera: no frame within 1 s", part=part)


@pytest.mark.parametrize(("part", "words"), [("camera", "camera fault"), ("ptu", "pan-tilt unit fault"),
                                             ("lasers", "lasers fault"), (None, "ranging fault")])
def test_a_fault_zone_is_blind_at_once_and_says_so(part: str | None, words: str) -> None:
    aid = quiet()
    aid.update(ok(AHEAD, 1.2), 0.0)
    cue = aid.update(part_fault(AHEAD, part), 0.1)
    assert cue is not None and cue.sound == BLIND and cue.reason == words
    assert cue.speech == CANNOT_SEE  # said even with speak_new off: it is not an announcement
    assert cue.range_m is None and cue.zone is None and cue.pitch_hz is None
    assert aid.update(part_fault(LEFT, part), 0.3) is None  # the same blindness: nothing new
    assert aid.speak(0.35) == CANNOT_SEE


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0.0, 0.69), min_size=1, max_size=20), st.floats(0.71, 30.0))
def test_nothing_from_the_rig_for_too_long_is_blind_never_silence(gaps: list[float], wait: float) -> None:
    """Results (and frames) that come often enough keep the readings; a wait longer than
    blind_after_s (0.7 s) is blind, whatever came before, and the first result after it ends it."""
    aid = quiet(blind_after_s=0.7)
    t = last = 0.0
    for g in gaps:
        t = last + g
        assert aid.update(ok(AHEAD, 4.0), t) is None  # clear, seen: silence all along
        last = t + g / 2
        aid.alive(last)  # a frame between results
        assert aid.tick(last + 0.69) is None
    t_frame = last
    cue = aid.tick(t_frame + wait)
    assert cue is not None and cue.sound == BLIND and cue.reason.startswith("nothing from the rig")
    assert aid.tick(t_frame + wait + 5.0) is None  # still blind: no new cue for the longer wait
    cue = aid.update(ok(AHEAD, 1.5), t_frame + wait + 5.1)
    assert cue is not None and cue.sound == BEEP and cue.range_m == 1.5


def test_blind_from_the_start_when_nothing_ever_comes() -> None:
    aid = quiet()
    assert aid.tick(10.0) is None  # the first tick starts the wait
    cue = aid.tick(10.8)
    assert cue is not None and cue.sound == BLIND


def test_a_frame_taken_before_the_stall_does_not_restart_the_wait() -> None:
    aid = quiet(blind_after_s=0.7)
    aid.update(ok(AHEAD, 1.5), 1.0)
    aid.alive(0.9)  # delivered late, exposed earlier: the wait still runs from 1.0
    cue = aid.tick(1.71)
    assert cue is not None and cue.sound == BLIND


def test_back_to_the_readings_after_good_zones() -> None:
    aid = BlindAid(BlindAidConfig(speak_min_gap_s=3.0))
    first = aid.update(ok(LEFT, 1.2), 0.0)
    assert first is not None and first.speech == "one point two metres, left"
    blind = aid.update(part_fault(LEFT, "camera"), 1.0)
    assert blind is not None and blind.sound == BLIND and blind.speech == CANNOT_SEE
    # Back: the zone ranges again; what is seen then is new, and said (the gap has passed).
    cue = aid.update(ok(AHEAD, 0.4), 3.5)
    assert cue is not None and cue.sound == TONE and cue.speech == "zero point four metres, ahead"
    # Blind again soon: the warble at once, the words not again within speak_min_gap_s.
    again = aid.update(part_fault(AHEAD, "camera"), 3.9)
    assert again is not None and again.sound == BLIND and again.speech is None


def test_the_service_can_say_it_cannot_see() -> None:
    aid = quiet()
    aid.update(ok(AHEAD, 1.0), 0.0)
    cue = aid.set_blinded("lasers switched off by cmd/lasers_off", 0.1)
    assert cue is not None and cue.sound == BLIND and cue.reason == "lasers switched off by cmd/lasers_off"
    assert aid.update(ok(AHEAD, 1.0), 0.2) is None  # zones may come; still blind while it says so
    cue = aid.set_blinded(None, 0.3)
    assert cue is not None and cue.sound == BEEP and cue.range_m == 1.0


def test_blind_after_s_bounded_so_the_cue_comes_within_a_second() -> None:
    with pytest.raises(FieldError):
        BlindAidConfig(blind_after_s=1.0)
    with pytest.raises(FieldError):
        BlindAidConfig(blind_after_s=0.0)


def test_fresh_reading_after_fault_ends_hold() -> None:
    aid = quiet(hold_s=0.5)
    aid.update(ok(AHEAD, 1.2), 0.0)
    assert aid.update(bad(AHEAD, FAULT), 0.1).sound == BLIND  # type: ignore[union-attr]
    aid.update(ok(AHEAD, 1.2), 0.3)
    aid.tick(0.9)
    assert aid.cue.sound == BEEP


def test_no_spot_clears_zone_but_not_when_too_near() -> None:
    aid = quiet(hold_s=0.5)
    aid.update(ok(AHEAD, 1.2), 0.0)
    cue = aid.update(bad(AHEAD, NO_SPOT), 0.1)
    assert cue is not None and cue.sound == SILENCE
    aid = quiet(hold_s=0.5)
    aid.update(ok(AHEAD, 0.3), 0.0)  # walked into something: the rig's next view is out of range
    assert aid.update(bad(AHEAD, OUT_OF_RANGE), 0.1) is None
    assert aid.cue.sound == TONE
    assert aid.tick(0.65).sound == SILENCE  # type: ignore[union-attr]


# --- speech ------------------------------------------------------------------------------------


@pytest.mark.parametrize(("n", "words"), [
    (0, "zero"), (7, "seven"), (13, "thirteen"), (20, "twenty"), (42, "forty-two"),
    (100, "one hundred"), (305, "three hundred and five"),
])
def test_integer_words(n: int, words: str) -> None:
    assert integer_words(n) == words


@pytest.mark.parametrize(("d", "words"), [
    (1.2, "one point two metres"), (1.25, "one point three metres"), (0.04, "zero point zero metres"),
    (0.96, "one point zero metres"), (2.0, "two point zero metres"), (12.34, "twelve point three metres"),
])
def test_distance_words(d: float, words: str) -> None:
    assert distance_words(d) == words


def test_speak_phrases() -> None:
    aid = quiet()
    assert aid.speak(0.0) == "way clear"
    aid.update(ok(LEFT, 1.2), 0.1)
    assert aid.speak(0.2) == "one point two metres, left"
    aid.reset()
    aid.update(ok(-10.0, 2.04), 0.0)
    assert aid.speak(0.1) == "two point zero metres, ahead"
    aid.reset()
    aid.update(ok(-20.0, 0.45), 0.0)
    assert aid.speak(0.1) == "zero point five metres, right"


def test_new_obstacle_announced_and_rate_limited() -> None:
    aid = BlindAid(BlindAidConfig(speak_min_gap_s=3.0))
    cue = aid.update(ok(LEFT, 1.2), 0.0)
    assert cue is not None and cue.speech == "one point two metres, left"
    assert aid.update(ok(LEFT, 1.0), 0.5).speech is None  # type: ignore[union-attr]  # same direction
    cue = aid.update(ok(RIGHT, 0.8), 1.0)  # another direction, but too soon: beeps only
    assert cue is not None and cue.zone == 6 and cue.speech is None
    assert aid.update(ok(RIGHT, 0.8), 2.0) is None
    cue = aid.update(ok(RIGHT, 0.8), 3.1)  # the gap has passed and it still holds: said now
    assert cue is not None and cue.speech == "zero point eight metres, right"
    assert aid.update(ok(RIGHT, 0.8), 3.2) is None  # said once


def test_announcement_after_clear_and_repeated_same_direction_after_clear() -> None:
    aid = BlindAid(BlindAidConfig(speak_min_gap_s=1.0))
    assert aid.update(ok(AHEAD, 2.0), 0.0).speech == "two point zero metres, ahead"  # type: ignore[union-attr]
    assert aid.update(ok(AHEAD, 4.0), 0.5).sound == SILENCE  # type: ignore[union-attr]
    cue = aid.update(ok(AHEAD, 1.5), 0.7)  # new after clear, within the gap: not yet
    assert cue is not None and cue.speech is None
    cue = aid.update(ok(AHEAD, 1.5), 1.2)
    assert cue is not None and cue.speech == "one point five metres, ahead"


def test_requested_speech_counts_for_rate_limit_and_speak_new_off() -> None:
    aid = BlindAid(BlindAidConfig(speak_min_gap_s=3.0))
    aid.speak(0.0)
    cue = aid.update(ok(LEFT, 1.0), 1.0)
    assert cue is not None and cue.speech is None
    aid = quiet()
    assert aid.update(ok(LEFT, 1.0), 0.0).speech is None  # type: ignore[union-attr]


def test_cue_json() -> None:
    cue = quiet().update(ok(LEFT, 1.23456), 0.0)
    assert cue is not None
    payload = cue.to_json()
    assert set(payload) == {"bearing_deg", "range_m", "zone", "sound", "interval_s", "pitch_hz", "pan", "speech",
                            "reason"}
    assert payload["reason"] is None
    assert payload["sound"] == "beep" and payload["range_m"] == 1.235 and payload["zone"] == 0
    assert "ts" not in payload
    json.dumps(payload)
    silent = Cue().to_json()
    assert silent["sound"] == "silence" and silent["range_m"] is None and silent["pitch_hz"] is None
