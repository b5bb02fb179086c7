#!/usr/bin/env python3
"""Issue 18's map targets, measured on simulated recordings against the scenes' truth.

    ./dev edge sim record --scene office --out rec/o1 --frames 2 --seed 1     # and seeds 2, 3
    ./dev edge sim record --scene kitchen --out rec/k1 --frames 2 --seed 1    # and seeds 2, 3
    ./dev edge sim record --scene office --out rec/o3d --frames 4 --set 'sweep.tilts_deg=[-40.0,-20.0,0.0,15.0,30.0]'
    ./dev edge sim record --scene kitchen --out rec/k3d --frames 4 --set 'sweep.tilts_deg=[-40.0,-20.0,0.0,15.0,30.0]'
    ./dev edge sim record --scene office --out rec/o8 --frames 4 \
        --set 'sweep.tilts_deg=[-40.0,-30.0,-20.0,-10.0,0.0,10.0,20.0,30.0]'    # 8 levels 10° apart
    .venv/bin/python tools/map_targets.py --grid office rec/o1 rec/o2 rec/o3 --grid kitchen rec/k1 rec/k2 rec/k3
    .venv/bin/python tools/map_targets.py --cloud office rec/o3d --cloud kitchen rec/k3d --cloud office rec/o8

--grid SCENE DIR…: the sweeps fused into one 5 cm grid, scored (occupied near a surface, surface
cells occupied, cells along rays free). --cloud SCENE DIR: one scan's cloud, scored (points'
error against the truth relative to range, normals on walls and floor, and the given normals'
median and worst angle there and on the other surfaces); `--frames 4` is the
configured two frame pairs a zone, what `edge sweep` takes (`--frames 2`, one pair, is noisier).
The normals depend on the noise: record each scan with two seeds or more (`--seed 2`) and measure
each. --worst N lists the cloud's N points farthest from the truth, for whoever looks into ranging.
--out DIR writes each map's files there as `edge map` does.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from edge.cloud import scan_cloud
from edge.config import load_config
from edge.grid import GridConfig
from edge.maps import Scan, build_map, write_map
from edge.ranging import OK
from edge.recording import read_recording
from edge.replay import Replayer
from edge.sim.map_truth import on_wall_or_floor, score_cloud, score_grid
from edge.sim.record import true_rig
from edge.sim.render import Renderer
from edge.sim.scene import load_scene, scene_dir


def ranged(path: str):
    rec = read_recording(path)
    config = load_config()
    results = list(Replayer(rec.rig, "triangulate", config.ranging).zones(rec))
    return rec, results


def normal_errors(given: np.ndarray, true: list, flat: list[bool]) -> str:
    """The given normals' angles from the true ones: median and worst on walls and floor, and on
    the other surfaces (furniture, appliances: not scored, but a wrong normal there is as wrong)."""
    parts = []
    for name, on in (("walls and floor", True), ("other surfaces", False)):
        angles = [math.degrees(math.acos(float(np.clip(n @ t, -1.0, 1.0))))
                  for n, t, f in zip(given, true, flat) if f == on and t is not None and np.linalg.norm(n) > 0.5]
        seen = sum(1 for t, f in zip(true, flat) if f == on and t is not None)
        figures = f", median {np.median(angles):.1f}°, worst {max(angles):.1f}°" if angles else ""
        parts.append(f"{name} {len(angles)} of {seen}{figures}")
        if on:
            parts[-1] = "normals given: " + parts[-1]
    return "; ".join(parts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", nargs="+", action="append", default=[], metavar="SCENE DIR")
    ap.add_argument("--cloud", nargs=2, action="append", default=[], metavar=("SCENE", "DIR"))
    ap.add_argument("--resolution", type=float, default=0.05)
    ap.add_argument("--out", help="write each map's files into OUT/<scene>[-3d]")
    ap.add_argument("--worst", type=int, default=0, metavar="N", help="list the cloud's N worst points")
    args = ap.parse_args()
    for scene_name, *dirs in args.grid:
        scene = load_scene(scene_name, [scene_dir()])
        scans, scored = [], []
        for d in dirs:
            rec, results = ranged(d)
            scans.append(Scan(d, rec.rig, results))
            scored.append((results, [z.truth for z in rec.zones]))
        grid, cloud = build_map(GridConfig(resolution_m=args.resolution), scans)
        score = score_grid(grid, scene, scans[0].rig, scored)
        print(f"{scene_name}, {len(dirs)} sweeps, {args.resolution * 100:g} cm:")
        for line in score.lines():
            print("  " + line)
        if args.out:
            write_map(Path(args.out) / scene_name, grid, cloud, title=f"{scene_name}, {len(dirs)} sweeps")
    for scene_name, d in args.cloud:
        scene = load_scene(scene_name, [scene_dir()])
        config = load_config(None, [f"sim.scene={scene_name!r}".replace("'", '"')])
        rec, results = ranged(d)
        cloud = scan_cloud(rec.rig, results)
        ok = [(r, z) for r, z in zip(results, rec.zones) if r.status == OK and r.point_base_m is not None]
        renderer = Renderer(scene, true_rig(config), config.sim, config.camera)
        to_base = scene.base_to_world().inverse()
        truths, normals, flat = [], [], []
        ref = rec.rig.reference.name
        for r, z in ok:
            truths.append(z.truth)
            spot = renderer.spots(r.pan_deg, r.tilt_deg)[ref]
            normals.append(None if spot.normal_world is None else to_base.rotate(spot.normal_world))
            flat.append(spot.point_world is not None and on_wall_or_floor(scene, spot.point_world))
        score = score_cloud(cloud.points, cloud.normals, truths, normals, flat)
        tilts = sorted({z.tilt_deg for z in rec.zones})
        print(f"{scene_name} 3D scan, tilts {tilts}, {len(rec.zones)} zones, {len(ok)} ok:")
        for line in score.lines():
            print("  " + line)
        print("  " + normal_errors(cloud.normals, normals, flat))
        within = [abs(r.range_m - z.truth["range_m"]) <= 2 * (r.sigma_m or 0.0) for r, z in ok]
        print(f"  ranges within 2σ of the truth: {sum(within)} of {len(within)} "
              f"({100 * sum(within) / max(len(within), 1):.0f} %; the contract's σ: 95 %)")
        worst = sorted(((r, z.truth) for r, z in ok), reverse=True,
                       key=lambda rz: abs(rz[0].range_m - rz[1]["range_m"]) / rz[1]["range_m"])
        for r, truth in worst[:args.worst]:
            true_m = truth["range_m"]
            err = r.range_m - true_m
            alone = r.lasers[ref].depth_m if ref in r.lasers else math.nan
            print(f"  zone {r.index}: pan {r.pan_deg:.2f}°, tilt {r.tilt_deg:.2f}°, range {r.range_m:.3f} m, "
                  f"true {true_m:.3f} m ({100 * err / true_m:+.2f} %, {err / (r.sigma_m or 1e-9):+.1f} σ; "
                  f"{ref} alone {100 * (alone - true_m) / true_m:+.2f} %), lasers {'+'.join(sorted(r.lasers))}, "
                  f"true point z {truth['point_base_m'][2]:+.2f} m")
        if args.out:
            grid, _ = build_map(GridConfig(resolution_m=args.resolution), [Scan(d, rec.rig, results)])
            write_map(Path(args.out) / f"{scene_name}-3d", grid, cloud, title=f"{scene_name} 3D scan")
    return 0


if __name__ == "__main__":
    sys.exit(main())
