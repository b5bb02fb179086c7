"""The Pi camera's ISP as geometry: the default rig's camera (`picam-v2`, 640 × 480) is its sensor read
out binned at 1640 × 1232, demosaiced there, a row cropped off the top and the bottom (1230 rows are
4:3) and the rest scaled by area, 2.5625 ×. Where a sensor pixel, a spot's shape and a camera model
land in the frames the ISP hands over, and how bright and sharp the sensor is per pixel for the same
scene (what the simulator's frames at 1640 × 1232 are scaled from: `edge.sim.isp`).

Pure: pixels, covariances and camera models in, the same out.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TypeVar

import numpy as np

from edge.rig import CAMERA_MODELS, CameraModel, Rig

RAW = CAMERA_MODELS["picam-v2-1640"]  # what the sensor reads out
OUT = CAMERA_MODELS["picam-v2"]  # what the ISP hands over
SCALE = RAW.width / OUT.width  # 2.5625, both ways
CROP_ROWS = (RAW.height - round(OUT.height * SCALE)) // 2  # 1, off the top and the bottom

Coordinate = TypeVar("Coordinate", float, np.ndarray)  # one pixel's, or an array's


def per_area(white_e_per_ms: float, full_well_e: float, psf_sigma_px: float, speckle_grain: float
             ) -> tuple[float, float, float, float]:
    """The room's light on a pixel, the well, the lens blur and the speckle's grain of the
    1640 × 1232 sensor that sees the scene as a 640 × 480 camera with these does, per area."""
    return white_e_per_ms / SCALE**2, full_well_e / SCALE**2, psf_sigma_px * SCALE, speckle_grain * SCALE


def scaled_pixel(u: Coordinate, v: Coordinate) -> tuple[Coordinate, Coordinate]:
    """A 1640 × 1232 pixel's place in the 640 × 480 frame (pixel centres at integers)."""
    return (u + 0.5) / SCALE - 0.5, (v - CROP_ROWS + 0.5) / SCALE - 0.5


def sensor_pixel(u: Coordinate, v: Coordinate) -> tuple[Coordinate, Coordinate]:
    """A 640 × 480 pixel's place on the 1640 × 1232 sensor (:func:`scaled_pixel` undone)."""
    return (u + 0.5) * SCALE - 0.5, (v + 0.5) * SCALE - 0.5 + CROP_ROWS


def scaled_covariance(cov_px: np.ndarray) -> np.ndarray:
    """A spot's optical image covariance (2, 2) on the sensor, in the 640 × 480 frame's pixels, with
    the sensor's pixel it was integrated over (a box: 1/12 of a pixel² a side). The 640 × 480 pixel
    it is then averaged over is left to whoever integrates a spot over the frame's pixels, as the
    renderer and the oracle do."""
    return (np.asarray(cov_px, dtype=np.float64) + np.eye(2) / 12.0) / SCALE**2


def scaled_camera(sensor: CameraModel) -> CameraModel:
    """The 640 × 480 camera whose frames the ISP makes of a 1640 × 1232 `sensor` (its lens's
    distortion is in normalised coordinates: the same)."""
    _check(sensor, RAW, "sensor")
    cx, cy = scaled_pixel(sensor.cx, sensor.cy)
    return replace(sensor, width=OUT.width, height=OUT.height, fx=sensor.fx / SCALE, fy=sensor.fy / SCALE, cx=cx, cy=cy)


def sensor_camera(camera: CameraModel) -> CameraModel:
    """The 1640 × 1232 sensor that the ISP turns into the 640 × 480 `camera` (:func:`scaled_camera`
    undone)."""
    _check(camera, OUT, "camera")
    cx, cy = sensor_pixel(camera.cx, camera.cy)
    return replace(camera, width=RAW.width, height=RAW.height, fx=camera.fx * SCALE, fy=camera.fy * SCALE, cx=cx, cy=cy)


def scaled_rig(rig: Rig) -> Rig:
    """`rig` with its 1640 × 1232 sensor seen through the ISP."""
    return replace(rig, camera=scaled_camera(rig.camera))


def _check(camera: CameraModel, size: CameraModel, what: str) -> None:
    if (camera.width, camera.height) != (size.width, size.height):
        raise ValueError(f"the ISP's {what} is {size.width}x{size.height}, got {camera.width}x{camera.height}")
