"""What the frames' noise is like, from the frames themselves: JPEG's blocks, the step between the
values a camera delivers, the laser-on minus laser-off difference's noise by the room's level, and
the matched filter a spot is detected by. Pure numpy (and one OpenCV box filter), no state:
`edge.vision.SpotFinder` measures these once per frame group.
"""

from __future__ import annotations

import cv2
import numpy as np

# The pixel noise a spot is judged against follows the room's level where it falls
# (`noise_by_level`): bins of equal steps of √level (shot noise's scale), each told by at least
# NOISE_BIN_SAMPLES background samples; and at most a factor NOISE_FLOOR_FRACTION below the
# picture's noise, for a JPEG can round a dark region's noise to nothing, and a spot there is no
# surer than the picture's noise allows.
NOISE_BINS = 8
NOISE_BIN_SAMPLES = 20
NOISE_FLOOR_FRACTION = 0.5


def jpeg_blockiness(image: np.ndarray) -> float:
    """How much larger a frame's steps across the 8 × 8 block boundaries are than inside blocks
    (1 for a frame that never was JPEG)."""
    g = image.astype(np.float32) if image.ndim == 2 else image[..., :3].astype(np.float32).mean(axis=2)
    dx = np.abs(np.diff(g, axis=1))
    dy = np.abs(np.diff(g, axis=0))
    inner_x = (dx.sum() - dx[:, 7::8].sum()) / max(dx.size - dx[:, 7::8].size, 1)
    inner_y = (dy.sum() - dy[7::8, :].sum()) / max(dy.size - dy[7::8, :].size, 1)
    bx = float(dx[:, 7::8].mean()) / max(float(inner_x), 1e-9)
    by = float(dy[7::8, :].mean()) / max(float(inner_y), 1e-9)
    return 0.5 * (bx + by)


# The coarsest step a 16-bit frame's values may have: an 8-bit sensor's, scaled to 16 bits.
COARSEST_STEP = 257.0


def value_step(frame: np.ndarray) -> float:
    """The step between the values a 16-bit `frame` holds: a sensor's 8-12 bits carried in 16 are
    scaled to its full range (×257, ×64.06, …), so that its values are that far apart, and the
    difference of two frames is that coarse. The least gap between the distinct values of every
    7th pixel (a room's noise shows neighbouring values), at most COARSEST_STEP: a frame of a few
    far-apart values (a lens cap's black and a few hot pixels) must not make every later spot
    noise. 1 for 8-bit frames, whose values are a sensor's 8 bits or fewer."""
    if frame.dtype != np.uint16:
        return 1.0
    values = np.unique(frame.reshape(-1)[::7])
    if values.size < 2:
        return 1.0
    return min(max(float(np.diff(values).min()), 1.0), COARSEST_STEP)


def level_bins(levels: np.ndarray) -> np.ndarray:
    """Each of `levels`' (full scale, ≥ 0) bin of NOISE_BINS equal steps of √level."""
    scaled = np.sqrt(levels)
    scaled *= NOISE_BINS
    index = scaled.astype(np.intp)
    return np.minimum(index, NOISE_BINS - 1, out=index)


def noise_by_level(levels: np.ndarray, deviation: np.ndarray, noise: float, least: float) -> np.ndarray | None:
    """The difference image's pixel noise by the room's level, from background samples' `levels`
    (the laser-off frame, full scale) and their absolute `deviation` from the background's median
    (clipped): a table of one σ per bin of NOISE_BINS equal steps of √level (shot noise's
    scale), float32, which `level_bins` of a level indexes.

    Shot noise grows with the light, and JPEG keeps less of a dark region's noise, so a spot on a
    dark surface stands above far less noise than the picture's median (tuning-18: 0.0058 against
    0.0108). A bin is no noisier than `noise`, the picture's (a bright region's own noise is
    `_local`'s to measure), nor quieter than `least`, nor than a darker bin; a bin with too few
    samples to tell takes the next brighter one's that can, else the picture's. None when no bin
    can tell. (Eight numbers: plain Python, cheaper than numpy's calls on them.)"""
    index = level_bins(levels)
    count = np.bincount(index, minlength=NOISE_BINS).tolist()
    total = np.bincount(index, weights=deviation, minlength=NOISE_BINS).tolist()
    if max(count) < NOISE_BIN_SAMPLES:
        return None
    table = [noise] * NOISE_BINS
    told = noise
    for i in range(NOISE_BINS - 1, -1, -1):  # brightest first: a bin that cannot tell takes the brighter one's
        if count[i] >= NOISE_BIN_SAMPLES:
            told = min(max(1.2533 * total[i] / count[i], least), noise)
        table[i] = told
    for i in range(1, NOISE_BINS):
        table[i] = max(table[i], table[i - 1])
    return np.array(table, np.float32)


BOX_PIXELS = 15  # the matched filter's pixels (spot_box): its white noise is √15 a pixel's


def spot_box(strips: np.ndarray) -> np.ndarray:
    """The matched filter of `strips` (width, path samples): each sum of 3 strip columns × 5 path
    samples (about a spot's size), for the columns 1 … width − 2, and 0 in the two samples at
    either end (float32, (width − 2, samples)). One OpenCV box filter: a fifth of numpy's
    additions of shifted views, which cost more to call than to add on a few thousand values."""
    box = cv2.boxFilter(strips, cv2.CV_32F, (5, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)[1:-1]
    box[:, :2] = 0.0
    box[:, -2:] = 0.0
    return box


def kth(values: np.ndarray, k: int) -> float:
    """The k-th smallest of `values` (reordered in place): np.partition's element, without the
    copy and dispatch that make the function cost twice the method on a thousand values."""
    values.partition(k)
    return values.item(k)
