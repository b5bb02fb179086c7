"""Calibration files, format ``edge-calibration/1``: the :class:`Calibration` value, read and write.

A calibration file is JSON: the `format`, when it was made (`created`), the target distances it was
fitted from (`distances_m`), the `camera` and the `lasers` as in ``sweep.json``
(``shared/spec/recording.md``), and the fit's residuals per laser (`residuals_px`: `rms`, `max`,
`n`). Since issue 15 it also keeps how well the fit knows each ray: `ray_covariance`, per laser the
4 × 4 covariance of its parameters (ax, x0, ay, y0) in the fit's line x = x0 + ax·z, y = y0 + ay·z
(camera frame, metres), and `spot_sigma_px`, one spot's scatter per axis (u, v) that the fit
measured; since the fit tells clipped spots from the others, `spot_sigma_px` is that of a spot that
does not clip the sensor, `clipped_spot_sigma_px` that of one that does, and `clipped_within_m` the
farthest distance where most spots clipped (absent: one scatter for all); `lens_dioptres`, where a
focus motor held the lens (absent: the camera has none), for which alone the fit holds; and, for people,
`range_error_m`, the 1-σ range errors they imply at 1, 2 and 4 m per laser and combined
(recomputed from the covariance when read: see :mod:`edge.calibration.uncertainty`).
Older files without them still load; they just know nothing of their uncertainty. Reading is
strict, by the loader of :mod:`edge.schema`: every problem is a :class:`CalibrationError` of one
line naming the file and the key. Unknown keys are ignored, as in recordings, so that the format can
grow. Writing is atomic: a power cut leaves the old file or the new one.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Annotated

import numpy as np

from edge.calibration.uncertainty import (
    REPORT_DEPTHS_M,
    RangeError,
    baseline,
    combined_range_error,
    laser_range_error,
    ray_parameters,
)
from edge.errors import CalibrationError
from edge.fsutil import atomic_write_bytes
from edge.hw.camera import lens_dioptres_problem
from edge.recording import LaserKeys, format_is, load, rig_of, rig_to_json, timestamp
from edge.rig import CameraModel, Laser, Rig
from edge.schema import read_json

FORMAT = "edge-calibration/1"


@dataclass(frozen=True)
class Calibration:
    """Fitted laser rays (origin at z = 0 of each line) and the camera they go with."""

    lasers: tuple[Laser, ...]
    camera: CameraModel
    distances_m: tuple[float, ...] = ()
    residuals_px: dict[str, dict] = field(default_factory=dict)
    created: str = ""
    # Per laser the (4, 4) covariance of (ax, x0, ay, y0); empty: unknown (an older file, --fit-focal).
    ray_covariance: dict[str, tuple[tuple[float, ...], ...]] = field(default_factory=dict)
    spot_sigma_px: tuple[float, ...] = ()  # (σu, σv) of one unclipped spot as the fit saw it; () unknown
    clipped_spot_sigma_px: tuple[float, ...] = ()  # ... of one clipped spot; () as an unclipped one
    clipped_within_m: float = 0.0  # up to here the calibration's spots clipped (0: nowhere)
    lens_dioptres: float | None = None  # where a focus motor held the lens (None: no motor, or not said)

    def spot_sigma_at(self, depth_m: float) -> tuple[float, ...]:
        """(σu, σv) of one spot at `depth_m` taken as the calibration's were: a clipped one's
        within the distance where its spots clipped, else an unclipped one's."""
        if depth_m <= self.clipped_within_m and len(self.clipped_spot_sigma_px) == 2:
            return self.clipped_spot_sigma_px
        return self.spot_sigma_px

    def range_errors(self, depths_m: Sequence[float] = REPORT_DEPTHS_M) -> dict[str, RangeError]:
        """Per laser, and ``combined``, the 1-σ range errors this calibration implies at
        `depths_m`; empty when it does not know its covariance."""
        if not self.ray_covariance or len(self.spot_sigma_px) != 2:
            return {}
        spot = np.array([self.spot_sigma_at(d) for d in depths_m]) / np.array([self.camera.fx, self.camera.fy])
        out: dict[str, RangeError] = {}
        bases: dict[str, float] = {}
        for laser in self.lasers:
            cov = self.ray_covariance.get(laser.name)
            if cov is None:
                continue
            params = ray_parameters(laser)
            out[laser.name] = laser_range_error(params, np.array(cov), spot, depths_m)
            bases[laser.name] = baseline(params)
        if out:
            out["combined"] = combined_range_error(out, bases)
        return out

    def apply(self, rig: Rig) -> Rig:
        """`rig` with its lasers and camera replaced by the calibrated ones (the reference flag
        stays `rig`'s)."""
        mine = {laser.name: laser for laser in self.lasers}
        for laser in rig.lasers:
            if laser.name not in mine:
                raise CalibrationError(
                    f"the calibration has no laser {laser.name!r} (it has {', '.join(mine)}): "
                    "calibrate this rig again")
        cam = rig.camera
        if (self.camera.width, self.camera.height) != (cam.width, cam.height):
            raise CalibrationError(
                f"the calibration is for a {self.camera.width}x{self.camera.height} camera, the "
                f"rig's is {cam.width}x{cam.height}: calibrate at this resolution")
        lasers = tuple(
            replace(mine[ln.name], reference=ln.reference)
            for ln in rig.lasers)
        return replace(rig, camera=self.camera, lasers=lasers)

    @staticmethod
    def from_rig(rig: Rig) -> Calibration:
        """A calibration that is exactly `rig` (e.g. a simulator's true rig)."""
        return Calibration(rig.lasers, rig.camera, created=timestamp())


