"""Issue 13's file and configuration cases: everything read from disk is a small regular file,
every output lands on a plain file or folder, every number is within a physical range, and every
such mistake is one line (exit status 2), never a hang, a MemoryError or a traceback."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import threading
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from test_recording import EXAMPLE, make_example  # tests/ is on sys.path

from edge.calibration.file import read_calibration, write_calibration
from edge.calibration.in_use import believed_rig
from edge.config import Config, MqttConfig, ServiceConfig, load_config
from edge.config_file import read_table
from edge.errors import CalibrationError, ConfigError, PtuError, RecordingError
from edge.fsutil import atomic_write_bytes
from edge.mqtt import read_password
from edge.recording import read_recording
from edge.rig import default_rig

SPECIAL = ("fifo", "dev-zero", "folder", "huge")


def special(folder: Path, kind: str, name: str = "file") -> Path:
    """A file of `kind` at folder/name: a FIFO, a link to /dev/zero, a folder, a 2 GB sparse file."""
    path = folder / name
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dev-zero":
        path.symlink_to("/dev/zero")
    elif kind == "folder":
        path.mkdir()
    else:
        with open(path, "wb") as fh:
            fh.truncate(2 << 30)
    return path


def finishes(call: Callable[[], Any], timeout: float = 60.0) -> Any:
    """`call()`, failing the test instead of hanging with it (a FIFO opened for reading waits)."""
    outcome: dict[str, Any] = {}

    def run() -> None:
        try:
            outcome["value"] = call()
        except BaseException as exc:  # noqa: BLE001  (re-raised below, in the test's thread)
            outcome["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(timeout)
    assert not thread.is_alive(), f"still reading after {timeout} s"
    if "error" in outcome:
        raise outcome["error"]
    return outcome.get("value")


def one_line(exc: BaseException) -> str:
    text = str(exc)
    assert len(text.splitlines()) == 1, text
    return text


def edge(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "edge", *args], capture_output=True, text=True,
                          timeout=timeout)


# ---- item 11: special files are refused, fast ----


@pytest.mark.parametrize("kind", SPECIAL)
def test_read_small_refuses_what_is_not_a_small_regular_file(tmp_path: Path, kind: str) -> None:
    from edge.fsutil import read_small

    with pytest.raises(OSError) as caught:
        finishes(lambda: read_small(special(tmp_path, kind), limit=1 << 20))
    assert ("not a regular file" if kind != "huge" else "too large") in caught.value.strerror
    (tmp_path / "ok").write_bytes(b"x" * 10)
    assert read_small(tmp_path / "ok", limit=10) == b"x" * 10
    with pytest.raises(OSError, match="too large"):
        read_small(tmp_path / "ok", limit=9)


@pytest.mark.parametrize("kind", SPECIAL)
def test_a_special_config_file_is_one_line(tmp_path: Path, kind: str) -> None:
    path = special(tmp_path, kind, "edge.toml")
    with pytest.raises(ConfigError) as caught:
        finishes(lambda: read_table(path))
    assert one_line(caught.value).startswith(f"{path}: cannot read: ")


@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_edge_lasers_off_and_edge_config_with_a_special_config_neither_hang_nor_crash(
        tmp_path: Path, kind: str) -> None:
    path = special(tmp_path, kind, "edge.toml")
    for command in (["config"], ["lasers", "off"]):
        proc = edge(*command, "--config", str(path), timeout=60)
        assert "Traceback" not in proc.stderr, proc.stderr
        assert proc.returncode in (0, 2), proc.stderr  # 0: lasers off falls back to the default wiring
        if proc.returncode == 2:
            assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


@pytest.mark.parametrize("kind", SPECIAL)
def test_a_special_calibration_file_is_one_line(tmp_path: Path, kind: str) -> None:
    path = special(tmp_path, kind, "cal.json")
    with pytest.raises(CalibrationError) as caught:
        finishes(lambda: read_calibration(path))
    assert "cannot be read" in one_line(caught.value)


@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_a_special_calibration_json_in_the_state_dir_is_a_health_fault(tmp_path: Path, kind: str) -> None:
    special(tmp_path, kind, "calibration.json")
    config = Config(service=ServiceConfig(state_dir=str(tmp_path)))
    believed = finishes(lambda: believed_rig(config, service=True))
    assert believed.health.startswith("fault: ") and "not a regular file" in believed.health
    assert believed.rig == config.rig.build()


@pytest.mark.parametrize("kind", SPECIAL)
def test_a_special_password_file_is_one_line(tmp_path: Path, kind: str) -> None:
    path = special(tmp_path, kind, "password")
    with pytest.raises(ConfigError) as caught:
        finishes(lambda: read_password(MqttConfig(password_file=str(path))))
    assert one_line(caught.value).startswith("mqtt.password_file: cannot read")


@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_a_special_sweep_json_is_one_line(tmp_path: Path, kind: str) -> None:
    rec = make_example(tmp_path / "rec")
    (rec / "sweep.json").unlink()
    special(rec, kind, "sweep.json")
    with pytest.raises(RecordingError) as caught:
        finishes(lambda: read_recording(rec))
    one_line(caught.value)


def test_deeply_nested_json_is_one_line(tmp_path: Path) -> None:
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(CalibrationError, match="nested"):
        read_calibration(deep)
    # Deeper than any document of ours nests, even where unknown keys are ignored.
    doc = json.loads(EXAMPLE)
    doc["extra"] = json.loads("[" * 40 + "]" * 40)
    rec = make_example(tmp_path / "rec", doc)
    with pytest.raises(RecordingError, match="nested more than 32 levels"):
        read_recording(rec)


# ---- item 10: outputs go to plain files and folders ----


def test_atomic_writes_never_replace_a_special_file(tmp_path: Path) -> None:
    fifo = special(tmp_path, "fifo", "out.json")
    with pytest.raises(OSError, match="FIFO, not a regular file"):
        atomic_write_bytes(fifo, b"{}")
    with pytest.raises(CalibrationError, match="cannot write the calibration: .*FIFO"):
        from edge.calibration.file import Calibration
        write_calibration(fifo, Calibration.from_rig(default_rig()))
    assert fifo.is_fifo()  # still the FIFO, not our file
    with pytest.raises(OSError, match="in /dev"):
        atomic_write_bytes("/dev/null", b"x")


@pytest.mark.parametrize("target", ["/dev/null", "/dev/sda1", "FOLDER", "LINK"])
def test_audio_out_must_be_a_plain_file(tmp_path: Path, target: str) -> None:
    if target == "FOLDER":
        target = str(tmp_path)
    elif target == "LINK":
        (tmp_path / "cues.wav").symlink_to("/dev/null")
        target = str(tmp_path / "cues.wav")
    with pytest.raises(ConfigError) as caught:
        load_config(None, [f"audio.out={json.dumps(target)}"])
    assert "audio.out: " in one_line(caught.value)
    for fine in ("", "alsa", "alsa:hw:1", "null", str(tmp_path / "cues.wav.new")):
        assert load_config(None, [f"audio.out={json.dumps(fine)}"]).audio.out == fine


def test_edge_calibrate_out_on_a_device_is_refused_before_the_fit(tmp_path: Path) -> None:
    proc = edge("calibrate", "--recording", str(tmp_path / "none"), "--distances", "0.5,1,2",
                "--out", "/dev/null")
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().startswith("edge: --out: /dev/null: ") and "in /dev" in proc.stderr
    fifo = special(tmp_path, "fifo", "cal.json")
    proc = edge("calibrate", "--recording", str(tmp_path / "none"), "--distances", "0.5,1,2",
                "--out", str(fifo))
    assert proc.returncode == 2 and "FIFO, not a regular file" in proc.stderr, proc.stderr
    assert fifo.is_fifo()


def test_sweep_out_that_is_a_file_is_refused_before_the_sweep(tmp_path: Path) -> None:
    (tmp_path / "taken").write_text("mine")
    proc = edge("sweep", "--out", str(tmp_path / "taken"), "--set", "sweep.zones=1")
    assert proc.returncode == 2 and proc.stderr.strip().startswith("edge: --out: "), proc.stderr
    assert "regular file, not a folder" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert (tmp_path / "taken").read_text() == "mine"


# ---- item 12: numbers within physical ranges, identifiers a broker takes ----


@pytest.mark.parametrize("override, key", [
    ("mqtt.session_expiry_s=4294967296", "mqtt.session_expiry_s"),
    ("rig.camera.width=100000", "rig.camera.width"),
    ("rig.camera.fx=1e308", "rig.camera.fx"),
    ("rig.camera.dist=[1e300, 0, 0, 0, 0]", "rig.camera.dist"),
    ("rig.camera.cx=-1e9", "rig.camera.cx"),
    ("rig.range_limits_m=[0.25, 1e300]", "rig.range_limits_m"),
    ('mqtt.client_id="edge+1"', "mqtt.client_id"),
    ('mqtt.client_id="edge#"', "mqtt.client_id"),
    ('mqtt.client_id="edge/1"', "mqtt.client_id"),
    ('mqtt.client_id="edge\\u0007"', "mqtt.client_id"),
    ("mqtt.reconnect_max_s=1e300", "mqtt.reconnect_max_s"),
    ("camera.analogue_gain=1e9", "camera.analogue_gain"),
    ("camera.timeout_s=1e300", "camera.timeout_s"),
    ("camera.latency_ms=1e300", "camera.latency_ms"),
    ("sweep.pan_step_deg=1e300", "sweep.pan_step_deg"),
    ("sweep.poses_deg=[[1e300, 0]]", "sweep.poses_deg[0]"),
    ("service.sweep_interval_s=1e300", "service.sweep_interval_s"),
])
def test_numbers_and_names_out_of_range_are_refused(override: str, key: str) -> None:
    with pytest.raises(ConfigError) as caught:
        load_config(None, [override])
    assert f": {key}: " in one_line(caught.value)


def test_the_largest_session_expiry_is_taken() -> None:
    assert load_config(None, ["mqtt.session_expiry_s=4294967295"]).mqtt.session_expiry_s == 4294967295


def test_edge_run_with_an_mqtt_session_expiry_too_large_stops_at_once() -> None:
    proc = edge("run", "--set", "mqtt.session_expiry_s=4294967296", "--for", "5", timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("edge: ") and "session_expiry_s" in proc.stderr


# ---- item 13: recordings of unbounded sizes, exit status 2 ----


def png_header_only(path: Path, width: int, height: int) -> None:
    """A PNG that claims width x height (8-bit grey) and holds one tiny compressed row."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                     + chunk(b"IDAT", zlib.compress(b"\0" * (width + 1))) + chunk(b"IEND", b""))


