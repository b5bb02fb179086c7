"""Ranging with the room turned between the laser-on and laser-off frames, with and without
`edge.motion`'s steadier: the table of docs/ranging.md ("The room moving between the frames").

One pair a zone over the simulated scene's 64 zones; the laser-off frame rendered with the camera
turned by each given angle in pan and 0.4 × that in tilt. Prints, per angle, the `ok` zones, the
mean |error| against the simulator's truth and the wrong `ok` (over 10 %), before (steadier
bypassed) → after.

    .venv/bin/python tools/motion_turns.py                    # 0, 0.05, 0.1, 0.2, 0.5, 1, 2 degrees
    .venv/bin/python tools/motion_turns.py 0.5 1 --set sim.sensor.isp=true --set 'sim.sensor.bayer="ea"'

It asserts nothing (tests/test_motion.py does).
"""

from __future__ import annotations

import argparse

import numpy as np

from edge.config import load_config
from edge.ranging import FrameGroup, Ranger
from edge.sim.record import scene_for, true_rig
from edge.sim.render import Renderer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("degrees", nargs="*", type=float, default=[0, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0])
    parser.add_argument("--set", action="append", default=[], help="a configuration override")
    args = parser.parse_args()
    config = load_config("config/sim.toml", args.set)
    rig = config.rig.build()
    renderer = Renderer(scene_for(config), true_rig(config), config.sim)
    lit = {n: 1.0 for n in rig.laser_names}
    pans = [-180 + i * 360 / 64 for i in range(64)]
    truth = {}
    for p in pans:
        spot = renderer.spots(p, 0.0)[rig.reference.name]
        truth[p] = spot.depth_m if spot.visible else None
    for turned in args.degrees:
        row = []
        for steady in (False, True):
            rng = np.random.default_rng(1)  # (the same frames for both)
            ranger = Ranger(rig)
            if not steady:
                ranger.steadied = lambda groups: list(groups)  # type: ignore[method-assign]
            ok, errors, wrong = 0, [], 0
            for i, p in enumerate(pans):
                on = renderer.render(p, 0.0, lit, 0.0, rng)
                off = renderer.render(p + turned, 0.4 * turned, {}, 0.0, rng)
                result = ranger.range_zone(i, p, 0.0, [FrameGroup([on], [off], rig.laser_names, (p, 0.0))])
                if result.status == "ok" and truth[p] and result.range_m is not None:
                    ok += 1
                    error = abs(result.range_m - truth[p]) / truth[p]
                    errors.append(error)
                    wrong += error > 0.1
            row.append((ok, 100 * float(np.mean(errors)) if errors else float("nan"), wrong))
        px = rig.camera.fx * np.radians(turned)
        print(f"{turned:g}° pan, {0.4 * turned:g}° tilt ({px:.1f} px): ok {row[0][0]} → {row[1][0]}, "
              f"mean |error| {row[0][1]:.2f} % → {row[1][1]:.2f} %, wrong {row[0][2]} → {row[1][2]}", flush=True)


if __name__ == "__main__":
    main()
