"""Calibration files, format ``edge-calibration/1``: the :class:`Calibration` value, read and write.

A calibration file is JSON: the `format`, when it was made (`created`), the target distances it was
fitted from (`distances_m`), the `camera` and the `lasers` as in ``sweep.json``
(``shared/spec/recording.md``), and the fit's residuals per laser (`residuals_px`: `rms`, `max`,
`n`). Reading is strict, by the loader of :mod:`edge.schema`: every problem is a
:class:`CalibrationError` of one line naming the file and the key. Unknown keys are ignored, as in
recordings, so that the format can grow. Writing is atomic: a power cut leaves the old file or the
new one.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Annotated

from edge.errors import CalibrationError
from edge.fsutil import atomic_write_bytes
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

    def __post_init__(self) -> None:
        rig_of(self.camera, self.lasers)  # Rig checks the laser names and the reference flag

    def calibration(self) -> Calibration:
        rig = rig_of(self.camera, self.lasers)
        return Calibration(rig.lasers, rig.camera, self.distances_m,
                           {name: asdict(r) for name, r in self.residuals_px.items()}, self.created)


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
    try:
        atomic_write_bytes(path, (json.dumps(doc, indent=2, allow_nan=False) + "\n").encode())
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot write the calibration: {exc.strerror or exc}") from None
