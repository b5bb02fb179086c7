"""The accuracy benchmark's parts: the family of conditions (seeded, disjoint, within its ranges, each
a valid configuration), the floor of rendered frames against a fit that reaches it, the scoring
rules, and a tiny family recorded, replayed and reported."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from edge import isp
from edge.accuracy import conditions as cond
from edge.accuracy.floor import OBSERVABLE_SNR, spot_profile
from edge.accuracy.score import Figures, ZoneOutcome, failing_by_chance, stricter, targets
from edge.config import load_config
from edge.ranging import OK, ZoneResult

# --- conditions ----------------------------------------------------------------------------------


def test_conditions_are_seeded_and_tuning_never_meets_evaluation() -> None:
    assert cond.condition("tuning", 3) == cond.condition("tuning", 3)
    tuning = cond.family("tuning", 50)
    evaluation = cond.family("evaluation", 50)
    assert [c.name for c in tuning[:2]] == ["tuning-0", "tuning-1"]
    assert not {c.seed for c in tuning} & {c.seed for c in evaluation}
    # By construction, over the whole of both families: seeds in disjoint blocks.
    last_tuning = cond.FAMILIES["tuning"] + cond.FAMILY_SIZE - 1
    assert last_tuning < cond.FAMILIES["evaluation"]
    assert tuning[0] != replace(evaluation[0], family="tuning", index=0, seed=tuning[0].seed)
    assert cond.family("evaluation", 3, start=10)[0] == cond.condition("evaluation", 10)
    with pytest.raises(ValueError, match="family"):
        cond.condition("test", 0)
    with pytest.raises(ValueError, match="index"):
        cond.condition("tuning", cond.FAMILY_SIZE)


def test_conditions_cover_what_the_issue_asks_within_its_ranges() -> None:
    family = cond.family("tuning", 200)
    jpeg = [c for c in family if c.jpeg_quality]
    assert 0.3 < len(jpeg) / len(family) < 0.7
    assert all(50 <= c.jpeg_quality <= 95 and c.output_bits == 8 for c in jpeg)
    assert {c.jpeg_chroma for c in jpeg} == {"4:2:0", "4:4:4"}
    assert {c.bayer for c in family if c.colour} == {"none", "bilinear", "vng", "ea"}
    assert any(not c.colour for c in family) and all(c.bayer == "none" for c in family if not c.colour)
    assert {(c.width, c.height) for c in family} == set(cond.RESOLUTIONS)
    assert {c.scene for c in family} == set(cond.SCENES)
    for key, lo, hi in [("laser_power", 0.25, 4), ("room_light", 0.25, 4), ("albedo_scale", 0.1, 1.2),
                        ("texture_scale", 0.3, 3), ("extra_gloss", 0, 0.3), ("laser_angle_deg", 0, 0.3),
                        ("focus_m", 0.5, 3), ("f_number", 1.8, 2.8), ("read_noise_e", 1.5, 15),
                        ("fill", 0.25, 0.8)]:
        values = [getattr(c, key) for c in family]
        assert lo <= min(values) and max(values) <= hi, key
        assert max(values) - min(values) > 0.5 * (hi - lo), f"{key} does not spread over its range"
    # Half-power points of the log-uniform scales: as many below 1 as above.
    assert 0.35 < np.mean([c.laser_power < 1 for c in family]) < 0.65
    # The default rig's own camera: about half of the lossless colour cameras at 640 × 480 are a
    # Bayer sensor read out at 1640 × 1232 and ISP-scaled, with each of the demosaicings, 8-bit.
    pi_like = [c for c in family if (c.width, c.height) == (640, 480) and c.colour and not c.jpeg_quality]
    scaled = [c for c in family if c.isp]
    assert set(scaled) <= set(pi_like) and 0.3 < len(scaled) / len(pi_like) < 0.7
    assert {c.bayer for c in scaled} == set(cond.ISP_DEMOSAICS) and {c.output_bits for c in scaled} == {8}
    assert {c.frames for c in scaled} == {"ISP-scaled lossless"}
    # A webcam (JPEG colour frames) mixes its channels as real sensors' matrices do, warm to cool;
    # the Pi camera (lossless) and grey cameras do not.
    webcams = [c for c in family if c.colour and c.jpeg_quality]
    assert all(not c.colour_matrix for c in family if c not in webcams)
    reds = []
    for c in webcams:
        m = np.array(c.colour_matrix).reshape(3, 3)
        assert np.allclose(m.sum(axis=1), 1.0, atol=0.02)  # grey stays grey
        reds.append(m[0, 0])
        warm_cool = [np.array(pair).reshape(2, 3, 3) for pair in cond.SENSOR_COLOUR_MATRICES.values()]
        assert any(np.all((m >= pair.min(axis=0) - 1e-3) & (m <= pair.max(axis=0) + 1e-3)) for pair in warm_cool)
    assert min(reds) < 1.6 and max(reds) > 2.1


def test_a_share_of_the_rigs_move_between_their_frames() -> None:
    """About MOVING_SHARE of the conditions turn the rig between each laser-on frame and the
    laser-off frame after it (sim.sway.jolt_deg), by 0.02-1°; the others are still and keep the
    configuration's motion, which a `--set` may give. The doctor's aim is at rest. A family kept
    before the knob was drawn reads as still, and every other draw is as it was."""
    base = load_config(None, [])
    family = cond.family("evaluation", 200)
    moving = [c for c in family if c.jolt_deg]
    assert 0.2 < len(moving) / len(family) < 0.45
    assert cond.JOLT_DEG[0] <= min(c.jolt_deg for c in moving) and max(c.jolt_deg for c in moving) <= cond.JOLT_DEG[1]
    assert max(c.jolt_deg for c in moving) > 10 * min(c.jolt_deg for c in moving)  # (log-uniform: all scales)
    given = ["sim.sway.jolt_deg=0.3"]
    for c in (moving[0], next(c for c in family if not c.jolt_deg)):
        extra = c.overrides(base.sim.beam.e_per_ms_at_1m, base.sim.ambient.white_e_per_ms, zones=5)
        assert load_config(None, list(extra)).sim.sway.jolt_deg == c.jolt_deg
        assert load_config(None, [*given, *extra]).sim.sway.jolt_deg == (c.jolt_deg or 0.3)
        aimed = c.aimed(base.sim.beam.e_per_ms_at_1m, base.sim.ambient.white_e_per_ms, 30.0, 0)
        assert load_config(None, list(aimed)).sim.sway.jolt_deg == 0.0
    assert "turned" in moving[0].describe()
    doc = json.loads(json.dumps(moving[0].to_json()))
    del doc["jolt_deg"]
    assert cond.Condition.from_json(doc) == replace(moving[0], jolt_deg=0.0)


def test_a_share_of_the_rigs_sample_the_room_over_their_pixels_area() -> None:
    """About AREA_SHARE of the conditions render with sim.optics.pixel_area; the others keep the
    configuration's (a `--set` may give it). A family kept before the knob was drawn reads as
    sampled at pixels' centres."""
    base = load_config(None, [])
    family = cond.family("evaluation", 200)
    area = [c for c in family if c.pixel_area]
    assert 0.35 < len(area) / len(family) < 0.65
    centre = next(c for c in family if not c.pixel_area)
    for c in (area[0], centre):
        extra = c.overrides(base.sim.beam.e_per_ms_at_1m, base.sim.ambient.white_e_per_ms, zones=5)
        assert load_config(None, list(extra)).sim.optics.pixel_area == c.pixel_area
        assert load_config(None, ["sim.optics.pixel_area=true", *extra]).sim.optics.pixel_area
    assert "area-sampled" in area[0].describe() and "area-sampled" not in centre.describe()
    doc = json.loads(json.dumps(area[0].to_json()))
    del doc["pixel_area"]
    assert cond.Condition.from_json(doc) == replace(area[0], pixel_area=False)


