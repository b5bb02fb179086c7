"""A laser that does not go off: its spot in a laser-off frame, along its strip.

A laser whose driver or GPIO line fails on stays lit in the frames taken as laser-off, and the
difference of a pair loses its spot. The sweep looks for it in every zone's laser-off frames
(`edge.sweep.lit_when_off`, which the service's laser health hears of), and `edge doctor` in its
own. Pure numpy, on a laser's `edge.paths.Band`.
"""

from __future__ import annotations

import math

import numpy as np

from edge.paths import Band, full_scale


def lit_in_off(band: Band, off: np.ndarray, max_spot_px: float, near: tuple[float, float] | None = None) -> bool:
    """Whether the spot of `band`'s laser shows in a laser-off frame (`lit_spots`: any)."""
    return bool(lit_spots(band, off, max_spot_px, near))


def lit_spots(band: Band, off: np.ndarray, max_spot_px: float, near: tuple[float, float] | None = None
              ) -> list[tuple[float, float]]:
    """Where the spot of `band`'s laser may show in a laser-off frame: the pixels (u, v) of compact
    peaks of red excess (red over the mean of green and blue; grey frames: brightness) along its
    path, well above the path's level and above the path a few spot widths (`max_spot_px`) either
    side of it; one per run of such path samples, at its brightest. `near` (u, v): only a peak
    there counts (where the laser-on frames put its spot).

    Compact, against the room: a warm wall, a worktop or a red curtain on the path stands above
    the rest of the path as a plateau, and JPEG and a display gamma lift it further; a spot
    stands above the path beside it too. What is left may still be the room's (a bright fleck of
    a textured cloth in a grey frame): the doctor tells them apart by turning the head."""
    if off.ndim == 3:
        img = off.astype(np.float32)
        excess = img[..., 2] - 0.5 * (img[..., 0] + img[..., 1])
    else:
        excess = off.astype(np.float32)
    across = excess[band.v, band.u]  # (L, strip width) along the path
    column = across.argmax(axis=1)
    profile = across[np.arange(column.size), column].astype(np.float64)
    level = float(np.median(profile))
    spread = 1.4826 * float(np.median(np.abs(profile - level)))
    beside = _beside(profile, band.step, level, max_spot_px)
    samples = np.arange(profile.size)
    if near is not None:
        reach = max(3.0, max_spot_px)
        close = np.hypot(band.path[:, 0] - near[0], band.path[:, 1] - near[1]) <= reach
        if not close.any():
            return []
        samples, profile, beside = samples[close], profile[close], beside[close]
    # Both: well above the path's own level, and well above the path beside it. (A stuck
    # spot's red excess, smeared by JPEG's half-resolution chroma, stood 0.13 of full scale
    # above a warm wall that it lay on, and the wall 0.04 above the path beside it.)
    full = full_scale(off)
    above = ((profile - level > max(8.0 * spread, 0.15 * full)) & (profile - beside > 0.08 * full)).nonzero()[0]
    out = []
    for run in np.split(above, (np.diff(above) > 1).nonzero()[0] + 1) if above.size else []:
        k = samples[run[int(np.argmax(profile[run]))]]
        out.append((float(band.u[k, column[k]]), float(band.v[k, column[k]])))
    return out


def _beside(profile: np.ndarray, step_px: float, level: float, max_spot_px: float) -> np.ndarray:
    """Per sample of a path's profile, the higher of its means over 2.5–4 largest spot widths
    before it and after it (one side where the path ends; `level` where it has neither)."""
    n = profile.size
    near = max(1, math.ceil(2.5 * max_spot_px / max(step_px, 1e-6)))
    far = max(near, math.ceil(4.0 * max_spot_px / max(step_px, 1e-6)))
    sums = np.concatenate(([0.0], np.cumsum(profile)))
    k = np.arange(n)

    def side(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:  # (means where hi >= lo; masked below)
        lo, hi = np.clip(lo, 0, n - 1), np.clip(hi, 0, n - 1)
        return (sums[hi + 1] - sums[lo]) / np.maximum(hi - lo + 1, 1)

    before = np.where(k - near >= 0, side(k - far, k - near), -np.inf)
    after = np.where(k + near <= n - 1, side(k + near, k + far), -np.inf)
    both = np.maximum(before, after)
    return np.where(np.isfinite(both), both, level)
