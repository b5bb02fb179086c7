"""`edge doctor`'s laser lines over conditions of the accuracy family, counted by verdict.

Each condition's camera, sensor, JPEG, light and room, with its rig built as configured (no
mounting errors: every line should be ok or, where the room hides the spot, "no spot"), aimed at
two of the condition's poses. A line that blames the wiring or the build ("active-low", "not built
as configured", "does not go off", "lies on laser …'s path": swapped wires) or the timing is a false
alarm there; with a fault given (`--set 'sim.laser_faults=[{laser="center", kind="stuck"}]'`) the
faulty laser's line should name it.

    .venv/bin/python tools/doctor_family.py --first 128 --conditions 32            # after ./dev
    .venv/bin/python tools/doctor_family.py --first 128 --conditions 16 --json out.json \\
        --set 'sim.laser_faults=[{laser="center", kind="stuck"}]'
    .venv/bin/python tools/doctor_family.py --first 0 --conditions 64 --isp    # the Pi camera's frames

`--isp` keeps the conditions whose frames are the Pi camera's ISP's (rendered live through it:
`sim.sensor.isp`), and counts the frames line's verdict on them too. `--family evaluation` runs the
evaluation family's conditions (report their counts only: no tuning looks at them one by one);
`--poses 1,6,11` aims at other poses than the two by default.

It asserts nothing: it prints the counts (and writes every line as JSON with --json).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

POSES = (4, 8)  # which of a condition's poses the unit is aimed at
KINDS = ("does not go off", "active-low", "lies on laser", "from where the rig says", "broad glow", "no spot",
         "holds", "comes about", "goes off later")


def kind(status: str, detail: str) -> str:
    if status == "ok":
        return "ok"
    return next((k for k in KINDS if k in detail), detail[:40])


def frames_kind(detail: str) -> str:
    return ("scaled" if "scaled after demosaicing" in detail
            else "demosaiced, no filter seen" if "no Bayer filter's pattern seen" in detail
            else "Bayer" if "colour filter" in detail or "Bayer filter" in detail
            else "JPEG" if "JPEG (" in detail and "not JPEG" not in detail else "other")


def one(args: tuple[str, int, int, tuple[str, ...]]) -> tuple[int, int, dict[str, list[str]]]:
    name, index, pose_index, extra = args
    from edge.accuracy.conditions import family
    from edge.config import load_config
    from edge.doctor import examine

    base = load_config(None)
    aimed = family(name, 1, index)[0].aimed(base.sim.beam.e_per_ms_at_1m, base.sim.ambient.white_e_per_ms,
                                                base.camera.frame_rate_hz, pose_index)
    result = examine(None, [*aimed, "mqtt.enabled=false", *extra])
    lines = [line for line in result.checks.lines if line.check.startswith("laser ") or line.check == "frames"]
    return index, pose_index, {
        x.check: [x.status, frames_kind(x.detail) if x.check == "frames" else kind(x.status, x.detail), x.detail]
        for x in lines}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", default="tuning", choices=("tuning", "evaluation"),
                        help="which family (default tuning; report the evaluation family's counts only)")
    parser.add_argument("--first", type=int, default=0, help="the first condition (default 0)")
    parser.add_argument("--conditions", type=int, default=32)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--set", action="append", default=[], help="a configuration override for every run")
    parser.add_argument("--json", help="write every laser line here")
    parser.add_argument("--poses", default=",".join(map(str, POSES)),
                        help=f"which of each condition's poses to aim at (default {','.join(map(str, POSES))})")
    parser.add_argument("--isp", action="store_true", help="only the conditions whose frames are the Pi camera's ISP's")
    args = parser.parse_args()
    from edge.accuracy.conditions import family

    indices = range(args.first, args.first + args.conditions)
    if args.isp:
        indices = [i for i, c in zip(indices, family(args.family, args.conditions, args.first)) if c.isp]
    poses = [int(p) for p in args.poses.split(",")]
    jobs = [(args.family, i, p, tuple(args.set)) for i in indices for p in poses]
    with ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        runs = list(pool.map(one, jobs))
    counts = Counter((check, line[1]) for _, _, lines in runs for check, line in lines.items())
    for (check, verdict), n in sorted(counts.items()):
        print(f"{check:16} {verdict:26} {n}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(runs, f, indent=0)


if __name__ == "__main__":
    main()
