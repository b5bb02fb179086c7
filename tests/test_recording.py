"""Tests for edge.recording: the edge-sweep/1 format, read strictly and written atomically."""

from __future__ import annotations

import copy
import json
import logging
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from edge.errors import RecordingError
from edge.recording import (
    FORMAT,
    FrameRecord,
    Recording,
    RecordingWriter,
    SweepFile,
    ZoneRecord,
    load,
    read_recording,
    rig_to_json,
)
from edge.rig import CameraModel, Mount, Rig, default_rig

# Verbatim from shared/spec/recording.md.
EXAMPLE = """\
{
  "format": "edge-sweep/1",
  "created": "2026-11-22T14:00:00Z",
  "device": "edge-01",
  "camera": {
    "width": 640, "height": 480,
    "fx": 530.0, "fy": 530.0, "cx": 319.5, "cy": 239.5,
    "dist": [0, 0, 0, 0, 0]
  },
  "lasers": [
    {"name": "center",   "origin_m": [0.035, 0.0, 0.0],   "direction": [0, 0, 1], "reference": true},
    {"name": "parallel", "origin_m": [0.035, -0.04, 0.0], "direction": [0, 0, 1]},
    {"name": "sloped",   "origin_m": [0.035, 0.0, 0.0],   "direction": [0, 0.17365, 0.98481]}
  ],
  "mount": {"origin_m": [0, 0, 0], "rpy_deg": [0, 0, 0]},
  "range_limits_m": [0.25, 5.0],
  "zones": [
    {
      "index": 0, "pan_deg": 0.0, "tilt_deg": 0.0,
      "frames": [
        {"file": "frames/z000-0-off.png", "lasers_on": []},
        {"file": "frames/z000-1-on.png",  "lasers_on": ["center", "parallel", "sloped"]}
      ]
    }
  ]
}
"""
OFF = "frames/z000-0-off.png"
ON = "frames/z000-1-on.png"


def write_png(path: Path, width: int = 640, height: int = 480, value: int = 0) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.full((height, width), value, np.uint8))


def make_example(folder: Path, doc: dict[str, Any] | None = None) -> Path:
    """The spec's example recording (or `doc`) with blank 640x480 frames."""
    folder.mkdir(parents=True, exist_ok=True)
    if doc is None:
        (folder / "sweep.json").write_text(EXAMPLE)
        doc = json.loads(EXAMPLE)
    else:
        (folder / "sweep.json").write_text(json.dumps(doc))
    for zone in doc["zones"]:
        for frame in zone["frames"]:
            write_png(folder / frame["file"])
    return folder


def assert_rig_equal(a: Rig, b: Rig) -> None:
    """Equal as a recording stores a rig: GPIO pins are not part of the format, and directions are
    renormalised on reading (a last-bit difference)."""
    assert a.camera == b.camera
    assert a.mount == b.mount
    assert a.range_limits_m == b.range_limits_m
    assert a.laser_names == b.laser_names
    assert a.reference.name == b.reference.name
    for la, lb in zip(a.lasers, b.lasers):
        assert la.origin_m == lb.origin_m
        np.testing.assert_allclose(la.direction, lb.direction, rtol=0, atol=1e-12)


def frames_(rng: np.random.Generator, kind: str, shape: tuple[int, int]) -> np.ndarray:
    h, w = shape
    if kind == "bgr8":
        return rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    if kind == "grey16":
        return rng.integers(0, 65536, (h, w), dtype=np.uint16)
    if kind == "bgr16":
        return rng.integers(0, 65536, (h, w, 3), dtype=np.uint16)
    return rng.integers(0, 256, (h, w), dtype=np.uint8)


# --------------------------------------------------------------------------------------------------
# Round trip


