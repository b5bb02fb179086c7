"""An oracle's ranging of the same frames: what the estimator is compared with besides the floor.

The floor (:mod:`edge.accuracy.floor`) is taken before the camera's pipeline: it cannot say what
JPEG and demosaicing leave to be found. The issue measures the estimator against "the ideal
estimator's error on the same frames"; this is the nearest to it the bench can run. The oracle is
told what no estimator knows: each spot's true pixel and image shape in each view (the renderer's
Gaussian, defocus and blur included) and the surface its lasers lie on. It fits only the spot's
centre (with an amplitude and an offset per colour plane) by least squares to each pair's
difference, in a window of 3σ about the true pixel. Behind a Bayer filter it reads each pixel's own
colour only, the samples the demosaicing kept (OpenCV's keeps them), so the interpolated ones, whose
errors are shared and shaped by the algorithm, cannot bias it. Each laser's pixel error is averaged
over the zone's views and turned into a depth error, and the lasers on the reference's surface are
fused as the floor fuses them (:func:`edge.accuracy.floor.fusion_weights`).

It is no bound: unweighted least squares is efficient only where the noise is white and even.
JPEG's is not white, and a bright spot's own shot noise is not even; the estimator, which weighs
each pixel by its noise, beats the oracle on 3-colour frames. What the oracle says is how far an
estimator that knows where to look, and what it looks for, gets on these frames. It fits one spot
at a time: another laser's spot within its window (the centre and parallel spots merge far away)
pulls it, which the estimator's deblending does not suffer. Leaving out the zones with another spot
within 8 px of the reference changed the evaluation sets' pooled ratio from 1.11 to 1.12.

The fit (:func:`fit_centre`) is pure; :class:`ZoneOracle` asks the renderer for the truths.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from edge import isp
from edge.accuracy.floor import fusion_weights, spot_profile
from edge.ranging import FrameGroup
from edge.tone import linear_table
from edge.triangulation import triangulate

if TYPE_CHECKING:
    from edge.config import Config
    from edge.sim.render import Renderer, SpotTruth

WINDOW_SIGMAS = 3.0  # the fit's window reaches this many of the spot's σ (its widest) from the truth
_ITERATIONS = 10


def fit_centre(diff: np.ndarray, usable: np.ndarray, start_px: np.ndarray | Sequence[float], cov: np.ndarray,
               bayer: bool = False) -> np.ndarray | None:
    """The centre (u, v) of a Gaussian spot of image covariance `cov` (2, 2) px² in `diff` (h, w) or
    (h, w, C), by least squares from `start_px`, an amplitude and an offset per plane free; pixels
    where `usable` (h, w) is False (clipped) are left out, and with `bayer` (a BGR frame demosaiced
    from RGGB) each pixel's own colour only. None when the window holds too few samples."""
    image = diff if diff.ndim == 3 else diff[..., None]
    h, w, planes = image.shape
    centre = np.array(start_px, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    r = int(math.ceil(WINDOW_SIGMAS * math.sqrt(float(np.linalg.eigvalsh(cov)[-1])))) + 2
    cu, cv = int(round(centre[0])), int(round(centre[1]))
    x0, x1, y0, y1 = max(0, cu - r), min(w, cu + r + 1), max(0, cv - r), min(h, cv + r + 1)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return None
    window = image[y0:y1, x0:x1]
    chosen = np.repeat(usable[y0:y1, x0:x1, None], planes, axis=2)
    if bayer and planes == 3:
        rows = (y0 + np.arange(y1 - y0))[:, None] % 2
        cols = (x0 + np.arange(x1 - x0))[None, :] % 2
        own = np.where((rows == 0) & (cols == 0), 2, np.where((rows == 1) & (cols == 1), 0, 1))  # B, G, R
        chosen &= own[..., None] == np.arange(3)
    pixel, plane = np.nonzero(chosen.reshape(-1, planes))
    if pixel.size < 6:
        return None
    data = window.reshape(-1, planes)[pixel, plane].astype(np.float64)
    onehot = (plane[:, None] == np.unique(plane)[None, :]).astype(np.float64)
    k = onehot.shape[1]
    for _ in range(_ITERATIONS):
        g, dg = spot_profile(centre, cov, x0, y0, x1 - x0, y1 - y0)
        g, du, dv = g.ravel()[pixel], dg[0].ravel()[pixel], dg[1].ravel()[pixel]
        design = np.concatenate([onehot * g[:, None], onehot], axis=1)
        coef = np.linalg.lstsq(design, data, rcond=None)[0]
        amplitude = onehot @ coef[:k]
        residual = data - design @ coef
        # Gauss–Newton on the centre with the planes' amplitudes and offsets at their best for it:
        # its fixed point is the joint least-squares optimum.
        step = np.linalg.lstsq(np.stack([du * amplitude, dv * amplitude], axis=1), residual, rcond=None)[0]
        step = np.clip(step, -1.0, 1.0)
        centre = centre + step
        if float(np.abs(step).max()) < 1e-4:
            break
    return centre


class ZoneOracle:
    """The oracle's range error for the zones of one simulated recording, from the renderer that
    made it (the rig it ranges with is the renderer's, the true one)."""

    def __init__(self, renderer: Renderer, bayer: bool, gamma: float = 1.0, scaled: bool = False) -> None:
        self.renderer = renderer
        self.bayer = bayer
        self.gamma = gamma  # the camera's tone curve, which the oracle undoes (it fits linear light)
        self.scaled = scaled  # the renderer's sensor is 1640 × 1232, its frames scaled by the ISP (`of`)

    @classmethod
    def of(cls, config: Config, scaled: bool = False) -> ZoneOracle:
        """The oracle of recordings made by ``edge.sim.record.record_sweep`` with `config`, or with
        `scaled`, made so of a 1640 × 1232 sensor and scaled as the Pi camera's ISP hands them over
        (``edge.sim.isp.scale_recording``): no pixel keeps its own colour then, and a spot's true
        place and shape are the sensor's, scaled."""
        from edge.sim.record import scene_for, true_rig
        from edge.sim.render import Renderer

        sensor = config.sim.sensor
        renderer = Renderer(scene_for(config), true_rig(config), config.sim, config.camera)
        return cls(renderer, sensor.colour and sensor.bayer != "none" and not scaled, sensor.gamma, scaled)

    def error_m(self, groups: Sequence[FrameGroup], truth: dict, t_s: float) -> float | None:
        """The oracle's error of the zone's reference range (m), from its frame `groups` and the
        `truth` the recording carries (its floor names the lasers on the reference's surface and
        their floors); None when the reference spot is not visible or cannot be fitted."""
        floor = truth.get("floor") or {}
        used = [n for n in floor.get("used") or [] if (floor.get("lasers") or {}).get(n)]
        rig = self.renderer.rig
        if not used or used[0] != rig.reference.name:
            return None
        names: list[str] = []
        depth_errors: list[float] = []
        points: list[np.ndarray] = []
        sigmas: list[float] = []
        normal: np.ndarray | None = None
        frames = [(group, *_difference(group, self.gamma)) for group in groups]  # once for all the lasers
        for name in used:
            fitted = self._depth_error(name, frames, t_s)
            if fitted is None:
                if name == used[0]:
                    return None  # the reference's own spot cannot be fitted
                continue
            error, point, surface_normal = fitted
            normal = surface_normal if normal is None else normal  # the reference's surface
            sigma = floor["lasers"][name].get("sigma_m")
            names.append(name)
            depth_errors.append(error)
            points.append(point)
            sigmas.append(math.inf if sigma is None else float(sigma))
        if normal is None:
            return None
        weights = fusion_weights(np.array(points), np.array(sigmas), np.array([rig.laser(n).d for n in names]),
                                 normal)
        if not weights.any():
            return None
        return float(weights @ np.array(depth_errors))

    def _depth_error(self, laser: str, frames: Sequence[tuple[FrameGroup, np.ndarray, np.ndarray]], t_s: float
                     ) -> tuple[float, np.ndarray, np.ndarray] | None:
        """`laser`'s depth error, its pixel error averaged over the views (`frames`: each group with
        its difference and usable pixels, :func:`_difference`), with its spot's true point and its
        surface's normal (camera frame) in the first view it is fitted in; None if it is fitted in
        none."""
        rig = self.renderer.rig
        errors: list[np.ndarray] = []
        first: SpotTruth | None = None
        view = (0.0, 0.0)
        for group, diff, usable in frames:
            pan, tilt = group.view
            model = self.renderer.spot_model(pan, tilt, laser, t_s)
            if model is None or model.truth.pixel is None or laser not in group.lasers:
                continue
            pixel, cov = np.asarray(model.truth.pixel, dtype=np.float64), model.covariance
            if self.scaled:
                pixel, cov = np.array(isp.scaled_pixel(*pixel)), isp.scaled_covariance(cov)
            fitted = fit_centre(diff, usable, pixel, cov, self.bayer)
            if fitted is None:
                continue
            errors.append((fitted - pixel) * (isp.SCALE if self.scaled else 1.0))  # (the sensor's pixels)
            if first is None:
                first, view = model.truth, group.view
        if first is None or first.pixel is None or first.point_camera is None or first.normal_world is None:
            return None
        pixel = np.asarray(first.pixel, dtype=np.float64)
        depths = triangulate(rig.laser(laser), rig.camera, np.stack([pixel, pixel + np.mean(errors, axis=0)]))[:, 2]
        normal = self.renderer.camera_to_world(*view).inverse().rotate(first.normal_world)
        return float(depths[1] - depths[0]), np.asarray(first.point_camera), normal


def _difference(group: FrameGroup, gamma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A frame group's mean laser-on less mean laser-off frame, in linear light (the frames'
    tone curve `gamma` undone), and which pixels no laser-on frame clipped: (h, w[, C]) float64
    and (h, w) bool."""
    frames = np.stack(group.on)
    top = np.iinfo(frames.dtype).max if frames.dtype.kind in "ui" else math.inf
    table = linear_table(frames.dtype, gamma) if gamma != 1.0 else None  # (the table ranging undoes it by)
    on = np.mean([f.astype(np.float64) if table is None else table[f] for f in group.on], axis=0)
    off = np.mean([f.astype(np.float64) if table is None else table[f] for f in group.off], axis=0)
    clipped = (frames >= top).reshape(len(group.on), *frames.shape[1:3], -1)
    return on - off, np.logical_not(clipped.any(axis=(0, 3)))
