"""What a Pi camera's ISP hands over at the default rig's 640 × 480: its sensor read out binned at
1640 × 1232, demosaiced there, a row cropped off the top and the bottom (1230 rows are 4:3) and the
rest scaled by area, 2.5625 ×. Neither a 3-colour sensor nor a Bayer filter at 640 × 480, the two
the simulator draws, makes such frames: `tools/isp_scaled.py` turns a recording of the
`picam-v2-1640` camera into them, and the tests render them so.

Pure: frames and pixels in, frames and pixels out.
"""

from __future__ import annotations

import cv2
import numpy as np

from edge.rig import CAMERA_MODELS

RAW = CAMERA_MODELS["picam-v2-1640"]  # what the sensor reads out
OUT = CAMERA_MODELS["picam-v2"]  # what the ISP hands over
SCALE = RAW.width / OUT.width  # 2.5625, both ways
CROP_ROWS = (RAW.height - round(OUT.height * SCALE)) // 2  # 1, off the top and the bottom
# `--set`s that render the sensor at 1640 × 1232 as the simulator's 640 × 480 camera sees the scene,
# per area: each 1640 × 1232 pixel is 1/SCALE² of a 640 × 480 one, so the room's light and the wells
# are SCALE² smaller and the blur and speckle SCALE × wider in pixels (the configured 600 e⁻/ms,
# 10 000 e⁻, 0.5 px and 1).
RAW_SETTINGS = ("rig.camera.model=picam-v2-1640", "sim.ambient.white_e_per_ms=91.4", "sim.sensor.full_well_e=1522",
                "sim.optics.psf_sigma_px=1.28", "sim.beam.speckle_grain=2.5625")


def scaled_frame(image: np.ndarray) -> np.ndarray:
    """A 1640 × 1232 frame as the ISP hands it over at 640 × 480."""
    return cv2.resize(image[CROP_ROWS:-CROP_ROWS], (OUT.width, OUT.height), interpolation=cv2.INTER_AREA)


def scaled_pixel(u: float, v: float) -> tuple[float, float]:
    """A 1640 × 1232 pixel's place in the 640 × 480 frame (pixel centres at integers)."""
    return (u + 0.5) / SCALE - 0.5, (v - CROP_ROWS + 0.5) / SCALE - 0.5
