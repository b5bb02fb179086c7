"""`edge map`: recordings and sweep results fused into an occupancy grid and a point cloud."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from edge.cli.common import add_config_options, load, usage


def add_parser(sub: Any) -> None:
    p = sub.add_parser("map", help="fuse recordings and sweep.json files into map.pgm/.yaml/.png and cloud.ply")
    p.add_argument("sources", nargs="+", metavar="SOURCE",
                   help="a recording (edge-sweep/1 folder) or a sweep.json of edge sweep/demo (edge-ranges/1)")
    p.add_argument("--out", required=True, help="folder for map.pgm, map.yaml, map.png and cloud.ply")
    p.add_argument("--resolution", type=float, metavar="M", help="cell size in metres (default: map.resolution_m)")
    add_config_options(p)
    p.set_defaults(func=cmd_map)


def cmd_map(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from edge.errors import UsageError
    from edge.fsutil import check_output
    from edge.maps import MAP_FILES, build_map, read_scan, write_map

    config = load(args)
    grid_config = config.map
    if args.resolution is not None:
        if not 0.005 <= args.resolution <= 1.0:
            raise usage(f"--resolution: must be 0.005-1 m, got {args.resolution:g}")
        grid_config = replace(grid_config, resolution_m=args.resolution)
    out = Path(args.out)
    check_output(out, "--out", folder=True, error=UsageError)
    for name in MAP_FILES:
        check_output(out / name, "--out", error=UsageError)
    rig = config.rig.build()
    scans = [read_scan(source, rig, config.ranging) for source in args.sources]
    grid, cloud = build_map(grid_config, scans)
    rays = sum(len(s.results) for s in scans)
    title = f"{len(scans)} sweep{'s' if len(scans) != 1 else ''}, {rays} zones"
    write_map(out, grid, cloud, title=title)
    occupied, free = int(grid.occupied().sum()), int(grid.free().sum())
    print(f"{title}: {len(cloud)} points; grid {grid.size} x {grid.size} cells of {grid.resolution:g} m, "
          f"{occupied} occupied, {free} free")
    print("wrote " + ", ".join(str(out / name) for name in MAP_FILES))
    return 0
