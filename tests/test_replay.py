"""Replaying simulated recordings against their truth: the accuracy targets of the ranging issue
as assertions (at a safe margin), the thesis baseline side by side, and the `edge replay` command."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from edge.config import load_config
from edge.errors import RecordingError
from edge.ranging import OK
from edge.recording import RecordingWriter, read_recording
from edge.replay import Replayer, score, straddles_switch, zone_groups
from edge.sim.record import flat_target_scene, record_sweep, record_targets
from edge.sim.render import Renderer

WALLS_M = [0.3, 0.4, 0.6, 0.8, 1.0, 1.3, 1.6, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 4.9]


@pytest.fixture(scope="module")
def walls(tmp_path_factory) -> Path:
    # Pi camera noise, 2 laser-on + 2 laser-off frames per zone (the pairs nudged one position).
    return record_targets(load_config(), WALLS_M, tmp_path_factory.mktemp("walls") / "rec", pairs=2)


def _summary(path: Path, estimator: str = "triangulate", config=None) -> dict:
    recording = read_recording(path)
    ranging = (config or load_config()).ranging
    results = list(Replayer(recording.rig, estimator, ranging).zones(recording))
    return score(recording, results).summary()


def test_walls_facing_the_camera_from_0_3_to_5_m(walls: Path) -> None:
    m = _summary(walls)
    assert m["statuses"]["ok"] == len(WALLS_M)
    assert m["median_rel_error"] <= 0.005  # target: median |relative error| ≤ 0.5 %
    assert m["wrong_ok"] == 0
    assert m["within_2sigma"] >= 0.9


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["office", "kitchen"])
def test_64_zone_sweeps(scene: str, tmp_path: Path) -> None:
    config = load_config(None, [f"sim.scene={json.dumps(scene)}"])
    path = record_sweep(config, tmp_path / scene)
    m = _summary(path)
    assert m["mean_rel_error"] <= 0.01  # target: ≤ 1 % mean
    assert m["wrong_ok"] == 0  # no wrong ok (|error| > 10 %) anywhere
    assert m["within_2sigma"] >= 0.9  # |error| ≤ 2·sigma for at least 90 % of ok zones
    assert m["statuses"]["ok"] >= 56  # a few zones look out of a doorway or at a dark chair
    assert m["no_spot_with_truth_in_range"] <= 2


@pytest.mark.slow
def test_webcam_thesis_rig_side_by_side(repo: Path, tmp_path: Path) -> None:
    """The thesis' own set-up (352 × 288 JPEG webcam, one frame pair per zone): our estimator and
    the thesis' on the same recording. The figures go in the closing note (edge replay --score)."""
    config = load_config(repo / "config" / "sim-webcam.toml")
    path = record_sweep(config, tmp_path / "webcam", zones=32, pairs=1)
    ours = _summary(path, "triangulate", config)
    thesis = _summary(path, "thesis", config)
    assert ours["median_rel_error"] < 0.02
    assert ours["median_rel_error"] * 4 < thesis["median_rel_error"]
    assert ours["wrong_ok"] < thesis["wrong_ok"]


def test_thesis_estimator_is_exact_on_a_noiseless_square_wall(tmp_path: Path) -> None:
    config = load_config(None, ["sim.beam.speckle=0.0", "sim.sensor.read_noise_e=0.0"])
    path = record_targets(config, [1.0, 2.0], tmp_path / "rec", pairs=1)
    recording = read_recording(path)
    for result, truth in zip(Replayer(recording.rig, "thesis").zones(recording), [1.0, 2.0]):
        assert result.status == OK
        # Whole-pixel rounding, as in the thesis, limits it to a few per cent.
        assert abs(result.range_m - truth) / truth < 0.05


def test_replay_json_is_one_document_on_stdout(walls: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "replay", str(walls), "--json"], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["format"] == "edge-ranges/1" and doc["recording"] == str(walls)
    assert len(doc["zones"]) == len(WALLS_M)
    for zone in doc["zones"]:
        for key in ("index", "pan_deg", "tilt_deg", "status", "range_m", "sigma_m", "point_m", "point_base_m"):
            assert key in zone
        if zone["status"] == "ok":
            assert zone["range_m"] == pytest.approx(zone["point_m"][2], abs=1e-5)
            assert zone["sigma_m"] > 0
        else:
            assert zone["range_m"] is None and zone["point_m"] is None


def test_replay_score_prints_a_table_and_a_summary(walls: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "replay", str(walls), "--score", "--estimator", "thesis"],
        capture_output=True, text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert "median" in proc.stdout and "wrong ok" in proc.stdout
    assert len(proc.stdout.splitlines()) >= len(WALLS_M) + 3


def test_replay_of_a_broken_recording_is_one_line(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "replay", str(tmp_path), "--json"], capture_output=True, text=True
    )
    assert proc.returncode == 2  # a RecordingError: bad input, as README says
    assert proc.stdout == ""
    assert len(proc.stderr.strip().splitlines()) == 1 and "sweep.json" in proc.stderr