# --- the file -----------------------------------------------------------------------------------


def _positive(distance: float) -> str | None:
    return None if distance > 0 else f"must be positive metres, got {distance:g}"


def _not_negative(distance: float) -> str | None:
    return None if distance >= 0 else f"must be 0 or more metres, got {distance:g}"


def _square4(m: tuple[tuple[float, ...], ...]) -> str | None:
    if len(m) != 4 or any(len(row) != 4 for row in m):
        return "must be a 4 x 4 matrix (ax, x0, ay, y0)"
    if any(m[k][k] < 0 for k in range(4)):
        return "a variance (diagonal) must not be negative"
    return None


def _pair(s: tuple[float, ...]) -> str | None:
    if s and (len(s) != 2 or any(x < 0 for x in s)):
        return "must be two non-negative pixels (u, v), or absent"
    return None


@dataclass(frozen=True)
class Residuals:
    """How well one laser's fitted ray matches its spots, in pixels."""

    rms: float
    max: float
    n: int  # spots it was fitted to


@dataclass(frozen=True)
class CalibrationFile:
    """A calibration file as it is on disk."""

    format: Annotated[str, format_is(FORMAT)]
    created: str
    distances_m: tuple[Annotated[float, _positive], ...]
    camera: CameraModel
    lasers: tuple[LaserKeys, ...]
    residuals_px: dict[str, Residuals]
    ray_covariance: dict[str, Annotated[tuple[tuple[float, ...], ...], _square4]] = field(default_factory=dict)
    spot_sigma_px: Annotated[tuple[float, ...], _pair] = ()
    clipped_spot_sigma_px: Annotated[tuple[float, ...], _pair] = ()
    clipped_within_m: Annotated[float, _not_negative] = 0.0
    lens_dioptres: Annotated[float, lens_dioptres_problem] | None = None

    def __post_init__(self) -> None:
        rig_of(self.camera, self.lasers)  # Rig checks the laser names and the reference flag

    def calibration(self) -> Calibration:
        rig = rig_of(self.camera, self.lasers)
        return Calibration(rig.lasers, rig.camera, self.distances_m,
                           {name: asdict(r) for name, r in self.residuals_px.items()}, self.created,
                           dict(self.ray_covariance), self.spot_sigma_px, self.clipped_spot_sigma_px,
                           self.clipped_within_m, self.lens_dioptres)


def read_calibration(path: str | Path) -> Calibration:
    """Read a calibration file strictly: every problem is one line naming the file and the key."""
    raw = read_json(path, CalibrationError, missing="no such calibration file (make one with edge calibrate)")
    doc: CalibrationFile = load(CalibrationFile, raw, str(path), error=CalibrationError)
    return doc.calibration()


def write_calibration(path: str | Path, cal: Calibration) -> None:
    """Write `cal` as JSON, atomically (temporary file, fsync, rename)."""
    rig = rig_to_json(Rig(cal.camera, cal.lasers))
    doc = {"format": FORMAT, "created": cal.created, "distances_m": list(cal.distances_m),
           "camera": rig["camera"], "lasers": rig["lasers"], "residuals_px": cal.residuals_px}
    if cal.ray_covariance:
        doc["ray_covariance"] = {n: [list(row) for row in m] for n, m in cal.ray_covariance.items()}
        doc["spot_sigma_px"] = list(cal.spot_sigma_px)
        if cal.clipped_spot_sigma_px:
            doc["clipped_spot_sigma_px"] = list(cal.clipped_spot_sigma_px)
            doc["clipped_within_m"] = cal.clipped_within_m
        doc["range_error_m"] = {n: e.to_json() for n, e in cal.range_errors().items()}
    if cal.lens_dioptres is not None:
        doc["lens_dioptres"] = cal.lens_dioptres
    try:
        atomic_write_bytes(path, (json.dumps(doc, indent=2, allow_nan=False) + "\n").encode())
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot write the calibration: {exc.strerror or exc}") from None
