"""Where ranging one 640 × 480 on/off pair spends its time (issue 15's speed target).

The same pair as ``edge bench ranging`` (the office, a wall about 1.3 m away, every laser on), so that
its figures and these agree:

    .venv/bin/python tools/ranging_speed.py time              # fastest and median, edge and thesis
    .venv/bin/python tools/ranging_speed.py stages            # fastest time of each stage, alone

A machine shared with other work makes wall times noisy; an instruction count is not. Count K
calls and none, and take the difference (callgrind's total includes start-up and set-up; the
garbage collector is off while counting). One BLAS thread, as ./dev sets: idle BLAS threads spin,
and callgrind counts their spinning too.

    .venv/bin/python -m compileall -q edge    # else the first run also counts compiling
    export OPENBLAS_NUM_THREADS=1 PYTHONHASHSEED=0
    for k in 0 30; do valgrind --tool=callgrind --callgrind-out-file=/dev/null \\
        .venv/bin/python tools/ranging_speed.py count --calls $k 2>&1 | grep Collected; done

Every stage's time is the fastest of many runs of that stage alone, on the pair's own inputs: the
stages add up to a little less than the whole (each runs with a warm cache). It prints; it asserts
nothing.
"""

from __future__ import annotations

import argparse
import functools
import gc
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from edge import thesis, vision
from edge.bench import _interleaved_ms, _thesis_range
from edge.config import CameraConfig, load_config
from edge.fusion import best_fusion, level_slopes
from edge.paths import Strips
from edge.ranging import FrameGroup, Ranger
from edge.sim.record import scene_for, true_rig
from edge.sim.render import Renderer
from edge.vision import SpotFinder

PAN = -90.0  # as bench_ranging: a wall in the office, about 1.3 m away
# The `auto` channel measures the frames' chroma in a finder's first groups: past them, every
# call does the same work.
WARM_UP = 10


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("what", choices=("time", "stages", "count"))
    p.add_argument("--repeats", type=int, default=3000, help="runs of each timed call (time, stages)")
    p.add_argument("--calls", type=int, default=30, help="calls of the ranging (count)")
    args = p.parse_args()

    config = load_config(None, [])
    config = replace(config, rig=replace(config.rig, camera=CameraConfig(model="picam-v2")))
    rig = config.rig.build()
    renderer = Renderer(scene_for(config), true_rig(config), config.sim)
    rng = np.random.default_rng(0)
    on = renderer.render(PAN, 0.0, {n: 1.0 for n in rig.laser_names}, 0.0, rng)
    off = renderer.render(PAN, 0.0, {}, 0.0, rng)
    ranger = Ranger(rig)
    groups = [FrameGroup([on], [off], rig.laser_names, (PAN, 0.0))]
    ours = functools.partial(ranger.range_zone, 0, PAN, 0.0, groups)
    for _ in range(WARM_UP):
        ours()

    if args.what == "count":
        # A cyclic collection costs millions of instructions and comes whenever the count of
        # allocations says, in one run's K calls and not in another's: off, the counts repeat.
        gc.disable()
        for _ in range(args.calls):
            ours()
        return
    if args.what == "time":
        theirs = functools.partial(_thesis_range, thesis.thesis_rig(rig), on, off, thesis.masks(rig))
        # Both under the same load (as `edge bench ranging`): 10 rounds, a tenth as many of theirs.
        a, b = _interleaved_ms([(ours, max(1, args.repeats // 10)), (theirs, max(2, args.repeats // 100))], 10)
        print(f"edge   fastest {1e3 * a[2]:8.1f} µs, median {1e3 * a[0]:8.1f} µs")
        print(f"thesis fastest {1e3 * b[2]:8.1f} µs, median {1e3 * b[0]:8.1f} µs")
        print(f"thesis / edge: {b[2] / a[2]:.1f} × (fastest), {b[0] / a[0]:.1f} × (median)")
        return
    stages(ranger, groups, args.repeats)


# SpotFinder.find's steps: where each is looked up when find calls it, and its name there.
STEPS = ((Strips, "gather"), (SpotFinder, "_texture"), (vision, "local_noise"), (SpotFinder, "_seeds"),
         (SpotFinder, "_refine"))


def stages(ranger: Ranger, groups: list[FrameGroup], repeats: int) -> None:
    """Each stage alone, on the inputs it has in the whole (the finder's steps seen by wrapping
    them for one call)."""
    finder, group, rig = ranger.finder, groups[0], ranger.rig
    originals = {name: getattr(owner, name) for owner, name in STEPS}
    calls: dict[str, list[tuple]] = {name: [] for _, name in STEPS}

    def recording(name: str) -> Callable:
        def step(*a, **k):
            calls[name].append((a, k))
            return originals[name](*a, **k)
        return step

    for owner, name in STEPS:
        setattr(owner, name, recording(name))
    try:
        ranger.range_zone(0, PAN, 0.0, groups)
    finally:
        for owner, name in STEPS:
            setattr(owner, name, originals[name])

    def each(name: str) -> Callable[[], object]:
        return lambda: [originals[name](*a, **k) for a, k in calls[name]]

    found = finder.find(group.on, group.off, group.lasers)
    tracks = ranger._tracks(groups)
    cands = {n: [ranger._measure(t) for t in ts] for n, ts in tracks.items()}
    ref = rig.reference.name
    others = {n: ms for n, ms in cands.items() if n != ref}
    known = level_slopes(rig.camera_to_base(PAN, 0.0))
    rows: list[tuple[str, Callable[[], object]]] = [
        ("range_zone, the whole", lambda: ranger.range_zone(0, PAN, 0.0, groups)),
        ("  SpotFinder.find", lambda: finder.find(group.on, group.off, group.lasers)),
        ("    gather strips and background (on, off)", each("gather")),
        ("    noise texture", each("_texture")),
        ("    local noise and matched filter", each("local_noise")),
        (f"    seeds ({len(calls['_seeds'])} paths)", each("_seeds")),
        (f"    place spots ({len(calls['_refine'])} windows)", each("_refine")),
        ("  deblend", lambda: ranger._deblend(group, {k: list(v) for k, v in found.items()})),
        ("  spots to depths (measure)", lambda: [ranger._measure(t) for ts in tracks.values() for t in ts]),
        ("  pose and known slopes", lambda: level_slopes(rig.camera_to_base(PAN, 0.0))),
        ("  fusion", lambda: best_fusion(rig, cands[ref][0], others, 0.05, known)),
    ]
    print(f"{'stage':48s} fastest of {repeats} (µs)")
    for label, fn in rows:
        print(f"{label:48s} {1e3 * _interleaved_ms([(fn, repeats)], 1)[0][2]:8.1f}")


if __name__ == "__main__":
    main()
