"""Simulated sweeps: the recording follows recording.md, carries truth, and can be looked at."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from edge.config import load_config
from edge.contact import contact_sheet, difference_image
from edge.recording import read_recording
from edge.sim.record import record_sweep, true_rig


@pytest.fixture(scope="module")
def office(tmp_path_factory: pytest.TempPathFactory) -> Path:
    config = load_config(None, ["sweep.pan_start_deg=-90.0"])
    return record_sweep(config, tmp_path_factory.mktemp("rec") / "office", zones=6, pairs=2)


def test_recording_validates_and_has_the_asked_shape(office: Path) -> None:
    rec = read_recording(office)  # strict: every rule of recording.md
    assert len(rec.zones) == 6
    for zone in rec.zones:
        assert len(zone.off_frames) == 2 and len(zone.on_frames) == 2
        assert [f.lasers_on for f in zone.on_frames] == [("center", "parallel", "sloped")] * 2
        image = rec.load_image(zone, zone.frames[0])
        assert image.shape == (480, 640, 3) and image.dtype == np.uint8
    zone = rec.zones[0]
    # The second pair is nudged one position in pan, for fresh speckle; the first is not.
    assert zone.frames[0].pan_deg is None
    assert zone.frames[2].pan_deg == pytest.approx(zone.pan_deg + 0.0514)
    starts = [f.t_start_ns for z in rec.zones for f in z.frames]
    assert starts == sorted(starts) and len(set(starts)) == len(starts)
    assert all(f.laser_switch_ns < f.t_start_ns for z in rec.zones for f in z.frames)


def test_truth_matches_the_geometry(office: Path) -> None:
    rec = read_recording(office)
    rig = rec.rig
    for zone in rec.zones:
        truth = zone.truth
        assert truth is not None
        assert truth["range_m"] == pytest.approx(truth["point_m"][2])
        base = rig.camera_to_base(zone.pan_deg, zone.tilt_deg).apply(truth["point_m"])
        assert truth["point_base_m"] == pytest.approx(base, abs=1e-5)
        center = truth["lasers"]["center"]
        if center["visible"]:
            # The reference spot lies on the centre beam's epipolar line (row cy).
            assert center["pixel"][1] == pytest.approx(rig.camera.cy, abs=1e-3)
            u = rig.camera.cx + rig.camera.fx * 0.035 / truth["range_m"]
            assert center["pixel"][0] == pytest.approx(u, abs=1e-3)


def test_spots_are_where_the_truth_says(office: Path) -> None:
    rec = read_recording(office)
    for zone in rec.zones:
        diff = difference_image(rec, zone)
        noise = 1.4826 * np.median(np.abs(diff - np.median(diff)))
        for name, spot in zone.truth["lasers"].items():
            if not spot["visible"] or spot["range_m"] > 4.0:
                continue
            u, v = (int(round(c)) for c in spot["pixel"])
            peak = diff[v - 2 : v + 3, u - 2 : u + 3].max()
            assert peak > 8 * noise, (zone.index, name, peak, noise)


def test_recording_carries_the_nominal_rig_and_truth_the_true_one(tmp_path: Path) -> None:
    config = load_config(None, ["sim.rig_error.laser_angle_deg=0.5", "sim.rig_error.seed=3",
                                "sweep.pan_start_deg=-90.0"])
    out = record_sweep(config, tmp_path / "bent", zones=1, pairs=1)
    rec = read_recording(out)
    nominal, true = config.rig.build(), true_rig(config)
    recorded = np.array([x.direction for x in rec.rig.lasers])
    assert recorded == pytest.approx(np.array([x.direction for x in nominal.lasers]))
    assert true.lasers != nominal.lasers
    sloped_pixel = rec.zones[0].truth["lasers"]["sloped"]["pixel"]
    z = rec.zones[0].truth["lasers"]["sloped"]["range_m"]
    nominal_pixel = nominal.camera.project(nominal.laser("sloped").point_at_depth(z))
    assert np.linalg.norm(np.array(sloped_pixel) - nominal_pixel) > 0.5  # the flaw shows


def test_contact_sheet_shows_each_zone(office: Path) -> None:
    rec = read_recording(office)
    sheet = contact_sheet(rec, columns=3, tile_width=160)
    assert sheet.dtype == np.uint8 and sheet.shape[2] == 3
    assert sheet.shape[1] == 3 * 162 + 2  # three tiles and their gaps
    assert sheet.shape[0] > 2 * 120


def test_cli_record_and_show(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    run = [sys.executable, "-m", "edge", "sim", "record", "--scene", "kitchen", "--out", str(out),
           "--zones", "2", "--frames", "2", "--seed", "5"]
    proc = subprocess.run(run, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "sweep.json").read_text())
    assert doc["format"] == "edge-sweep/1" and len(doc["zones"]) == 2
    assert len(doc["zones"][0]["frames"]) == 2
    proc = subprocess.run([sys.executable, "-m", "edge", "sim", "show", str(out)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    sheet = cv2.imread(str(out / "contact.png"))
    assert sheet is not None and sheet.shape[0] > 100


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--frames", "3"], "--frames must be an even number"),
        (["--scene", "moon"], "unknown scene 'moon'"),
        (["--set", "sim.sensor.output_bits=12"], "sim.sensor.output_bits: expected one of 8, 16"),
    ],
)
def test_cli_record_rejects_bad_input_in_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "sim", "record", "--out", str(tmp_path / "r"), "--zones", "1", *args],
        capture_output=True, text=True,
    )
    assert proc.returncode == 2
    assert message in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not (tmp_path / "r").exists()


def test_cli_show_of_a_broken_recording_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "sweep.json").write_text("{")
    proc = subprocess.run([sys.executable, "-m", "edge", "sim", "show", str(tmp_path / "broken")],
                          capture_output=True, text=True)
    assert proc.returncode == 2  # a RecordingError: bad input, as README says
    assert "sweep.json: not valid JSON" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
