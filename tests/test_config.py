"""Configuration: the shipped files load; every wrong key, type or value is one precise line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from edge.config import Config, load_config
from edge.errors import ConfigError
from edge.rig import default_rig


def test_shipped_sim_config_is_the_default_rig(repo: Path) -> None:
    config = load_config(repo / "config" / "sim.toml")
    rig = config.rig.build()
    nominal = default_rig()
    assert rig.camera == nominal.camera
    for got, want in zip(rig.lasers, nominal.lasers, strict=True):
        assert got.name == want.name
        assert got.origin_m == pytest.approx(want.origin_m)
        assert got.direction == pytest.approx(want.direction, abs=1e-12)
    assert rig.reference.name == "center"
    poses = config.sweep.poses()
    assert len(poses) == 64
    assert poses[1] == (5.625, 0.0)
    assert poses[63][0] == pytest.approx(-5.625)  # wrapped into (-180, 180]


def test_webcam_config_loads(repo: Path) -> None:
    config = load_config(repo / "config" / "sim-webcam.toml")
    assert (config.rig.build().camera.width, config.rig.build().camera.height) == (352, 288)
    assert config.sim.sensor.jpeg_quality == 75


def test_defaults_without_a_file_match_the_shipped_file(repo: Path) -> None:
    shipped = load_config(repo / "config" / "sim.toml")
    assert shipped.rig.build().camera == Config().rig.build().camera
    assert shipped.sweep == Config().sweep


def test_overrides_are_typed_and_validated(repo: Path) -> None:
    config = load_config(repo / "config" / "sim.toml", ["sim.scene=kitchen", "sweep.zones=8"])
    assert config.sim.scene == "kitchen"
    assert config.sweep.zones == 8
    with pytest.raises(ConfigError, match=r"sweep\.zones: expected a whole number"):
        load_config(repo / "config" / "sim.toml", ["sweep.zones=many"])


BAD = [
    ("[rig]\nrange_limits_m = [5.0, 0.25]\n", r"rig\.range_limits_m: must be 0 < near < far"),
    ('[rig]\ncalibration = "a\\u0000b"\n', r"rig\.calibration: must not contain a NUL character"),
    ('[lasers]\nsim_wires = "w\\u0000"\n', r"lasers\.sim_wires: must not contain a NUL character"),
    ("[rig]\nwat = 1\n",
     r"rig\.wat: unknown key \(expected one of: calibration, camera, lasers, mount, range_limits_m\)"),
    ("[sweep]\nzones = \"64\"\n", r"sweep\.zones: expected a whole number, got string '64'"),
    ("[sweep]\nzones = true\n", r"sweep\.zones: expected a whole number, got boolean true"),
    ("[sweep]\nzones = 0\n", r"sweep\.zones: must be 1-4096"),
    ("[rig.camera]\nmodel = \"gopro\"\n", r"rig\.camera\.model: unknown camera model 'gopro' \(known: picam-v2"),
    ("[rig.camera]\nfx = -3.0\n", r"rig\.camera\.fx: must be positive"),
    ("[[rig.lasers]]\nname = \"a\"\norigin_m = [0, 0]\ndirection = [0, 0, 1]\n",
     r"rig\.lasers\[0\]\.origin_m: expected 3 values, got 2"),
    ("[[rig.lasers]]\nname = \"a\"\norigin_m = [0, 0, 0]\ndirection = [0, 0, 2]\n",
     r"rig\.lasers\[0\]\.direction: must be a unit vector \(its length is 2\)"),
    ("[[rig.lasers]]\nname = \"a\"\norigin_m = [0, 0, 0]\n", r"rig\.lasers\[0\]\.direction: missing required key"),
    ("[[rig.lasers]]\nname = \"a\"\norigin_m = [0, 0, 0]\ndirection = [0, 0, 1]\n"
     "[[rig.lasers]]\nname = \"a\"\norigin_m = [0, 0, 0]\ndirection = [0, 0, 1]\n",
     r"rig\.lasers\[1\]\.name: duplicate laser name 'a'"),
    ("[[rig.lasers]]\nname = \"a\"\norigin_m = [0, 0, 0]\ndirection = [0, 0, 1]\npin = 40\n",
     r"rig\.lasers\[0\]\.pin: must be a BCM GPIO number 0-27, got 40"),
    ("[sim.sensor]\noutput_bits = 12\n", r"sim\.sensor\.output_bits: expected one of 8, 16, got 12"),
    ("[sim.sensor]\njpeg_quality = 80\noutput_bits = 16\n", r"sim\.sensor\.jpeg_quality: JPEG frames are 8-bit"),
    ("[camera]\nexposure_us = 50000.0\n", r"camera\.exposure_us: must fit in one frame time"),
    ("[ptu]\nbaudrate = 1000\n", r"ptu\.baudrate: not a PTU-D46 baud rate: 1000"),
    ("[camera]\nbackend = \"gopro\"\n", r"camera\.backend: expected one of 'sim', 'picamera2', 'opencv'"),
    ("[sim]\nseed = 1.5\n", r"sim\.seed: expected a whole number, got number 1.5"),
    ("[[sim.laser_faults]]\nlaser = \"center\"\nkind = \"slow\"\nlag_ms = 0\n",
     r"sim\.laser_faults\[0\]\.lag_ms: must be more than 0 and at most 1000 ms"),
    ("log_level = \"loud\"\n", r"log_level: expected one of 'debug', 'info', 'warning', 'error', got 'loud'"),
    ("rig = 3\n", r"rig: expected a table, got number 3"),
    ("[sim\n", r"not valid TOML"),
]


@pytest.mark.parametrize(("text", "pattern"), BAD)
def test_bad_config_is_one_line_naming_file_and_key(tmp_path: Path, text: str, pattern: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    assert "\n" not in message
    assert ConfigError.exit_code == 2
    import re

    assert re.search(pattern, message), message


def test_missing_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such configuration file"):
        load_config(tmp_path / "nope.toml")


def test_cli_reports_bad_config_in_one_line_with_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("[sweep]\nzones = -1\n")
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "config", "--config", str(path)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"edge: {path}: sweep.zones: must be 1-4096, got -1"
    assert "Traceback" not in proc.stderr


def test_cli_usage_error_exits_2() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "sim", "record"], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert "--out" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
