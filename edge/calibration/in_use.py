"""The rig that ranging believes: the configured (nominal) rig with its calibration applied.

Real rigs are never built exactly, and a laser half a degree off costs percent of range, so a
device ranges with its calibration whenever it has one:

- ``[rig] calibration = FILE`` names an ``edge-calibration/1`` file (relative to the config file).
  It must exist and fit the rig: a configured calibration that cannot be used is an error, never a
  silent fall-back to the nominal rig.
- Otherwise the service (``edge run``) uses ``<service.state_dir>/calibration.json`` when it
  exists — that is where ``cmd/calibrate`` saves what it fits. Should that file be unusable (the
  rig's lasers were renamed since), the service says so in ``state`` and ranges with the nominal
  rig rather than not at all.
- Otherwise: the nominal rig.

A calibration made with a focus motor's lens held at one position (a Camera Module 3) says so; held
elsewhere now (``camera.lens_dioptres``), its health is a fault: calibrate again.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from edge.calibration.file import Calibration, read_calibration
from edge.config import Config, resolve_path
from edge.errors import CalibrationError, ConfigError
from edge.rig import Rig

STATE_FILE = "calibration.json"
LENS_MOVED = 0.05  # dioptres: a focus motor's step; beyond it the lens was moved
NOMINAL = "nominal rig (no calibration file)"


@dataclass(frozen=True)
class BelievedRig:
    rig: Rig
    health: str  # what `state` says under health.calibration
    path: Path | None = None  # the calibration file used, if any
    calibration: Calibration | None = None


def calibration_file(config: Config, service: bool = False) -> Path | None:
    """Where this configuration's calibration is, or would be saved by `cmd/calibrate`."""
    if config.rig.calibration:
        return resolve_path(config, config.rig.calibration)
    if service:
        return config.service.resolved_state_dir() / STATE_FILE
    return None


def describe(cal: Calibration, path: Path) -> str:
    worst = max((r["max"] for r in cal.residuals_px.values()), default=0.0)
    at = ", ".join(f"{d:g}" for d in cal.distances_m)
    return f"calibrated {cal.created} at {at} m, residuals ≤ {worst:.2f} px ({path})"


def believed_rig(config: Config, service: bool = False) -> BelievedRig:
    """The rig to range with (see the module notes); raises ConfigError when the configured
    calibration file is missing or does not fit the rig."""
    nominal = config.rig.build()
    path = calibration_file(config, service)
    configured = bool(config.rig.calibration)
    if path is None or (not configured and not path.exists()):
        return BelievedRig(nominal, NOMINAL)
    # (A webcam's or the simulator's lens is where it is: only the Pi camera holds a focus motor's.)
    lens = config.camera.lens_dioptres if config.camera.backend == "picamera2" else None
    try:
        return apply(nominal, read_calibration(path), path, lens)
    except CalibrationError as exc:
        if configured:  # the configuration names a file it cannot use: bad input
            raise ConfigError(f"rig.calibration: {exc}") from None
        return BelievedRig(nominal, f"fault: {exc}; ranging with the nominal rig")


def apply(nominal: Rig, cal: Calibration, path: Path, lens_dioptres: float | None = None) -> BelievedRig:
    """`cal` applied to `nominal`; its health a fault where the calibration's frames had a focus
    motor's lens held elsewhere than `lens_dioptres` (where it is held now): the focal length moved
    with the lens. The calibration is still used (its rays are nearer the truth than the nominal
    ones), and the fault says to calibrate again."""
    health = describe(cal, path)
    if (cal.lens_dioptres is not None and lens_dioptres is not None
            and abs(cal.lens_dioptres - lens_dioptres) > LENS_MOVED):
        health = (f"fault: calibrated with the lens at {cal.lens_dioptres:g} dioptres, and camera.lens_dioptres "
                  f"holds it at {lens_dioptres:g} now: the focal length moved with it ({path})")
    return BelievedRig(cal.apply(nominal), health, path, cal)
