"""Benchmarks: measured, printed, never asserted (the machines that run tests are shared)."""

from __future__ import annotations

import functools
import math
import statistics
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from edge.config import Config

if TYPE_CHECKING:
    from edge.thesis import ThesisRig


def _median_ms(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), float(np.percentile(times, 90))


def bench_render(config: Config, repeats: int = 20) -> list[str]:
    """Time the virtual camera: a new view (ray cast and shading) and a frame of a cached view."""
    from edge.sim.record import scene_for, true_rig
    from edge.sim.render import Renderer

    renderer = Renderer(scene_for(config), true_rig(config), config.sim)
    names = {n: 1.0 for n in renderer.rig.laser_names}
    rng = np.random.default_rng(0)
    pans = iter(np.arange(repeats * 4) * 5.625)
    cam = renderer.rig.camera
    view_ms = _median_ms(lambda: renderer.render(next(pans), 0.0, {}, 0.0, rng), repeats)
    renderer.render(0.0, 0.0, {}, 0.0, rng)
    off_ms = _median_ms(lambda: renderer.render(0.0, 0.0, {}, 0.0, rng), repeats)
    on_ms = _median_ms(lambda: renderer.render(0.0, 0.0, names, 0.0, rng), repeats)
    return [
        f"render {cam.width}x{cam.height}, scene {renderer.scene.name} (median / p90 of {repeats}):",
        f"  new view (ray cast + shading + frame): {view_ms[0]:7.1f} / {view_ms[1]:.1f} ms",
        f"  frame of a cached view, lasers off:    {off_ms[0]:7.1f} / {off_ms[1]:.1f} ms",
        f"  frame of a cached view, lasers on:     {on_ms[0]:7.1f} / {on_ms[1]:.1f} ms",
    ]


def bench_ranging(config: Config, repeats: int = 200) -> list[str]:
    """Time ranging one laser-off/laser-on pair, decoded frames in memory, at 640 × 480 and at
    1640 × 1232, beside the thesis' straightforward full-frame numpy pipeline on the same frames."""
    from dataclasses import replace

    from edge import thesis
    from edge.config import CameraConfig
    from edge.ranging import FrameGroup, Ranger
    from edge.sim.record import scene_for, true_rig
    from edge.sim.render import Renderer

    lines = [f"ranging one on/off pair (median / p90 of {repeats} runs, one core):"]
    for model in ("picam-v2", "picam-v2-1640"):
        cfg = replace(config, rig=replace(config.rig, camera=CameraConfig(model=model)))
        rig = cfg.rig.build()
        renderer = Renderer(scene_for(cfg), true_rig(cfg), cfg.sim)
        rng = np.random.default_rng(0)
        pan = -90.0  # a wall in the office, about 1.3 m away
        names = {n: 1.0 for n in rig.laser_names}
        on = renderer.render(pan, 0.0, names, 0.0, rng)
        off = renderer.render(pan, 0.0, {}, 0.0, rng)
        ranger = Ranger(rig)
        group = [FrameGroup([on], [off], rig.laser_names, (pan, 0.0))]
        result = ranger.range_zone(0, pan, 0.0, group)
        ours = _median_ms(functools.partial(ranger.range_zone, 0, pan, 0.0, group), repeats)
        baseline = functools.partial(_thesis_range, thesis.thesis_rig(rig), on, off, thesis.masks(rig))
        r_thesis = baseline()
        theirs = _median_ms(baseline, max(20, repeats // 5))
        cam = rig.camera
        lines += [
            f"  {cam.width}x{cam.height}: triangulate {ours[0]:.3f} / {ours[1]:.3f} ms "
            f"(range {result.range_m:.3f} m, {result.status}); thesis full-frame "
            f"{theirs[0]:.2f} / {theirs[1]:.2f} ms (range {r_thesis:.3f} m); "
            f"{theirs[0] / ours[0]:.1f}x faster",
        ]
    return lines


def _thesis_range(t: ThesisRig, on: np.ndarray, off: np.ndarray, boxes: dict[str, np.ndarray]) -> float:
    """The thesis' pipeline on one 8-bit pair: full-frame spots, then its formula (nan: a spot is missing)."""
    from edge import thesis

    p = thesis.spot_positions(on, off, boxes, 0.08 * 255)
    pc, pp, ps = p.get(t.center.name), p.get(t.parallel.name), p.get(t.sloped.name)
    if pc is None or pp is None or ps is None:
        return math.nan
    return thesis.thesis_range(t, pc, pp, ps)


def bench_blindaid(config: Config, repeats: int = 3) -> list[str]:
    """Latency of the blind aid on the simulated rig: from the end of the exposure of the frame
    that shows an obstacle to the first sample of its cue's sound. Every zone counts as if it
    changed the cue (the chunk boundary its cue would start at), and the cues that really changed
    are reported apart. A live sound card adds the lead and its buffer, reported as such."""
    from dataclasses import replace

    from edge.modes.blindaid.logic import BlindAid, Cue
    from edge.modes.blindaid.runner import BlindAidRunner
    from edge.parts import open_parts
    from edge.ranging import ZoneResult

    config = replace(config, audio=replace(config.audio, out=""))
    chunk = config.audio.chunk_ms / 1000
    per_zone: list[float] = []
    with open_parts(config) as parts:
        runner = BlindAidRunner(config, parts, on_cue=lambda cue: None)

        class TimedAid(BlindAid):
            def update(self, result: ZoneResult, t_s: float, seen_s: float | None = None) -> Cue | None:
                cue = super().update(result, t_s, seen_s)
                frame_t = (runner.sweeper.last_frame_end_ns - runner._t0_ns) / 1e9
                start = -(-runner.now() // chunk) * chunk  # the chunk boundary its sound would start at
                per_zone.append(start - frame_t)
                return cue

        runner.aid = TimedAid(config.blindaid)  # as fresh as the runner's own: nothing has run yet
        for _ in range(repeats):
            runner.scan(lambda: False)
        real = runner.sound_latencies_s()
        runner.close()
    ms = np.array(per_zone) * 1e3
    live = config.audio.lead_ms + 2 * config.audio.lead_ms  # lead + the aplay buffer (2 × lead)
    lines = [
        f"blind aid, {len(per_zone)} zones over {repeats} fan passes (chunk {config.audio.chunk_ms:g} ms):",
        f"  frame end → cue sound in the stream: median {np.median(ms):.1f} ms, p95 "
        f"{np.percentile(ms, 95):.1f} ms, max {ms.max():.1f} ms",
        f"  on a sound card add the lead and buffer ({live:g} ms): max {ms.max() + live:.1f} ms",
    ]
    if real:
        lines.append(f"  cues that changed ({len(real)}): " + ", ".join(f"{1e3 * x:.1f}" for x in real) + " ms")
    return lines
