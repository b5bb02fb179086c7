"""The thesis' own estimator (Majeed 2006, §3.3), kept as a baseline to compare against.

Difference image C = on − off on the red channel over the whole frame, one mask per laser, a
threshold, the rounded mean position of the pixels above it, and r = k·(b/a)/tan θ with a the image
distance between the `center` and `parallel` spots, b between `center` and `sloped`. It is exact only
for a wall facing the camera squarely, and it rounds spot positions to whole pixels, as the thesis
did. The masks are bands around each laser's image path (the thesis drew them by hand).

This is deliberately the straightforward full-frame numpy version: ``edge bench ranging`` times it
beside the real pipeline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from edge.errors import EdgeError
from edge.rig import Laser, Rig
from edge.vision import SpotFinder

# Rounding a position to whole pixels leaves a uniform error of ±0.5 px: σ = 1/√12.
_ROUNDING_SIGMA_PX = 1.0 / math.sqrt(12.0)
_MASK_MARGIN_PX = 6


@dataclass(frozen=True)
class ThesisRig:
    """The three lasers the formula needs, and its two constants."""

    center: Laser
    parallel: Laser
    sloped: Laser
    k_m: float  # separation of the parallel beams
    theta_rad: float  # angle between `center` and `sloped`


def thesis_rig(rig: Rig) -> ThesisRig:
    """Find the thesis' three lasers in `rig` by their geometry, or say why the formula cannot
    apply: it needs a reference, a laser parallel to it, and one from the same origin at an angle."""
    center = rig.reference
    parallel = sloped = None
    for laser in rig.lasers:
        if laser is center:
            continue
        angle = math.acos(min(1.0, abs(float(laser.d @ center.d))))
        offset = laser.o - center.o
        across = float(np.linalg.norm(offset - (offset @ center.d) * center.d))
        if angle < math.radians(0.5) and across > 0.005 and parallel is None:
            parallel = laser
        elif angle > math.radians(1.0) and across < 0.005 and sloped is None:
            sloped = laser
    if parallel is None or sloped is None:
        raise EdgeError(
            "the thesis estimator needs the thesis rig: a reference laser, one parallel to it and "
            "one from the same point at an angle; use --estimator triangulate"
        )
    offset = parallel.o - center.o
    k = float(np.linalg.norm(offset - (offset @ center.d) * center.d))
    theta = math.acos(min(1.0, float(sloped.d @ center.d)))
    return ThesisRig(center, parallel, sloped, k, theta)


def masks(rig: Rig) -> dict[str, np.ndarray]:
    """Per laser, a full-frame 0/1 mask of where its spot can be: the pixels within a few pixels of
    its image path over the working range, and nearer to it than to any other laser's path (the
    thesis drew such regions by hand)."""
    cam = rig.camera
    distances = []
    for laser in rig.lasers:
        canvas = np.full((cam.height, cam.width), 255, np.uint8)
        path = np.rint(rig.laser_image_path(laser, 256)).astype(np.int32)
        cv2.polylines(canvas, [path.reshape(-1, 1, 2)], False, 0, 1)
        distances.append(cv2.distanceTransform(canvas, cv2.DIST_L2, 3))
    nearest = np.argmin(np.stack(distances), axis=0)
    return {
        laser.name: ((distances[i] <= _MASK_MARGIN_PX) & (nearest == i)).astype(np.float64)
        for i, laser in enumerate(rig.lasers)
    }


def red(image: np.ndarray) -> np.ndarray:
    return SpotFinder.laser_channel(image).astype(np.float64)


def spot_positions(
    on: np.ndarray, off: np.ndarray, masks_: dict[str, np.ndarray], min_level: float
) -> dict[str, np.ndarray | None]:
    """The thesis' localisation: C = B − A, pattern = C .* mask, and the rounded mean (u, v) of the
    pixels of the pattern above half its peak; None where the peak does not exceed `min_level`."""
    c = red(on) - red(off)  # C = B − A, the whole frame
    out: dict[str, np.ndarray | None] = {}
    for name, mask in masks_.items():
        pattern = c * mask
        peak = pattern.max()
        if peak <= min_level:
            out[name] = None
            continue
        y, x = np.nonzero(pattern > 0.5 * peak)
        out[name] = np.array([round(float(x.mean())), round(float(y.mean()))], dtype=float)
    return out


def thesis_range(t: ThesisRig, p_center: np.ndarray, p_parallel: np.ndarray, p_sloped: np.ndarray) -> float:
    a = float(np.linalg.norm(p_center - p_parallel))
    b = float(np.linalg.norm(p_center - p_sloped))
    if a <= 0:
        return math.inf
    return t.k_m * (b / a) / math.tan(t.theta_rad)


def thesis_sigma(t: ThesisRig, pc: np.ndarray, pp: np.ndarray, ps: np.ndarray) -> float:
    """The range's σ from the ±0.5 px rounding of the three positions, to first order."""
    r0 = thesis_range(t, pc, pp, ps)
    total = 0.0
    for which in range(3):
        for axis in range(2):
            pts = [pc.copy(), pp.copy(), ps.copy()]
            pts[which][axis] += 0.01
            total += ((thesis_range(t, *pts) - r0) / 0.01) ** 2
    return math.sqrt(total) * _ROUNDING_SIGMA_PX
