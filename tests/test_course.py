"""The service's course (edge.service.course): which step comes next, and when the step under way
ends early — pure, with the times passed in."""

from __future__ import annotations

import math

from edge.service.course import PAUSED_LASERS_OFF, Course, Step


def test_each_mode_has_its_own_step():
    for mode, step in (("rangefinder", Step.RANGE), ("guard", Step.SWEEP), ("blindaid", Step.FAN)):
        assert Course(mode, (0.0, 0.0)).next_step(0.0, calibrating=False) is step


def test_the_range_finder_sweeps_when_its_interval_is_due_and_not_before():
    course = Course("rangefinder", (0.0, 0.0), sweep_interval_s=300.0)
    course.start(1000.0)
    assert course.next_step(1299.0, calibrating=False) is Step.RANGE
    assert not course.sweep_due(1299.0) and course.sweep_due(1300.0)
    assert course.next_step(1300.0, calibrating=False) is Step.SWEEP
    assert course.next_sweep == 1600.0  # the next one an interval after this one
    assert course.next_step(1301.0, calibrating=False) is Step.RANGE


def test_without_an_interval_only_cmd_sweep_sweeps():
    course = Course("rangefinder", (0.0, 0.0))
    course.start(0.0)
    assert course.next_sweep == math.inf and course.next_step(1e9, calibrating=False) is Step.RANGE
    course.ask_sweep()
    assert course.should_end(sweeping=False) and not course.should_end(sweeping=True)
    assert course.next_step(1e9, calibrating=False) is Step.SWEEP
    assert course.next_step(1e9, calibrating=False) is Step.RANGE  # once


def test_a_pause_comes_before_everything_drops_a_sweep_asked_for_and_refuses_ranging():
    course = Course("guard", (0.0, 0.0))
    course.ask_sweep()
    assert course.pause() is True and course.pause() is False  # already paused
    assert course.paused == PAUSED_LASERS_OFF and course.should_end(sweeping=True)
    assert course.next_step(0.0, calibrating=True) is Step.PAUSED
    assert "cmd/lasers_off" in (course.refusal() or "")
    assert course.resume() is True and course.resume() is False
    assert course.refusal() is None
    assert course.next_step(0.0, calibrating=False) is Step.SWEEP  # the guard's own, not the dropped one


def test_a_calibration_session_comes_before_the_mode():
    course = Course("blindaid", (0.0, 0.0))
    assert course.next_step(0.0, calibrating=True) is Step.CALIBRATE


def test_changing_course_ends_the_step_under_way_until_the_next_step_begins():
    course = Course("rangefinder", (0.0, 0.0))
    assert course.change_mode("rangefinder") is False and not course.should_end(sweeping=False)
    assert course.change_mode("guard") is True and course.should_end(sweeping=True)
    course.next_step(0.0, calibrating=False)
    assert not course.should_end(sweeping=True)
    course.aim_at(30.0, -5.0)
    assert course.aim == (30.0, -5.0) and course.should_end(sweeping=False)
