"""Simulated sweeps written as `edge-sweep/1` recordings, with the truth for every zone.

The virtual rig takes, for each zone, ``pairs`` laser-off/laser-on frame pairs on a frame clock,
nudging the pan by ``sweep.nudge_deg`` between pairs so that each pair sees fresh speckle, exactly
as the device does. The recording carries the *nominal* rig (what the device believes); the frames
and the truth come from the *true* rig, which differs when ``sim.rig_error`` says so.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from edge.config import Config, resolve_path
from edge.recording import RecordingWriter
from edge.rig import Rig
from edge.sim.render import Renderer, SpotTruth, perturb_rig
from edge.sim.scene import DevicePlacement, Scene, SceneSpec, load_scene, scene_dir

log = logging.getLogger(__name__)

# More truth for a zone: given the renderer, the views of the zone's frame pairs (pan, tilt) and the
# zone's time, a dict merged into the zone's `truth` (e.g. the physical floor, edge.accuracy.truth).
ExtraTruth = Callable[[Renderer, list[tuple[float, float]], float], dict]

# The lasers switch this long before a frame's exposure starts (they settle well within it).
_SWITCH_LEAD_NS = 2_000_000


def scene_for(config: Config) -> Scene:
    """The scene named by ``sim.scene``: a shipped name, or a path relative to the config file."""
    name = config.sim.scene
    if name.endswith(".toml"):
        return load_scene(str(resolve_path(config, name)))
    return load_scene(name, [scene_dir()])


def true_rig(config: Config) -> Rig:
    return perturb_rig(config.rig.build(), config.sim.rig_error)


def zone_truth(rig: Rig, spots: dict[str, SpotTruth], pose_to_base) -> dict:
    """The `truth` object of a zone: the reference laser's point, and each laser's spot."""
    ref = spots[rig.reference.name]
    truth: dict = {"range_m": None, "point_m": None}
    if ref.point_camera is not None:
        p = ref.point_camera
        truth["range_m"] = round(float(p[2]), 6)
        truth["point_m"] = [round(float(c), 6) for c in p]
        truth["point_base_m"] = [round(float(c), 6) for c in pose_to_base.apply(p)]
    truth["lasers"] = {
        name: {
            "visible": s.visible,
            "why": s.why,
            "range_m": None if s.depth_m is None else round(s.depth_m, 6),
            "pixel": None if s.pixel is None else [round(float(c), 4) for c in s.pixel],
        }
        for name, s in spots.items()
    }
    return truth


def flat_target_scene(distance_m: float, material: str = "paint-white") -> Scene:
    """A flat wall squarely in front of the rig at pan 0, tilt 0, `distance_m` from the pan-tilt
    axes along base x: the calibration target, and the simplest test of a range finder."""
    width, back, height = 8.0, 1.0, 3.0
    spec = SceneSpec(
        name=f"target-{distance_m:g}m",
        height_m=height,
        outline_m=((-back, -width / 2), (distance_m, -width / 2), (distance_m, width / 2), (-back, width / 2)),
        device=DevicePlacement((0.0, 0.0, 1.5)),
        wall_material=material,
    )
    return Scene(spec, f"<flat target at {distance_m:g} m>")


def record_sweep(
    config: Config,
    out: Path,
    zones: int | None = None,
    pairs: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    extra_truth: ExtraTruth | None = None,
    rig: Rig | None = None,
) -> Path:
    """Simulate one sweep of `config` and write it to `out`. Returns `out`. `rig` is the rig as
    built (default: the configuration's with ``sim.rig_error``)."""
    sweep = config.sweep
    if zones is not None:
        sweep = replace(sweep, zones=zones, poses_deg=())
    scene = scene_for(config)
    renderer = Renderer(scene, true_rig(config) if rig is None else rig, config.sim, config.camera)
    views = [(renderer, pan, tilt) for pan, tilt in sweep.poses()]
    return _record(config, out, views, pairs or sweep.pairs_per_zone, f"sim-{scene.name}", progress, extra_truth)


def record_targets(
    config: Config,
    distances_m: list[float],
    out: Path,
    pairs: int | None = None,
    material: str = "paint-white",
    progress: Callable[[int, int], None] | None = None,
    extra_truth: ExtraTruth | None = None,
    rig: Rig | None = None,
) -> Path:
    """Zone i shows a flat target squarely at distances_m[i] (pan 0, tilt 0): what `edge calibrate`
    takes, and the wall test of the ranging targets. `rig` is the rig as built (default: the
    configuration's with ``sim.rig_error``), for a caller that builds its own mounting errors."""
    rig = true_rig(config) if rig is None else rig
    views = [(Renderer(flat_target_scene(d, material), rig, config.sim, config.camera), 0.0, 0.0) for d in distances_m]
    return _record(config, out, views, pairs or config.sweep.pairs_per_zone, "sim-target", progress, extra_truth)


def _record(
    config: Config,
    out: Path,
    views: list[tuple[Renderer, float, float]],
    pairs: int,
    device: str,
    progress: Callable[[int, int], None] | None,
    extra_truth: ExtraTruth | None = None,
) -> Path:
    camera = config.camera
    frame_ns = camera.frame_ns
    exposure_ns = int(camera.exposure_us * 1000)
    clock_ns = 0
    with RecordingWriter(out, config.rig.build(), device=device, frame_gamma=config.sim.sensor.gamma) as writer:
        for index, (renderer, pan, tilt) in enumerate(views):
            names = list(renderer.rig.laser_names)
            frames: list[tuple[np.ndarray, list[str], dict]] = []
            turns: list[list[float]] = []  # each laser-off frame's turn (sim.sway.jolt_deg)
            zone_t_s = clock_ns / 1e9
            for nudge in config.sweep.nudges_deg(pairs):
                frame_pan = pan + nudge
                for lit in (False, True):
                    t_s = clock_ns / 1e9
                    seed = [config.sim.seed, index, len(frames)]
                    lasers = {n: 1.0 for n in names} if lit else {}
                    if not lit:  # (what render will draw first from the same generator)
                        turns.append([round(a, 9) for a in renderer.jolt(lasers, np.random.default_rng(seed))])
                    image = renderer.render(frame_pan, tilt, lasers, t_s, np.random.default_rng(seed))
                    extra: dict = {
                        "t_start_ns": clock_ns,
                        "exposure_us": camera.exposure_us,
                        "laser_switch_ns": clock_ns - _SWITCH_LEAD_NS,
                    }
                    if nudge:
                        extra["pan_deg"] = round(frame_pan, 9)
                    frames.append((image, names if lit else [], extra))
                    clock_ns += frame_ns
            spots = renderer.spots(pan, tilt, zone_t_s)
            truth = zone_truth(renderer.rig, spots, renderer.rig.camera_to_base(pan, tilt))
            if any(any(turn) for turn in turns):
                # The turn that no estimator is told (edge.motion finds it): a bench can take it
                # out exactly, to judge what the frames hold apart from the motion.
                truth["off_turn_deg"] = turns
            if extra_truth is not None:
                pair_views = [(pan + nudge, tilt) for nudge in config.sweep.nudges_deg(pairs)]
                truth.update(extra_truth(renderer, pair_views, zone_t_s))
            writer.add_zone(index, pan, tilt, frames, truth)
            clock_ns += exposure_ns  # the unit moves between zones; the clock only needs to advance
            if progress:
                progress(index + 1, len(views))
    log.info("wrote %d zones to %s", len(views), out)
    return out
