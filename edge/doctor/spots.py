"""Where one laser, switched alone, put its spot — and what that says about how it is built.

The doctor switches each laser on alone and takes a laser-off and a laser-on frame. The spot is
the brightest compact peak of their difference anywhere in the picture (not only along the laser's
path, as ranging looks: the point is to find it where it should not be). Where it lies tells:

- on its own path (within ``ranging.path_tolerance_px``, as ranging keeps spots): all is well;
- on another laser's path: the two lasers' pins are swapped;
- on no path: the rig is not built as configured (not calibrated, or a laser knocked since);
- a spot *darker* in the laser-on frame: the laser lights while its pin is at the "off" level, so
  its driver is active-low and ``active_high`` says otherwise;
- no spot, but one in the laser-off frame on its path: it does not go off (a shorted driver);
- no spot at all: it does not light (wiring, driver, supply), or nothing in range to light.

Pure: frames and the rig in, a :class:`SpotReport` out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge.rig import Rig
from edge.vision import FAR_FACTOR, NEAR_FACTOR, SpotFinder

MIN_SNR = 8.0  # a spot's (3 × 3 mean) peak over the difference image's noise
_SAMPLE = 4  # every 4th pixel each way is enough for the noise and the flicker gain


@dataclass(frozen=True)
class SpotReport:
    laser: str
    pixel: tuple[float, float] | None  # where the spot is (u, v), if one was found
    snr: float  # of the strongest peak found, lit or (for `inverted`) dark
    from_path_px: dict[str, float]  # distance from each laser's path
    depth_m: float | None  # where along its own path the spot lies
    inverted: bool  # a dark spot: lit while "off", dark while "on"
    lit_when_off: bool  # its spot shows in the laser-off frame

    @property
    def nearest(self) -> str | None:
        return min(self.from_path_px, key=self.from_path_px.__getitem__) if self.from_path_px else None


def _channel(image: np.ndarray) -> np.ndarray:
    plane = image[..., 2] if image.ndim == 3 else image  # a red laser: the red of BGR
    return plane.astype(np.float32) / np.float32(SpotFinder.full_scale(image))


def _box3(a: np.ndarray) -> np.ndarray:
    """The 3 × 3 mean (edges replicated): a spot covers several pixels, noise does not."""
    p = np.pad(a, 1, mode="edge")
    h, w = a.shape
    return sum((p[i:i + h, j:j + w] for i in range(3) for j in range(3)), np.zeros_like(a)) / np.float32(9)


def _centroid(diff: np.ndarray, v: int, u: int, peak: float) -> tuple[float, float]:
    """Centroid of the pixels above half the peak in a 9 × 9 window around (v, u)."""
    h, w = diff.shape
    v0, v1, u0, u1 = max(v - 4, 0), min(v + 5, h), max(u - 4, 0), min(u + 5, w)
    win = diff[v0:v1, u0:u1]
    weight = np.clip(win - 0.5 * peak, 0, None)
    if float(weight.sum()) <= 0:
        return float(u), float(v)
    gv, gu = np.mgrid[v0:v1, u0:u1]
    return float((gu * weight).sum() / weight.sum()), float((gv * weight).sum() / weight.sum())


def path_of(rig: Rig, laser: str, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """(pixels (n, 2), depths (n,)) of `laser`'s image path where ranging searches it."""
    lo, hi = rig.range_limits_m
    inv = np.linspace(1.0 / (lo * NEAR_FACTOR), 1.0 / (hi * FAR_FACTOR), n)
    beam = rig.laser(laser)
    return rig.camera.project(beam.point_at_depth(1.0 / inv)), 1.0 / inv


def distance_to_path(path: np.ndarray, point: np.ndarray) -> tuple[float, int]:
    """Distance (px) from `point` to the polyline `path`, and the index of the nearest vertex."""
    a, b = path[:-1], path[1:]
    ab = b - a
    t = np.clip(((point - a) * ab).sum(axis=1) / np.maximum((ab * ab).sum(axis=1), 1e-12), 0.0, 1.0)
    d = np.linalg.norm(a + t[:, None] * ab - point, axis=1)
    k = int(np.argmin(d))
    return float(d[k]), k + int(round(float(t[k])))


def judge(laser: str, on: np.ndarray, off: np.ndarray, rig: Rig) -> SpotReport:
    """Where `laser`'s spot is in the difference of `on` (it alone lit) and `off` (all off)."""
    a, b = _channel(on), _channel(off)
    sample = (slice(None, None, _SAMPLE), slice(None, None, _SAMPLE))
    # Room light changes a little from frame to frame (flicker): scale the off frame to the on one.
    level = float(np.median(b[sample]))
    gain = float(np.median(a[sample])) / level if level > 1e-6 else 1.0
    diff = _box3(a - np.float32(gain) * b)
    centre = float(np.median(diff[sample]))
    noise = max(1.4826 * float(np.median(np.abs(diff[sample] - centre))), 1e-6)
    diff -= np.float32(centre)
    flat = int(np.argmax(diff))
    v, u = divmod(flat, diff.shape[1])
    peak = float(diff[v, u])
    dark = float(-diff.min())
    lit_when_off = SpotFinder(rig, lasers=[laser]).lit_in_off(off, laser)
    if peak / noise < MIN_SNR:
        return SpotReport(laser, None, max(peak, dark) / noise, {}, None,
                          inverted=dark / noise >= MIN_SNR, lit_when_off=lit_when_off)
    pixel = np.array(_centroid(diff, v, u, peak))
    distances, depth = {}, None
    for name in rig.laser_names:
        path, depths = path_of(rig, name)
        distances[name], k = distance_to_path(path, pixel)
        if name == laser:
            depth = float(depths[min(k, len(depths) - 1)])
    return SpotReport(laser, (float(pixel[0]), float(pixel[1])), peak / noise, distances, depth,
                      inverted=False, lit_when_off=lit_when_off)