def test_no_drawn_lens_folds_inside_its_picture() -> None:
    """Every pixel of every drawn camera has a ray, and the ray leads back to it: the distorted
    radius still grows at the picture's corners. (Drawn unbounded, 8 % of the conditions folded
    inside the picture, and the simulator rendered their corners through rays that do not exist.)
    Only the strongest barrels were bounded: the rest keep their draw."""
    bounded = 0
    for family in ("tuning", "evaluation"):
        for c in cond.family(family, 300):
            cam = c.camera
            corners = np.array([[0.0, 0.0], [cam.width - 1.0, 0.0], [0.0, cam.height - 1.0],
                                [cam.width - 1.0, cam.height - 1.0]])
            assert np.abs(cam.project(cam.rays(corners)) - corners).max() < 0.01, c.name
            bounded += c.k1 == cond.unfolded_k1(c.width, c.height, c.fx, c.cx, c.cy)
    assert 10 < bounded < 100  # (about 8 % of 600)


def test_a_family_kept_before_the_colour_matrix_was_drawn_reads_as_without_one() -> None:
    c = cond.condition("tuning", 321)
    assert c.colour_matrix  # a JPEG colour condition
    doc = json.loads(json.dumps(c.to_json()))
    assert cond.Condition.from_json(doc) == c
    del doc["colour_matrix"]
    assert cond.Condition.from_json(doc) == replace(c, colour_matrix=())
    del doc["seed"]
    with pytest.raises(KeyError, match="seed"):
        cond.Condition.from_json(doc)


def test_a_condition_is_a_valid_configuration_of_what_it_says() -> None:
    base = load_config(None, [])
    conditions = cond.family("evaluation", 12)
    assert any(c.isp for c in conditions) and not all(c.isp for c in conditions)
    for c in conditions:
        extra = c.overrides(base.sim.beam.e_per_ms_at_1m, base.sim.ambient.white_e_per_ms, zones=5)
        config = load_config(None, list(extra))
        assert config.sim.seed == c.seed == config.sim.rig_error.seed
        assert config.sim.scene == c.scene
        camera = config.rig.build().camera
        # An ISP condition renders the Pi camera's 1640 × 1232 sensor, which the ISP scales to the
        # condition's camera; per area, the sensor sees the room as that camera would.
        per_area = isp.SCALE**2 if c.isp else 1.0
        ranged = isp.scaled_camera(camera) if c.isp else camera
        assert [getattr(ranged, k) for k in ("width", "height", "fx", "fy", "cx", "cy")] == pytest.approx(
            [getattr(c.camera, k) for k in ("width", "height", "fx", "fy", "cx", "cy")], abs=1e-9)
        assert camera.width == (isp.RAW.width if c.isp else c.width) and config.rig.camera.dist == (c.k1, 0, 0, 0, 0)
        assert config.sim.beam.e_per_ms_at_1m == pytest.approx(20000.0 * c.laser_power)
        assert config.sim.ambient.white_e_per_ms == pytest.approx(600.0 * c.room_light / per_area)
        assert config.sim.sensor.full_well_e == pytest.approx(c.full_well_e / per_area)
        assert config.sim.optics.psf_sigma_px == pytest.approx(c.psf_sigma_px * math.sqrt(per_area))
        assert config.sim.beam.speckle_grain == pytest.approx(c.speckle_grain * math.sqrt(per_area))
        assert config.sim.sensor.bayer == c.bayer and config.sim.sensor.jpeg_quality == c.jpeg_quality
        assert config.sim.surfaces.albedo_scale == c.albedo_scale
        assert config.sim.sensor.colour_matrix == c.colour_matrix
        assert config.sweep.poses() == c.poses(5)
        white = config.sim.ambient.white_e_per_ms * config.camera.exposure_us / 1000.0  # e of a white wall
        assert 500.0 <= config.camera.exposure_us <= 30000.0
        assert (white == pytest.approx(c.fill * config.sim.sensor.full_well_e, rel=1e-3)
                or config.camera.exposure_us in (500, 30000))
        assert c.name in c.describe() or c.scene in c.describe()
    # A matrix given by `--set` reaches the cameras that draw none (the Pi camera's lossless frames);
    # a webcam keeps its own.
    lossless, webcam = cond.condition("tuning", 320), cond.condition("tuning", 321)
    given = ["sim.sensor.colour_matrix=[2.0, -0.5, -0.5, -0.5, 2.0, -0.5, -0.5, -0.5, 2.0]"]
    for c, matrix in ((lossless, (2.0, -0.5, -0.5, -0.5, 2.0, -0.5, -0.5, -0.5, 2.0)), (webcam, webcam.colour_matrix)):
        extra = c.overrides(base.sim.beam.e_per_ms_at_1m, base.sim.ambient.white_e_per_ms, zones=5)
        assert load_config(None, [*given, *extra]).sim.sensor.colour_matrix == matrix
    c = cond.condition("tuning", 0)
    assert c.poses(12)[:5] == c.poses(5)  # a short run is a prefix of a long one
    assert all(-180 <= p <= 180 and -30 <= t <= 15 for p, t in c.poses(50))


