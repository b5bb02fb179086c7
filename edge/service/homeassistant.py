"""What Home Assistant's entities follow, beyond the contract's topics (README: "Home Assistant").

The contract's topics stay as they are: ``range`` carries every frame and every zone, ``alert``
every guard event, ``cue`` every change of the blind aid's sound. Those make poor entity states: a
sensor on ``range`` changes 28 times a second in the range finder and jumps from wall to wall in a
guard sweep; a motion sensor on ``alert`` misses the `cleared` of a mode change and is `unknown`
after a restart of Home Assistant. So the service publishes besides, retained, a few snapshots
(the link sends each at most twice a second and the latest at every connect):

- ``distance``: the range finder's reading, at most once a second unless it changes much
  (:data:`DISTANCE_STEP`), ``active`` only while the range finder runs (not paused);
- ``obstacle``: the blind aid's nearest obstacle, the same way (:data:`OBSTACLE_STEP_M`,
  :data:`OBSTACLE_STEP_DEG`), ``active`` only while the blind aid runs;
- ``guard``: whether the guard watches (``active``), whether anything is there (``occupied``: a
  followed object, as long as any is followed), how many, and whether it is still learning;
  published after each guard sweep and whenever the mode, a pause or a relearn changes it;
- ``map``: the last complete sweep drawn as a PNG (:func:`edge.mapping.draw_map`).

Called on the service's thread; publishing never waits for the broker.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from typing import Any

from edge.ranging import ZoneResult

log = logging.getLogger(__name__)

# (kind, payload, min interval s): MqttLink.publish_snapshot
PublishSnapshot = Callable[[str, "dict[str, Any] | bytes", float], None]

CALM_INTERVAL_S = 1.0  # a reading that changed little goes out at most this often
QUICK_INTERVAL_S = 0.6  # one that changed much, this often (the link's floor)
DISTANCE_STEP = (0.02, 0.02)  # a distance change is significant from 2 cm or 2 %, whichever is more
OBSTACLE_STEP_M = (0.10, 0.10)  # the obstacle's: 10 cm or 10 %
OBSTACLE_STEP_DEG = 10.0  # or its bearing by 10°
MAP_PX = 480  # the map picture's side: a PNG of about 35 kB for a 32-zone sweep


def _round(value: Any, digits: int) -> float | None:
    return round(float(value), digits) if isinstance(value, (int, float)) and math.isfinite(value) else None


def _moved(new: float | None, old: float | None, step: tuple[float, float]) -> bool:
    if (new is None) != (old is None):
        return True
    return new is not None and old is not None and abs(new - old) >= max(step[0], step[1] * abs(old))


class HomeAssistantFeed:
    """The snapshots above, published through `publish` (kind, payload, min interval)."""

    def __init__(self, publish: PublishSnapshot, *, device_id: str, range_limit_m: float) -> None:
        self._publish = publish
        self._device_id = device_id
        self._range_limit_m = range_limit_m
        self._running: str | None = None  # the mode that runs (None while paused)
        self._distance_ref: tuple[Any, float | None] | None = None  # (status, range) last sent quickly
        self._obstacle_ref: tuple[Any, float | None, float | None] | None = None  # (sound, range, bearing)

    # ---- what runs ----

    def activity(self, mode: str, paused: bool) -> None:
        """The mode that runs changed, or a pause began or ended (and at start): the distance and
        the obstacle say whether they are measured, with no reading yet."""
        self._running = None if paused else mode
        self._distance_ref = self._obstacle_ref = None
        self._publish("distance", {"active": self._running == "rangefinder", "range_m": None, "sigma_m": None,
                                   "status": None, "pan_deg": None, "tilt_deg": None}, QUICK_INTERVAL_S)
        self._publish("obstacle", {"active": self._running == "blindaid", "range_m": None, "bearing_deg": None,
                                   "sound": None, "reason": None}, QUICK_INTERVAL_S)

    # ---- readings ----

    def live(self, kind: str, payload: dict[str, Any]) -> None:
        """A ``range`` or ``cue`` as the contract's topic got it."""
        if kind == "range" and self._running == "rangefinder" and payload.get("index") == -1:
            self._distance(payload)
        elif kind == "cue" and self._running == "blindaid":
            self._obstacle(payload)

    def _distance(self, payload: dict[str, Any]) -> None:
        filtered = payload.get("filtered_m")
        value = _round(filtered if filtered is not None else payload.get("range_m"), 3)
        status = payload.get("status")
        ref = self._distance_ref
        quick = ref is None or ref[0] != status or _moved(value, ref[1], DISTANCE_STEP)
        if quick:
            self._distance_ref = (status, value)
        sigma = payload.get("filtered_sigma_m") if filtered is not None else payload.get("sigma_m")
        self._publish("distance", {"active": True, "range_m": value, "sigma_m": _round(sigma, 4), "status": status,
                                   "pan_deg": _round(payload.get("pan_deg"), 2),
                                   "tilt_deg": _round(payload.get("tilt_deg"), 2)},
                      QUICK_INTERVAL_S if quick else CALM_INTERVAL_S)

    def _obstacle(self, payload: dict[str, Any]) -> None:
        sound = payload.get("sound")
        range_m, bearing = _round(payload.get("range_m"), 3), _round(payload.get("bearing_deg"), 1)
        ref = self._obstacle_ref
        quick = (ref is None or ref[0] != sound or _moved(range_m, ref[1], OBSTACLE_STEP_M)
                 or _moved(bearing, ref[2], (OBSTACLE_STEP_DEG, 0.0)))
        if quick:
            self._obstacle_ref = (sound, range_m, bearing)
        self._publish("obstacle", {"active": True, "range_m": range_m, "bearing_deg": bearing, "sound": sound,
                                   "reason": payload.get("reason")},
                      QUICK_INTERVAL_S if quick else CALM_INTERVAL_S)

    # ---- the guard, the map ----

    def guard(self, active: bool, learning: bool, tracks: Sequence[Any]) -> None:
        """The guard as it stands: `active` while guard mode runs; `tracks` its followed objects
        (`edge.modes.guard.Track`), counted only while active."""
        followed = list(tracks) if active else []
        self._publish("guard", {
            "active": active,
            "occupied": bool(followed),
            "tracks": len(followed),
            "learning": bool(learning),
            "objects": [{"id": t.id, "bearing_deg": round(t.bearing_deg, 1), "range_m": round(t.range_m, 2),
                         "zones": list(t.zones)} for t in followed],
        }, QUICK_INTERVAL_S)

    def map(self, results: Sequence[ZoneResult], sweep: int, mode: str, when: str) -> None:
        """A complete sweep as a picture on ``map``."""
        try:
            png = map_png(results, f"{self._device_id}: sweep {sweep} ({mode}), {when}", self._range_limit_m)
        except Exception:  # noqa: BLE001 - a picture must never stop the device
            log.exception("map: drawing sweep %d failed", sweep)
            return
        self._publish("map", png, QUICK_INTERVAL_S)


def map_png(results: Sequence[ZoneResult], title: str, range_limit_m: float, size_px: int = MAP_PX) -> bytes:
    """The sweep drawn by `edge.mapping.draw_map`, as a small PNG."""
    import cv2

    from edge.mapping import draw_map

    image = draw_map(results, size_px=size_px, range_limit_m=range_limit_m, title=title)
    ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()
