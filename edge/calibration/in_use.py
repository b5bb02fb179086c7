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
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from edge.calibration.file import Calibration, read_calibration
from edge.config import Config, resolve_path
from edge.errors import CalibrationError, ConfigError
from edge.rig import Rig

STATE_FILE = "calibration.json"
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
    try:
        return apply(nominal, read_calibration(path), path)
    except CalibrationError as exc:
        if configured:  # the configuration names a file it cannot use: bad input
            raise ConfigError(f"rig.calibration: {exc}") from None
        return BelievedRig(nominal, f"fault: {exc}; ranging with the nominal rig")


def apply(nominal: Rig, cal: Calibration, path: Path) -> BelievedRig:
    return BelievedRig(cal.apply(nominal), describe(cal, path), path, cal)
