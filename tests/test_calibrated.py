"""Which rig ranging believes: the configured calibration file, else the service's own, else the
nominal rig — and a configured file that cannot be used is an error, never a silent default."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from edge.calibration.file import Calibration, write_calibration
from edge.calibration.in_use import NOMINAL, believed_rig
from edge.config import load_config
from edge.errors import ConfigError
from edge.rig import default_rig
from edge.service import Service

REPO = Path(__file__).resolve().parents[1]


def turned(rig, degrees: float = 0.4) -> Calibration:
    """A calibration whose lasers are turned a little about the camera's y axis."""
    a = np.radians(degrees)
    rot = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    lasers = tuple(replace(laser, direction=tuple(float(c) for c in rot @ np.asarray(laser.direction)))
                   for laser in rig.lasers)
    return Calibration(lasers, rig.camera, (0.5, 1.0, 2.0), {ln.name: {"rms": 0.1, "max": 0.2, "n": 3}
                                                           for ln in rig.lasers}, "2026-11-23T10:00:00Z")


def edge_config(setting: str) -> str:
    """What `edge config --set setting` prints; it must succeed."""
    result = subprocess.run([sys.executable, "-m", "edge", "config", "--set", setting],
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    return result.stdout


def directions(rig) -> list[tuple[float, ...]]:
    return [tuple(round(c, 9) for c in laser.direction) for laser in rig.lasers]


def test_without_any_calibration_the_nominal_rig(tmp_path):
    config = load_config(None, [f"service.state_dir={json.dumps(str(tmp_path))}"])
    for service in (False, True):
        believed = believed_rig(config, service=service)
        assert believed.rig == config.rig.build() and believed.health == NOMINAL and believed.path is None


def test_a_configured_calibration_is_applied_relative_to_the_config_file(tmp_path):
    cal = turned(default_rig())
    write_calibration(tmp_path / "rig-cal.json", cal)
    (tmp_path / "edge.toml").write_text('[rig]\ncalibration = "rig-cal.json"\n')
    config = load_config(str(tmp_path / "edge.toml"))
    believed = believed_rig(config)
    assert directions(believed.rig) == directions(cal.apply(config.rig.build()))
    assert directions(believed.rig) != directions(config.rig.build())
    assert not hasattr(believed.rig.lasers[0], "pin")  # geometry only: the wiring stays the config's
    assert believed.health.startswith("calibrated 2026-11-23T10:00:00Z at 0.5, 1, 2 m, residuals ≤ 0.20 px")
    assert str(tmp_path / "rig-cal.json") in believed.health


def test_a_configured_calibration_that_cannot_be_used_is_an_error(tmp_path):
    config = load_config(None, [f"rig.calibration={json.dumps(str(tmp_path / 'nope.json'))}"])
    with pytest.raises(ConfigError, match=r"^rig.calibration: .*nope.json: no such calibration file"):
        believed_rig(config)
    (tmp_path / "nope.json").write_text("{")
    with pytest.raises(ConfigError, match=r"^rig.calibration: .*nope.json: not valid JSON"):
        believed_rig(config, service=True)
    # and from the command line: one line, no traceback, exit status of a bad input
    result = subprocess.run([sys.executable, "-m", "edge", "run", "--set",
                             f"rig.calibration={json.dumps(str(tmp_path / 'nope.json'))}", "--for", "1"],
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    lines = [ln for ln in result.stderr.splitlines() if ln.startswith("edge:")]
    assert len(lines) == 1 and "rig.calibration:" in lines[0] and "nope.json: not valid JSON" in lines[0]
    assert "Traceback" not in result.stderr


def test_the_service_uses_its_own_calibration_and_other_commands_do_not(tmp_path):
    config = load_config(None, [f"service.state_dir={json.dumps(str(tmp_path))}", "mqtt.enabled=false"])
    cal = turned(config.rig.build())
    write_calibration(tmp_path / "calibration.json", cal)
    assert directions(believed_rig(config, service=True).rig) == directions(cal.apply(config.rig.build()))
    assert believed_rig(config).health == NOMINAL  # `edge sweep` in the same folder: only if configured
    service = Service(config)
    assert directions(service.ranger.rig) == directions(cal.apply(config.rig.build()))
    assert service.state()["health"]["calibration"].startswith("calibrated 2026-11-23T10:00:00Z")


def test_a_broken_own_calibration_is_reported_and_the_service_ranges_nominally(tmp_path, caplog):
    config = load_config(None, [f"service.state_dir={json.dumps(str(tmp_path))}", "mqtt.enabled=false"])
    other = replace(turned(config.rig.build()), lasers=turned(config.rig.build()).lasers[:2])  # a laser short
    write_calibration(tmp_path / "calibration.json", other)
    service = Service(config)
    health = service.state()["health"]["calibration"]
    assert health.startswith("fault: the calibration has no laser 'sloped'") and "nominal rig" in health
    assert directions(service.ranger.rig) == directions(config.rig.build())
    assert any("calibration" in r.getMessage() and r.levelname == "ERROR" for r in caplog.records)


def test_edge_config_says_what_the_rig_is_based_on(tmp_path):
    write_calibration(tmp_path / "c.json", turned(default_rig()))
    said = edge_config(f"rig.calibration={json.dumps(str(tmp_path / 'c.json'))}")
    assert "calibration: calibrated 2026-11-23T10:00:00Z" in said


def test_a_new_calibration_is_saved_used_and_makes_the_guard_learn_again(tmp_path):
    """The end of a cmd/calibrate session in the service, with the session's own outcome given:
    the file is written, the ranger uses it, and a guard that had learnt its room with the old
    rays learns it again (against the new ones every wall would seem to have moved)."""
    from edge.calibration.session import Outcome
    from edge.ranging import OK, ZoneResult

    config = load_config(None, [f"service.state_dir={json.dumps(str(tmp_path))}", "mqtt.enabled=false",
                                'mode="guard"', "guard.learn_sweeps=2"])
    service = Service(config)
    for sweep in (1, 2):
        service.guard.sweep([ZoneResult(i, 45.0 * i, 0.0, OK, range_m=2.0, sigma_m=0.005) for i in range(8)],
                            sweep, sweep)
    assert not service.guard.learning
    cal = turned(config.rig.build())

    service.calibration.adopt(Outcome(cal))  # a session whose board was carried to every distance
    assert directions(service.ranger.rig) == directions(cal.apply(config.rig.build()))
    assert service.health.calibrated and not service.calibration.running
    assert service.state()["health"]["calibration"].startswith("calibrated 2026-11-23T10:00:00Z")
    assert (tmp_path / "calibration.json").exists()
    assert service.guard.learning


def test_edge_config_also_says_what_the_service_would_use(tmp_path):
    write_calibration(tmp_path / "calibration.json", turned(default_rig()))
    said = edge_config(f"service.state_dir={json.dumps(str(tmp_path))}")
    assert f"  calibration: {NOMINAL}\n" in said
    assert "  calibration of edge run: calibrated 2026-11-23T10:00:00Z" in said


def test_a_calibration_holds_for_the_lens_position_it_was_made_at(tmp_path):
    """A Camera Module 3's focus motor moves the focal length with the lens: a calibration made with
    the lens held at 1 dioptre says so in its file, and once camera.lens_dioptres holds it elsewhere
    the calibration's health is a fault that says to calibrate again (the doctor's calibration line
    fails on it). Files of cameras without a motor, and older ones, carry no position."""
    from edge.calibration.file import read_calibration

    cal = replace(turned(default_rig()), lens_dioptres=1.0)
    write_calibration(tmp_path / "c.json", cal)
    assert json.loads((tmp_path / "c.json").read_text())["lens_dioptres"] == 1.0
    assert read_calibration(tmp_path / "c.json").lens_dioptres == 1.0
    write_calibration(tmp_path / "plain.json", turned(default_rig()))
    assert "lens_dioptres" not in json.loads((tmp_path / "plain.json").read_text())
    assert read_calibration(tmp_path / "plain.json").lens_dioptres is None

    def believed(lens: float, backend: str = "picamera2"):
        return believed_rig(load_config(None, [f"rig.calibration={json.dumps(str(tmp_path / 'c.json'))}",
                                               f'camera.backend="{backend}"', f"camera.lens_dioptres={lens}"]))

    assert believed(1.0).health.startswith("calibrated 2026-11-23T10:00:00Z")
    moved = believed(2.5)
    assert moved.health.startswith("fault: calibrated with the lens at 1 dioptres, and camera.lens_dioptres "
                                   "holds it at 2.5 now")
    assert directions(moved.rig) == directions(cal.apply(default_rig()))  # still nearer the truth than nominal
    assert believed(2.5, backend="sim").health.startswith("calibrated")  # no focus motor to hold
    doc = json.loads((tmp_path / "c.json").read_text()) | {"lens_dioptres": -1}
    (tmp_path / "c.json").write_text(json.dumps(doc))
    with pytest.raises(ConfigError, match=r"c.json: lens_dioptres: "):
        believed(1.0)