def test_round_trip_default_rig(tmp_path: Path) -> None:
    rig = default_rig()
    rng = np.random.default_rng(1)
    shape = (rig.camera.height, rig.camera.width)
    all_on = ["center", "parallel", "sloped"]
    plan = [
        (0, 0.0, 0.0, "bgr8", {"range_m": 1.5, "point_m": [0.035, 0.0, 1.5]}),
        (1, 5.625, -2.5, "grey16", None),
        (7, 39.375, 10.0, "grey8", {"range_m": None, "note": "tape measure"}),
    ]
    images: dict[tuple[int, int], np.ndarray] = {}
    written: list[ZoneRecord] = []
    rec = tmp_path / "rec"
    with RecordingWriter(rec, rig, device="edge-01", created="2026-11-22T14:00:00Z") as w:
        for index, pan, tilt, kind, truth in plan:
            frames = [
                (frames_(rng, kind, shape), [], {"t_start_ns": 1000 * index, "exposure_us": 250.0}),
                (frames_(rng, kind, shape), all_on,
                 {"t_start_ns": 1000 * index + 500, "exposure_us": 250.0, "laser_switch_ns": 400}),
                (frames_(rng, kind, shape), ["sloped"], {"pan_deg": pan + 0.1, "tilt_deg": tilt}),
                (frames_(rng, kind, shape), [], {"pan_deg": pan + 0.1, "tilt_deg": tilt}),
            ]
            for k, (image, _, _) in enumerate(frames):
                images[(index, k)] = image
            written.append(w.add_zone(index, pan, tilt, frames, truth=truth))

    got = read_recording(rec)
    assert isinstance(got, Recording)
    assert got.path == rec
    assert got.created == "2026-11-22T14:00:00Z" and got.device == "edge-01"
    assert_rig_equal(got.rig, rig)
    assert got.zones == tuple(written)
    assert [z.index for z in got.zones] == [0, 1, 7]
    assert got.zones[0].truth == {"range_m": 1.5, "point_m": [0.035, 0.0, 1.5]}
    assert got.zones[1].truth is None
    assert got.zones[2].truth == {"range_m": None, "note": "tape measure"}

    z0 = got.zones[0]
    assert (z0.pan_deg, z0.tilt_deg) == (0.0, 0.0)
    assert z0.frames[0] == FrameRecord("frames/z000-0-off.png", (), t_start_ns=0, exposure_us=250.0)
    assert z0.frames[1] == FrameRecord("frames/z000-1-on.png", tuple(all_on), t_start_ns=500,
                                       exposure_us=250.0, laser_switch_ns=400)
    assert z0.frames[2].pan_deg == pytest.approx(0.1) and z0.frames[2].tilt_deg == 0.0
    assert z0.frames[2].t_start_ns is None and z0.frames[2].exposure_us is None
    assert [f.file for f in z0.off_frames] == ["frames/z000-0-off.png", "frames/z000-3-off.png"]
    assert [f.lasers_on for f in z0.on_frames] == [tuple(all_on), ("sloped",)]

    for zone in got.zones:
        for k, frame in enumerate(zone.frames):
            image = got.load_image(zone, frame)
            expected = images[(zone.index, k)]
            assert image.dtype == expected.dtype and image.shape == expected.shape
            np.testing.assert_array_equal(image, expected)
    assert got.load_image(got.zones[1], got.zones[1].frames[0]).dtype == np.uint16


def test_written_sweep_json_follows_the_spec(tmp_path: Path) -> None:
    rig = default_rig()
    shape = (rig.camera.height, rig.camera.width)
    with RecordingWriter(tmp_path / "rec", rig) as w:
        w.add_zone(0, 0.0, 0.0, [(np.zeros(shape, np.uint8), [], {}),
                                 (np.zeros(shape, np.uint8), ["center"], {"pan_deg": None})])
    doc = json.loads((tmp_path / "rec" / "sweep.json").read_text())
    assert doc["format"] == "edge-sweep/1"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", doc["created"])
    assert "device" not in doc
    assert doc["camera"] == {"width": 640, "height": 480, "fx": 530.0, "fy": 530.0,
                             "cx": 319.5, "cy": 239.5, "dist": [0.0] * 5}
    assert [laser.get("reference") for laser in doc["lasers"]] == [True, None, None]
    assert set(doc["lasers"][0]) == {"name", "origin_m", "direction", "reference"}
    assert doc["mount"] == {"origin_m": [0.0, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]}
    assert doc["range_limits_m"] == [0.25, 5.0]
    assert doc["zones"][0]["frames"] == [
        {"file": "frames/z000-0-off.png", "lasers_on": []},
        {"file": "frames/z000-1-on.png", "lasers_on": ["center"]},
    ]
    assert (tmp_path / "rec" / "frames" / "z000-1-on.png").is_file()


def test_rig_json_helpers_round_trip() -> None:
    rig = Rig(CameraModel(352, 288, 400.0, 401.0, 175.5, 143.5, (-0.12, 0.05, 0.001, 0.0, 0.01)),
              default_rig().lasers, Mount((0.01, 0.0, 0.05), (0.0, -3.0, 1.5)), (0.3, 4.0))
    doc = json.loads(json.dumps({"format": FORMAT, **rig_to_json(rig), "zones": []}))
    assert_rig_equal(load(SweepFile, doc, "x.json").rig(), rig)


# --------------------------------------------------------------------------------------------------
# The spec's example


def test_spec_example_reads(tmp_path: Path) -> None:
    got = read_recording(make_example(tmp_path / "rec"))
    assert got.created == "2026-11-22T14:00:00Z" and got.device == "edge-01"
    assert got.rig.camera == CameraModel(640, 480, 530.0, 530.0, 319.5, 239.5)
    assert got.rig.laser_names == ("center", "parallel", "sloped")
    assert got.rig.reference.name == "center"
    assert got.rig.laser("parallel").origin_m == (0.035, -0.04, 0.0)
    assert np.linalg.norm(got.rig.laser("sloped").d) == pytest.approx(1.0)
    assert got.zones == (
        ZoneRecord(0, 0.0, 0.0, (FrameRecord(OFF, ()),
                                 FrameRecord(ON, ("center", "parallel", "sloped")))),
    )
    image = got.load_image(got.zones[0], got.zones[0].frames[1])
    assert image.shape == (480, 640) and image.dtype == np.uint8


