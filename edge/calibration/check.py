"""How well a calibration ranges a recording it was not fitted to (``edge calibrate --check``).

Zone i of the check recording shows a flat target squarely at distances_m[i], as a calibration
recording does. Each laser's spot is found and assigned as the fit does it (:mod:`edge.calibration.fit`),
but predicted by the calibrated rig; its depth is the calibrated beam's point nearest to the camera
ray through the spot (:func:`edge.ranging.triangulate`), and its error is that depth minus the
tape-measured distance. Pure: a recording and a calibration in, numbers out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from edge.calibration.file import Calibration
from edge.calibration.fit import assign_spots, zone_blobs
from edge.errors import CalibrationError
from edge.ranging import triangulate
from edge.recording import Recording


@dataclass(frozen=True)
class CheckedZone:
    """One zone of a check: per laser the measured depth and its error (None: no spot)."""

    distance_m: float
    depth_m: dict[str, float | None]
    combined_m: float | None  # the lasers' depths averaged with the weights ranging gives them

    def error(self, laser: str) -> float | None:
        d = self.depth_m.get(laser)
        return None if d is None else d - self.distance_m

    @property
    def combined_error(self) -> float | None:
        return None if self.combined_m is None else self.combined_m - self.distance_m


def check_calibration(recording: Recording, distances_m: Sequence[float], cal: Calibration
                      ) -> list[CheckedZone]:
    """Range every laser's spot in every zone of `recording` (zone i: a flat target squarely at
    distances_m[i]) with `cal`."""
    zones = len(recording.zones)
    d = tuple(float(x) for x in distances_m)
    if len(d) != zones:
        raise CalibrationError(
            f"--distances: the recording has {zones} zones but {len(d)} distances were given: "
            "give one distance per zone, in zone order")
    bad = [x for x in d if not (math.isfinite(x) and x > 0)]
    if bad:
        raise CalibrationError(f"--distances: must be positive metres, got {bad[0]:g}")
    rig = cal.apply(recording.rig)
    blobs = [zone_blobs(recording, i) for i in range(zones)]
    points = assign_spots(rig, blobs, d)
    out = []
    for i, dist in enumerate(d):
        depth: dict[str, float | None] = {}
        weights: dict[str, float] = {}
        for laser in rig.lasers:
            px = points[laser.name].get(i)
            if px is None:
                depth[laser.name] = None
                continue
            depth[laser.name] = float(triangulate(laser, rig.camera, px[None, :])[0, 2])
            # A spot's depth error grows as depth² / baseline: ranging weighs lasers so.
            base = math.hypot(laser.origin_m[0], laser.origin_m[1])
            weights[laser.name] = (base / max(dist, 1e-6) ** 2) ** 2
        total = sum(weights.values())
        combined = (sum(w * float(depth[n] or 0.0) for n, w in weights.items()) / total
                    if total > 0 else None)
        out.append(CheckedZone(dist, depth, combined))
    return out