# --- the floor of rendered frames ----------------------------------------------------------------

_SMALL = ["rig.camera.width=160", "rig.camera.height=120", "rig.camera.fx=132.5", "rig.camera.fy=132.5",
          "rig.camera.cx=79.5", "rig.camera.cy=59.5"]


def test_the_floor_of_a_rendered_spot_is_what_a_fit_of_its_frames_reaches() -> None:
    """The renderer's noise is the floor's: a least-squares fit of the spot's known shape to the
    difference of real frames scatters as the floor's noise term says."""
    from edge.accuracy.truth import sensor_of, zone_floors
    from edge.sim.record import flat_target_scene
    from edge.sim.render import Renderer

    config = load_config(None, [*_SMALL, "sim.sensor.colour=false", "sim.sensor.output_bits=16",
                                "sim.beam.speckle=0", "sim.ambient.flicker=0", "sim.beam.e_per_ms_at_1m=400"])
    renderer = Renderer(flat_target_scene(1.5, "cardboard"), config.rig.build(), config.sim, config.camera)
    floors, zone = zone_floors(renderer, sensor_of(config), [(0.0, 0.0)])
    assert set(floors) == {"center", "parallel", "sloped"} and zone["used"] == ["center", "parallel", "sloped"]
    center = floors["center"]
    assert center.observable and center.speckle_m == 0.0 and center.clipped == 0
    assert zone["reference_sigma_m"] == pytest.approx(center.sigma_m, rel=1e-6)
    assert zone["sigma_m"] < 0.8 * center.sigma_m  # the sloped laser's depth is the sharper
    model = renderer.spot_model(0.0, 0.0, "center")
    assert model is not None and model.truth.pixel is not None
    s = config.sim.sensor
    e_per_dn = s.full_well_e / 65535.0
    bg = model.background
    h, w = bg.electrons.shape[:2]
    rows, cols = slice(bg.y0, bg.y0 + h), slice(bg.x0, bg.x0 + w)
    rng = np.random.default_rng(2)
    fits = []
    for _ in range(120):
        on = renderer.render(0.0, 0.0, {"center": 1.0}, 0.0, rng)[rows, cols].astype(float)
        off = renderer.render(0.0, 0.0, {}, 0.0, rng)[rows, cols].astype(float)
        diff = (on - off) * e_per_dn
        c = model.truth.pixel.copy()
        for _ in range(5):
            g, d = spot_profile(c, model.covariance, bg.x0, bg.y0, w, h)
            jac = (model.total_e * d).reshape(2, -1).T
            c = c + np.linalg.lstsq(jac, (diff - model.total_e * g).ravel(), rcond=None)[0]
        fits.append(c)
    spread = np.array(fits).std(axis=0)
    bound = np.sqrt(np.diag(center.noise_cov_px))
    # An unweighted fit is nearly efficient here (the room light's noise dominates the spot's own).
    assert np.all(spread >= 0.85 * bound) and np.all(spread <= 1.3 * bound), (spread, bound)


# --- scoring -------------------------------------------------------------------------------------


def _zone(index: int, status: str = OK, range_m: float | None = 2.0, sigma_m: float | None = 0.01,
          truth_m: float | None = 2.0, visible: bool = True, floor_m: float | None = 0.01,
          snr: float = 20.0) -> ZoneOutcome:
    return ZoneOutcome(index, status, range_m if status == OK else None, sigma_m if status == OK else None,
                       truth_m, visible, floor_m, snr)