def test_a_frame_claiming_a_huge_size_is_refused_before_decoding(tmp_path: Path) -> None:
    rec = make_example(tmp_path / "rec")
    got = read_recording(rec)
    png_header_only(rec / "frames/z000-1-on.png", 30000, 30000)  # changed after reading
    with pytest.raises(RecordingError, match="image is 30000x30000 but the camera is 640x480"):
        got.load_image(got.zones[0], got.zones[0].frames[1])


@pytest.mark.parametrize("camera, key", [
    ({"width": 30000, "height": 30000}, "camera.width"),
    ({"fx": 1e308}, "camera.fx"),
    ({"dist": [1e300, 1e300, 0, 0, 0]}, "camera.dist"),
])
def test_a_recording_with_an_impossible_camera_is_one_line_and_exit_2(tmp_path: Path, camera: dict,
                                                                        key: str) -> None:
    doc = json.loads(EXAMPLE)
    rec = make_example(tmp_path / "rec", doc)
    doc["camera"].update(camera)
    (rec / "sweep.json").write_text(json.dumps(doc))
    if "width" in camera:
        for frame in ("frames/z000-0-off.png", "frames/z000-1-on.png"):
            png_header_only(rec / frame, 30000, 30000)
    proc = edge("replay", str(rec))
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and f"sweep.json: {key}: " in proc.stderr, proc.stderr


# ---- item 14: limits printed with the digits that make them true ----


def test_the_ptu_limit_message_shows_the_real_limit() -> None:
    from edge.hw.ptu import PtuConfig
    from edge.parts import open_ptu

    unit, _ = open_ptu(PtuConfig(port="sim://"))  # the unit closes its emulator
    with unit:
        (_, hi), _ = unit.limits_deg
        assert 179.9999 < hi < 180.0
        with pytest.raises(PtuError) as caught:
            unit.to_positions(180.1, 0.0)
        assert "-179.99994°…179.99994°" in str(caught.value), caught.value
