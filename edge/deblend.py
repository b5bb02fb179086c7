"""Two lasers' spots merged into one blob, placed together on their paths.

Far away, and on small cameras sooner, the `center` and `parallel` spots come within a spot's width
of each other (3.5 px at 2.7 m on a 352 × 288 camera): the finder sees one blob, whose windowed
centroid lies between the two spots and so on neither path, or is given to one laser off by a pixel
or more. But each spot lies on its laser's path, a curve the rig fixes: two spots on two known paths
have one unknown each (the inverse depth) besides their brightness. A sum of two Gaussians of one
width on a flat background, fitted with that constraint, separates them where a free fit could not.

Pure: a difference window and the rig's geometry in, placed spots out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from edge.rig import CameraModel, Laser

# A blob this near another laser's path (px) may hold that laser's spot too.
DEBLEND_PX = 5.0
_ITERATIONS = 25


@dataclass(frozen=True)
class Placed:
    """One spot of a pair fitted together."""

    laser: str
    pixel: np.ndarray  # (2,) (u, v)
    sigma_px: float  # 1 σ along its path, from the fit's covariance and residual
    inv_depth: float  # 1/m along its laser's beam
    snr: float  # the spot's peak over the fit's residual noise
    size_px: float  # the Gaussians' shared σ
    peak: float = 0.0  # the spot's fitted peak (the window's units)


def _pixel(laser: Laser, camera: CameraModel, w: float) -> np.ndarray:
    return camera.project(laser.point_at_depth(np.array([1.0 / w])))[0]


def place_pair(diff: np.ndarray, origin: tuple[int, int], lasers: tuple[Laser, Laser], camera: CameraModel,
               guess: tuple[float, float], bounds: tuple[float, float]) -> tuple[Placed, Placed] | None:
    """Fit two spots, one on each laser's path, to the difference window `diff` whose pixel (0, 0)
    is image pixel `origin` (u, v). `guess`: each spot's inverse depth to start from; `bounds`:
    the inverse depths the paths are searched over. None if the fit does not settle, a spot leaves
    the window, or the shapes are not spots."""
    h, w = diff.shape
    vs, us = np.mgrid[0:h, 0:w]
    us = (us + origin[0]).astype(np.float64).ravel()
    vs = (vs + origin[1]).astype(np.float64).ravel()
    y = diff.astype(np.float64).ravel()
    lo, hi = bounds
    ws = [min(max(g, lo), hi) for g in guess]
    bg = float(np.median(np.concatenate([diff[0], diff[-1], diff[:, 0], diff[:, -1]])))
    sigma = 1.0
    peaks = []
    for laser, wi in zip(lasers, ws):
        p = _pixel(laser, camera, wi)
        iu, iv = int(round(p[0])) - origin[0], int(round(p[1])) - origin[1]
        peaks.append(max(float(diff[min(max(iv, 0), h - 1), min(max(iu, 0), w - 1)]) - bg, 1e-6))
    theta = np.array([peaks[0], peaks[1], ws[0], ws[1], math.log(sigma), bg])
    J = np.zeros((y.size, 6))
    for _ in range(_ITERATIONS):
        model, J, scale = _model(theta, lasers, camera, us, vs, J)
        step = np.linalg.lstsq(J, y - model, rcond=None)[0]
        # Inverse depth moves the spot by px per (1/m) that vary a lot along a path: cap a step at
        # about a pixel, so that the fit walks rather than jumps.
        for k in range(2):
            limit = 1.0 / max(scale[k], 1e-9)
            step[2 + k] = min(max(step[2 + k], -limit), limit)
        theta = theta + step
        theta[2] = min(max(theta[2], lo), hi)
        theta[3] = min(max(theta[3], lo), hi)
        theta[4] = min(max(theta[4], math.log(0.3)), math.log(4.0))
        moved = max(abs(step[2 + k]) * scale[k] for k in range(2))
        if moved < 1e-3:
            break
    else:
        return None
    model, J, scale = _model(theta, lasers, camera, us, vs, J)
    dof = y.size - 6
    resid = float(((y - model) ** 2).sum()) / max(dof, 1)
    if resid <= 0.0 or theta[0] <= 0.0 or theta[1] <= 0.0:
        return None
    try:
        cov = np.linalg.inv(J.T @ J) * resid
    except np.linalg.LinAlgError:
        return None
    noise = math.sqrt(resid)
    size = math.exp(theta[4])
    out = []
    for k, laser in enumerate(lasers):
        wk = float(theta[2 + k])
        p = _pixel(laser, camera, wk)
        rel = p - np.array(origin, dtype=np.float64)
        if not (0.0 <= rel[0] <= w - 1 and 0.0 <= rel[1] <= h - 1):
            return None  # a spot outside the window: not this blob's
        sigma_px = math.sqrt(max(float(cov[2 + k, 2 + k]), 0.0)) * scale[k]
        out.append(Placed(laser.name, p, sigma_px, wk, float(theta[k]) / noise, size, float(theta[k])))
    return out[0], out[1]


def _model(theta: np.ndarray, lasers: tuple[Laser, Laser], camera: CameraModel, us: np.ndarray, vs: np.ndarray,
           J: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """The two-spot picture at `theta` (A1, A2, w1, w2, ln σ, background), its Jacobian, and how
    fast each spot moves along its path (px per 1/m)."""
    sigma = math.exp(float(theta[4]))
    model = np.full(us.shape, float(theta[5]))
    J[:, 4] = 0.0
    J[:, 5] = 1.0
    speed = []
    for k, laser in enumerate(lasers):
        a, wk = float(theta[k]), float(theta[2 + k])
        p = _pixel(laser, camera, wk)
        dp = (_pixel(laser, camera, wk * 1.0001) - p) / (wk * 0.0001)  # d(u, v)/dw
        speed.append(float(np.hypot(dp[0], dp[1])))
        du, dv = us - p[0], vs - p[1]
        r2 = (du * du + dv * dv) / (sigma * sigma)
        g = np.exp(-0.5 * r2)
        model += a * g
        J[:, k] = g
        # d/dw of a·g: a·g·((u − pu)·dpu/dw + (v − pv)·dpv/dw)/σ²
        J[:, 2 + k] = a * g * (du * dp[0] + dv * dp[1]) / (sigma * sigma)
        J[:, 4] += a * g * r2
    return model, J, speed
