"""A 1640 × 1232 recording as a Pi camera's ISP hands it over at 640 × 480 (issue 15, measured).

The default rig's camera (`picam-v2`) is a Pi Camera v2 read out binned at 1640 × 1232: its ISP
demosaics that and scales it to 640 × 480 (2.5625 ×, after cropping a row off the top and the bottom
to keep 4:3). Its frames are then neither a 3-colour sensor's nor a Bayer filter's at 640 × 480, the
two the simulator draws. This makes them from a recording of the `picam-v2-1640` camera behind a
Bayer filter: every frame cropped and scaled by area, the camera written as `picam-v2`'s, and each
laser's true pixel moved to match.

    ./dev edge sim record --out rec/raw --set rig.camera.model=picam-v2-1640 --set sim.sensor.bayer=ea \\
        --set sim.optics.psf_sigma_px=1.28 --set sim.ambient.white_e_per_ms=91.4 \\
        --set sim.sensor.full_well_e=1522 --set sim.beam.speckle_grain=2.5625
    .venv/bin/python tools/isp_scaled.py rec/raw rec/isp
    ./dev edge replay rec/isp --score

(The --set values keep the room as bright, the wells as deep, and the blur and speckle as fine, per
area of the scene, as the simulator's own 640 × 480 camera has them: each 1640 × 1232 pixel is
1/2.5625² of one of its pixels.)
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import cv2

SCALE = 2.5625  # 1640 → 640 columns, and 1230 → 480 rows
RAW_SIZE = (1640, 1232)
OUT_SIZE = (640, 480)
CROP_ROWS = 1  # off the top and the bottom: 1230 rows are 4:3
CAMERA = {"width": 640, "height": 480, "fx": 530.0, "fy": 530.0, "cx": 319.5, "cy": 239.5, "dist": [0.0] * 5}


def scaled_pixel(u: float, v: float) -> list[float]:
    """A 1640 × 1232 pixel's place in the 640 × 480 frame (pixel centres at integers)."""
    return [round((u + 0.5) / SCALE - 0.5, 4), round((v - CROP_ROWS + 0.5) / SCALE - 0.5, 4)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("raw", type=Path, help="a recording of the picam-v2-1640 camera")
    parser.add_argument("out", type=Path, help="the 640 × 480 recording to write (replaced)")
    args = parser.parse_args(argv)
    try:
        sweep = json.loads((args.raw / "sweep.json").read_text())
    except (OSError, ValueError) as exc:
        print(f"isp_scaled: {args.raw / 'sweep.json'}: cannot be read as a recording: {exc}", file=sys.stderr)
        return 2
    camera = sweep["camera"]
    if (camera["width"], camera["height"]) != RAW_SIZE:
        print(f"isp_scaled: {args.raw / 'sweep.json'}: camera is {camera['width']}x{camera['height']}, "
              f"not {RAW_SIZE[0]}x{RAW_SIZE[1]}", file=sys.stderr)
        return 2
    sweep["camera"] = CAMERA
    for zone in sweep["zones"]:
        for laser in zone.get("truth", {}).get("lasers", {}).values():
            if laser.get("pixel"):
                laser["pixel"] = scaled_pixel(*laser["pixel"])
    if args.out.exists():
        shutil.rmtree(args.out)
    (args.out / "frames").mkdir(parents=True)
    (args.out / "sweep.json").write_text(json.dumps(sweep, indent=1))
    for frame in sorted((args.raw / "frames").iterdir()):
        image = cv2.imread(str(frame), cv2.IMREAD_UNCHANGED)
        small = cv2.resize(image[CROP_ROWS:-CROP_ROWS], OUT_SIZE, interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(args.out / "frames" / frame.name), small)
    print(f"wrote {args.out}: {len(sweep['zones'])} zones at {OUT_SIZE[0]}x{OUT_SIZE[1]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
