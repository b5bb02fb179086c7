"""Each part of the rig alone, then all of them through the doctor: the first thing to run on a
newly built rig (README: "From a bare Pi to a running unit", step "hardware tests").

What a failure means: the pan-tilt unit's test fails on a unit that does not answer or does not get
where it is sent (power, cable, ptu.baudrate, a load too heavy for ptu.speed_deg_s); the lasers'
on a pin that cannot be driven (group gpio, python3-lgpio) or a watchdog that did not cut a laser;
the camera's on frames at another rate or an exposure that is not fixed; the doctor's names the
line at fault and what to do."""

from __future__ import annotations

import statistics

import pytest

from edge.config import Config
from edge.parts import laser_factory, open_camera, open_lasers, open_ptu, rig_clock

pytestmark = pytest.mark.hardware


def test_the_pan_tilt_unit_alone(rig_config: Config) -> None:
    clock = rig_clock(rig_config)
    unit, _ = open_ptu(rig_config.ptu, clock, rig_config.sim.ptu_faults)
    with unit:
        (pan_lo, pan_hi), (tilt_lo, tilt_hi) = unit.limits_deg
        assert pan_lo < 0 < pan_hi and tilt_lo < 0 < tilt_hi, unit.limits_deg
        step_pan, step_tilt = unit.resolution_deg
        for pan, tilt in ((30.0, 10.0), (-30.0, -10.0), (0.0, 0.0)):
            unit.move(pan, tilt)
            at = unit.position()
            assert abs(at[0] - pan) <= step_pan and abs(at[1] - tilt) <= step_tilt, (pan, tilt, at)


def test_the_lasers_alone_and_their_eye_safety_watchdog(rig_config: Config) -> None:
    """Each laser lights for 0.3 s in turn (watch them), then one is left on: the watchdog cuts it."""
    clock = rig_clock(rig_config)
    lasers = open_lasers(rig_config, laser_factory(rig_config.lasers, clock), clock)
    with lasers:
        for name in lasers.names:
            lasers.set({name})
            assert lasers.lit == {name}
            clock.sleep(0.3)
            lasers.off()
            assert not lasers.lit
        lasers.set({lasers.names[0]})
        clock.sleep(rig_config.lasers.max_on_s + 0.5)
        assert not lasers.lit and lasers.watchdog_trips == 1


def test_the_camera_alone_at_its_rate_with_a_fixed_exposure(rig_config: Config) -> None:
    clock = rig_clock(rig_config)
    pins = laser_factory(rig_config.lasers, clock)
    camera = open_camera(rig_config, pins, clock)
    try:
        camera.start()
        frames = [camera.frame_after(clock.now_ns())]
        while len(frames) < 30:
            frames.append(camera.frame_after(frames[-1].t_start_ns + 1))
    finally:
        camera.close()
    model = rig_config.rig.build().camera
    assert {f.image.shape[:2] for f in frames} == {(model.height, model.width)}
    intervals_ms = [(b.t_start_ns - a.t_start_ns) / 1e6 for a, b in zip(frames, frames[1:])]
    period_ms = 1e3 / rig_config.camera.frame_rate_hz
    # The sensor's cadence: the shortest interval (a frame collected late doubles one, no more).
    assert min(intervals_ms) == pytest.approx(period_ms, rel=0.03), intervals_ms
    assert statistics.median(intervals_ms) == pytest.approx(period_ms, rel=0.03), intervals_ms
    exposures = {round(f.exposure_us) for f in frames}
    assert max(exposures) - min(exposures) <= 0.02 * rig_config.camera.exposure_us, exposures
    assert statistics.median(exposures) == pytest.approx(rig_config.camera.exposure_us, rel=0.05)


def test_the_doctor_finds_every_part_ok(rig_config_path) -> None:
    """Every line of `edge doctor` (each laser's spot on its own path, none when off, lit frames wholly
    lit; the camera's tone curve the one ranging undoes; the broker)."""
    from edge.doctor import examine

    result = examine(str(rig_config_path))
    print(result.checks.text())
    failed = [f"{line.check}: {line.detail} → {line.remedy}" for line in result.checks.lines
              if line.status not in ("ok", "skip")]
    assert not failed, "\n".join(failed)
