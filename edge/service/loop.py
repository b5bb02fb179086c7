"""The headless service (`edge run`): the rig, the mode, MQTT in and out, systemd, signals.

One thread does all the work: it runs the current mode one step at a time (`ModeSteps`: a sweep, a
fan pass, a burst of ranges; or a `CalibrationController` pair) and between zones it answers
commands (`Dispatcher`), feeds systemd's watchdog and notices a stop. paho's network thread only
moves bytes; commands reach us through the `Link`'s queue, and what we publish goes out through the
on-disk outbox (alerts, sweeps) or straight away (ranges, cues). `RigHealth` keeps each part's
condition and restarts the camera; `GuardWatch` keeps the guard across sweeps.

Stopping: SIGTERM and SIGINT (and ``--for``) set a flag that the sweep checks between zones; the
lasers go off as the parts close, a last ``state`` goes out, then ``offline``. A crash or a
watchdog kill skips all that, which is why the unit's ExecStopPost runs ``edge lasers off`` and the
broker publishes our Last Will.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from types import FrameType
from typing import TYPE_CHECKING, Any

from edge import __version__
from edge.calibration.in_use import NOMINAL, BelievedRig, believed_rig
from edge.commands import Command, label
from edge.config import Config
from edge.errors import HardwareError
from edge.notify import Notifier, WatchdogFeeder
from edge.ranging import FAULT, Ranger
from edge.service.calibrating import CalibrationController
from edge.service.commanding import LATER, Dispatcher, Handler, Later
from edge.service.guarding import GuardWatch
from edge.service.health import RigHealth
from edge.service.link import Link, NullLink, open_link
from edge.service.steps import ModeSteps

if TYPE_CHECKING:
    from edge.parts import Parts

log = logging.getLogger(__name__)

# Between steps the loop waits at most this long for a command or a stop.
_IDLE_S = 0.05
# Commands are carried out one by one, the watchdog fed after each; once a turn of the loop has spent
# this long on them, the rest wait for the next turn (a burst of slow cmd/point must not starve the
# mode, nor hold off a stop).
_COMMANDS_PER_TURN_S = 0.25
# `state`'s "paused" while cmd/lasers_off holds the lasers off.
PAUSED_LASERS_OFF = "lasers_off"


class Service:
    """`edge run`: see the module notes. A `link` given is already started; it stops with the service."""

    def __init__(self, config: Config, *, run_for_s: float | None = None, link: Link | None = None,
                 notifier: Notifier | None = None) -> None:
        self.config = config
        self.run_for_s = run_for_s
        self.mode = config.mode
        self.device_id = config.device.resolved_id()
        self.started = time.monotonic()
        self.stop_requested = threading.Event()
        self.link: Link = link or NullLink()
        self._given_link = link is not None
        self._notifier = notifier or Notifier()
        self._feeder = WatchdogFeeder(self._notifier) if config.service.watchdog else None
        self._parts: Parts | None = None
        self._next_sweep = 0.0  # monotonic time of the next scheduled sweep
        self._sweep_now = False
        self._interrupt = False  # a command wants the current step to end early
        self._paused: str | None = None  # why ranging is paused (cmd/lasers_off), or None
        self._pending: deque[tuple[str, bytes]] = deque()  # commands taken from the link, not yet carried out
        self._aim = (config.rangefinder.pan_deg, config.rangefinder.tilt_deg)
        believed = believed_rig(config, service=True)
        if believed.calibration is None and believed.health != NOMINAL:
            log.error("calibration: %s", believed.health)
        # Built once per rig: it lays out each laser's search band, the same for every zone and frame.
        self.ranger = Ranger(believed.rig, config.ranging)
        self.health = RigHealth(believed.rig.laser_names, believed.health,
                                calibrated=believed.calibration is not None,
                                camera=lambda: self._parts.camera if self._parts else None,
                                changed=self._publish_state)
        self.guard = GuardWatch(config.guard, lambda alert: self.link.publish_event("alert", alert),
                                config.service.resolved_state_dir())
        self.steps = ModeSteps(self.health, self.guard, publish_live=lambda kind, p: self.link.publish_live(kind, p),
                               publish_event=lambda kind, p: self.link.publish_event(kind, p),
                               pause=self.stop_requested.wait, started=self.started)
        self.calibration = CalibrationController(
            config, self.device_id,
            publish_result=lambda ok, error, request_id, extra: self.link.publish_result(
                "calibrate", ok, error=error, request_id=request_id, extra=extra),
            publish_state=self._publish_state, publish_range=lambda r: self.link.publish_live("range", r),
            report_zone=self.steps.zone, adopt=self._adopt, pause=self.stop_requested.wait)
        handlers: dict[str, Handler] = {"mode": self._cmd_mode, "sweep": self._cmd_sweep, "point": self._cmd_point,
                                        "relearn": self._cmd_relearn, "calibrate": self._cmd_calibrate,
                                        "lasers_off": self._cmd_lasers_off}
        self.commands = Dispatcher(
            handlers, lambda name, ok, error, request_id: self.link.publish_result(
                name, ok, error=error, request_id=request_id),
            lambda: self._parts.ptu.limits_deg if self._parts else ((-180.0, 180.0), (-90.0, 90.0)),
            config.mqtt.max_payload_bytes)

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
        self.health.recalibrated(believed.health, believed.rig.laser_names)
        self.guard.relearn("with the calibrated rig")

    # ---- life cycle ----

    def run(self) -> int:
        from edge.parts import open_parts

        self._install_signal_handlers()
        deadline = None if self.run_for_s is None else self.started + self.run_for_s
        with contextlib.ExitStack() as stack:
            if self._given_link:
                stack.callback(self.link.stop)
            else:
                self.link = stack.enter_context(open_link(self.config, self.device_id, self.health.storage))
            stack.callback(setattr, self, "_parts", None)
            self._notifier.status("starting the rig")
            try:
                with open_parts(self.config) as parts:
                    self._parts = parts
                    self._publish_state()
                    self._notifier.ready()
                    self._notifier.status(f"running: {self.mode}")
                    log.info("edge %s running as %s in %s mode", __version__, self.device_id, self.mode)
                    try:
                        self._loop(deadline)
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

    def _install_signal_handlers(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return  # tests run services in threads; they stop them with stop_requested

        def stop(signum: int, _frame: FrameType | None) -> None:
            log.info("%s: stopping", signal.Signals(signum).name)
            self.stop_requested.set()

        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, stop)

    # ---- the loop ----

    def _loop(self, deadline: float | None) -> None:
        interval = self.config.service.sweep_interval_s
        self._next_sweep = time.monotonic() + interval if interval > 0 else float("inf")
        while not self._stopping(deadline):
            self._between_steps()
            if self._stopping(deadline):
                break
            self._interrupt = False
            parts = self._parts
            assert parts is not None
            if self._paused is not None:
                if parts.lasers.lit:  # what a step cut short by cmd/lasers_off may have left on
                    parts.lasers.off()
                self.stop_requested.wait(_IDLE_S)
            elif self.calibration.running:
                self.steps.close_fan()  # here, not in the command: the blind aid may be mid-scan there
                self.calibration.step()
            elif self._sweep_now or (self.mode == "rangefinder" and time.monotonic() >= self._next_sweep):
                self._sweep_now = False
                if interval > 0:
                    self._next_sweep = time.monotonic() + interval
                self._sweep(parts, deadline)
            elif self.mode == "rangefinder":
                due = lambda: time.monotonic() >= self._next_sweep  # noqa: E731
                self.steps.range(parts, self.ranger, self._aim, self._should_stop(deadline, due))
            elif self.mode == "guard":
                self._sweep(parts, deadline)
            elif self.mode == "blindaid":
                self.steps.fan(parts, self.config, self.ranger,  # cmd/mode closes it when leaving the mode
                               self._should_stop(deadline, lambda: self.mode != "blindaid"))
            else:
                self.stop_requested.wait(_IDLE_S)

    def _sweep(self, parts: Parts, deadline: float | None) -> None:
        if self.steps.sweep(parts, self.config, self.ranger, self._should_stop(deadline, sweeping=True)):
            self._publish_state()

    def _between_steps(self) -> None:
        """Feed the watchdog (the loop made progress) and carry out the commands received, one by
        one, feeding it after each; what is left after `_COMMANDS_PER_TURN_S` waits for the next
        turn. New commands are taken from the link only when the last ones are done, so that the
        link's bounded queue stays the bound (beyond it the link refuses them)."""
        self._progressed()
        if not self._pending:
            self._pending.extend(self.link.commands())
        began = time.monotonic()
        while self._pending and not self.stop_requested.is_set():
            name, payload = self._pending.popleft()
            self.handle_command(name, payload)
            self._progressed()
            if time.monotonic() - began >= _COMMANDS_PER_TURN_S:
                break

    def _progressed(self) -> None:
        if self._feeder is not None:
            self._feeder.progressed()
            self._feeder.feed_if_due()

    def _should_stop(self, deadline: float | None, also: Callable[[], bool] | None = None,
                     sweeping: bool = False) -> Callable[[], bool]:
        """What a mode checks between zones or frames: feed the watchdog, take commands, and end
        the step on a stop, a command that changes course (cmd/sweep, unless this is a sweep), or
        `also`."""

        def should_stop() -> bool:
            self._between_steps()
            return (self._stopping(deadline) or self._interrupt or (self._sweep_now and not sweeping)
                    or bool(also and also()))

        return should_stop

    def _stopping(self, deadline: float | None) -> bool:
        if deadline is not None and time.monotonic() >= deadline:
            self.stop_requested.set()
        return self.stop_requested.is_set()

    # ---- commands ----

    def handle_command(self, name: str, payload: bytes) -> None:
        """Validate and carry out one command; every command that can be answered gets a result,
        ok or not. Nothing a sender can send ends the loop: whatever escapes is logged."""
        try:
            self.commands.handle(name, payload)
        except Exception:  # noqa: BLE001 - the name and payload came from outside
            log.exception("command %s: failed; the service goes on", label(name))

    def _cmd_mode(self, command: Command) -> str | None:
        mode = command.args["mode"]
        self.calibration.cancel("cancelled by cmd/mode")
        self._resume("cmd/mode")
        if mode != self.mode:
            log.info("mode %s → %s", self.mode, mode)
            if self.mode == "blindaid":
                self.steps.close_fan()
            self.mode = mode
            self._interrupt = True
            self.config = replace(self.config, mode=mode)
            self._notifier.status(f"running: {self.mode}")
        self._publish_state()
        return None

    def _cmd_sweep(self, command: Command) -> str | None:
        if self.calibration.running:
            return self.calibration.refusal()
        if self._resume("cmd/sweep"):
            self._publish_state()
        self._sweep_now = True
        return None

    def _cmd_point(self, command: Command) -> str | None:
        """Aim and range once; the range finder then keeps ranging there."""
        refused = ("the rig is not running" if self._parts is None
                   else self._paused_refusal() or self.calibration.refusal())
        if refused or self._parts is None:
            return refused
        pan, tilt = self._aim = (command.args["pan_deg"], command.args["tilt_deg"])
        self._interrupt = True
        result = self.steps.point(self._parts, self.ranger, pan, tilt)
        return None if result.status != FAULT else f"pan {pan:g}°, tilt {tilt:g}°: {result.detail}"

    def _cmd_relearn(self, command: Command) -> str | None:
        """The guard learns its background again (from the next complete sweep)."""
        self.guard.relearn()
        self._interrupt = self.mode == "guard"  # a sweep half done would mix old and new
        return None

    def _cmd_calibrate(self, command: Command) -> str | Later | None:
        """Start an interactive flat-target calibration; its result comes when it ends."""
        error = self._paused_refusal() or self.calibration.start(
            command.args["distances_m"], command.request_id, self._parts, self.ranger)
        if error is not None:
            return error
        self._interrupt = True
        return LATER

    def _cmd_lasers_off(self, command: Command) -> str | None:
        """Lasers off, and kept off: ranging pauses (the loop idles, still feeding the watchdog and
        taking commands) until cmd/mode or cmd/sweep resumes it."""
        self.calibration.cancel("cancelled by cmd/lasers_off")
        if self._parts is not None:
            self._parts.lasers.off()
        if self._paused is None:
            log.info("lasers off: ranging paused until cmd/mode or cmd/sweep")
            self._notifier.status("paused: lasers off")
        self._paused = PAUSED_LASERS_OFF
        self._sweep_now = False  # a sweep asked for before is not carried out with the lasers off
        self._interrupt = True  # the step under way ends at its next frame or zone
        self._publish_state()
        return None

    def _resume(self, why: str) -> bool:
        """End a pause; whether there was one."""
        if self._paused is None:
            return False
        log.info("%s: ranging resumes", why)
        self._paused = None
        self._notifier.status(f"running: {self.mode}")
        return True

    def _paused_refusal(self) -> str | None:
        if self._paused == PAUSED_LASERS_OFF:
            return "the lasers are off (cmd/lasers_off): send cmd/mode or cmd/sweep to resume first"
        return None

    # ---- publishing ----

    def state(self) -> dict[str, Any]:
        guard, calibration = self.guard.state(), self.calibration.state()
        return {
            "device": self.device_id,
            "mode": self.mode,
            "health": self.health.parts,
            "version": __version__,
            "uptime_s": round(time.monotonic() - self.started, 1),
            "sweeps": self.sweeps,
            "camera_restarts": self.health.camera_restarts,
            **({"paused": self._paused} if self._paused is not None else {}),
            **({"guard": guard} if guard is not None else {}),
            **({"calibration": calibration} if calibration is not None else {}),
        }

    def _publish_state(self) -> None:
        self.link.publish_state(self.state())
