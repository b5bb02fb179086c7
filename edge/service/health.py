"""The rig's health as `state` reports it, and the one recovery the service tries on its own.

Each part's condition is "ok" or "fault: …". Faults are routed by the part they blame
(`ZoneResult.part`, `HardwareError.part`), never by the words of their message, which are for
people; the lasers are judged besides from the zones' spots (`edge.laserhealth`), whose typed
verdicts are worded here, where they become `state`. Frames that stop or come torn in several zones
in a row get the camera started again (a picamera2 pipeline or a webcam stream often recovers so).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence

from edge.errors import HardwareError
from edge.hw.base import Camera
from edge.laserhealth import LaserHealth, LaserVerdict
from edge.ranging import FAULT, ZoneResult

log = logging.getLogger(__name__)

# The camera is restarted after this many zones in a row failed for want of frames.
CAMERA_RESTART_AFTER = 2
# The parts `state` reports, in its order; a zone that went through passed the first three. The
# storage is the state folder's disk, as the outbox finds it ("full: …" while it drops or cannot queue).
PARTS = ("camera", "lasers", "ptu", "calibration", "storage")
_ZONE_PARTS = PARTS[:3]


class RigHealth:
    """Each part's latest condition, kept from the zones as they come.

    `camera()` gives the camera to restart (None while the rig is not open); `changed()` is called
    whenever a condition changed, before any restart (so `state` goes out then)."""

    def __init__(self, laser_names: Sequence[str], calibration: str, *, calibrated: bool,
                 camera: Callable[[], Camera | None], changed: Callable[[], None]) -> None:
        self._parts = {**dict.fromkeys(PARTS, "ok"), "calibration": calibration}
        self.lasers = LaserHealth(laser_names)
        self.calibrated = calibrated
        self.camera_restarts = 0
        self._camera = camera
        self._changed = changed
        self._laser_verdicts: dict[str, LaserVerdict] = {}
        self._camera_faults = 0  # zones in a row that blamed the camera

    @property
    def parts(self) -> dict[str, str]:
        """Part → "ok" or what went wrong, as `state` says it (a copy)."""
        return dict(self._parts)

    def zone(self, result: ZoneResult, lit_when_off: Sequence[str] | frozenset[str] = frozenset()) -> None:
        """Take one zone's or frame's outcome: conditions, laser verdicts, a camera restart."""
        before = dict(self._parts)
        self._zone_parts(result)
        self.lasers.update(result, lit_when_off)
        self._word_laser_verdicts()
        # Compared whole: a zone that went through sets "lasers" to "ok" and a standing verdict sets
        # it back, which is no change and must not send `state` again at every zone.
        if self._parts != before:
            self._changed()
        blames_camera = result.status == FAULT and result.part == "camera"
        self._camera_faults = self._camera_faults + 1 if blames_camera else 0
        if self._camera_faults >= CAMERA_RESTART_AFTER:
            self._restart_camera()

    def storage(self, condition: str) -> None:
        """The outbox's word on the state disk ("ok" or "full: …")."""
        if self._parts["storage"] != condition:
            self._parts["storage"] = condition
            self._changed()

    def cannot_see(self, reference: str) -> str | None:
        """Why ranging is blind although zones come back, or None: the `reference` laser (the one
        every range is measured with) does not light or does not go off, so every zone reads
        `no_spot`, which looks like open space. The blind aid says "cannot see" for it."""
        verdict = self._laser_verdicts.get(reference)
        return None if verdict is None else verdict.words(self.calibrated)

    def failed(self, exc: HardwareError) -> None:
        """A part failed for good (the service is about to stop): say which, and how."""
        if exc.part in self._parts:
            self._parts[exc.part] = f"fault: {exc}"

    def recalibrated(self, calibration: str, laser_names: Sequence[str]) -> None:
        """A new calibration is in use: the lasers are judged afresh with its rays."""
        self._parts["calibration"] = calibration
        self.calibrated = True
        self.lasers = LaserHealth(laser_names, self.lasers.hysteresis)
        if self._laser_verdicts:
            self._laser_verdicts = {}
            self._parts["lasers"] = "ok"

    def _zone_parts(self, result: ZoneResult) -> None:
        if result.status == FAULT:
            if result.part is not None:
                self._parts[result.part] = f"fault: {result.detail}"
        else:
            for name in _ZONE_PARTS:  # a zone went through all three
                self._parts[name] = "ok"

    def _word_laser_verdicts(self) -> None:
        verdicts = self.lasers.verdicts()
        if verdicts:
            self._parts["lasers"] = "fault: " + "; ".join(v.words(self.calibrated) for v in verdicts.values())
        if verdicts == self._laser_verdicts:
            return
        for name, verdict in verdicts.items():  # each new verdict once, not the standing ones again
            if self._laser_verdicts.get(name) != verdict:
                log.error("%s", verdict.words(self.calibrated))
        if not verdicts:
            log.info("lasers: all working again")
        else:
            for name in self._laser_verdicts.keys() - verdicts.keys():
                log.info("laser %s: working again", name)
        self._laser_verdicts = verdicts

    def _restart_camera(self) -> None:
        self._camera_faults = 0
        camera = self._camera()
        if camera is None:
            return
        log.warning("camera: %d zones without usable frames; restarting it", CAMERA_RESTART_AFTER)
        self.camera_restarts += 1
        try:
            camera.stop()
            camera.start()
        except Exception as exc:  # the next zones will say what is wrong
            log.error("camera: restart failed: %s", exc)
