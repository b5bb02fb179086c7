"""A 1640 × 1232 recording as a Pi camera's ISP hands it over at 640 × 480 (issue 15, measured).

The default rig's camera (`picam-v2`) is a Pi Camera v2 read out binned at 1640 × 1232: its ISP
demosaics that and scales it to 640 × 480 (2.5625 ×, after cropping a row off the top and the bottom
to keep 4:3). Its frames are then neither a 3-colour sensor's nor a Bayer filter's at 640 × 480, the
two the simulator draws. This makes them from a recording of the `picam-v2-1640` camera behind a
Bayer filter: every frame cropped and scaled by area, the camera written as `picam-v2`'s, and each
laser's true pixel moved to match.

    ./dev edge sim record --out rec/raw --set sim.sensor.bayer=ea \
        --set rig.camera.model=picam-v2-1640 --set sim.ambient.white_e_per_ms=91.4 \
        --set sim.sensor.full_well_e=1522 --set sim.optics.psf_sigma_px=1.28 --set sim.beam.speckle_grain=2.5625
    .venv/bin/python tools/isp_scaled.py rec/raw rec/isp
    ./dev edge replay rec/isp --score

(The --set values, `edge.sim.isp.RAW_SETTINGS`, keep the room as bright, the wells as deep, and the
blur and speckle as fine, per area of the scene, as the simulator's own 640 × 480 camera has them.)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from edge.errors import EdgeError
from edge.isp import OUT
from edge.sim.isp import scale_recording


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("raw", type=Path, help="a recording of the picam-v2-1640 camera")
    parser.add_argument("out", type=Path, help="the 640 × 480 recording to write (replaced)")
    args = parser.parse_args(argv)
    try:
        zones = scale_recording(args.raw, args.out)
    except (OSError, ValueError, EdgeError) as exc:
        print(f"isp_scaled: {args.raw / 'sweep.json'}: cannot be read as a 1640x1232 recording: {exc}",
              file=sys.stderr)
        return 2
    print(f"wrote {args.out}: {zones} zones at {OUT.width}x{OUT.height}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
