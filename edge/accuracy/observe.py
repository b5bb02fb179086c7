"""Is a zone's reference spot observable in the frames the camera delivered?

The floor's SNR (:mod:`edge.accuracy.floor`) is the renderer's: photo-electrons and sensor noise,
before the camera's pipeline. A JPEG encoder at quality 80 rounds a 2-DN spot in a dark frame to
nothing, and no estimator can find what the frames no longer hold. This module measures, on the
recorded frames themselves, the matched-filter SNR of the reference spot at its true pixel in the
zone's mean difference image (the issue's definition of observable), with the filter's noise taken
from its own responses across the frame's background, so that JPEG's and demosaicing's correlated
noise counts as it is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

# Matched filters: Gaussians of these σ (px), for focused to defocused spots; the best one counts.
TEMPLATE_SIGMAS_PX = (0.8, 1.6, 3.2)
# Background responses are sampled on a grid of this pitch (px), this far from any laser's spot,
# within _NEAR_PX of the spot where at least _MIN_SAMPLES points are (else the whole frame): noise is
# not the same across a frame (a window's shot noise, JPEG's rounding of dark flat walls to exactly
# nothing beside its rounding of textured ones), and a spot stands against the noise where it is.
_PITCH = 12
_CLEAR_PX = 14.0
_NEAR_PX = 72.0
_MIN_SAMPLES = 30


# Where a red laser's spot is in a BGR frame: red, or luma (JPEG 4:2:0 keeps red at half
# resolution, luma at full); the better of the two counts.
_PLANES = {"red": (0.0, 0.0, 1.0), "luma": (0.114, 0.587, 0.299)}


@dataclass(frozen=True)
class Difference:
    """A zone's mean difference image in one plane, and what one step of the frames' values is
    (quantisation: JPEG can leave a flat background's difference exactly 0, whose noise is then
    the rounding's, not none)."""

    image: np.ndarray  # float32
    step: float
    frames: int  # frames of each kind averaged


def mean_differences(on: Sequence[np.ndarray], off: Sequence[np.ndarray]) -> list[Difference]:
    """The mean of the laser-on frames less the laser-off frames: of each plane a red spot can be
    read from (red and luma of a colour frame; a grey frame as it is)."""
    diff = np.mean([f.astype(np.float32) for f in on], axis=0) - np.mean([f.astype(np.float32) for f in off], axis=0)
    values = np.unique(off[0][::7, ::7])
    step = float(np.diff(values).min()) if values.size > 1 else 1.0
    n = min(len(on), len(off))
    if diff.ndim == 2:
        return [Difference(np.asarray(diff, np.float32), step, n)]
    return [Difference(np.asarray(diff[..., :3] @ np.array(w, np.float32), np.float32), step, n)
            for w in _PLANES.values()]


def frame_snr(diffs: Sequence[Difference], pixel: Sequence[float], avoid: Sequence[Sequence[float]]) -> float:
    """The best matched-filter SNR of a spot at `pixel` (u, v) in the difference images `diffs`
    (planes of one): the filter's response there over the robust spread of its responses on a
    grid of background points around it (none within 14 px of `pixel` or of any point of `avoid`,
    the other spots); filters wide enough to reach another spot are not tried (the narrowest
    always is). 0 when the pixel is outside the image or the background shows no noise."""
    return max((_snr(d, pixel, avoid) for d in diffs), default=0.0)


def _snr(d: Difference, pixel: Sequence[float], avoid: Sequence[Sequence[float]]) -> float:
    diff = d.image
    h, w = diff.shape
    u, v = int(round(float(pixel[0]))), int(round(float(pixel[1])))
    if not (0 <= u < w and 0 <= v < h):
        return 0.0
    gv, gu = np.mgrid[_PITCH // 2:h:_PITCH, _PITCH // 2:w:_PITCH]
    gu, gv = gu.ravel(), gv.ravel()
    keep = np.ones(gu.size, bool)
    for a in (pixel, *avoid):
        keep &= np.hypot(gu - float(a[0]), gv - float(a[1])) > _CLEAR_PX
    gu, gv = gu[keep], gv[keep]
    if gu.size < _MIN_SAMPLES:
        return 0.0
    near = np.hypot(gu - float(pixel[0]), gv - float(pixel[1])) <= _NEAR_PX
    if np.count_nonzero(near) >= _MIN_SAMPLES:
        gu, gv = gu[near], gv[near]
    # The closest other spot: a filter that reaches it measures its light, not this spot's (a
    # hidden reference beside a bright neighbour 8 px away read SNR 100).
    gap = min((math.dist((float(a[0]), float(a[1])), (float(pixel[0]), float(pixel[1]))) for a in avoid),
              default=math.inf)
    best = 0.0
    for sigma in TEMPLATE_SIGMAS_PX:
        r = int(np.ceil(3.0 * sigma))
        if sigma > TEMPLATE_SIGMAS_PX[0] and r + 2.0 > gap:
            continue
        g = cv2.getGaussianKernel(2 * r + 1, sigma).astype(np.float32)
        response = cv2.sepFilter2D(diff, cv2.CV_32F, g, g, borderType=cv2.BORDER_REFLECT)
        background = response[gv, gu]
        centre = float(np.median(background))
        spread = 1.4826 * float(np.median(np.abs(background - centre)))
        # At least the rounding's noise: a step's uniform error (step²/12) in each of the frames
        # averaged, of both kinds, through the filter (Σ g² = Σ g_row² Σ g_col²).
        rounding = d.step * math.sqrt(2.0 / (12.0 * d.frames)) * float((g**2).sum())
        spread = max(spread, rounding)
        best = max(best, (float(response[v, u]) - centre) / spread)
    return best
