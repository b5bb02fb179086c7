"""What a Pi camera's ISP hands over at the default rig's 640 × 480, as frames (the geometry is
`edge.isp`'s): neither a 3-colour sensor nor a Bayer filter at 640 × 480, the two the simulator
renders, makes such frames. :func:`scale_recording` turns a recording of a 1640 × 1232 sensor into
them (for `tools/isp_scaled.py` and the accuracy family's ISP conditions), and the tests render them
so with :func:`scaled_frame`.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np

from edge.isp import CROP_ROWS, OUT, SCALE, scaled_camera, scaled_pixel
from edge.rig import CameraModel

# `--set`s that render the sensor at 1640 × 1232 as the simulator's 640 × 480 camera sees the scene,
# per area: each 1640 × 1232 pixel is 1/SCALE² of a 640 × 480 one, so the room's light and the wells
# are SCALE² smaller and the blur and speckle SCALE × wider in pixels (the configured 600 e⁻/ms,
# 10 000 e⁻, 0.5 px and 1: `edge.isp.per_area` of them, rounded).
RAW_SETTINGS = ("rig.camera.model=picam-v2-1640", "sim.ambient.white_e_per_ms=91.4", "sim.sensor.full_well_e=1522",
                "sim.optics.psf_sigma_px=1.28", "sim.beam.speckle_grain=2.5625")


def scaled_frame(image: np.ndarray) -> np.ndarray:
    """A 1640 × 1232 frame as the ISP hands it over at 640 × 480."""
    return cv2.resize(image[CROP_ROWS:-CROP_ROWS], (OUT.width, OUT.height), interpolation=cv2.INTER_AREA)


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
