"""What a Pi camera's ISP hands over at the default rig's 640 × 480, as frames (the geometry is
`edge.isp`'s): neither a 3-colour sensor nor a Bayer filter at 640 × 480, the two the simulator
renders, makes such frames. :func:`scale_recording` turns a recording of a 1640 × 1232 sensor into
them (for `tools/isp_scaled.py` and the accuracy family's ISP conditions), and the tests render them
so with :func:`scaled_frame`. The live simulator renders them itself where `sim.sensor.isp` says so
(`edge.sim.render.Renderer`, with :func:`sensor_parts` and :func:`scaled_spots`), so that `edge run`,
`edge demo` and `edge doctor` on the simulator meet the frames the product's own camera hands over.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from edge.isp import CROP_ROWS, OUT, RAW, SCALE, per_area, scaled_camera, scaled_pixel, sensor_camera
from edge.rig import CameraModel, Rig
from edge.sim.settings import SimConfig

if TYPE_CHECKING:
    from edge.sim.render import SpotTruth

# `--set`s that render the sensor at 1640 × 1232 as the simulator's 640 × 480 camera sees the scene,
# per area: each 1640 × 1232 pixel is 1/SCALE² of a 640 × 480 one, so the room's light and the wells
# are SCALE² smaller and the blur and speckle SCALE × wider in pixels (the configured 600 e⁻/ms,
# 10 000 e⁻, 0.5 px and 1: `edge.isp.per_area` of them, rounded).
RAW_SETTINGS = ("rig.camera.model=picam-v2-1640", "sim.ambient.white_e_per_ms=91.4", "sim.sensor.full_well_e=1522",
                "sim.optics.psf_sigma_px=1.28", "sim.beam.speckle_grain=2.5625")


def scaled_frame(image: np.ndarray) -> np.ndarray:
    """A 1640 × 1232 frame as the ISP hands it over at 640 × 480."""
    return cv2.resize(image[CROP_ROWS:-CROP_ROWS], (OUT.width, OUT.height), interpolation=cv2.INTER_AREA)


def sensor_parts(rig: Rig, sim: SimConfig) -> tuple[Rig, SimConfig, np.ndarray]:
    """What the live simulator renders for `sim.sensor.isp`: the 1640 × 1232 sensor behind `rig`'s
    640 × 480 camera, the settings that let it see the room as that camera does per area, and, per
    sensor row, the frame row it lands in (where the rolling shutter's per-row laser light is
    read: the frame's rows are the sensor's, scaled)."""
    white, well, blur, grain = per_area(sim.ambient.white_e_per_ms, sim.sensor.full_well_e,
                                        sim.optics.psf_sigma_px, sim.beam.speckle_grain)
    sensor_sim = replace(sim, sensor=replace(sim.sensor, isp=False, full_well_e=well),
                         ambient=replace(sim.ambient, white_e_per_ms=white),
                         optics=replace(sim.optics, psf_sigma_px=blur), beam=replace(sim.beam, speckle_grain=grain))
    rows = np.rint((np.arange(RAW.height) - CROP_ROWS + 0.5) / SCALE - 0.5).astype(np.intp)
    return replace(rig, camera=sensor_camera(rig.camera)), sensor_sim, np.clip(rows, 0, OUT.height - 1)


def scaled_spots(spots: dict[str, SpotTruth], camera: CameraModel) -> dict[str, SpotTruth]:
    """The sensor's `spots` in the frames the ISP makes for `camera`: each pixel scaled, and a spot
    on a cropped row outside the image."""
    out = {}
    for name, spot in spots.items():
        if spot.pixel is not None:
            pixel = np.array(scaled_pixel(float(spot.pixel[0]), float(spot.pixel[1])))
            spot = replace(spot, pixel=pixel)
            if spot.visible and not camera.contains(pixel):
                spot = replace(spot, visible=False, why="outside_image")
        out[name] = spot
    return out


def scale_recording(sensor: Path, out: Path) -> int:
    """Write to `out` (replaced) the recording `sensor` of a 1640 × 1232 sensor as the ISP hands it
    over: every frame cropped and scaled, the camera :func:`scaled_camera`'s, each laser's true pixel
    moved to match and its floor's pixel σ scaled (the floor's range σ is the sensor's, the bound
    that no processing beats). Returns the number of zones. RecordingError for a recording that
    cannot be read, ValueError for a sensor of another size, OSError for a frame."""
    from edge.recording import camera_to_json, read_recording

    given = read_recording(sensor, check_images=False).rig.camera  # (checked: the file and key named)
    sweep = json.loads((sensor / "sweep.json").read_text())
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
