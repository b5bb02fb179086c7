"""The cmd/calibrate controller through its public interface: it answers the command once, when
the session ends however it ends, saves only a calibration the rig can use, and hands it over."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from test_calibrated import directions, turned

from edge.calibration.in_use import believed_rig
from edge.calibration.session import Outcome
from edge.config import load_config
from edge.parts import open_parts
from edge.ranging import Ranger
from edge.service.calibrating import CalibrationController


class Published:
    """What the controller asked to be published, in order."""

    def __init__(self) -> None:
        self.results: list[tuple] = []
        self.states = 0
        self.ranges: list[dict] = []
        self.zones: list = []
        self.adopted: list = []


@pytest.fixture
def config(tmp_path):
    return load_config(None, [f"service.state_dir={json.dumps(str(tmp_path))}", "mqtt.enabled=false"])


def controller(config, out: Published) -> CalibrationController:
    def count_state() -> None:
        out.states += 1

    return CalibrationController(
        config, "test-device",
        publish_result=lambda ok, error, request_id, extra: out.results.append((ok, error, request_id, extra)),
        publish_state=count_state, publish_range=out.ranges.append, report_zone=out.zones.append,
        adopt=out.adopted.append, pause=lambda s: None)


def test_an_outcome_with_a_calibration_is_saved_and_handed_over(config, tmp_path):
    out = Published()
    cal = turned(config.rig.build())
    controller(config, out).adopt(Outcome(cal))
    assert (tmp_path / "calibration.json").exists()
    [believed] = out.adopted
    assert directions(believed.rig) == directions(cal.apply(config.rig.build()))
    assert directions(believed_rig(config, service=True).rig) == directions(believed.rig)  # what a restart uses
    [(ok, error, request_id, extra)] = out.results
    assert ok and error is None and request_id is None
    assert extra["calibration"]["file"] == str(tmp_path / "calibration.json")
    assert set(extra["calibration"]["lasers"]) == {"center", "parallel", "sloped"}
    assert out.states == 1


def test_a_failed_fit_changes_nothing(config, tmp_path):
    out = Published()
    controller(config, out).adopt(Outcome(None, "the fit failed: too few points; nothing changed"))
    assert out.results == [(False, "the fit failed: too few points; nothing changed", None, None)]
    assert not (tmp_path / "calibration.json").exists() and out.adopted == []


def test_a_calibration_the_rig_cannot_use_is_never_saved(config, tmp_path):
    out = Published()
    cal = turned(config.rig.build())
    controller(config, out).adopt(Outcome(replace(cal, lasers=cal.lasers[:2])))  # a laser short
    [(ok, error, _, _)] = out.results
    assert not ok and error.endswith("; nothing changed") and "sloped" in error
    assert not (tmp_path / "calibration.json").exists() and out.adopted == []


def test_without_the_rig_no_session_starts(config):
    out = Published()
    calibration = controller(config, out)
    ranger = Ranger(config.rig.build(), config.ranging)
    assert calibration.start((0.5, 1.0), "r0", None, ranger) == "the rig is not running"
    assert not calibration.running and calibration.refusal() is None and calibration.state() is None
    calibration.cancel("nothing to cancel")
    assert out.results == [] and out.states == 0


def test_a_session_runs_on_the_rig_until_cancelled(config, tmp_path):
    out = Published()
    calibration = controller(config, out)
    ranger = Ranger(config.rig.build(), config.ranging)
    with open_parts(config) as parts:
        assert calibration.start((0.5, 1.0), "r1", parts, ranger) is None
        assert calibration.running and out.states == 1 and out.results == []
        assert calibration.state()["distances_m"] == [0.5, 1.0]
        assert "waiting for the target at 0.5 m" in calibration.refusal()
        assert calibration.start((0.7, 1.0), "r2", parts, ranger) == calibration.refusal()  # one at a time
        for _ in range(3):
            calibration.step()  # no target comes: pairs are ranged and shown, nothing is taken
        assert len(out.ranges) == 3 and calibration.state()["taken_m"] == []
        calibration.cancel("cancelled by cmd/mode")
    assert out.results == [(False, "cancelled by cmd/mode", "r1", None)]
    assert not calibration.running and calibration.state() is None and calibration.refusal() is None
    assert not (tmp_path / "calibration.json").exists() and out.adopted == []
