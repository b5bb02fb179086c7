"""What a Pi camera's ISP hands over at the default rig's 640 × 480: its sensor read out binned at
1640 × 1232, demosaiced there, a row cropped off the top and the bottom (1230 rows are 4:3) and the
rest scaled by area, 2.5625 ×. Neither a 3-colour sensor nor a Bayer filter at 640 × 480, the two
the simulator draws, makes such frames: :func:`scale_recording` turns a recording of a 1640 × 1232
sensor into them (for `tools/isp_scaled.py` and the accuracy family's ISP conditions), and the tests
render them so.

Pure but for :func:`scale_recording`: frames, pixels and cameras in, the same out.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from edge.rig import CAMERA_MODELS, CameraModel, Rig

RAW = CAMERA_MODELS["picam-v2-1640"]  # what the sensor reads out
OUT = CAMERA_MODELS["picam-v2"]  # what the ISP hands over
SCALE = RAW.width / OUT.width  # 2.5625, both ways
CROP_ROWS = (RAW.height - round(OUT.height * SCALE)) // 2  # 1, off the top and the bottom
# `--set`s that render the sensor at 1640 × 1232 as the simulator's 640 × 480 camera sees the scene,
# per area: each 1640 × 1232 pixel is 1/SCALE² of a 640 × 480 one, so the room's light and the wells
# are SCALE² smaller and the blur and speckle SCALE × wider in pixels (the configured 600 e⁻/ms,
# 10 000 e⁻, 0.5 px and 1: `per_area` of them, rounded).
RAW_SETTINGS = ("rig.camera.model=picam-v2-1640", "sim.ambient.white_e_per_ms=91.4", "sim.sensor.full_well_e=1522",
                "sim.optics.psf_sigma_px=1.28", "sim.beam.speckle_grain=2.5625")


def per_area(white_e_per_ms: float, full_well_e: float, psf_sigma_px: float, speckle_grain: float
             ) -> tuple[float, float, float, float]:
    """The room's light on a pixel, the well, the lens blur and the speckle's grain of the
    1640 × 1232 sensor that sees the scene as a 640 × 480 camera with these does, per area."""
    return white_e_per_ms / SCALE**2, full_well_e / SCALE**2, psf_sigma_px * SCALE, speckle_grain * SCALE


def scaled_frame(image: np.ndarray) -> np.ndarray:
    """A 1640 × 1232 frame as the ISP hands it over at 640 × 480."""
    return cv2.resize(image[CROP_ROWS:-CROP_ROWS], (OUT.width, OUT.height), interpolation=cv2.INTER_AREA)


def scaled_pixel(u: float, v: float) -> tuple[float, float]:
    """A 1640 × 1232 pixel's place in the 640 × 480 frame (pixel centres at integers)."""
    return (u + 0.5) / SCALE - 0.5, (v - CROP_ROWS + 0.5) / SCALE - 0.5


def sensor_pixel(u: float, v: float) -> tuple[float, float]:
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


def scale_recording(sensor: Path, out: Path) -> int:
    """Write to `out` (replaced) the recording `sensor` of a 1640 × 1232 sensor as the ISP hands it
    over: every frame cropped and scaled, the camera :func:`scaled_camera`'s, each laser's true pixel
    moved to match and its floor's pixel σ scaled (the floor's range σ is the sensor's, the bound
    that no processing beats). Returns the number of zones. ValueError for a sensor of another size;
    OSError and ValueError (JSON) for a recording that cannot be read."""
    from edge.recording import camera_to_json

    sweep = json.loads((sensor / "sweep.json").read_text())
    cam = sweep["camera"]
    given = CameraModel(cam["width"], cam["height"], cam["fx"], cam["fy"], cam["cx"], cam["cy"], tuple(cam["dist"]))
    sweep["camera"] = camera_to_json(scaled_camera(given))
    for zone in sweep["zones"]:
        truth = zone.get("truth") or {}
        for laser in (truth.get("lasers") or {}).values():
            if laser.get("pixel"):
                laser["pixel"] = [round(c, 4) for c in scaled_pixel(*laser["pixel"])]
        for floor in ((truth.get("floor") or {}).get("lasers") or {}).values():
            for key in ("noise_px", "speckle_px"):
                if floor.get(key) is not None:
                    floor[key] = round(floor[key] / SCALE, 5)
    if out.exists():
        shutil.rmtree(out)
    (out / "frames").mkdir(parents=True)
    (out / "sweep.json").write_text(json.dumps(sweep, indent=1))
    for frame in sorted((sensor / "frames").iterdir()):
        image = cv2.imread(str(frame), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"{frame}: not an image")
        cv2.imwrite(str(out / "frames" / frame.name), scaled_frame(image))
    return len(sweep["zones"])
