"""The rig's health through its public interface: which part a fault blames, the laser verdicts,
and the camera restart. Faults are routed by their part alone: the messages here are reworded at
random, and made to name the wrong part, and the routing does not change."""

from __future__ import annotations

import itertools
import logging
import random
import string

import numpy as np
import pytest

from edge.errors import AudioError, CameraError, HardwareError, LaserError, PtuError
from edge.laserhealth import LaserFault
from edge.ranging import FAULT, NO_SPOT, OK, ZoneResult
from edge.service import CAMERA_RESTART_AFTER, RigHealth
from edge.triangulation import LaserMeasurement

NAMES = ("center", "parallel", "sloped")
ERRORS = (CameraError, LaserError, PtuError)
# Words that once decided routing, or that name another part: none may sway it.
MISLEADING = ("camera", "laser center does not light", "pan-tilt unit", "no frame", "does not go off",
              "fault: lasers", "ptu", "")
_views = itertools.count()


class Camera:
    """Counts restarts; optionally fails to start."""

    def __init__(self, fails: bool = False) -> None:
        self.stops = self.starts = 0
        self.fails = fails

    def stop(self) -> None:
        self.stops += 1

    def start(self) -> None:
        self.starts += 1
        if self.fails:
            raise CameraError("still no camera")


def health(camera: Camera | None = None, calibrated: bool = True, changes: list | None = None) -> RigHealth:
    return RigHealth(NAMES, "nominal rig", calibrated=calibrated, camera=lambda: camera,
                     changed=lambda: changes.append(1) if changes is not None else None)


def odd_message(rng: random.Random) -> str:
    noise = "".join(rng.choice(string.ascii_letters + string.punctuation + " éß°") for _ in range(rng.randint(0, 40)))
    return rng.choice(MISLEADING) + noise


def zone(found: tuple[str, ...] = NAMES) -> ZoneResult:
    """A zone of a sweep (each at a view of its own) whose range used the spots of `found`."""
    lasers = {n: LaserMeasurement(n, np.zeros(2), 0.1, np.zeros(3), 2.0, 0.01, 30.0, 1) for n in found}
    pan = next(_views) * 5.625 % 360.0 - 180.0
    return ZoneResult(0, pan, 0.0, OK if "center" in found else NO_SPOT, range_m=2.0, lasers=lasers)


def fault(error: type[HardwareError], message: str) -> ZoneResult:
    exc = error(message)
    return ZoneResult(-1, 0.0, 0.0, FAULT, detail=str(exc), part=exc.part)


def test_starts_ok_with_the_calibration_it_is_given() -> None:
    assert health().parts == {"camera": "ok", "lasers": "ok", "ptu": "ok", "calibration": "nominal rig",
                             "storage": "ok"}


@pytest.mark.parametrize("seed", range(5))
def test_every_fault_blames_its_part_whatever_its_words(seed: int) -> None:
    rng = random.Random(seed)
    for error in ERRORS:
        camera = Camera()
        rig = health(camera)
        message = odd_message(rng)
        rig.zone(fault(error, message))
        blamed = {part for part, condition in rig.parts.items() if condition != "ok" and part != "calibration"}
        assert blamed == {error.part}, (error, message, rig.parts)
        assert rig.parts[error.part] == f"fault: {message}"
        rig.zone(zone())  # a zone that went through clears all three
        assert all(rig.parts[p] == "ok" for p in ("camera", "lasers", "ptu"))


@pytest.mark.parametrize("seed", range(5))
def test_only_camera_faults_in_a_row_restart_the_camera(seed: int) -> None:
    rng = random.Random(seed)
    for error in ERRORS:
        camera = Camera()
        rig = health(camera)
        for _ in range(3 * CAMERA_RESTART_AFTER):
            rig.zone(fault(error, odd_message(rng)))
        expected = 3 if error is CameraError else 0
        assert (camera.stops, camera.starts, rig.camera_restarts) == (expected, expected, expected), error
    # Camera faults that do not come in a row restart nothing.
    camera = Camera()
    rig = health(camera)
    for _ in range(4):
        rig.zone(fault(CameraError, odd_message(rng)))
        rig.zone(fault(PtuError, "camera camera camera"))
    assert camera.starts == 0 and rig.camera_restarts == 0