def test_outcomes_read_the_truth_the_recording_carries() -> None:
    truth = {"range_m": 2.0, "lasers": {"center": {"visible": True}},
             "floor": {"sigma_m": 0.004, "reference_sigma_m": 0.01, "lasers": {"center": {"snr": 12.5}}}}
    result = ZoneResult(3, 10.0, 0.0, OK, 2.01, 0.006)
    z = ZoneOutcome.of(result, truth, "center")
    assert (z.truth_m, z.visible, z.floor_m, z.snr, z.reference_floor_m) == (2.0, True, 0.004, 12.5, 0.01)
    assert z.observable and z.error_m == pytest.approx(0.01) and z.ratio == pytest.approx(2.5)
    assert z.within_2sigma is True and not z.wrong
    blind = ZoneOutcome.of(ZoneResult(4, 0.0, 0.0, "no_spot"), {"range_m": None}, "center")
    assert not blind.observable and blind.snr == 0.0 and blind.error_m is None
    # Hidden at the zone's pose, seen in its other view (the floor counts every view): seen.
    nudged = {"range_m": 1.87, "lasers": {"center": {"visible": False, "why": "occluded"}},
              "floor": {"sigma_m": 0.045, "lasers": {"center": {"snr": 59.25, "views": 1}}}}
    z = ZoneOutcome.of(ZoneResult(5, 0.0, 0.0, OK, 1.885, 0.058), nudged, "center")
    assert z.visible and z.observable and not z.wrong
    hidden = {"range_m": 1.87, "lasers": {"center": {"visible": False, "why": "occluded"}},
              "floor": {"sigma_m": 0.045, "lasers": {}}}
    z = ZoneOutcome.of(ZoneResult(6, 0.0, 0.0, OK, 1.885, 0.058), hidden, "center")
    assert not z.visible and z.wrong and z.blunder


def test_figures_and_targets_follow_the_rules() -> None:
    zones = [
        _zone(0, range_m=2.01),  # 1 floor off, within its claimed 2σ
        _zone(1, range_m=2.03, sigma_m=0.01),  # 3 floors off, claims too little
        _zone(2, status="no_spot"),  # observable, missed
        _zone(3, status="no_spot", snr=OBSERVABLE_SNR - 1),  # too faint to count
        _zone(4, range_m=2.5),  # 25 % off: wrong
        _zone(5, visible=False, floor_m=None, snr=0.0),  # ranged what the camera cannot see: wrong
    ]
    f = Figures.of(zones)
    assert (f.zones, f.observable, f.covered, f.ok, f.wrong_ok) == (6, 4, 3, 4, 2)
    # Both wrong ones are blunders: 25 % off at ± 0.5 %, and a spot the camera cannot see.
    assert f.blunders == 2 and zones[4].blunder and zones[5].blunder and not zones[1].blunder
    tail = _zone(6, range_m=2.21, sigma_m=0.09)  # 10.5 % off at ± 4.1 %: 2.3σ, the tail honest σ leaves
    assert tail.wrong and not tail.blunder
    assert f.coverage == pytest.approx(3 / 4)
    assert f.missed == {"no_spot": 1}
    assert f.mean_abs_m == pytest.approx((0.01 + 0.03 + 0.5) / 3)
    assert f.median_ratio == pytest.approx(3.0)
    assert f.within_2sigma == pytest.approx(2 / 4)  # zones 0 and 5 (error 0) of the four ok
    met = {t.what.split(" ")[0]: t.met for t in targets([f], f)}
    assert met == {"wrong": False, "within": False, "coverage": False, "mean": False}
    good = Figures.of([_zone(i, range_m=2.0 + 0.005 * (-1) ** i) for i in range(10)])
    assert all(t.met for t in targets([good], good))
    assert math.isnan(Figures.of([]).coverage)


def test_a_surer_ok_is_read_off_the_claimed_sigmas() -> None:
    zones = [
        _zone(0, range_m=2.0, sigma_m=0.02),  # 1 %: ok at every share
        _zone(1, range_m=2.21, sigma_m=0.09),  # 4.1 % of its range, and 10.5 % off: wrong
        _zone(2, range_m=1.98, sigma_m=0.068),  # 3.4 %: ok at 3.5 % and over
        _zone(3, status="no_spot"),  # observable, never ok
        _zone(4, range_m=2.0, sigma_m=0.06, snr=OBSERVABLE_SNR - 1),  # 3 %, but not observable
    ]
    at = {round(x.fraction, 3): x for x in stricter(zones, (0.05, 0.04, 0.035, 0.03))}
    assert all(x.observable == 4 for x in at.values())
    assert [(at[f].covered, at[f].wrong_ok) for f in (0.05, 0.04, 0.035, 0.03)] == [(3, 1), (2, 0), (2, 0), (1, 0)]
    assert at[0.04].coverage == pytest.approx(2 / 4)
    # At the estimator's own share, it is the family's figures.
    f = Figures.of(zones)
    assert (at[0.05].covered, at[0.05].wrong_ok) == (f.covered, f.wrong_ok)


# --- a tiny family, end to end ------------------------------------------------------------------


def test_a_tiny_family_is_recorded_replayed_and_reported(tmp_path: Path) -> None:
    from edge.accuracy.bench import report, run_family
    from edge.recording import read_recording

    tiny = replace(cond.condition("tuning", 0), width=160, height=120, fx=110.0, cx=79.5, cy=59.5, k1=0.0,
                   scene="office")
    runs = run_family(None, [], [tiny], zones=3, rig="true", jobs=1, keep=tmp_path)
    (run,) = runs
    assert len(run.outcomes) == 3 and len(run.rows) == 3 and run.rig == "true"
    rec = read_recording(tmp_path / "tuning-0")
    assert rec.rig.camera.width == 160 and len(rec.zones) == 3
    for zone in rec.zones:
        assert zone.truth is not None and "floor" in zone.truth
        if zone.truth["lasers"]["center"]["visible"]:
            assert zone.truth["floor"]["lasers"]["center"]["snr"] > 0
    # The oracle ranged each zone whose reference it sees, from the same frames, to within a few floors.
    for row in run.rows:
        if row["visible"] and row["floor"].get("sigma_m"):
            assert row["oracle_error_m"] is not None
            assert abs(row["oracle_error_m"]) < 5.0 * row["floor"]["sigma_m"], row
    text = "\n".join(report(runs, "tuning", 3, "true"))
    kind = f"    {tiny.frames} "
    assert tiny.frames in {"grey lossless", "grey JPEG", "3-colour lossless", "3-colour JPEG", "Bayer lossless",
                           "Bayer JPEG"}
    assert sum(line.startswith(kind) and "(1): coverage" in line for line in text.splitlines()) == 1
    for label in ("tuning-0", "family:", "coverage", "÷ floor", "the oracle's", "by kind of frames", "targets",
                  "wrong ok = 0", "a surer `ok`"):
        assert label in text