def test_spec_example_defaults(tmp_path: Path) -> None:
    doc = json.loads(EXAMPLE)
    for key in ("created", "device", "mount", "range_limits_m"):
        del doc[key]
    del doc["camera"]["dist"]
    got = read_recording(make_example(tmp_path / "rec", doc))
    assert got.created is None and got.device is None
    assert got.rig.camera.dist == (0.0, 0.0, 0.0, 0.0, 0.0)
    assert got.rig.mount == Mount((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert got.rig.range_limits_m == (0.25, 5.0)


def test_path_to_sweep_json_and_check_images_off(tmp_path: Path) -> None:
    rec = make_example(tmp_path / "rec")
    assert read_recording(rec / "sweep.json").path == rec
    (rec / ON).write_bytes(b"not a png")  # not decoded without check_images
    got = read_recording(str(rec), check_images=False)
    with pytest.raises(RecordingError, match="unreadable"):
        got.load_image(got.zones[0], got.zones[0].frames[1])


# --------------------------------------------------------------------------------------------------
# Every rule's error


def zone0(doc: dict[str, Any]) -> dict[str, Any]:
    return doc["zones"][0]


def set_frames(doc: dict[str, Any], *which: int) -> None:
    zone0(doc)["frames"] = [zone0(doc)["frames"][i] for i in which]


Mutation = Callable[[dict[str, Any], Path], None]
CASES: list[tuple[str, Mutation, list[str]]] = [
    ("wrong format", lambda d, p: d.update(format="edge-sweep/2"),
     ["format", "'edge-sweep/1'", "'edge-sweep/2'"]),
    ("missing format", lambda d, p: d.pop("format"), ["format", "missing required key"]),
    ("missing camera", lambda d, p: d.pop("camera"), ["camera", "missing required key"]),
    ("missing camera key", lambda d, p: d["camera"].pop("fy"), ["camera.fy", "missing"]),
    ("missing lasers", lambda d, p: d.pop("lasers"), ["lasers", "missing required key"]),
    ("no lasers", lambda d, p: d.update(lasers=[]), ["lasers", "at least one laser"]),
    ("missing zones", lambda d, p: d.pop("zones"), ["zones", "missing required key"]),
    ("non-unit direction", lambda d, p: d["lasers"][1].update(direction=[0, 0, 1.2]),
     ["lasers[1].direction", "must be a unit vector", "1.2"]),
    ("duplicate laser name", lambda d, p: d["lasers"][2].update(name="center"),
     ["lasers[2].name", "duplicate laser name 'center'"]),
    ("two reference lasers", lambda d, p: d["lasers"][1].update(reference=True),
     ["lasers", "only one laser may be the reference"]),
    ("unknown laser", lambda d, p: zone0(d)["frames"][1].update(lasers_on=["center", "green"]),
     ["zone 0, frame frames/z000-1-on.png", "lasers_on names unknown laser 'green'",
      "(lasers: center, parallel, sloped)"]),
    ("laser named twice", lambda d, p: zone0(d)["frames"][1].update(lasers_on=["sloped", "sloped"]),
     ["zone 0, frame frames/z000-1-on.png", "lasers_on", "twice"]),
    ("lasers_on not a list", lambda d, p: zone0(d)["frames"][1].update(lasers_on="center"),
     ["zone 0, frame frames/z000-1-on.png", "lasers_on", "expected a list"]),
    ("only on frames", lambda d, p: set_frames(d, 1),
     ["zone 0", "frames", "no frame with no laser on"]),
    ("only off frames", lambda d, p: set_frames(d, 0),
     ["zone 0", "frames", "no frame with lasers on"]),
    ("no frames", lambda d, p: set_frames(d), ["zone 0", "frames", "no frame at all"]),
    ("frame without file", lambda d, p: zone0(d)["frames"][0].pop("file"),
     ["zone 0, frames[0]", "file", "missing required key"]),
    ("missing image", lambda d, p: (p / ON).unlink(),
     ["zone 0, frame frames/z000-1-on.png", "image is missing"]),
    ("unreadable image", lambda d, p: (p / ON).write_bytes(b"\x00garbage" * 40),
     ["zone 0, frame frames/z000-1-on.png", "unreadable", "not a PNG"]),
    ("truncated image", lambda d, p: (p / ON).write_bytes((p / ON).read_bytes()[:20]),
     ["zone 0, frame frames/z000-1-on.png", "unreadable"]),
    ("image of wrong size", lambda d, p: write_png(p / ON, 320, 240),
     ["zone 0, frame frames/z000-1-on.png", "320x240", "640x480"]),
    ("path escaping with ..", lambda d, p: (
        write_png(p.parent / "outside.png"),
        zone0(d)["frames"][1].update(file="frames/../../outside.png")),
     ["zone 0, frames[1]", "file", "leaves the recording folder"]),
    ("absolute path", lambda d, p: (
        write_png(p.parent / "outside.png"),
        zone0(d)["frames"][1].update(file=str(p.parent / "outside.png"))),
     ["zone 0, frames[1]", "file", "is absolute"]),
    ("path escaping by symlink", lambda d, p: (
        write_png(p.parent / "outside.png"), (p / ON).unlink(),
        (p / ON).symlink_to(p.parent / "outside.png")),
     ["zone 0, frame frames/z000-1-on.png", "resolves outside the recording folder"]),
    ("string where a number belongs", lambda d, p: d["camera"].update(fx="530"),
     ["camera.fx", "expected a number", "string '530'"]),
    ("string for zone pan", lambda d, p: zone0(d).update(pan_deg="0"),
     ["zone 0: pan_deg", "expected a number", "string '0'"]),
    ("bool where a number belongs", lambda d, p: zone0(d).update(tilt_deg=True),
     ["zone 0: tilt_deg", "expected a number", "boolean true"]),
    ("bool for width", lambda d, p: d["camera"].update(width=False),
     ["camera.width", "expected a whole number", "boolean false"]),
    ("float for timestamp", lambda d, p: zone0(d)["frames"][0].update(t_start_ns=1.5),
     ["zone 0, frame frames/z000-0-off.png", "t_start_ns", "expected a whole number"]),
    ("NaN", lambda d, p: d.update(range_limits_m=[0.25, float("nan")]),
     ["range_limits_m[1]", "finite"]),
    ("dist of 4", lambda d, p: d["camera"].update(dist=[0, 0, 0, 0]),
     ["camera.dist", "expected 5 values, got 4"]),
    ("truth not an object", lambda d, p: zone0(d).update(truth=[1.0]),
     ["zone 0: truth", "expected an object"]),
    ("duplicate zone index", lambda d, p: d["zones"].append(copy.deepcopy(zone0(d))),
     ["zone 0: index", "duplicate zone index", "zones[0]", "zones[1]"]),
    ("zone without index", lambda d, p: zone0(d).pop("index"),
     ["zones[0]: index", "missing required key"]),
]


@pytest.mark.parametrize("mutate, expected", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_rule_errors(tmp_path: Path, mutate: Mutation, expected: list[str]) -> None:
    rec = make_example(tmp_path / "rec")
    doc = json.loads(EXAMPLE)
    mutate(doc, rec)
    (rec / "sweep.json").write_text(json.dumps(doc))
    with pytest.raises(RecordingError) as info:
        read_recording(rec)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{rec / 'sweep.json'}: ")
    for part in expected:
        assert part in message


def test_bad_json(tmp_path: Path) -> None:
    rec = make_example(tmp_path / "rec")
    text = '{\n "format": "edge-sweep/1",\n "camera": {}\n "lasers": []\n}'
    (rec / "sweep.json").write_text(text)
    with pytest.raises(RecordingError) as info:
        read_recording(rec)
    assert str(info.value) == (
        f"{rec / 'sweep.json'}: not valid JSON (line 4, column 2: Expecting ',' delimiter)"
    )


@pytest.mark.parametrize("content, expected", [("[1, 2]", "expected a JSON object"),
                                               (b"\xff\xfe\xfa", "not valid JSON")])
def test_not_an_object(tmp_path: Path, content: str | bytes, expected: str) -> None:
    rec = make_example(tmp_path / "rec")
    path = rec / "sweep.json"
    path.write_bytes(content.encode() if isinstance(content, str) else content)
    with pytest.raises(RecordingError, match=re.escape(expected)):
        read_recording(rec)


def test_no_sweep_json(tmp_path: Path) -> None:
    (tmp_path / "rec").mkdir()
    with pytest.raises(RecordingError) as info:
        read_recording(tmp_path / "rec")
    assert str(info.value) == f"{tmp_path / 'rec'}: no sweep.json in this folder"
    with pytest.raises(RecordingError, match="no such folder"):
        read_recording(tmp_path / "nowhere")


def test_load_image_errors(tmp_path: Path) -> None:
    rec = make_example(tmp_path / "rec")
    got = read_recording(rec)
    zone, frame = got.zones[0], got.zones[0].frames[1]
    write_png(rec / ON, 64, 48)
    with pytest.raises(RecordingError, match=r"zone 0, frame frames/z000-1-on.png: .*64x48"):
        got.load_image(zone, frame)
    (rec / ON).unlink()
    with pytest.raises(RecordingError, match=r"zone 0, frame frames/z000-1-on.png: image is miss"):
        got.load_image(zone, frame)
    # A valid header over a truncated body passes the header check; decoding catches it.
    write_png(rec / ON, value=7)
    data = (rec / ON).read_bytes()
    (rec / ON).write_bytes(data[: len(data) // 2])
    got = read_recording(rec)
    with pytest.raises(RecordingError, match=r"zone 0, frame frames/z000-1-on.png: .*unreadable"):
        got.load_image(zone, frame)


def test_load_image_drops_alpha(tmp_path: Path) -> None:
    rec = make_example(tmp_path / "rec")
    bgra = np.random.default_rng(0).integers(0, 256, (480, 640, 4), dtype=np.uint8)
    assert cv2.imwrite(str(rec / ON), bgra)
    got = read_recording(rec)
    image = got.load_image(got.zones[0], got.zones[0].frames[1])
    assert image.shape == (480, 640, 3) and image.flags.c_contiguous
    np.testing.assert_array_equal(image, bgra[:, :, :3])


def test_unknown_keys_are_ignored(tmp_path: Path) -> None:
    doc = json.loads(EXAMPLE)
    doc["x-top"] = {"anything": [1, "two"]}
    doc["camera"]["model"] = "imx219"
    doc["lasers"][0]["pin"] = "GPIO17"
    doc["mount"]["note"] = None
    zone0(doc)["x-zone"] = 1
    zone0(doc)["frames"][0]["x-frame"] = "yes"
    zone0(doc)["frames"][1]["gain"] = 2.5
    got = read_recording(make_example(tmp_path / "rec", doc))
    plain = read_recording(make_example(tmp_path / "plain"))
    assert got.zones == plain.zones
    assert got.rig == plain.rig


# --------------------------------------------------------------------------------------------------
# Writer


def small_rig() -> Rig:
    return Rig(CameraModel(8, 6, 10.0, 10.0, 3.5, 2.5), default_rig().lasers)


def blank(dtype: type = np.uint8) -> np.ndarray:
    return np.zeros((6, 8), dtype)


def pair() -> list[tuple[np.ndarray, list[str], dict[str, object]]]:
    return [(blank(), [], {}), (blank(), ["center"], {})]


def siblings(tmp_path: Path) -> list[str]:
    return sorted(p.name for p in tmp_path.iterdir())


def test_exception_leaves_nothing(tmp_path: Path) -> None:
    with pytest.raises(KeyError):
        with RecordingWriter(tmp_path / "rec", small_rig()) as w:
            w.add_zone(0, 0.0, 0.0, pair())
            assert any(".partial-" in name for name in siblings(tmp_path))
            raise KeyError("boom")
    assert siblings(tmp_path) == []


def test_overwrites_an_earlier_recording(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    with RecordingWriter(rec, small_rig(), device="first") as w:
        w.add_zone(0, 0.0, 0.0, pair())
        w.add_zone(1, 5.0, 0.0, pair())
    with RecordingWriter(rec, small_rig(), device="second") as w:
        w.add_zone(3, 1.0, 2.0, pair())
    got = read_recording(rec)
    assert got.device == "second" and [z.index for z in got.zones] == [3]
    assert sorted(p.name for p in (rec / "frames").iterdir()) == ["z003-0-off.png", "z003-1-on.png"]
    assert siblings(tmp_path) == ["rec"]


def test_failed_overwrite_keeps_the_earlier_recording(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    with RecordingWriter(rec, small_rig(), device="first") as w:
        w.add_zone(0, 0.0, 0.0, pair())
    with pytest.raises(RuntimeError):
        with RecordingWriter(rec, small_rig(), device="second") as w:
            raise RuntimeError
    assert read_recording(rec).device == "first"
    assert siblings(tmp_path) == ["rec"]


def test_writes_into_an_empty_folder(tmp_path: Path) -> None:
    (tmp_path / "rec").mkdir()
    with RecordingWriter(tmp_path / "rec", small_rig()) as w:
        w.add_zone(0, 0.0, 0.0, pair())
    assert len(read_recording(tmp_path / "rec").zones) == 1


@pytest.mark.parametrize("occupant", ["folder", "file", "other recording format"])
def test_refuses_to_replace_user_data(tmp_path: Path, occupant: str) -> None:
    rec = tmp_path / "rec"
    if occupant == "file":
        rec.write_text("precious")
    else:
        rec.mkdir()
        (rec / "sweep.json" if occupant != "folder" else rec / "notes.txt").write_text(
            '{"format": "other/1"}')
    before = sorted(tmp_path.rglob("*"))
    with pytest.raises(RecordingError) as info:
        RecordingWriter(rec, small_rig())
    assert str(info.value).startswith(f"{rec}: refusing to replace it")
    assert sorted(tmp_path.rglob("*")) == before


def test_refuses_when_user_data_appears_during_recording(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    with pytest.raises(RecordingError, match="refusing"):
        with RecordingWriter(rec, small_rig()) as w:
            w.add_zone(0, 0.0, 0.0, pair())
            rec.mkdir()
            (rec / "notes.txt").write_text("precious")
    assert siblings(tmp_path) == ["rec"]
    assert (rec / "notes.txt").read_text() == "precious"


@pytest.mark.parametrize("frames, expected", [
    ([(blank(), [], {}), (blank(), ["green"], {})], "unknown laser 'green'"),
    ([(blank(), ["center"], {})], "no frame with no laser on"),
    ([(blank(), [], {}), (np.zeros((6, 9), np.uint8), ["center"], {})], "9x6"),
    ([(blank(), [], {}), (blank(np.float32), ["center"], {})], "uint8/uint16"),
    ([(blank(), [], {}), (blank(), ["center"], {"t_start_ns": "soon"})], "t_start_ns"),
    ([(blank(), [], {}), (blank(), ["center"], {"file": "/etc/passwd"})], "'file'"),
    ([(blank(), [], {}), (blank(), ["center"], {"x": object()})], "cannot be written as JSON"),
])
def test_writer_rejects_a_bad_zone(tmp_path: Path, frames: list[Any], expected: str) -> None:
    with RecordingWriter(tmp_path / "rec", small_rig()) as w:
        with pytest.raises(RecordingError, match=re.escape(expected)) as info:
            w.add_zone(2, 0.0, 0.0, frames)
        assert "\n" not in str(info.value) and "zone 2" in str(info.value)
        w.add_zone(2, 0.0, 0.0, pair())
        with pytest.raises(RecordingError, match="duplicate zone index"):
            w.add_zone(2, 0.0, 0.0, pair())
    assert [z.index for z in read_recording(tmp_path / "rec").zones] == [2]


def test_writer_accepts_numpy_scalars(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path / "rec", small_rig()) as w:
        w.add_zone(np.int64(4), np.float32(1.5), 0.0,
                   [(blank(), [], {"t_start_ns": np.int64(7)}), (blank(), ["center"], {})],
                   truth={"point_m": np.array([0.0, 0.5, 2.0])})
    zone = read_recording(tmp_path / "rec").zones[0]
    assert (zone.index, zone.pan_deg, zone.frames[0].t_start_ns) == (4, 1.5, 7)
    assert zone.truth == {"point_m": [0.0, 0.5, 2.0]}


def test_add_zone_outside_with(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="outside"):
        RecordingWriter(tmp_path / "rec", small_rig()).add_zone(0, 0.0, 0.0, pair())


# --------------------------------------------------------------------------------------------------
# Leftovers of killed writers: cleaned up by the next writer of the same recording


def dead_pid() -> int:
    """The pid of a process that has exited and been reaped."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    with pytest.raises(ProcessLookupError):
        os.kill(proc.pid, 0)
    return proc.pid


@pytest.fixture
def sleeper() -> Any:
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    yield proc.pid
    proc.kill()
    proc.wait()


def write(rec: Path, device: str, zones: int = 1) -> None:
    with RecordingWriter(rec, small_rig(), device=device) as w:
        for z in range(zones):
            w.add_zone(z, 0.0, 0.0, pair())


def half_written(folder: Path) -> Path:
    """What a writer killed mid-recording leaves: frames, no sweep.json."""
    write_png(folder / "frames" / "z000-0-off.png", 8, 6)
    return folder


def killed_mid_swap(rec: Path, pid: int, new_device: str = "finished") -> None:
    """What a writer with `pid`, killed between moving `rec` aside and renaming its new recording
    in, leaves: no `rec`, the old recording as rec.old-<pid>, the new one (finished: the swap
    comes after sweep.json is on disk) as rec.partial-<pid>."""
    os.rename(rec, rec.with_name(f"rec.old-{pid}"))
    write(rec.with_name("scratch"), new_device)
    os.rename(rec.with_name("scratch"), rec.with_name(f"rec.partial-{pid}"))


def test_leftovers_of_dead_writers_are_removed(tmp_path: Path, caplog: Any) -> None:
    rec = tmp_path / "rec"
    write(rec, "first")
    dead = dead_pid()
    half_written(tmp_path / f"rec.partial-{dead}")
    shutil.copytree(rec, tmp_path / f"rec.old-{dead}")  # killed while deleting the old one
    shutil.copytree(rec, tmp_path / f"rec.old-{os.getpid()}")  # our pid: a crashed process's
    caplog.set_level(logging.INFO, logger="edge.recording")
    write(rec, "second")
    assert siblings(tmp_path) == ["rec"]
    assert read_recording(rec).device == "second"
    removed = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    for name in (f"rec.partial-{dead}", f"rec.old-{dead}", f"rec.old-{os.getpid()}"):
        assert any(str(tmp_path / name) in m and "removed" in m for m in removed), (name, removed)


def test_leftovers_of_live_writers_are_kept(tmp_path: Path, sleeper: int) -> None:
    rec = tmp_path / "rec"
    write(rec, "first")
    half_written(tmp_path / f"rec.partial-{sleeper}")
    shutil.copytree(rec, tmp_path / f"rec.old-{sleeper}")
    half_written(tmp_path / f"rec.partial-{os.getppid()}")
    before = sorted(tmp_path.rglob("*"))
    write(rec, "second")
    assert sorted(tmp_path.rglob("*")) == before
    assert read_recording(rec).device == "second"


def test_leftovers_of_another_users_process_are_kept(tmp_path: Path, monkeypatch: Any) -> None:
    rec = tmp_path / "rec"
    dead = dead_pid()
    half_written(tmp_path / f"rec.partial-{dead}")
    real_kill = os.kill

    def kill(pid: int, sig: int) -> None:
        if pid == dead:
            raise PermissionError(1, "Operation not permitted")
        real_kill(pid, sig)

    monkeypatch.setattr(os, "kill", kill)
    write(rec, "first")
    assert siblings(tmp_path) == ["rec", f"rec.partial-{dead}"]


def test_unrelated_siblings_are_kept(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    write(rec, "first")
    dead = dead_pid()
    outside = tmp_path / "outside"
    write(outside / "kept", "outside")
    for name in ("rec.partial-abc", f"rec.partial-{dead}x", "rec.partial-", f"rec.partial-0{dead}",
                 f"other.partial-{dead}", f"other.old-{dead}", f"recx.partial-{dead}",
                 f"xrec.old-{dead}", f"rec.partial-{dead}.d", f"rec.backup-{dead}"):
        half_written(tmp_path / name)
    (tmp_path / f"rec.partial-{dead}").write_text("a file, not a writer's folder")
    (tmp_path / f"rec.old-{dead}").symlink_to(outside / "kept")
    before = sorted(tmp_path.rglob("*"))
    write(rec, "second")
    assert sorted(tmp_path.rglob("*")) == before
    assert read_recording(outside / "kept").device == "outside"


def test_a_finished_recording_orphaned_mid_swap_is_put_in_place(tmp_path: Path, caplog: Any) -> None:
    rec = tmp_path / "rec"
    write(rec, "first", zones=2)
    dead = dead_pid()
    killed_mid_swap(rec, dead)
    assert siblings(tmp_path) == [f"rec.old-{dead}", f"rec.partial-{dead}"]
    caplog.set_level(logging.INFO, logger="edge.recording")
    with pytest.raises(RuntimeError):
        with RecordingWriter(rec, small_rig(), device="second") as w:
            assert read_recording(rec).device == "finished"  # the newest whole recording
            assert siblings(tmp_path) == ["rec", f"rec.partial-{os.getpid()}"]
            w.add_zone(0, 0.0, 0.0, pair())
            raise RuntimeError("killed midway")
    assert read_recording(rec).device == "finished"
    assert siblings(tmp_path) == ["rec"]
    assert any("restored" in r.getMessage() and str(tmp_path / f"rec.partial-{dead}") in r.getMessage()
               for r in caplog.records if r.levelno == logging.INFO)


def test_orphaned_old_recording_is_restored_when_the_new_one_is_not_whole(tmp_path: Path, caplog: Any) -> None:
    rec = tmp_path / "rec"
    write(rec, "first", zones=2)
    dead = dead_pid()
    killed_mid_swap(rec, dead)
    (tmp_path / f"rec.partial-{dead}" / "sweep.json").unlink()
    caplog.set_level(logging.INFO, logger="edge.recording")
    with pytest.raises(RuntimeError):
        with RecordingWriter(rec, small_rig(), device="second") as w:
            assert read_recording(rec).device == "first"  # the recording while this one is made
            w.add_zone(0, 0.0, 0.0, pair())
            raise RuntimeError("killed midway")
    got = read_recording(rec)
    assert (got.device, [z.index for z in got.zones]) == ("first", [0, 1])
    assert siblings(tmp_path) == ["rec"]
    assert any("restored" in r.getMessage() and str(tmp_path / f"rec.old-{dead}") in r.getMessage()
               for r in caplog.records if r.levelno == logging.INFO)


def test_orphaned_old_recording_is_replaced_by_the_next_recording(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    write(rec, "first")
    killed_mid_swap(rec, dead_pid())
    write(rec, "second")
    assert read_recording(rec).device == "second"
    assert siblings(tmp_path) == ["rec"]


def test_an_orphaned_recording_goes_into_an_empty_folder(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    write(rec, "first")
    killed_mid_swap(rec, dead_pid())
    rec.mkdir()
    with pytest.raises(RuntimeError):
        with RecordingWriter(rec, small_rig()):
            raise RuntimeError
    assert read_recording(rec).device == "finished"
    assert siblings(tmp_path) == ["rec"]


def test_newest_orphaned_old_recording_is_restored(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    older, newer = dead_pid(), dead_pid()
    for pid, device, when in ((newer, "newer", 2_000_000_000), (older, "older", 1_000_000_000)):
        write(tmp_path / "scratch", device)  # not at rec: that writer would clean up already
        os.utime(tmp_path / "scratch" / "sweep.json", (when, when))
        os.rename(tmp_path / "scratch", tmp_path / f"rec.old-{pid}")
    with pytest.raises(RuntimeError):
        with RecordingWriter(rec, small_rig()):
            raise RuntimeError
    assert read_recording(rec).device == "newer"
    assert siblings(tmp_path) == ["rec"]


def test_broken_orphaned_old_recording_is_not_restored(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    write(rec, "first")
    dead = dead_pid()
    killed_mid_swap(rec, dead)
    (tmp_path / f"rec.old-{dead}" / "frames" / "z000-1-on.png").unlink()  # half deleted
    (tmp_path / f"rec.partial-{dead}" / "frames" / "z000-1-on.png").unlink()
    with pytest.raises(RuntimeError):
        with RecordingWriter(rec, small_rig()):
            raise RuntimeError
    assert siblings(tmp_path) == []


def test_symlinked_old_recording_is_not_restored(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    write(tmp_path / "elsewhere", "elsewhere")
    dead = dead_pid()
    (tmp_path / f"rec.old-{dead}").symlink_to(tmp_path / "elsewhere")
    write(rec, "new")
    assert siblings(tmp_path) == ["elsewhere", "rec", f"rec.old-{dead}"]
    assert read_recording(tmp_path / f"rec.old-{dead}").device == "elsewhere"


def test_failing_to_remove_a_leftover_only_warns(tmp_path: Path, monkeypatch: Any,
                                                 caplog: Any) -> None:
    rec = tmp_path / "rec"
    stale = half_written(tmp_path / f"rec.partial-{dead_pid()}")
    real_rmtree = shutil.rmtree

    def rmtree(path: Any, *args: Any, **kwargs: Any) -> None:
        if Path(path) == stale:
            raise PermissionError(13, "Permission denied", str(path))
        real_rmtree(path, *args, **kwargs)

    monkeypatch.setattr(shutil, "rmtree", rmtree)
    write(rec, "first")
    assert read_recording(rec).device == "first"
    assert siblings(tmp_path) == ["rec", stale.name]
    assert [r.levelno for r in caplog.records if str(stale) in r.getMessage()] == [logging.WARNING]


def test_failing_to_restore_keeps_the_recording_it_could_not_restore(tmp_path: Path, monkeypatch: Any,
                                                    caplog: Any) -> None:
    rec = tmp_path / "rec"
    write(rec, "first")
    dead = dead_pid()
    killed_mid_swap(rec, dead)
    old = tmp_path / f"rec.partial-{dead}"  # the finished one, to be restored
    real_rename = os.rename

    def rename(src: Any, dst: Any) -> None:
        if Path(src) == old:
            raise OSError(5, "Input/output error")
        real_rename(src, dst)

    monkeypatch.setattr(os, "rename", rename)
    write(rec, "second")
    assert read_recording(rec).device == "second"
    assert read_recording(old).device == "finished"  # never delete the only copy
    assert siblings(tmp_path) == ["rec", f"rec.old-{dead}", old.name]
    assert any(r.levelno == logging.WARNING and str(old) in r.getMessage() for r in caplog.records)
    monkeypatch.undo()
    write(rec, "third")  # now superseded: removed
    assert siblings(tmp_path) == ["rec"]


# --------------------------------------------------------------------------------------------------
# Property: any valid metadata round-trips unchanged

NAMES = ("center", "parallel", "sloped")
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
extras = st.fixed_dictionaries({}, optional={
    "pan_deg": finite, "tilt_deg": finite, "t_start_ns": st.integers(0, 2**63 - 1),
    "exposure_us": st.floats(0, 1e6), "laser_switch_ns": st.integers(-(2**40), 2**63 - 1),
})
on_sets = st.lists(st.sampled_from(NAMES), min_size=1, max_size=3, unique=True)
kinds = st.sampled_from(["grey8", "bgr8", "grey16", "bgr16"])


@st.composite
def zone_plans(draw: st.DrawFn, index: int) -> dict[str, Any]:
    offs = [([], draw(extras), draw(kinds)) for _ in range(draw(st.integers(1, 2)))]
    ons = [(draw(on_sets), draw(extras), draw(kinds)) for _ in range(draw(st.integers(1, 3)))]
    frames = offs + ons
    truth = draw(st.none() | st.fixed_dictionaries(
        {"range_m": finite, "point_m": st.lists(finite, min_size=3, max_size=3)}))
    return {"index": index, "pan_deg": draw(finite), "tilt_deg": draw(finite),
            "frames": draw(st.permutations(frames)), "truth": truth}


sweeps = st.lists(st.integers(0, 1200), unique=True, max_size=4).flatmap(
    lambda indices: st.tuples(*(zone_plans(i) for i in indices)))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(plans=sweeps, seed=st.integers(0, 2**32 - 1))
def test_property_metadata_round_trips(plans: tuple[dict[str, Any], ...], seed: int) -> None:
    rng = np.random.default_rng(seed)
    rig = small_rig()
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "rec"
        images = {}
        written = []
        with RecordingWriter(rec, rig) as w:
            for plan in plans:
                frames = [(frames_(rng, kind, (6, 8)), on, extra)
                          for on, extra, kind in plan["frames"]]
                zone = w.add_zone(plan["index"], plan["pan_deg"], plan["tilt_deg"], frames,
                                  truth=plan["truth"])
                expected = ZoneRecord(
                    plan["index"], plan["pan_deg"], plan["tilt_deg"],
                    tuple(FrameRecord(f.file, tuple(on), **extra)
                          for f, (on, extra, _) in zip(zone.frames, plan["frames"])),
                    plan["truth"])
                assert zone == expected
                written.append(zone)
                for f, (image, _, _) in zip(zone.frames, frames):
                    images[(zone.index, f.file)] = image
        got = read_recording(rec)
        assert_rig_equal(got.rig, rig)
        assert got.zones == tuple(written)
        assert [z.index for z in got.zones] == [p["index"] for p in plans]
        for zone, plan in zip(got.zones, plans):
            assert (zone.pan_deg, zone.tilt_deg, zone.truth) == (
                plan["pan_deg"], plan["tilt_deg"], plan["truth"])
            assert [f.lasers_on for f in zone.frames] == [tuple(on) for on, _, _ in plan["frames"]]
            for frame, (_, extra, _) in zip(zone.frames, plan["frames"]):
                assert {k: getattr(frame, k) for k in extra} == extra
                np.testing.assert_array_equal(got.load_image(zone, frame),
                                              images[(zone.index, frame.file)])


def test_a_recording_says_where_a_focus_motor_held_the_lens(tmp_path):
    """Edge's own key, as frame_gamma: written only where a camera has a focus motor (a
    calibration fitted from the frames holds for that lens position), and read back."""
    from edge.recording import RecordingWriter, read_recording
    from edge.rig import default_rig

    image = np.zeros((480, 640, 3), np.uint8)
    for lens, name in ((1.5, "motor"), (None, "fixed")):
        with RecordingWriter(tmp_path / name, default_rig(), lens_dioptres=lens) as w:
            w.add_zone(0, 0.0, 0.0, [(image, [], {}), (image, ["center"], {})])
        doc = json.loads((tmp_path / name / "sweep.json").read_text())
        assert doc.get("lens_dioptres") == lens
        assert read_recording(tmp_path / name).lens_dioptres == lens
