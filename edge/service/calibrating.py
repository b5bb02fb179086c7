"""The service's side of `cmd/calibrate`: one interactive flat-target session at a time.

The session itself (`edge.calibration.session.TargetCalibration`) takes frames and watches the
target come to rest at each distance; this controller owns it while it runs, steps it between
commands, aims the unit, and at the end saves and hands over the fitted rig. It publishes nothing
itself: it is given what to call (frigate's `CameraActivityManager(config, publish)` is the model).
The command's result comes when the session ends, however it ends: fitted, failed, timed out or
cancelled.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from edge.calibration.file import write_calibration
from edge.calibration.in_use import BelievedRig, apply, calibration_file
from edge.calibration.report import report
from edge.calibration.session import Outcome, TargetCalibration, summary
from edge.config import Config
from edge.errors import EdgeError, HardwareError
from edge.ranging import FAULT, Ranger, ZoneResult

if TYPE_CHECKING:
    from edge.parts import Parts

log = logging.getLogger(__name__)

# Each distance: this many laser-off/on pairs, nudged as in a sweep (fresh speckle for each).
PAIRS_PER_DISTANCE = 4

# (ok, error, request id, extra keys of the result)
PublishResult = Callable[[bool, "str | None", "str | None", "dict[str, Any] | None"], None]


class CalibrationController:
    """At most one session. `publish_result` answers the command; `publish_state` is called when
    `state` changed; `publish_range` gets each pair's range (for whoever holds the target);
    `report_zone` gets a zone a part failed in; `adopt` gets the rig fitted and saved;
    `pause(s)` waits after a failure (and ends early on a stop)."""

    def __init__(self, config: Config, device_id: str, *, publish_result: PublishResult,
                 publish_state: Callable[[], None], publish_range: Callable[[dict[str, Any]], object],
                 report_zone: Callable[[ZoneResult], None], adopt: Callable[[BelievedRig], None],
                 pause: Callable[[float], object]) -> None:
        self.config = config
        self.device_id = device_id
        self._publish_result = publish_result
        self._publish_state = publish_state
        self._publish_range = publish_range
        self._report_zone = report_zone
        self._adopt = adopt
        self._pause = pause
        self._session: TargetCalibration | None = None
        self._parts: Parts | None = None
        self._request_id: str | None = None
        self._aimed = False  # the unit points where the session looks

    @property
    def running(self) -> bool:
        return self._session is not None

    def refusal(self) -> str | None:
        """Why a command that moves the unit must wait, while a session runs."""
        if self._session is None:
            return None
        return (f"a calibration is running (waiting for the target at {self._session.waiting_for:g} m): "
                "send cmd/mode to cancel it")

    def state(self) -> dict[str, Any] | None:
        """The session's part of `state` while one runs."""
        return None if self._session is None else self._session.state()

    def start(self, distances_m: Sequence[float], request_id: str | None, parts: Parts | None,
              ranger: Ranger) -> str | None:
        """Begin a session on opened parts; returns why not, or None: then the result comes at
        its end. `distances_m` are checked by edge.commands: a session can take them."""
        if parts is None:
            return "the rig is not running"
        refused = self.refusal()
        if refused:
            return refused
        from edge.sweep import sweeper_for

        folder = self.config.service.resolved_state_dir() / "calibration-frames"
        config = replace(self.config, sweep=replace(self.config.sweep, pairs_per_zone=PAIRS_PER_DISTANCE))
        sweeper = sweeper_for(parts, config=config, ranger=ranger)
        try:
            self._session = TargetCalibration(
                distances_m, ranger, self.config.rig.build(), parts.capture, folder, sweeper.zone,
                timeout_s=self.config.service.calibrate_timeout_s, device=self.device_id,
                clock=lambda: parts.clock.now_ns() / 1e9)  # the board's rest is timed on the rig's frames
        except OSError as exc:  # the state folder is not writable, or full
            return f"cannot keep the calibration frames in {folder}: {exc.strerror or exc}"
        self._parts = parts
        self._request_id = request_id
        self._aimed = False
        log.info("calibration: bring a flat target squarely in front of the unit to %s m in this order, "
                 "starting from elsewhere, and hold it still at each",
                 ", ".join(f"{d:g}" for d in distances_m))
        self._publish_state()
        return None

    def step(self) -> None:
        """One laser-off/on pair of the running session (the service's loop step)."""
        session, parts = self._session, self._parts
        if session is None or parts is None:
            return
        if session.timed_out:
            self.cancel(f"timed out after {self.config.service.calibrate_timeout_s:g} s waiting for "
                        f"the target at {session.missing()} m; nothing changed")
            return
        try:
            if not self._aimed:
                parts.ptu.move(session.pan_deg, session.tilt_deg)
                self._aimed = True
            taken = session.step()
        except HardwareError as exc:
            self._report_zone(ZoneResult(-1, session.pan_deg, session.tilt_deg, FAULT, detail=str(exc),
                                         part=exc.part))
            self._pause(0.2)
            return
        except (EdgeError, OSError) as exc:  # the frames could not be written (a full card)
            self.cancel(f"cannot keep the calibration frames: {exc}; nothing changed")
            return
        if session.last is not None:
            # Published for whoever holds the target, but not judged: the rig is being calibrated
            # and the nominal one may well miss its spots (no laser fault for that).
            self._publish_range(session.last.to_json())
        if taken is None:
            return
        self._aimed = False  # the zone's nudges left the unit a little off pan 0
        ranged = session.recorded.range_m if session.recorded is not None else None
        log.info("calibration: took the target at %g m (the rig in use ranged %s)", taken,
                 "nothing" if ranged is None else f"{ranged:.3f} m")
        if not session.complete:
            log.info("calibration: now at %g m", session.waiting_for)
            self._publish_state()
            return
        self._end()
        try:
            outcome = session.finish()
        except (EdgeError, OSError) as exc:  # the frames could not be saved (a full card)
            self._result(False, f"cannot keep the calibration frames: {exc}; nothing changed")
            return
        self.adopt(outcome)

    def adopt(self, outcome: Outcome) -> None:
        """End with a session's outcome: save the fitted calibration and hand the rig over, or
        say why not. A file the rig cannot use is never saved."""
        self._end()
        if outcome.calibration is None:
            self._result(False, outcome.error)
            return
        cal = outcome.calibration
        nominal = self.config.rig.build()
        path = calibration_file(self.config, service=True)
        assert path is not None  # the service always has one: its state folder's
        try:
            believed = apply(nominal, cal, path)  # before writing: a file the rig cannot use is never saved
            path.parent.mkdir(parents=True, exist_ok=True)
            write_calibration(path, cal)
        except (EdgeError, OSError) as exc:
            self._result(False, f"{exc}; nothing changed")
            return
        for line in report(cal, nominal):
            log.info("calibration: %s", line)
        self._adopt(believed)
        self._result(True, None, {"calibration": {"file": str(path), **summary(cal, nominal)}})

    def cancel(self, why: str) -> None:
        """End a running session without a fit (a mode change, lasers_off, a stop): nothing changes."""
        session = self._session
        if session is None:
            return
        session.abandon()
        self._end()
        self._result(False, why)

    def _end(self) -> None:
        self._session = None
        self._parts = None

    def _result(self, ok: bool, error: str | None, extra: dict[str, Any] | None = None) -> None:
        if ok:
            log.info("command calibrate done")
        else:
            log.warning("command calibrate failed: %s", error)
        request_id, self._request_id = self._request_id, None
        self._publish_result(ok, error, request_id, extra)
        self._publish_state()
