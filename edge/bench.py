"""Benchmarks: measured, printed, never asserted (the machines that run tests are shared)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from edge.config import Config


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
