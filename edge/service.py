"""The headless service (`edge run`): the rig, the mode, MQTT in and out, systemd, signals.

One thread does all the work: it runs the current mode one step at a time (a sweep, a fan pass, a
burst of ranges) and between zones it answers commands, feeds systemd's watchdog and notices a
stop. paho's network thread only moves bytes; commands reach us through the link's queue, and what
we publish goes out through the on-disk outbox (alerts, sweeps) or straight away (ranges, cues).

Stopping: SIGTERM and SIGINT (and ``--for``) set a flag that the sweep checks between zones; the
lasers go off as the parts close, a last ``state`` goes out, then ``offline``. A crash or a
watchdog kill skips all that, which is why the unit's ExecStopPost runs ``edge lasers off`` and the
broker publishes our Last Will.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from edge import __version__
from edge.config import Config
from edge.errors import CommandError, EdgeError, HardwareError
from edge.ranging import FAULT, ZoneResult

log = logging.getLogger(__name__)

# Between steps the loop waits at most this long for a command or a stop.
_IDLE_S = 0.05
# The camera is restarted after this many zones in a row failed for want of frames.
CAMERA_RESTART_AFTER = 2


class _Later:
    """What a command handler returns when its result comes later (cmd/calibrate, at the end)."""


LATER = _Later()


class Health:
    """Each part's latest condition, as `state` reports it: "ok" or what went wrong."""

    PARTS = ("camera", "lasers", "ptu", "calibration")

    def __init__(self, calibration: str) -> None:
        self.parts = {"camera": "ok", "lasers": "ok", "ptu": "ok", "calibration": calibration}

    def zone(self, result: ZoneResult) -> bool:
        """Take a zone's outcome into account; True when something changed."""
        before = dict(self.parts)
        part = result.part if result.status == FAULT else None
        if part is not None:
            self.parts[part] = f"fault: {result.detail}"
        elif result.status != FAULT:
            for name in ("camera", "lasers", "ptu"):  # a zone went through all three
                self.parts[name] = "ok"
        return before != self.parts


