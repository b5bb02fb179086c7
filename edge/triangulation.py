"""From a spot's pixel to a depth: where the camera ray through the spot meets the laser's beam.

Each laser is a known ray in the camera frame; the camera ray through its spot meets it where the
light landed, so each found spot gives a depth, with a σ propagated to first order from the spot's
pixel uncertainty (its covariance where the finder gave one). Pure: no frames, no hardware.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from edge.rig import CameraModel, Laser


# Not frozen, though never changed once made: a frozen dataclass costs 3 × as much to build
# (vision.Candidate), and every spot of every zone makes one.
@dataclass
class LaserMeasurement:
    """One laser's spot and what it says about depth."""

    laser: str
    pixel: np.ndarray  # (2,) float64
    sigma_px: float
    point_m: np.ndarray  # (3,) where the beam meets the surface, camera frame
    depth_m: float
    sigma_m: float
    snr: float
    views: int  # distinct views (speckle patterns) averaged
    beam_dir: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))  # (3,) the laser's

    def to_json(self) -> dict:
        return {
            "pixel": [round(float(c), 3) for c in self.pixel],
            "sigma_px": round(self.sigma_px, 4),
            "depth_m": round(self.depth_m, 5),
            "sigma_m": round(self.sigma_m, 5),
            "snr": round(self.snr, 1),
            "views": self.views,
        }


def triangulate(laser: Laser, camera: CameraModel, pixels: np.ndarray) -> np.ndarray:
    """Points (N, 3) on `laser`'s beam nearest to the camera rays through `pixels` (N, 2)."""
    r = camera.rays(np.atleast_2d(pixels))
    o, d = laser.o, laser.d
    c = r @ d
    s = (c * (r @ o) - d @ o) / np.maximum(1.0 - c * c, 1e-12)
    return o + s[:, None] * d


def _ray(camera: CameraModel, u: float, v: float, distorted: bool = True) -> tuple[float, float, float]:
    """Unit camera ray through pixel (u, v), in plain floats (one spot at a time, no array
    overhead); the same as ``CameraModel.rays``. `distorted`: whether the camera has distortion."""
    x, y = (u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy
    if distorted and camera.distorted:
        x, y = (float(c) for c in camera.undistort(np.array([x, y])))
    n = math.sqrt(x * x + y * y + 1.0)
    return x / n, y / n, 1.0 / n


def _on_beam(o: tuple, d: tuple, r: tuple) -> tuple[float, float, float]:
    """The point of the beam o + s·d nearest to the camera ray through the origin along r."""
    c = r[0] * d[0] + r[1] * d[1] + r[2] * d[2]
    ro = r[0] * o[0] + r[1] * o[1] + r[2] * o[2]
    do = d[0] * o[0] + d[1] * o[1] + d[2] * o[2]
    s = (c * ro - do) / max(1.0 - c * c, 1e-12)
    return o[0] + s * d[0], o[1] + s * d[1], o[2] + s * d[2]


def measure(
    laser: Laser, camera: CameraModel, pixel: np.ndarray, sigma_px: float, snr: float, views: int,
    cov_px: tuple[float, float, float] | None = None,
) -> LaserMeasurement:
    """Depth of one spot and its 1-σ uncertainty: first-order propagation of the position's
    covariance `cov_px` (var u, var v, cov uv; px²), or of `sigma_px` on each axis. The depth moves
    with the spot along the laser's path, hardly across it, so the measurement's `sigma_px` is
    the position's σ along the depth's gradient: what `sigma_m` is made of."""
    u, v = pixel.tolist()  # (plain floats: cheaper than numpy's)
    o, d = laser.origin_m, laser.direction
    if any(camera.dist):  # camera.distorted (a float is true unless 0), without its generator
        h = 0.05  # central differences: depth is strongly convex in the pixel far away

        def depth(uu: float, vv: float) -> float:
            return _on_beam(o, d, _ray(camera, uu, vv))[2]

        p = _on_beam(o, d, _ray(camera, u, v))
        dz_du = (depth(u + h, v) - depth(u - h, v)) / (2 * h)
        dz_dv = (depth(u, v + h) - depth(u, v - h)) / (2 * h)
    else:
        # _on_beam(_ray(…)) in one, for the unnormalised ray q = (x, y, 1): the beam's parameter
        # is s = (q·d q·o − d·o q·q) / (q·q − (q·d)²).
        (ox, oy, oz), (dx, dy, dz) = o, d
        fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
        do = dx * ox + dy * oy + dz * oz
        x, y = (u - cx) / fx, (v - cy) / fy
        qq, qd, qo = x * x + y * y + 1.0, x * dx + y * dy + dz, x * ox + y * oy + oz
        num, den = qd * qo - do * qq, max(qq - qd * qd, 1e-12 * qq)
        s0 = num / den
        p = (ox + s0 * dx, oy + s0 * dy, oz + s0 * dz)
        # z = oz + s·dz: its derivatives in closed form (d/du = d/dx / fx).
        dz_du = dz * ((dx * qo + qd * ox - 2.0 * do * x) - s0 * (2.0 * x - 2.0 * qd * dx)) / den / fx
        dz_dv = dz * ((dy * qo + qd * oy - 2.0 * do * y) - s0 * (2.0 * y - 2.0 * qd * dy)) / den / fy
    slope = math.hypot(dz_du, dz_dv)
    if cov_px is None or slope <= 0.0:
        sigma_m = slope * sigma_px
    else:
        var_u, var_v, cov_uv = cov_px
        sigma_m = math.sqrt(max(dz_du * dz_du * var_u + dz_dv * dz_dv * var_v + 2.0 * dz_du * dz_dv * cov_uv, 0.0))
        sigma_px = sigma_m / slope
    return LaserMeasurement(laser.name, np.array((u, v)), sigma_px, np.array(p), p[2], sigma_m, snr, views,
                            _beam_dir(laser.direction))


@functools.lru_cache(maxsize=64)
def _beam_dir(direction: tuple[float, float, float]) -> np.ndarray:
    """A laser's direction as an array, made once (LaserMeasurement.beam_dir; never written to)."""
    out = np.array(direction, dtype=np.float64)
    out.flags.writeable = False
    return out