def test_thesis_estimator_refuses_a_rig_it_cannot_handle(tmp_path: Path) -> None:
    config = load_config(None, ["rig.lasers=[{name=\"only\", origin_m=[0.035,0,0], direction=[0,0,1]}]"])
    path = record_targets(config, [1.0], tmp_path / "one", pairs=1)
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "replay", str(path), "--estimator", "thesis"],
        capture_output=True, text=True,
    )
    assert proc.returncode == 1
    assert "thesis estimator needs the thesis rig" in proc.stderr
    # The triangulating estimator ranges a one-laser rig.
    assert _summary(path)["statuses"]["ok"] == 1


def test_frames_exposed_across_a_laser_switch_are_dropped(tmp_path: Path) -> None:
    """A frame whose exposure began before the lasers switched on is half lit; with its timing in
    the recording it is dropped, and the range is the same as without it."""
    config = load_config()
    renderer = Renderer(flat_target_scene(1.5), config.rig.build(), config.sim)
    names = list(renderer.rig.laser_names)
    rng = np.random.default_rng(0)
    off = renderer.render(0.0, 0.0, {}, 0.0, rng)
    on = renderer.render(0.0, 0.0, {n: 1.0 for n in names}, 0.0, rng)
    # Rolling shutter: the rows above 245 were exposed before the lasers came on.
    rows = np.zeros(renderer.rig.camera.height)
    rows[245:] = 1.0
    half = renderer.digitise(renderer.render_electrons(0.0, 0.0, {n: rows for n in names}), rng)
    frames = [
        (off, [], {"t_start_ns": 0, "laser_switch_ns": -1}),
        (on, names, {"t_start_ns": 100, "laser_switch_ns": 50}),
        (half, names, {"t_start_ns": 200, "laser_switch_ns": 250}),  # switched mid-exposure
    ]
    with RecordingWriter(tmp_path / "rec", config.rig.build()) as writer:
        writer.add_zone(0, 0.0, 0.0, frames, {"range_m": 1.5})
    recording = read_recording(tmp_path / "rec")
    zone = recording.zones[0]
    assert [straddles_switch(f) for f in zone.frames] == [False, False, True]
    groups, dropped = zone_groups(recording, zone)
    assert dropped == 1 and len(groups) == 1 and len(groups[0].on) == 1
    result = next(Replayer(recording.rig).zones(recording))
    assert result.status == OK and result.range_m == pytest.approx(1.5, rel=0.01)
    assert len(result.lasers) == 3


def test_a_recording_says_the_tone_curve_its_frames_came_through(tmp_path: Path) -> None:
    """A camera with a display gamma records its curve (sweep.json's `frame_gamma`, an edge key the
    format lets grow); replay ranges with it whatever the configuration says, as ranging that is
    told the curve does. A linear recording says nothing, and its sweep.json is as before."""
    from edge.replay import ranging_for

    curved = read_recording(record_targets(load_config(None, ["sim.sensor.gamma=2.2"]), [0.8, 2.0],
                                           tmp_path / "curved", pairs=1))
    plain = read_recording(record_targets(load_config(), [0.8], tmp_path / "plain", pairs=1))
    assert curved.frame_gamma == 2.2 and plain.frame_gamma is None
    assert "frame_gamma" not in json.loads((tmp_path / "plain" / "sweep.json").read_text())
    default = load_config().ranging
    assert ranging_for(curved, default).frame_gamma == 2.2 and ranging_for(plain, default) is default
    told = list(Replayer(curved.rig, "triangulate", default.__class__(frame_gamma=2.2)).zones(curved))
    replayed = json.loads(subprocess.run(
        [sys.executable, "-m", "edge", "replay", str(tmp_path / "curved"), "--json"],
        capture_output=True, text=True, check=True).stdout)["zones"]
    assert all(r.status == OK for r in told)
    assert [z["range_m"] for z in replayed] == pytest.approx([r.range_m for r in told], abs=1e-4)  # (rounded)
    as_delivered = list(Replayer(curved.rig, "triangulate", default).zones(curved))
    for z, t, d in zip(replayed, told, as_delivered):  # the spots' SNR tells which it was
        assert z["lasers"]["center"]["snr"] == pytest.approx(t.lasers["center"].snr, abs=0.06)
        assert z["lasers"]["center"]["snr"] > 1.25 * d.lasers["center"].snr  # (1.46 at 2 m)
    # A curve outside 1-3 is refused, naming the file and the key.
    doc = json.loads((tmp_path / "curved" / "sweep.json").read_text())
    doc["frame_gamma"] = 0.5
    (tmp_path / "curved" / "sweep.json").write_text(json.dumps(doc))
    with pytest.raises(RecordingError, match=r"sweep\.json.*frame_gamma: must be 1-3"):
        read_recording(tmp_path / "curved")