class Service:
    """`edge run`: see the module notes."""

    def __init__(self, config: Config, *, run_for_s: float | None = None, link: Any = None,
                 notifier: Any = None) -> None:
        self.config = config
        self.run_for_s = run_for_s
        self.mode = config.mode
        self.device_id = config.device.resolved_id()
        self.started = time.monotonic()
        self.sweeps = 0
        self.stop_requested = threading.Event()
        self._link = link
        self._notifier = notifier
        self._feeder = None
        self._outbox = None
        self._parts = None
        self._next_sweep = 0.0  # monotonic time of the next scheduled sweep
        self._sweep_now = False
        self._interrupt = False  # a command wants the current step to end early
        self._aim = (config.rangefinder.pan_deg, config.rangefinder.tilt_deg)
        self._guard: Any = None
        from edge.laserhealth import LaserHealth

        self.laser_health = LaserHealth(config.rig.build().laser_names)
        self._laser_faults: dict[str, str] = {}
        self._camera_faults = 0
        self.camera_restarts = 0
        self._blindaid: Any = None
        from edge.calibration.in_use import believed_rig

        believed = believed_rig(config, service=True)
        if believed.health.startswith("fault"):
            log.error("calibration: %s", believed.health)
        self.health = Health(believed.health)
        self._use_rig(believed.rig, calibrated=believed.calibration is not None)
        self._calibration: Any = None  # a cmd/calibrate session while one runs
        self._calibration_request: str | None = None
        self._calibration_aimed = False
        self._handlers: dict[str, Callable[[Any], str | _Later | None]] = {
            "mode": self._cmd_mode,
            "sweep": self._cmd_sweep,
            "point": self._cmd_point,
            "relearn": self._cmd_relearn,
            "calibrate": self._cmd_calibrate,
            "lasers_off": self._cmd_lasers_off,
        }

    def _use_rig(self, rig: Any, calibrated: bool) -> None:
        from edge.ranging import Ranger

        self.calibrated = calibrated
        # Built once per rig: it lays out each laser's search band, the same for every zone and frame.
        self.ranger = Ranger(rig, self.config.ranging)

    # ---- life cycle ----

    def run(self) -> int:
        from edge.notify import Notifier, WatchdogFeeder
        from edge.parts import open_parts

        self._install_signal_handlers()
        notifier = self._notifier or Notifier()
        self._feeder = WatchdogFeeder(notifier) if self.config.service.watchdog else None
        self._notifier = notifier
        deadline = None if self.run_for_s is None else self.started + self.run_for_s
        try:
            self._start_link()
            notifier.status("starting the rig")
            try:
                with open_parts(self.config) as parts:
                    self._parts = parts
                    self._publish_state()
                    notifier.ready()
                    notifier.status(f"running: {self.mode}")
                    log.info("edge %s running as %s in %s mode", __version__, self.device_id, self.mode)
                    try:
                        self._loop(deadline)
                    finally:
                        self._end_calibration("cancelled: the service is stopping")
                        self._close_blindaid()
                    self._parts = None
            except HardwareError as exc:
                # Say why on MQTT before systemd restarts us: a silent restart loop helps nobody.
                if exc.part in self.health.parts:
                    self.health.parts[exc.part] = f"fault: {exc}"
                self._publish_state()
                raise
            notifier.stopping()
            notifier.status("stopping")
            self._publish_state()
        finally:
            self._parts = None
            if self._link is not None:
                self._link.stop()
            if self._outbox is not None:
                self._outbox.close()
        log.info("edge stopped after %d sweeps", self.sweeps)
        return 0

    def _install_signal_handlers(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return  # tests run services in threads; they stop them with stop_requested

        def stop(signum: int, _frame: Any) -> None:
            log.info("%s: stopping", signal.Signals(signum).name)
            self.stop_requested.set()

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, stop)

    def _start_link(self) -> None:
        if self._link is not None or not self.config.mqtt.enabled:
            return
        from edge.mqtt import MqttLink
        from edge.outbox import Outbox

        state_dir = self.config.service.resolved_state_dir()
        self._outbox = Outbox(state_dir / "outbox.sqlite3", self.config.service.outbox_max_messages)
        self._link = MqttLink(self.config.mqtt, self.device_id, self._outbox, version=__version__)
        self._link.start()

    # ---- the loop ----

    def _loop(self, deadline: float | None) -> None:
        interval = self.config.service.sweep_interval_s
        self._next_sweep = time.monotonic() + interval if interval > 0 else float("inf")
        while not self._stopping(deadline):
            self._progressed()
            self._handle_commands()
            if self._stopping(deadline):
                break
            self._interrupt = False
            if self._calibration is not None:
                self._calibrate_step()
            elif self._sweep_now or (self.mode == "rangefinder" and time.monotonic() >= self._next_sweep):
                self._sweep_now = False
                if interval > 0:
                    self._next_sweep = time.monotonic() + interval
                self._sweep(deadline)
            elif self.mode == "rangefinder":
                self._range(deadline)
            elif self.mode == "guard":
                self._sweep(deadline)
            elif self.mode == "blindaid":
                self._fan(deadline)
            else:
                self.stop_requested.wait(_IDLE_S)

    def _should_stop(self, deadline: float | None, also: Callable[[], bool] | None = None,
                     sweeping: bool = False) -> Callable[[], bool]:
        """What a mode checks between zones or frames: feed the watchdog, take commands, and end
        the step on a stop, a command that changes course (cmd/sweep, unless this is a sweep), or
        `also`."""

        def should_stop() -> bool:
            self._progressed()
            self._handle_commands()
            return (self._stopping(deadline) or self._interrupt or (self._sweep_now and not sweeping)
                    or bool(also and also()))

        return should_stop

    def _range(self, deadline: float | None) -> None:
        from edge.modes.rangefinder import Rangefinder, range_payload

        parts = self._parts
        assert parts is not None
        pan, tilt = self._aim
        try:
            parts.ptu.move(pan, tilt)
        except HardwareError as exc:
            self._zone(ZoneResult(-1, pan, tilt, FAULT, detail=str(exc), part=exc.part))
            self.stop_requested.wait(1.0)  # a unit that failed gets a moment before the next try
            return
        finder = Rangefinder(parts.capture, self.ranger, parts.lasers.names)

        def on_range(result: ZoneResult, filtered: Any, extra: dict) -> None:
            self._publish_live("range", range_payload(result, filtered, extra))
            self._note(result)

        due = lambda: time.monotonic() >= self._next_sweep  # noqa: E731
        finder.run(pan, tilt, on_range, self._should_stop(deadline, due))

    def _fan(self, deadline: float | None) -> None:
        if self._blindaid is None:
            from edge.modes.blindaid.runner import BlindAidRunner

            self._blindaid = BlindAidRunner(self.config, self._parts,
                                            on_cue=lambda cue: self._publish_live("cue", cue.to_json()),
                                            on_zone=self._zone, ranger=self.ranger)
        self._blindaid.scan(self._should_stop(deadline, lambda: self.mode != "blindaid"))
        if self.mode != "blindaid":
            self._close_blindaid()

    def _close_blindaid(self) -> None:
        if self._blindaid is not None:
            self._blindaid.close()
            self._blindaid = None

    def _stopping(self, deadline: float | None) -> bool:
        if deadline is not None and time.monotonic() >= deadline:
            self.stop_requested.set()
        return self.stop_requested.is_set()

    def _progressed(self) -> None:
        if self._feeder is not None:
            self._feeder.progressed()
            self._feeder.feed_if_due()

    def _sweep(self, deadline: float | None) -> None:
        from edge.sweep import sweeper_for

        assert self._parts is not None
        guarding = self.mode == "guard"
        config = self.config
        if guarding:
            config = replace(config, sweep=replace(config.sweep, pairs_per_zone=config.service.guard_pairs_per_zone))
        zone_t: dict[int, float] = {}

        def on_zone(result: ZoneResult) -> None:
            zone_t[result.index] = time.monotonic() - self.started
            self._zone(result, sweeper)

        sweeper = sweeper_for(self._parts, on_zone=on_zone, config=config, ranger=self.ranger)
        report = sweeper.run(should_stop=self._should_stop(deadline, sweeping=True))
        if len(report.results) < len(config.sweep.poses()):
            log.info("sweep ended early after %d zones", len(report.results))
            return
        self.sweeps += 1
        self._publish_event("sweep", {
            "sweep": self.sweeps,
            "duration_s": round(report.duration_s, 3),
            "zones": [r.to_json() for r in report.results],
        })
        ok = sum(r.status == "ok" for r in report.results)
        log.info("sweep %d: %d of %d zones ok in %.1f s (limit %.1f s), %d faults",
                 self.sweeps, ok, len(report.results), report.duration_s, report.limit_s, report.faults)
        if guarding:
            guard = self._guard_for(len(report.results))
            was_learning = guard.learning
            events = guard.update(report.results, self.sweeps, time.monotonic() - self.started, zone_t)
            if was_learning and not guard.learning:
                log.info("guard: background learnt over %d sweeps; watching", self.config.guard.learn_sweeps)
            for event in events:
                log.warning("guard: %s %s in zones %s at %.2f m, bearing %.1f°", event.event, event.id,
                            list(event.zones), event.range_m, event.bearing_deg)
                self._publish_event("alert", event.to_json())
        self._publish_state()

    def _guard_for(self, zones: int):
        from edge.modes.guard import Guard

        if self._guard is None or self._guard.zone_count != zones:
            self._guard = Guard(self.config.guard, zones)
        return self._guard

    def _zone(self, result: ZoneResult, sweeper: Any = None) -> None:
        self._publish_live("range", result.to_json())
        self._note(result, getattr(sweeper, "lit_when_off", frozenset()))

    def _note(self, result: ZoneResult, lit_when_off: set[str] | frozenset = frozenset()) -> None:
        """Health and recovery after each zone or frame."""
        changed = self.health.zone(result)
        if self.laser_health.update(result, lit_when_off) or changed:
            faults = self.laser_health.faults()
            if not self.calibrated:
                # A hand-mounted laser half a degree off puts its spot outside the narrow band the
                # nominal rig searches: on an uncalibrated rig that is the likelier cause.
                faults = {name: text + ("; or, as this rig is not calibrated, its spot may lie where the nominal "
                                        "rig does not look: calibrate it (cmd/calibrate)"
                                        if "does not light" in text else "")
                          for name, text in faults.items()}
            if faults:
                self.health.parts["lasers"] = "fault: " + "; ".join(faults.values())
            if faults != self._laser_faults:
                for text in faults.values():
                    log.error("%s", text)
                if not faults:
                    log.info("lasers: all working again")
                self._laser_faults = faults
            changed = True
        if changed:
            self._publish_state()
        self._camera_faults = self._camera_faults + 1 if result.part == "camera" and result.status == FAULT else 0
        if self._camera_faults >= CAMERA_RESTART_AFTER:
            self._restart_camera()

    def _restart_camera(self) -> None:
        """Frames stopped or came torn in several zones in a row: start the camera again (a
        picamera2 pipeline or a webcam stream often recovers so). Zones meanwhile are `fault`."""
        self._camera_faults = 0
        camera = self._parts.camera if self._parts else None
        if camera is None:
            return
        log.warning("camera: %d zones without usable frames; restarting it", CAMERA_RESTART_AFTER)
        self.camera_restarts += 1
        try:
            camera.stop()
            camera.start()
        except Exception as exc:  # the next zones will say what is wrong
            log.error("camera: restart failed: %s", exc)

    # ---- commands ----

    def _handle_commands(self) -> None:
        if self._link is None:
            return
        for name, payload in self._link.commands():
            self.handle_command(name, payload)

    def handle_command(self, name: str, payload: bytes) -> None:
        """Validate and carry out one command; every command gets a result, ok or not."""
        from edge.commands import parse_command, request_id_of

        limits = self._limits()
        try:
            command = parse_command(name, payload, max_bytes=self.config.mqtt.max_payload_bytes,
                                    pan_limits=limits[0], tilt_limits=limits[1])
        except CommandError as exc:
            log.warning("command %s refused: %s", name, exc)
            self._result(name, False, str(exc), request_id_of(payload))
            return
        try:
            error = self._handlers[command.name](command)
        except EdgeError as exc:
            error = str(exc)
        if error is LATER:
            self._calibration_request = command.request_id
            log.info("command %s started", name)
            return
        if error:
            log.warning("command %s failed: %s", name, error)
        else:
            log.info("command %s done", name)
        self._result(name, error is None, error, command.request_id)

    def _limits(self) -> tuple[tuple[float, float], tuple[float, float]]:
        limits = getattr(self._parts.ptu, "limits_deg", None) if self._parts else None
        return limits or ((-180.0, 180.0), (-90.0, 90.0))

    def _cmd_mode(self, command: Any) -> str | None:
        mode = command.args["mode"]
        self._end_calibration("cancelled by cmd/mode")
        if mode != self.mode:
            log.info("mode %s → %s", self.mode, mode)
            if self.mode == "blindaid":
                self._close_blindaid()
            self.mode = mode
            self._interrupt = True
            self.config = replace(self.config, mode=mode)
            if self._notifier is not None:
                self._notifier.status(f"running: {self.mode}")
        self._publish_state()
        return None

    def _cmd_sweep(self, command: Any) -> str | None:
        if self._calibration is not None:
            return self._calibrating()
        self._sweep_now = True
        return None

    def _calibrating(self) -> str:
        return (f"a calibration is running (waiting for the target at {self._calibration.waiting_for:g} m): "
                "send cmd/mode to cancel it")

    def _cmd_point(self, command: Any) -> str | None:
        """Aim and range once; the range finder then keeps ranging there."""
        if self._parts is None:
            return "the rig is not running"
        if self._calibration is not None:
            return self._calibrating()
        from edge.sweep import sweeper_for

        pan, tilt = command.args["pan_deg"], command.args["tilt_deg"]
        self._aim = (pan, tilt)
        self._interrupt = True
        result = sweeper_for(self._parts, ranger=self.ranger).zone(-1, pan, tilt)
        self._zone(result)
        return None if result.status != FAULT else f"pan {pan:g}°, tilt {tilt:g}°: {result.detail}"

    def _cmd_relearn(self, command: Any) -> str | None:
        """The guard learns its background again (from the next complete sweep)."""
        if self._guard is not None:
            for event in self._guard.relearn():
                self._publish_event("alert", event.to_json())
        self._interrupt = self.mode == "guard"  # a sweep half done would mix old and new
        return None

    def _cmd_calibrate(self, command: Any) -> str | _Later | None:
        """Start an interactive flat-target calibration (edge.calibration.session); its result comes
        when it ends."""
        from edge.calibration.session import TargetCalibration

        if self._parts is None:
            return "the rig is not running"
        if self._calibration is not None:
            return self._calibrating()
        distances = command.args["distances_m"]  # checked by edge.commands: a session can take them
        from edge.sweep import sweeper_for

        folder = self.config.service.resolved_state_dir() / "calibration-frames"
        # Each distance: 4 laser-off/on pairs, nudged as in a sweep (fresh speckle for each).
        config = replace(self.config, sweep=replace(self.config.sweep, pairs_per_zone=4))
        sweeper = sweeper_for(self._parts, config=config, ranger=self.ranger)
        try:
            self._calibration = TargetCalibration(
                distances, self.ranger, self.config.rig.build(), self._parts.capture, folder, sweeper.zone,
                timeout_s=self.config.service.calibrate_timeout_s, device=self.device_id)
        except OSError as exc:  # the state folder is not writable, or full
            return f"cannot keep the calibration frames in {folder}: {exc.strerror or exc}"
        self._calibration_aimed = False
        self._interrupt = True
        log.info("calibration: bring a flat target squarely in front of the unit to %s m in this order, "
                 "starting from elsewhere, and hold it still at each",
                 ", ".join(f"{d:g}" for d in distances))
        self._publish_state()
        return LATER

    def _calibrate_step(self) -> None:
        session = self._calibration
        parts = self._parts
        assert session is not None and parts is not None
        self._close_blindaid()  # here, not in the command: the blind aid may be mid-scan there
        if session.timed_out:
            self._end_calibration(f"timed out after {self.config.service.calibrate_timeout_s:g} s waiting for "
                                  f"the target at {session.missing()} m; nothing changed")
            return
        try:
            if not self._calibration_aimed:
                parts.ptu.move(session.pan_deg, session.tilt_deg)
                self._calibration_aimed = True
            taken = session.step()
        except HardwareError as exc:
            self._zone(ZoneResult(-1, session.pan_deg, session.tilt_deg, FAULT, detail=str(exc), part=exc.part))
            self.stop_requested.wait(0.2)
            return
        except (EdgeError, OSError) as exc:  # the frames could not be written (a full card)
            self._end_calibration(f"cannot keep the calibration frames: {exc}; nothing changed")
            return
        if session.last is not None:
            # Published for whoever holds the target, but not judged: the rig is being calibrated
            # and the nominal one may well miss its spots (no laser fault for that).
            self._publish_live("range", session.last.to_json())
        if taken is None:
            return
        self._calibration_aimed = False  # the zone's nudges left the unit a little off pan 0
        ranged = session.recorded.range_m if session.recorded is not None else None
        log.info("calibration: took the target at %g m (the rig in use ranged %s)", taken,
                 "nothing" if ranged is None else f"{ranged:.3f} m")
        if session.complete:
            self._finish_calibration()
        else:
            log.info("calibration: now at %g m", session.waiting_for)
            self._publish_state()

    def _finish_calibration(self) -> None:
        from edge.calibration.in_use import apply, calibration_file
        from edge.calibration.file import write_calibration
        from edge.calibration.report import report
        from edge.calibration.session import summary

        session = self._calibration
        self._calibration = None
        try:
            outcome = session.finish()
        except (EdgeError, OSError) as exc:  # the frames could not be saved (a full card)
            self._calibration_result(False, f"cannot keep the calibration frames: {exc}; nothing changed")
            return
        if outcome.calibration is None:
            self._calibration_result(False, outcome.error)
            return
        cal = outcome.calibration
        nominal = self.config.rig.build()
        path = calibration_file(self.config, service=True)
        try:
            believed = apply(nominal, cal, path)  # before writing: a file the rig cannot use is never saved
            path.parent.mkdir(parents=True, exist_ok=True)
            write_calibration(path, cal)
        except (EdgeError, OSError) as exc:
            self._calibration_result(False, f"{exc}; nothing changed")
            return
        for line in report(cal, nominal):
            log.info("calibration: %s", line)
        self._use_rig(believed.rig, calibrated=True)
        self.health.parts["calibration"] = believed.health
        if self._guard is not None:
            # Its background was ranged with the old rays: against the new ones a wall would
            # seem to have moved by a percent or two. Learn it again rather than raise alarms.
            log.info("guard: learning the background again with the calibrated rig")
            for event in self._guard.relearn():
                self._publish_event("alert", event.to_json())
        from edge.laserhealth import LaserHealth

        self.laser_health = LaserHealth(believed.rig.laser_names)  # judged afresh with the new rays
        if self._laser_faults:
            self._laser_faults = {}
            self.health.parts["lasers"] = "ok"
        self._calibration_result(True, None, {"file": str(path), **summary(cal, nominal)})

    def _end_calibration(self, why: str) -> None:
        """Cancel a running session (a mode change, lasers_off, a stop): nothing changes."""
        if self._calibration is None:
            return
        self._calibration.abandon()
        self._calibration = None
        self._calibration_result(False, why)

    def _calibration_result(self, ok: bool, error: str | None, calibration: dict | None = None) -> None:
        if ok:
            log.info("command calibrate done")
        else:
            log.warning("command calibrate failed: %s", error)
        if self._link is not None:
            self._link.publish_result("calibrate", ok, error=error, request_id=self._calibration_request,
                                      extra={"calibration": calibration} if calibration else None)
        self._calibration_request = None
        self._publish_state()

    def _cmd_lasers_off(self, command: Any) -> str | None:
        self._end_calibration("cancelled by cmd/lasers_off")
        if self._parts is not None:
            self._parts.lasers.off()
        return None

    # ---- publishing ----

    def state(self) -> dict:
        return {
            "device": self.device_id,
            "mode": self.mode,
            "health": dict(self.health.parts),
            "version": __version__,
            "uptime_s": round(time.monotonic() - self.started, 1),
            "sweeps": self.sweeps,
            "camera_restarts": self.camera_restarts,
            **({"guard": self._guard.state()} if self._guard is not None else {}),
            **({"calibration": self._calibration.state()} if self._calibration is not None else {}),
        }

    def _publish_state(self) -> None:
        if self._link is not None:
            self._link.publish_state(self.state())

    def _publish_event(self, kind: str, payload: dict) -> None:
        if self._link is not None:
            self._link.publish_event(kind, payload)

    def _publish_live(self, kind: str, payload: dict) -> None:
        if self._link is not None:
            self._link.publish_live(kind, payload)

    def _result(self, name: str, ok: bool, error: str | None, request_id: str | None) -> None:
        if self._link is not None:
            self._link.publish_result(name, ok, error=error, request_id=request_id)

