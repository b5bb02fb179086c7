"""The physical floor of each zone of a simulated recording, from the renderer that made its frames:
what :mod:`edge.accuracy.floor` needs of each spot (its true pixel, shape, photo-electrons, the room
light under it, its speckle), gathered while the zone is recorded and written into its `truth`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from edge.accuracy.floor import Floor, Sensor, Spot, depth_gradient, fused_sigma, speckle_covariance, spot_floor
from edge.config import Config
from edge.sim.optics import SPECKLE_KMAX, SPECKLE_WAVES
from edge.sim.record import ExtraTruth
from edge.sim.render import Renderer


def sensor_of(config: Config) -> Sensor:
    """The simulated sensor's noise, as the floor takes it."""
    s = config.sim.sensor
    return Sensor.of(s.full_well_e, s.read_noise_e, s.adc_bits, s.output_bits, config.camera.analogue_gain,
                     bayer=s.colour and s.bayer != "none")


def zone_floors(renderer: Renderer, sensor: Sensor, views: Sequence[tuple[float, float]], t_s: float = 0.0
                ) -> tuple[dict[str, Floor], dict]:
    """The floor of each laser whose spot the camera sees, from the zone's pair `views` (pan, tilt),
    and the floor of the zone's range: ``{"sigma_m", "reference_sigma_m", "used"}`` (``used``: the
    lasers on the reference's surface; sigmas None when the reference is not visible)."""
    out: dict[str, Floor] = {}
    truths = {}
    rig = renderer.rig
    for laser in rig.lasers:
        models = [m for pan, tilt in views if (m := renderer.spot_model(pan, tilt, laser.name, t_s)) is not None]
        if not models:
            continue
        spots = [Spot(m.truth.pixel, m.covariance, m.total_e, m.response, m.background.electrons,
                      m.background.x0, m.background.y0) for m in models if m.truth.pixel is not None]
        first = models[0]
        assert first.truth.pixel is not None  # spot_model gives visible spots only
        speckle = speckle_covariance(first.covariance, first.speckle_contrast, SPECKLE_KMAX / first.speckle_grain,
                                     SPECKLE_WAVES)
        distinct = len({m.speckle_key for m in models})
        gradient = depth_gradient(laser, rig.camera, first.truth.pixel)
        out[laser.name] = spot_floor(spots, sensor, speckle, distinct, gradient)
        truths[laser.name] = first.truth
    ref = rig.reference.name
    zone: dict = {"sigma_m": None, "reference_sigma_m": None, "used": []}
    if ref in out:
        mine = truths[ref]
        assert mine.point_camera is not None and mine.normal_world is not None
        same = [n for n in out if truths[n].face_key == mine.face_key and truths[n].point_camera is not None]
        same.sort(key=lambda n: n != ref)  # the reference first
        pan, tilt = views[0]
        normal = renderer.camera_to_world(pan, tilt).inverse().rotate(mine.normal_world)
        fused = fused_sigma(np.array([truths[n].point_camera for n in same]),
                            np.array([out[n].sigma_m for n in same]),
                            np.array([rig.laser(n).d for n in same]), normal)
        zone = {"sigma_m": _finite(fused), "reference_sigma_m": _finite(out[ref].sigma_m), "used": same}
    return out, zone


def _finite(x: float) -> float | None:
    return round(x, 7) if np.isfinite(x) else None


def floor_truth(config: Config) -> ExtraTruth:
    """For :func:`edge.sim.record.record_sweep`: each zone's truth gains ``floor``: the zone's range
    floor (``sigma_m``: all spots on the reference's surface; ``reference_sigma_m``: its spot alone;
    ``used``: the lasers that gives) and, under ``lasers``, each visible laser's floor
    (:meth:`edge.accuracy.floor.Floor.to_json`)."""
    sensor = sensor_of(config)

    def extra(renderer: Renderer, views: list[tuple[float, float]], t_s: float) -> dict:
        floors, zone = zone_floors(renderer, sensor, views, t_s)
        return {"floor": {**zone, "lasers": {n: f.to_json() for n, f in floors.items()}}}

    return extra