def test_a_moving_rig_is_judged_on_its_frames_with_the_true_turn_taken_out(tmp_path: Path) -> None:
    """A condition whose rig turns between its frames is recorded turned, with each laser-off
    frame's turn in the zone's truth, and ranged from those frames; what is observable, and the
    oracle, are read from the same frames with each laser-off frame turned back by its true turn."""
    from edge.accuracy.bench import _frame_snr, condition_config, report, run_family
    from edge.accuracy.unturned import TURNS_KEY, unturned_groups
    from edge.recording import read_recording
    from edge.replay import zone_groups
    from edge.sim.record import scene_for, true_rig
    from edge.sim.render import Renderer

    # (A room of faint texture and lossless frames without a Bayer filter: turned back, they are
    # nearly the frames at rest. A room's strong texture, sampled once a pixel, does not resample:
    # turned back, the difference keeps it, as it would for any estimator.)
    tiny = replace(cond.condition("tuning", 3), width=160, height=120, fx=110.0, cx=79.5, cy=59.5, k1=0.0,
                   scene="office", isp=False, jolt_deg=1.0, bayer="none", texture_scale=0.2, pixel_area=False)
    (run,) = run_family(None, [], [tiny], zones=4, rig="true", jobs=1, keep=tmp_path)
    rec = read_recording(tmp_path / "tuning-3")
    config = condition_config(None, [], tiny, 4)
    renderer = Renderer(scene_for(config), true_rig(config), config.sim, config.camera)
    turned, unturned, judged, in_turned = [], [], [], []
    for zone, row in zip(rec.zones, run.rows):
        turns = zone.truth[TURNS_KEY]
        assert len(turns) == sum(1 for f in zone.frames if not f.lasers_on)
        assert all(math.hypot(*t) == pytest.approx(1.0) for t in turns)  # (1°, each in a direction of its own)
        groups, _ = zone_groups(rec, zone)
        back = unturned_groups(rec, zone, renderer)
        on = groups[0].on[0].astype(float)
        turned.append(np.abs(on - groups[0].off[0]).mean())
        unturned.append(np.abs(on - back[0].off[0]).mean())
        assert row["visible"] and row["frame_snr"] is not None
        assert row["frame_snr"] == _frame_snr(back, zone, "center")
        judged.append(row["frame_snr"])
        in_turned.append(_frame_snr(groups, zone, "center") or 0.0)
    # Read in the turned frames, the room's edges hid the spots.
    assert np.mean(judged) > 1.25 * np.mean(in_turned)
    # Turned 1° (2 px here), the room's edges stay in the laser-on less laser-off difference; turned
    # back by the true turn, the difference is nearly that of the rig at rest.
    still = replace(tiny, jolt_deg=0.0)
    run_family(None, [], [still], zones=4, rig="true", jobs=1, keep=tmp_path / "still")
    rec_still = read_recording(tmp_path / "still" / "tuning-3")
    calm = []
    for zone in rec_still.zones:
        assert TURNS_KEY not in zone.truth
        groups, _ = zone_groups(rec_still, zone)
        calm.append(np.abs(groups[0].on[0].astype(float) - groups[0].off[0].astype(float)).mean())
    assert np.mean(turned) > 1.4 * np.mean(calm)
    assert np.mean(unturned) < 1.3 * np.mean(calm) and np.mean(unturned) < 0.8 * np.mean(turned)
    text = "\n".join(report([run], "tuning", 4, "true"))
    assert "by the rig's motion between its frames" in text and "    moving " in text