def test_a_restart_without_a_camera_or_that_fails_is_survived(caplog) -> None:
    rig = health(None)
    for _ in range(CAMERA_RESTART_AFTER):
        rig.zone(fault(CameraError, "x"))
    assert rig.camera_restarts == 0  # the rig is not open: nothing to restart
    camera = Camera(fails=True)
    rig = health(camera)
    with caplog.at_level(logging.ERROR):
        for _ in range(CAMERA_RESTART_AFTER):
            rig.zone(fault(CameraError, "x"))
    assert rig.camera_restarts == 1 and camera.starts == 1
    assert any("restart failed" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("seed", range(3))
def test_a_part_that_fails_for_good_is_blamed_by_its_type(seed: int) -> None:
    rng = random.Random(seed)
    for error in ERRORS:
        rig = health()
        message = odd_message(rng)
        rig.failed(error(message))
        assert rig.parts[error.part] == f"fault: {message}"
        assert [p for p, c in rig.parts.items() if c != "ok" and p != "calibration"] == [error.part]
    rig = health()
    rig.failed(HardwareError("the camera and the ptu and the lasers"))  # no single part to blame
    rig.failed(AudioError("the camera"))  # not a part `state` reports
    assert rig.parts == health().parts


def test_a_dark_laser_is_a_typed_verdict_worded_in_state() -> None:
    changes: list = []
    rig = health(calibrated=True, changes=changes)
    for _ in range(rig.lasers.hysteresis.enter_dark):
        rig.zone(zone(("parallel", "sloped")))
    verdicts = rig.lasers.verdicts()
    assert set(verdicts) == {"center"} and verdicts["center"].fault is LaserFault.DARK
    assert rig.parts["lasers"] == "fault: " + verdicts["center"].words(calibrated=True)
    assert "calibrate it" not in rig.parts["lasers"]
    assert len(changes) == 1  # `state` went out, once
    for _ in range(3 * rig.lasers.hysteresis.enter_dark):
        rig.zone(zone(("parallel", "sloped")))  # nor again while the verdict only stands
    assert len(changes) == 1
    rig.zone(zone())  # one spot could be a stray light on its path
    assert rig.lasers.verdicts() and len(changes) == 1
    rig.zone(zone())
    assert rig.parts["lasers"] == "ok" and rig.lasers.verdicts() == {} and len(changes) == 2


def test_each_verdict_is_logged_once_and_its_end_too(caplog) -> None:
    rig = health()
    with caplog.at_level(logging.INFO, logger="edge.service.health"):
        for _ in range(3 * rig.lasers.hysteresis.enter_dark):
            rig.zone(zone(("center", "parallel")))
        for _ in range(rig.lasers.hysteresis.enter_dark):
            rig.zone(zone(("center",)))  # now parallel as well
        for _ in range(rig.lasers.hysteresis.leave):
            rig.zone(zone(("center", "sloped")))  # sloped is back
        for _ in range(rig.lasers.hysteresis.leave):
            rig.zone(zone())
    said = [r.getMessage() for r in caplog.records]
    assert [m[:24] for m in said] == ["laser sloped does not li", "laser parallel does not ",
                                      "laser sloped: working ag", "lasers: all working agai"]


def test_on_an_uncalibrated_rig_a_dark_laser_may_be_misaimed() -> None:
    rig = health(calibrated=False)
    for _ in range(rig.lasers.hysteresis.enter_dark):
        rig.zone(zone(("parallel", "sloped")))
    assert "does not light" in rig.parts["lasers"] and "calibrate it (cmd/calibrate)" in rig.parts["lasers"]


def test_a_laser_stuck_on_and_a_new_calibration_that_judges_afresh() -> None:
    rig = health(calibrated=False)
    for _ in range(rig.lasers.hysteresis.enter_stuck):
        rig.zone(zone(("parallel", "sloped")), frozenset({"center"}))
    assert rig.lasers.verdicts()["center"].fault is LaserFault.STUCK_ON
    assert "does not go off" in rig.parts["lasers"]
    rig.recalibrated("calibrated today", NAMES)
    assert rig.calibrated and rig.lasers.verdicts() == {}
    assert rig.parts["lasers"] == "ok" and rig.parts["calibration"] == "calibrated today"


def test_nothing_new_publishes_nothing() -> None:
    changes: list = []
    rig = health(changes=changes)
    rig.zone(zone())
    rig.zone(zone())
    assert changes == []
    rig.zone(fault(PtuError, "gone"))
    rig.zone(fault(PtuError, "gone"))
    assert len(changes) == 1


def test_the_blind_aid_cannot_see_when_its_reference_laser_does_not_range() -> None:
    """The reference laser dark (or stuck on): every zone reads no_spot, which looks like open
    space; the health says why the blind aid cannot see. Another laser dark: it still sees."""
    h = health()
    for _ in range(8):
        h.zone(zone(("parallel", "sloped")))
    assert h.cannot_see("center") is not None and "laser center does not light" in h.cannot_see("center")
    h = health()
    for _ in range(8):
        h.zone(zone(("center", "parallel")))
    assert h.parts["lasers"].startswith("fault: laser sloped")
    assert h.cannot_see("center") is None
