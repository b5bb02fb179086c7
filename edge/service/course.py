"""Where the service's loop goes next, and why the step under way should end early.

The commands change course (a mode, an aim, a sweep asked for, a pause); the loop asks, between
steps, which step comes next. Pure: times are passed in, nothing is done here.

A pause (``cmd/lasers_off``) comes first: nothing ranges until ``cmd/mode`` or ``cmd/sweep``
resumes. Then a running calibration session. Then a sweep asked for, or one the range finder's
``service.sweep_interval_s`` makes due. Then the mode's own step: the range finder's frames, the
guard's next sweep, the blind aid's fan.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from edge.modes import Mode

# `state`'s "paused" while cmd/lasers_off holds the lasers off.
PAUSED_LASERS_OFF = "lasers_off"


class Step(enum.Enum):
    PAUSED = "paused"  # idle, lasers held off
    CALIBRATE = "calibrate"  # one pair of the cmd/calibrate session
    SWEEP = "sweep"  # a full sweep (asked for, due, or the guard's next)
    RANGE = "range"  # the range finder's frames at the aim
    FAN = "fan"  # one pass of the blind aid's fan


_MODE_STEP = {"rangefinder": Step.RANGE, "guard": Step.SWEEP, "blindaid": Step.FAN}


@dataclass
class Course:
    mode: Mode
    aim: tuple[float, float]  # where the range finder points (pan, tilt), degrees
    sweep_interval_s: float = 0.0  # the range finder's map sweeps; 0: on cmd/sweep only
    paused: str | None = None  # why ranging is paused, or None
    sweep_asked: bool = False  # cmd/sweep came: a sweep as soon as the current step ends
    interrupt: bool = False  # a command wants the current step to end early
    next_sweep: float = math.inf  # monotonic time of the range finder's next map sweep

    def start(self, now: float) -> None:
        """The loop begins: the first map sweep comes one interval from now."""
        self.next_sweep = now + self.sweep_interval_s if self.sweep_interval_s > 0 else math.inf

    def next_step(self, now: float, calibrating: bool) -> Step:
        self.interrupt = False
        if self.paused is not None:
            return Step.PAUSED
        if calibrating:
            return Step.CALIBRATE
        if self.sweep_asked or self.sweep_due(now):
            self.sweep_asked = False
            if self.sweep_interval_s > 0:
                self.next_sweep = now + self.sweep_interval_s
            return Step.SWEEP
        return _MODE_STEP[self.mode]

    def sweep_due(self, now: float) -> bool:
        """The range finder's scheduled map sweep is due (it ends the ranging under way)."""
        return self.mode == "rangefinder" and now >= self.next_sweep

    def should_end(self, sweeping: bool) -> bool:
        """The step under way ends: a command changed course, or (unless it is a sweep) a sweep
        was asked for."""
        return self.interrupt or (self.sweep_asked and not sweeping)

    # ---- what the commands change ----

    def change_mode(self, mode: Mode) -> bool:
        """Whether the mode changed (the step under way then ends)."""
        if mode == self.mode:
            return False
        self.mode = mode
        self.interrupt = True
        return True

    def aim_at(self, pan_deg: float, tilt_deg: float) -> None:
        self.aim = (pan_deg, tilt_deg)
        self.interrupt = True

    def ask_sweep(self) -> None:
        self.sweep_asked = True

    def pause(self, why: str = PAUSED_LASERS_OFF) -> bool:
        """Hold ranging; whether it was running. A sweep asked for before is dropped (not carried
        out with the lasers off) and the step under way ends at its next frame or zone."""
        was_running = self.paused is None
        self.paused = why
        self.sweep_asked = False
        self.interrupt = True
        return was_running

    def resume(self) -> bool:
        """End a pause; whether there was one."""
        was_paused = self.paused is not None
        self.paused = None
        return was_paused

    def refusal(self) -> str | None:
        """Why a command that ranges is refused now, or None."""
        if self.paused == PAUSED_LASERS_OFF:
            return "the lasers are off (cmd/lasers_off): send cmd/mode or cmd/sweep to resume first"
        return None