def test_a_frame_turned_back_by_its_true_turn_is_the_frame_taken_at_rest() -> None:
    """Noise-free frames of the office turned 1.5° and turned back match the frame taken at rest.
    By the room's depth, not the turn alone: with the camera mounted 20 cm off the unit's axes, a
    turn by rotation alone (what a room at infinity would give) leaves far more. (Without the lens's
    fall-off, which stays with the sensor as the room turns: an estimator would take it out by
    a flat field.)"""
    from edge.accuracy.unturned import turned_back
    from edge.sim.record import scene_for, true_rig
    from edge.sim.render import Renderer

    off_axes = ["rig.mount.origin_m=[0.0, -0.2, 0.0]", "sim.optics.vignetting=false"]
    rest = load_config(None, off_axes)
    moving = load_config(None, [*off_axes, "sim.sway.jolt_deg=1.5"])
    still_renderer = Renderer(scene_for(rest), true_rig(rest), rest.sim, rest.camera)
    renderer = Renderer(scene_for(moving), true_rig(moving), moving.sim, moving.camera)
    pan = -90.0  # a wall about 1.3 m away
    turn = renderer.jolt({}, np.random.default_rng(5))
    frame = renderer.render(pan, 0.0, {}, 0.0, np.random.default_rng(5), noise=False)
    at_rest = still_renderer.render(pan, 0.0, {}, 0.0, np.random.default_rng(5), noise=False).astype(float)
    inner = (slice(16, -16), slice(16, -16))

    def rms(image: np.ndarray) -> float:
        return float(np.sqrt(((image.astype(float) - at_rest)[inner] ** 2).mean()))

    # The turn alone (a room at infinity): each pixel's ray turned into the turned camera.
    cam = renderer.rig.camera
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(float)
    turned_camera = renderer.camera_to_world(pan + turn[0], turn[1]).inverse()
    rays = renderer.camera_to_world(pan, 0.0).rotate(cam.rays(np.stack([u, v], axis=-1)))
    seen = cam.project(turned_camera.rotate(rays)).astype(np.float32)
    by_rotation = cv2.remap(frame, seen[..., 0], seen[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    exact = turned_back(frame, renderer, (pan, 0.0), turn)
    assert rms(exact) < 0.15 * rms(frame)
    assert rms(exact) < 0.7 * rms(by_rotation)


def test_kept_recordings_are_ranged_again_by_replay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`--keep` keeps a family's recordings and their figures; `--replay` ranges them again, as the
    estimator is now, without rendering or running the oracle again: the same zones, the same
    results from the same estimator, and what ranging was given follows --rig."""
    from edge.accuracy.bench import KEPT_FILE, KeptFamily, family_document, replay_family, run_family, software
    from edge.cli import main

    tiny = replace(cond.condition("tuning", 0), width=160, height=120, fx=140.0, cx=79.5, cy=59.5, k1=0.0,
                   scene="office", jpeg_quality=0, bayer="none", laser_power=3.0)
    runs = run_family(None, [], [tiny], zones=3, rig="true", jobs=1, keep=tmp_path)
    (tmp_path / KEPT_FILE).write_text(json.dumps(family_document(runs, "tuning", 3, "true", None, [])))
    kept = KeptFamily.read(tmp_path)
    assert kept.conditions == (tiny,) and kept.zones == 3 and kept.rig == "true"
    (again,) = replay_family(None, [], kept, "true")
    assert again.rows == runs[0].rows  # frame SNR and the oracle's errors kept, the ranging the same
    assert any(row["status"] == "ok" for row in again.rows)
    # An `ok` row names the spots its range was fused from (the reference's among them); others none.
    for row in again.rows:
        if row["status"] == "ok":
            assert row["used"]["center"] == [round(row["spot"]["depth_m"], 5), round(row["spot"]["sigma_m"], 5)]
            assert all(sigma > 0 for _, sigma in row["used"].values())
        else:
            assert row["used"] is None
    (nominal,) = replay_family(None, [], kept, "nominal")
    assert nominal.rig == "nominal" and [r["frame_snr"] for r in nominal.rows] == [r["frame_snr"] for r in again.rows]
    assert nominal.rows != again.rows  # the nominal rig is not the rig as built: other ranges

    out = tmp_path / "again.json"
    assert main(["bench", "accuracy", "--replay", str(tmp_path), "--jobs", "1", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "family: 3 zones" in printed
    written = json.loads(out.read_text())
    assert written["rows"] == json.loads(json.dumps(list(runs[0].rows)))
    # What rendered the frames and what ranged them: the same software here, said once.
    assert written["rendered_with"] == written["ranged_with"] == software() and kept.rendered_with == software()
    assert f"software: numpy {np.__version__}, opencv {cv2.__version__}, python" in printed

    # Frames rendered by other versions than those ranging them now: both are said, and kept.
    doc = json.loads((tmp_path / KEPT_FILE).read_text())
    doc["rendered_with"] = {"python": "3.11.7", "numpy": "1.26.4", "opencv": "4.10.0"}
    (tmp_path / KEPT_FILE).write_text(json.dumps(doc))
    assert main(["bench", "accuracy", "--replay", str(tmp_path), "--jobs", "1", "--json", str(out)]) == 0
    assert "software: rendered with numpy 1.26.4, opencv 4.10.0, python 3.11.7; ranged with numpy" in (
        capsys.readouterr().out)
    assert json.loads(out.read_text())["rendered_with"]["opencv"] == "4.10.0"
    # A family kept before the versions were: said, not guessed.
    del doc["rendered_with"]
    (tmp_path / KEPT_FILE).write_text(json.dumps(doc))
    assert main(["bench", "accuracy", "--replay", str(tmp_path), "--jobs", "1"]) == 0
    assert "what rendered the frames was not kept" in capsys.readouterr().out
    doc["rendered_with"] = "opencv 4"
    (tmp_path / KEPT_FILE).write_text(json.dumps(doc))
    assert main(["bench", "accuracy", "--replay", str(tmp_path), "--jobs", "1"]) != 0
    err = capsys.readouterr().err
    assert "rendered_with must be a table of versions" in err and "Traceback" not in err


def test_the_command_refuses_what_it_cannot_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from edge.cli import main

    assert main(["bench", "accuracy", "--conditions", "0"]) != 0
    assert "--conditions: must be 1-1000" in capsys.readouterr().err
    assert main(["bench", "accuracy", "--zones", "0"]) != 0
    assert "--zones" in capsys.readouterr().err
    assert main(["bench", "accuracy", "--replay", str(tmp_path), "--seed", "3"]) != 0
    assert "the family, its conditions and zones are the kept ones; drop --seed" in capsys.readouterr().err
    assert main(["bench", "accuracy", "--replay", str(tmp_path)]) != 0
    err = capsys.readouterr().err
    assert f"--replay {tmp_path}: no accuracy.json there" in err and "Traceback" not in err
    (tmp_path / "accuracy.json").write_text('{"family": "tuning"}')
    assert main(["bench", "accuracy", "--replay", str(tmp_path)]) != 0
    assert "is not what --keep writes" in capsys.readouterr().err
    (tmp_path / "accuracy.json").write_text(json.dumps(
        {"family": "tuning", "zones": 2, "rig": "true", "conditions": [cond.condition("tuning", 5).to_json()],
         "rows": []}))
    assert main(["bench", "accuracy", "--replay", str(tmp_path)]) != 0
    assert "tuning-5 has no recording there" in capsys.readouterr().err


@pytest.mark.slow  # a calibration recording: six distances of four nudged pairs
def test_the_calibrated_rig_is_fitted_from_a_simulated_board(tmp_path: Path) -> None:
    from edge.accuracy.bench import CALIBRATION_DISTANCES_M, run_condition
    from edge.recording import read_recording

    c = replace(cond.condition("tuning", 0), width=320, height=240, fx=265.0, cx=159.5, cy=119.5, k1=0.0,
                jpeg_quality=0, bayer="none", colour=True, laser_angle_deg=0.3)
    run = run_condition(None, [], c, 2, "calibrated", tmp_path, oracle=False)
    assert run.rig == "calibrated" and len(run.outcomes) == 2
    board = read_recording(tmp_path / "tuning-0-calibration")
    assert [z.truth["range_m"] for z in board.zones if z.truth] == pytest.approx(CALIBRATION_DISTANCES_M, abs=0.01)


@pytest.mark.slow  # two zones rendered at 1640 × 1232
def test_an_isp_condition_is_ranged_from_the_frames_the_pi_camera_s_isp_hands_over(tmp_path: Path) -> None:
    """The default rig's own camera in the family: its 1640 × 1232 sensor is recorded, scaled to
    640 × 480 as the ISP hands it over and ranged with the true rig seen through the ISP; the truth,
    the floor (the sensor's) and the oracle (told the scaled spot) agree with what ranging finds."""
    from edge.accuracy.bench import run_condition
    from edge.recording import read_recording

    c = cond.condition("tuning", 1)
    assert c.isp and c.bayer == "bilinear"
    run = run_condition(None, [], c, 2, "true", tmp_path, oracle=True)
    recording = read_recording(tmp_path / c.name)
    assert not (tmp_path / f"{c.name}-sensor").exists()  # only the scaled frames are kept
    camera = recording.rig.camera
    assert (camera.width, camera.height) == (640, 480) and camera.fx == pytest.approx(c.fx)
    assert (camera.cx, camera.cy) == pytest.approx((c.cx, c.cy))
    zone = recording.zones[1]
    assert recording.load_image(zone, zone.frames[0]).shape == (480, 640, 3)
    near = run.outcomes[1]  # a white-ish wall at 1.0 m, its spot 25 × the noise
    assert near.status == OK and near.floor_m is not None and near.sigma_m is not None and near.error_m is not None
    assert abs(near.error_m) < 2.5 * near.sigma_m and near.sigma_m < 0.02 * near.truth_m
    # The oracle, told where the sensor's spot lands in the scaled frames and how wide it is there,
    # places it as the floor allows.
    assert near.oracle_error_m is not None and abs(near.oracle_error_m) < 2.0 * near.floor_m


# --- observable in the frames (edge/accuracy/observe.py) ---


def _spot_frames(amplitude: float, noise: float, seed: int, background: float = 0.0):
    """An 8-bit BGR laser-on and laser-off frame: a red Gaussian spot (σ 1.6 px) at (100.3, 80.6)."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:160, 0:200]
    spot = amplitude * np.exp(-((u - 100.3) ** 2 + (v - 80.6) ** 2) / (2 * 1.6**2))
    frames = []
    for lit in (spot, 0.0):
        img = np.full((160, 200, 3), 40.0 + background) + rng.normal(0.0, noise, (160, 200, 3))
        img[..., 2] += lit
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return frames


def test_frame_snr_is_the_matched_filters_in_white_noise() -> None:
    from edge.accuracy.observe import frame_snr, mean_differences

    # Amplitude A in noise σ per frame (√2 σ in a difference): the matched filter's SNR is A σ_s √π / (√2 σ).
    expected = 6.0 * 1.6 * math.sqrt(math.pi) / (math.sqrt(2.0) * 2.0)
    got = [frame_snr(mean_differences([on], [off]), (100.3, 80.6), []) for on, off in
           (_spot_frames(6.0, 2.0, seed) for seed in range(8))]
    assert np.median(got) == pytest.approx(expected, rel=0.15)
    assert frame_snr(mean_differences(*[[f] for f in _spot_frames(0.0, 2.0, 1)]), (100.3, 80.6), []) < 4.0


def test_a_spot_that_jpeg_rounds_away_is_not_observable_in_its_frames() -> None:
    """A dim spot in dark, flat frames: plain to the matched filter in the raw frames, gone once
    JPEG at quality 60 has rounded its block's coefficients."""
    import cv2

    from edge.accuracy.observe import frame_snr, mean_differences

    on, off = _spot_frames(2.0, 0.4, 3, background=-38.0)
    raw = frame_snr(mean_differences([on], [off]), (100.3, 80.6), [])
    params = [cv2.IMWRITE_JPEG_QUALITY, 60]
    jpeg = [cv2.imdecode(cv2.imencode(".jpg", f, params)[1], cv2.IMREAD_COLOR) for f in (on, off)]
    compressed = frame_snr(mean_differences([jpeg[0]], [jpeg[1]]), (100.3, 80.6), [])
    assert raw >= 1.5 * OBSERVABLE_SNR
    assert compressed < OBSERVABLE_SNR, (raw, compressed)
    # A brighter one survives, on a background JPEG has flattened to exactly 0: its noise is then
    # the rounding's, not none (an SNR of millions).
    on, off = _spot_frames(3.0, 0.4, 3, background=-38.0)
    jpeg = [cv2.imdecode(cv2.imencode(".jpg", f, params)[1], cv2.IMREAD_COLOR) for f in (on, off)]
    assert OBSERVABLE_SNR <= frame_snr(mean_differences([jpeg[0]], [jpeg[1]]), (100.3, 80.6), []) < 30.0


def test_a_spot_stands_against_the_noise_around_it() -> None:
    """A dim spot on a patch of noisy texture (a bright window's shot noise, JPEG's rounding of a
    textured wall) in an otherwise quiet, dark frame: against the frame's noise it would look
    plain; against the noise where it is, it is not observable."""
    from edge.accuracy.observe import frame_snr, mean_differences

    rng = np.random.default_rng(5)
    v, u = np.mgrid[0:240, 0:320]
    spot = 8.0 * np.exp(-((u - 100.3) ** 2 + (v - 80.6) ** 2) / (2 * 1.6**2))
    sd = np.where((abs(u - 100) < 60) & (abs(v - 80) < 60), 6.0, 0.5)[..., None]
    frames = []
    for lit in (spot, 0.0):
        img = 60.0 + sd * rng.normal(0.0, 1.0, (240, 320, 3))
        img[..., 2] += lit
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    assert frame_snr(mean_differences([frames[0]], [frames[1]]), (100.3, 80.6), []) < OBSERVABLE_SNR


def test_a_hidden_spot_beside_a_bright_one_is_not_observable_by_its_light() -> None:
    """The reference's beam hidden, another laser's bright spot 8.5 px away: the filters wide
    enough to reach that spot would read its light as the reference's (tuning-65 zone 16, SNR 100
    where the renderer's was 0.2)."""
    from edge.accuracy.observe import frame_snr, mean_differences

    rng = np.random.default_rng(6)
    v, u = np.mgrid[0:160, 0:200]
    neighbour = 200.0 * np.exp(-((u - 108.8) ** 2 + (v - 80.6) ** 2) / (2 * 1.6**2))
    frames = []
    for lit in (neighbour, 0.0):
        img = 40.0 + rng.normal(0.0, 2.0, (160, 200, 3))
        img[..., 2] += lit
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    snr = frame_snr(mean_differences([frames[0]], [frames[1]]), (100.3, 80.6), [(108.8, 80.6)])
    assert snr < OBSERVABLE_SNR


def test_a_kept_row_replays_as_observable_as_it_was_recorded() -> None:
    """A zone's frame SNR is kept in its row and read back by `--replay`: one a hair under the
    line (rounded to two places it was 6.00) must stay not observable."""
    from edge.accuracy.bench import _row

    truth = {"range_m": 2.0, "lasers": {"center": {"visible": True}},
             "floor": {"sigma_m": 0.01, "lasers": {"center": {"snr": 20.0}}}}
    result = ZoneResult(0, 0.0, 0.0, "no_spot")
    recorded = ZoneOutcome.of(result, truth, "center", frame_snr=OBSERVABLE_SNR - 0.004)
    row = json.loads(json.dumps(_row(cond.condition("tuning", 0), 0.0, 0.0, recorded, result, truth, "center")))
    replayed = ZoneOutcome.of(result, truth, "center", frame_snr=row["frame_snr"])
    assert not recorded.observable and replayed.observable == recorded.observable == row["observable"]


def test_coverage_counts_the_zones_observable_in_their_frames() -> None:
    seen = ZoneOutcome(0, "no_spot", None, None, 2.0, True, 0.01, 30.0, frame_snr=3.0)
    assert seen.observable_model and not seen.observable
    figures = Figures.of([seen, replace(seen, index=1, frame_snr=None)])
    assert (figures.observable, figures.observable_model) == (1, 2)


def test_honest_sigma_fails_small_conditions_by_chance() -> None:
    # Each zone outside 2σ with probability p = 4.55 %: a condition of 5 zones fails on one miss,
    # 1 − (1 − p)^5; one of 10 takes one miss (90 %) and fails on two; 0 zones count for nothing.
    p = math.erfc(2.0 / math.sqrt(2.0))
    assert p == pytest.approx(0.0455, abs=1e-4)
    assert failing_by_chance([5]) == pytest.approx(1 - (1 - p) ** 5)
    assert failing_by_chance([10]) == pytest.approx(1 - (1 - p) ** 10 - 10 * p * (1 - p) ** 9)
    assert failing_by_chance([5, 10, 0]) == pytest.approx(failing_by_chance([5]) + failing_by_chance([10]))
    # Honest σ over many small conditions: about a fifth of 5-zone conditions fail.
    assert 0.2 < failing_by_chance([5] * 100) / 100 < 0.21
    assert failing_by_chance([10], outside=0.0) == 0.0


def test_a_sensor_that_averages_over_its_pixels_turns_back_closer_to_the_pose() -> None:
    """sim.optics.pixel_area: averaged over each pixel's area, a room's fine texture and its edges
    resample, and a noise-free frame of the office turned 1° and turned back by its true turn is
    nearer the frame from the pose than when each pixel samples the room at its centre."""
    from edge.accuracy.unturned import turned_back
    from edge.sim.record import scene_for, true_rig
    from edge.sim.render import Renderer

    def left(area: str) -> float:
        rest = load_config(None, [f"sim.optics.pixel_area={area}"])
        moving = load_config(None, [f"sim.optics.pixel_area={area}", "sim.sway.jolt_deg=1.0"])
        still_renderer = Renderer(scene_for(rest), true_rig(rest), rest.sim, rest.camera)
        renderer = Renderer(scene_for(moving), true_rig(moving), moving.sim, moving.camera)
        turn = renderer.jolt({}, np.random.default_rng(3))
        frame = renderer.render(40.0, 0.0, {}, 0.0, np.random.default_rng(3), noise=False)
        at_rest = still_renderer.render(40.0, 0.0, {}, 0.0, np.random.default_rng(3), noise=False).astype(float)
        back = turned_back(frame, renderer, (40.0, 0.0), turn).astype(float)
        return float(np.sqrt(((back - at_rest)[16:-16, 16:-16] ** 2).mean()))

    assert left("true") < 0.7 * left("false")
