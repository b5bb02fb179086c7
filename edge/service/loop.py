"""The headless service (`edge run`): the rig, the mode, MQTT in and out, systemd, signals.

One thread does all the work: it runs the current mode one step at a time (`ModeSteps`: a sweep, a
fan pass, a burst of ranges; or a `CalibrationController` pair) and between zones it answers
commands (`Dispatcher`), feeds systemd's watchdog and notices a stop. paho's network thread only
moves bytes; commands reach us through the `Link`'s queue, and what we publish goes out through the
on-disk outbox (alerts, sweeps) or straight away (ranges, cues). `RigHealth` keeps each part's
condition and restarts the camera; `GuardWatch` keeps the guard across sweeps.

Time is the rig's clock (:func:`edge.parts.rig_clock`): ``--for``, the range finder's sweep
interval, uptimes and the guard's times count the rig's seconds, simulated ones on a simulated rig.
Waiting for a command while paused is real time under either clock.

Stopping: SIGTERM and SIGINT (and ``--for``) set a flag that the sweep checks between zones; the
lasers go off as the parts close, a last ``state`` goes out, then ``offline``. A crash or a
watchdog kill skips all that, which is why the unit's ExecStopPost runs ``edge lasers off`` and the
broker publishes our Last Will.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from edge import __version__
from edge.calibration.in_use import NOMINAL, BelievedRig, believed_rig
from edge.commands import Command
from edge.config import Config
from edge.errors import HardwareError
from edge.notify import Notifier, WatchdogFeeder, stop_on_signals
from edge.ranging import FAULT, Ranger
from edge.service.calibrating import CalibrationController
from edge.service.commanding import LATER, CommandQueue, Dispatcher, Handler, Later
from edge.service.course import Course, Step
from edge.service.guarding import GuardWatch
from edge.service.health import RigHealth
from edge.service.homeassistant import HomeAssistantFeed
from edge.service.identity import BootId
from edge.service.link import Link, NullLink, open_link
from edge.service.steps import ModeSteps

if TYPE_CHECKING:
    from edge.parts import Parts

log = logging.getLogger(__name__)

# Between steps the loop waits at most this long for a command or a stop.
_IDLE_S = 0.05
# `state` goes out at least this often (real seconds), so that its calibration age stays current.
STATE_REFRESH_S = 600.0


class Service:
    """`edge run`: see the module notes. A `link` given is already started; it stops with the service."""

    def __init__(self, config: Config, *, run_for_s: float | None = None, link: Link | None = None,
                 notifier: Notifier | None = None) -> None:
        self.config = config
        self.run_for_s = run_for_s
        self.course = Course(config.mode, (config.rangefinder.pan_deg, config.rangefinder.tilt_deg),
                             config.service.sweep_interval_s)
        self.device_id = config.device.resolved_id()
        from edge.parts import rig_clock

        self.clock = rig_clock(config)
        self.started = self._now()
        self.stop_requested = threading.Event()
        self.link: Link = link or NullLink()
        self._given_link = link is not None
        self._notifier = notifier or Notifier()
        feeder = WatchdogFeeder(self._notifier) if config.service.watchdog else None
        self._progressed: Callable[[], None] = feeder.tick if feeder is not None else lambda: None
        self._parts: Parts | None = None
        believed = believed_rig(config, service=True)
        if believed.calibration is None and believed.health != NOMINAL:
            log.error("calibration: %s", believed.health)
        # Built once per rig: it lays out each laser's search band, the same for every zone and frame.
        self.ranger = Ranger(believed.rig, config.ranging)
        self._calibrated_at = believed.calibration.created if believed.calibration is not None else None
        self._state_at = -math.inf  # time.monotonic() of the last state published
        self.health = RigHealth(believed.rig.laser_names, believed.health,
                                calibrated=believed.calibration is not None,
                                camera=lambda: self._parts.camera if self._parts else None,
                                changed=lambda: self._publish_state(at_once=True))
        boot = BootId(config.service.resolved_state_dir())  # in every sweep and alert
        from edge.maps import GridKeeper

        # The occupancy grid of every sweep, kept in state_dir (its picture: self.map.png()).
        self.map = GridKeeper(config.map, believed.rig, config.service.resolved_state_dir())
        self.guard = GuardWatch(config.guard, lambda alert: self.link.publish_event("alert", alert), boot,
                                doorways=lambda results: self.map.outside_m(self.ranger.rig, results),
                                reference=lambda: self.ranger.rig.reference)
        self.ha = HomeAssistantFeed(lambda kind, p, interval: self.link.publish_snapshot(kind, p, interval),
                                    device_id=self.device_id, range_limit_m=config.rig.range_limits_m[1])
        self.steps = ModeSteps(self.health, self.guard, boot,
                               publish_live=self._publish_live,
                               publish_event=lambda kind, p: self.link.publish_event(kind, p),
                               pause=self._pause, now=self._now, grid=self.map)
        self.calibration = CalibrationController(
            config, self.device_id,
            publish_result=lambda ok, error, request_id, extra: self.link.publish_result(
                "calibrate", ok, error=error, request_id=request_id, extra=extra),
            publish_state=self._publish_state, publish_range=lambda r: self.link.publish_live("range", r),
            report_zone=self.steps.zone, adopt=self._adopt, pause=self._pause)
        handlers: dict[str, Handler] = {"mode": self._cmd_mode, "sweep": self._cmd_sweep, "point": self._cmd_point,
                                        "relearn": self._cmd_relearn, "calibrate": self._cmd_calibrate,
                                        "lasers_off": self._cmd_lasers_off}
        self.commands = Dispatcher(
            handlers, lambda name, ok, error, request_id: self.link.publish_result(
                name, ok, error=error, request_id=request_id),
            lambda: self._parts.ptu.limits_deg if self._parts else ((-180.0, 180.0), (-90.0, 90.0)),
            config.mqtt.max_payload_bytes)
        self.queue = CommandQueue(lambda: self.link.commands(), self.commands.handle, self._progressed)

    def _now(self) -> float:
        """The rig's time, s."""
        return self.clock.now_ns() / 1e9

    def _pause(self, seconds: float) -> bool:
        """Wait a moment (after a failure), ending early on a stop."""
        return self.clock.idle(self.stop_requested, seconds)

    @property
    def mode(self) -> str:
        return self.course.mode

    @property
    def sweeps(self) -> int:
        """Complete sweeps so far."""
        return self.steps.sweeps

    @property
    def parts(self) -> Parts | None:
        """The opened parts while the service runs."""
        return self._parts

    def _adopt(self, believed: BelievedRig) -> None:
        """A calibration was fitted and saved: range with it from now on. The guard learns its room
        again: against the new rays every wall would seem to have moved by a percent or two."""
        self.ranger = Ranger(believed.rig, self.config.ranging)
        self._calibrated_at = believed.calibration.created if believed.calibration is not None else None
        self.health.recalibrated(believed.health, believed.rig.laser_names)
        self.guard.relearn("with the calibrated rig")
        self._publish_guard()

    # ---- life cycle ----

    def run(self) -> int:
        from edge.parts import open_parts

        stop_on_signals(self.stop_requested)
        with contextlib.ExitStack() as stack:
            if self.run_for_s is not None:  # --for: a stop like any other, checked between zones
                timer = self.clock.timer(self.stop_requested.set, "--for")
                timer.arm(round((self.started + self.run_for_s) * 1e9))
                stack.callback(timer.close)
            if self._given_link:
                stack.callback(self.link.stop)
            else:
                self.link = stack.enter_context(open_link(self.config, self.device_id, self.health.storage))
            stack.callback(setattr, self, "_parts", None)
            self._notifier.status("starting the rig")
            try:
                with open_parts(self.config, self.clock) as parts:
                    self._parts = parts
                    self._publish_state()
                    self._publish_activity()
                    self._notifier.ready()
                    self._notifier.status(f"running: {self.mode}")
                    log.info("edge %s running as %s in %s mode", __version__, self.device_id, self.mode)
                    try:
                        self._loop()
                    finally:
                        self.calibration.cancel("cancelled: the service is stopping")
                        self.steps.close_fan()
                    self._parts = None
            except HardwareError as exc:
                # Say why on MQTT before systemd restarts us: a silent restart loop helps nobody.
                self.health.failed(exc)
                self._publish_state()
                raise
            self._notifier.stopping()
            self._notifier.status("stopping")
            self._publish_state()
        log.info("edge stopped after %d sweeps", self.sweeps)
        return 0

    # ---- the loop ----

    def _loop(self) -> None:
        self.course.start(self._now())
        while not self.stop_requested.is_set():
            self._between_steps()
            if self.stop_requested.is_set():
                break
            parts = self._parts
            assert parts is not None
            step = self.course.next_step(self._now(), self.calibration.running)
            if step is Step.PAUSED:
                if parts.lasers.lit:  # what a step cut short by cmd/lasers_off may have left on
                    parts.lasers.off()
                self.clock.idle(self.stop_requested, _IDLE_S)
            elif step is Step.CALIBRATE:
                self.steps.close_fan()  # here, not in the command: the blind aid may be mid-scan there
                self.calibration.step()
            elif step is Step.SWEEP:
                self._sweep(parts)
            elif step is Step.RANGE:
                due = lambda: self.course.sweep_due(self._now())  # noqa: E731
                self.steps.range(parts, self.ranger, self.course.aim, self._should_stop(due))
            elif step is Step.FAN:
                self.steps.fan(parts, self.config, self.ranger,  # cmd/mode closes it when leaving the mode
                               self._should_stop(lambda: self.mode != "blindaid"))

    def _sweep(self, parts: Parts) -> None:
        if self.steps.sweep(parts, self.config, self.ranger, self._should_stop(sweeping=True)):
            self._publish_state()
            if self.mode == "guard":
                self._publish_guard()
            self.ha.map(self.steps.last_sweep, self.sweeps, self.mode, f"{datetime.now(UTC):%Y-%m-%d %H:%M:%S} UTC")

    def _between_steps(self) -> None:
        """Feed the watchdog (the loop made progress) and carry out a turn's commands."""
        self._progressed()
        self.queue.run(self.stop_requested.is_set)
        if time.monotonic() - self._state_at >= STATE_REFRESH_S:
            self._publish_state()

    def _should_stop(self, also: Callable[[], bool] | None = None, sweeping: bool = False) -> Callable[[], bool]:
        """What a mode checks between zones or frames: feed the watchdog, take commands, and end
        the step on a stop, a command that changes course (cmd/sweep, unless this is a sweep), or
        `also`."""

        def should_stop() -> bool:
            self._between_steps()
            return self.stop_requested.is_set() or self.course.should_end(sweeping) or bool(also and also())

        return should_stop

    # ---- commands ----

    def handle_command(self, name: str, payload: bytes) -> None:
        """Validate and carry out one command; every command that can be answered gets a result,
        ok or not. Nothing a sender can send ends the loop: whatever escapes is logged."""
        self.queue.handle(name, payload)

    def _cmd_mode(self, command: Command) -> str | None:
        self.calibration.cancel("cancelled by cmd/mode")
        self._resume("cmd/mode")
        before = self.mode
        if self.course.change_mode(command.args["mode"]):
            log.info("mode %s → %s", before, self.mode)
            if before == "blindaid":
                self.steps.close_fan()
            if before == "guard":  # it stands down: see GuardWatch.relearn
                self.guard.relearn("after leaving guard mode")
            self.config = replace(self.config, mode=self.course.mode)
            self._notifier.status(f"running: {self.mode}")
            self._publish_activity()
        self._publish_state()
        return None

    def _cmd_sweep(self, command: Command) -> str | None:
        if self.calibration.running:
            return self.calibration.refusal()
        if self._resume("cmd/sweep"):
            self._publish_state()
        self.course.ask_sweep()
        return None

    def _cmd_point(self, command: Command) -> str | None:
        """Aim and range once; the range finder then keeps ranging there."""
        refused = ("the rig is not running" if self._parts is None
                   else self.course.refusal() or self.calibration.refusal())
        if refused or self._parts is None:
            return refused
        pan, tilt = command.args["pan_deg"], command.args["tilt_deg"]
        self.course.aim_at(pan, tilt)
        result = self.steps.point(self._parts, self.ranger, pan, tilt)
        return None if result.status != FAULT else f"pan {pan:g}°, tilt {tilt:g}°: {result.detail}"

    def _cmd_relearn(self, command: Command) -> str | None:
        """The guard learns its background again (from the next complete sweep)."""
        self.guard.relearn()
        self.course.interrupt = self.mode == "guard"  # a sweep half done would mix old and new
        self._publish_guard()
        return None

    def _cmd_calibrate(self, command: Command) -> str | Later | None:
        """Start an interactive flat-target calibration; its result comes when it ends."""
        error = self.course.refusal() or self.calibration.start(
            command.args["distances_m"], command.request_id, self._parts, self.ranger)
        if error is not None:
            return error
        self.course.interrupt = True
        return LATER

    def _cmd_lasers_off(self, command: Command) -> str | None:
        """Lasers off, and kept off: ranging pauses (the loop idles, still feeding the watchdog and
        taking commands) until cmd/mode or cmd/sweep resumes it."""
        self.calibration.cancel("cancelled by cmd/lasers_off")
        if self._parts is not None:
            self._parts.lasers.off()
        if self.course.pause():
            log.info("lasers off: ranging paused until cmd/mode or cmd/sweep")
            self._notifier.status("paused: lasers off")
            if self.mode == "guard":  # it stands down: see GuardWatch.relearn
                self.guard.relearn("after cmd/lasers_off")
            self._publish_activity()
        self.steps.blinded("lasers off")  # the blind aid's fan stays open: it says "cannot see"
        self._publish_state()
        return None

    def _resume(self, why: str) -> bool:
        """End a pause; whether there was one."""
        if not self.course.resume():
            return False
        log.info("%s: ranging resumes", why)
        self.steps.blinded(None)
        self._notifier.status(f"running: {self.mode}")
        self._publish_activity()
        return True

    # ---- publishing ----

    def state(self) -> dict[str, Any]:
        present = {"paused": self.course.paused, "guard": self.guard.state(), "calibration": self.calibration.state()}
        health = self.health.parts
        return {"device": self.device_id, "mode": self.mode, "health": health, "version": __version__,
                "uptime_s": round(self._now() - self.started, 1), "sweeps": self.sweeps,
                "camera_restarts": self.health.camera_restarts,
                "faults": [part for part, condition in health.items() if condition.startswith("fault")],
                "calibrated_at": self._calibrated_at or None,
                "calibration_age_d": _age_days(self._calibrated_at),
                **{key: value for key, value in present.items() if value is not None}}

    def _publish_state(self, at_once: bool = False) -> None:
        self._state_at = time.monotonic()
        self.link.publish_state(self.state(), at_once=at_once)

    def _publish_live(self, kind: str, payload: dict[str, Any]) -> None:
        """A range or a cue: on the contract's topic, every one, and to Home Assistant's feed."""
        self.link.publish_live(kind, payload)
        self.ha.live(kind, payload)

    def _publish_activity(self) -> None:
        """What runs changed (or the service started): Home Assistant's distance, obstacle and guard."""
        self.ha.activity(self.mode, self.course.paused is not None)
        self._publish_guard()

    def _publish_guard(self) -> None:
        self.ha.guard(self.mode == "guard" and self.course.paused is None, self.guard.learning, self.guard.tracks)


def _age_days(created: str | None) -> float | None:
    """Days since an ISO 8601 UTC time (a calibration's `created`), or None."""
    if not created:
        return None
    try:
        moment = datetime.fromisoformat(created)
    except ValueError:
        return None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return round(max(time.time() - moment.timestamp(), 0.0) / 86400.0, 2)
