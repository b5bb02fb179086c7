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
- no spot at all: it does not light (wiring, driver, supply), or nothing in range to light;
- only a broad glow far from every path: its light reflected (glass, a glossy surface) or
  scattered, its spot out of range or out of sight.

A noisy picture's difference holds peaks as strong as a faint spot's: a spot has to clear the
noise measured beside it (two laser-off frames' difference) and show again in a second pair.

Pure: frames and the rig in, a :class:`SpotReport` out.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge.rig import Rig
from edge.vision import FAR_FACTOR, NEAR_FACTOR, SpotFinder

MIN_SNR = 8.0  # a spot's (3 × 3 mean) peak over the difference image's noise
# A spot shows again in a second pair of frames: within REPEAT_PX of where it was, at REPEAT_SNR
# over the noise there. (Its SNR there is its first one, give or take one: a spot of 8 shows at
# 7-9, well over 3.5; a fluke of 8 shows at 0 ± 1.)
REPEAT_PX, REPEAT_SNR = 2, 3.5
OWN_PATH_PX = 3.0  # a peak this near a laser's path is taken for its spot first
EDGE_PX = 4  # peaks this near the picture's edge are not looked at
MAX_PEAKS, PEAK_APART = 5, 6  # peaks tried in turn, and how far apart (px) they are told apart
LOCAL_PX = 15  # the square (px) over which the noise beside a peak is measured (see _local_noise)
LOCAL_SNR = 4.0  # a spot's peak over that noise (its RMS, not a robust spread: JPEG's is sparse)
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
    fleeting: bool = False  # no spot, but changes over MIN_SNR: none clear of the noise there, or none again
    broad: bool = False  # the spot fills its window: a glow (a reflection), or a defocused near spot

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


def _broad(diff: np.ndarray, v: int, u: int, peak: float) -> bool:
    """Whether the ring 4 px around (v, u) keeps, in its median, 0.4 of the peak: a spot of σ up to
    2.8 px keeps under 0.37 there; this is a glow of its light reflected or scattered (or, bright,
    a spot far out of focus in front of the camera)."""
    h, w = diff.shape
    if not (4 <= v < h - 4 and 4 <= u < w - 4):
        return False
    win = diff[v - 4:v + 5, u - 4:u + 5]
    ring = np.concatenate([win[0], win[-1], win[1:-1, 0], win[1:-1, -1]])
    return float(np.median(ring)) > 0.4 * peak


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


def _difference(on: np.ndarray, off: np.ndarray) -> tuple[np.ndarray, float]:
    """The 3 × 3 mean of `on` − `off` in the laser's channel, centred on the picture's median, and
    its noise (robust spread)."""
    a, b = _channel(on), _channel(off)
    sample = (slice(None, None, _SAMPLE), slice(None, None, _SAMPLE))
    # Room light changes a little from frame to frame (flicker): scale the off frame to the on one.
    level = float(np.median(b[sample]))
    gain = float(np.median(a[sample])) / level if level > 1e-6 else 1.0
    diff = _box3(a - np.float32(gain) * b)
    centre = float(np.median(diff[sample]))
    noise = max(1.4826 * float(np.median(np.abs(diff[sample] - centre))), 1e-6)
    diff -= np.float32(centre)
    return diff, noise


def _peaks(diff: np.ndarray, least: float) -> list[tuple[int, int, float]]:
    """(v, u, value) of up to MAX_PEAKS strongest peaks of `diff` of at least `least`, each the
    strongest within PEAK_APART px of itself, none within EDGE_PX of the picture's edge."""
    work = diff.copy()
    h, w = work.shape
    # Not at the picture's edge: a spot cut by it cannot be placed, and demosaicing and JPEG leave
    # their own artefacts there (a 'spot' at u = 1.6, 390 px from every path).
    e = EDGE_PX
    work[:e], work[h - e:], work[:, :e], work[:, w - e:] = -np.inf, -np.inf, -np.inf, -np.inf
    found = []
    for _ in range(MAX_PEAKS):
        v, u = divmod(int(np.argmax(work)), w)
        value = float(work[v, u])
        if value < least:
            break
        # (A peak's shoulder, its top beyond the edge kept out of `work`, is no peak of its own.)
        if float(diff[max(v - 1, 0):v + 2, max(u - 1, 0):u + 2].max()) <= value:
            found.append((v, u, value))
        work[max(v - PEAK_APART, 0):v + PEAK_APART + 1, max(u - PEAK_APART, 0):u + PEAK_APART + 1] = -np.inf
    return found


def _local_noise(null: np.ndarray) -> np.ndarray:
    """Per pixel, the RMS of `null` (the difference of two laser-off frames, made as the others
    are) over LOCAL_PX × LOCAL_PX around it: the noise a difference has there, where the picture's
    own robust spread says too little: JPEG rings along a sharp edge by several times it, and a
    rolling shutter under flickering light leaves bands, strongest where the room is bright."""
    return np.sqrt(np.maximum(cv2.blur(null * null, (LOCAL_PX, LOCAL_PX), borderType=cv2.BORDER_REFLECT), 0.0))


def _repeats(again: tuple[np.ndarray, float] | None, v: int, u: int, sign: float,
             local: np.ndarray | None) -> bool:
    """Whether the change at (v, u) shows again, with the same sign, in the difference `again`."""
    if again is None:
        return True
    diff, noise = again
    near = (slice(max(v - REPEAT_PX, 0), v + REPEAT_PX + 1), slice(max(u - REPEAT_PX, 0), u + REPEAT_PX + 1))
    floor = noise if local is None else np.maximum(local[near], noise)
    return bool(((sign * diff[near]) >= REPEAT_SNR * floor).any())


def _noise_at(local: np.ndarray | None, noise: float, v: int, u: int) -> float:
    """The noise a peak at (v, u) is measured against: the picture's, or the noise beside it where
    that is larger. (JPEG can round a flat wall's difference to exactly 0, and a spot there read
    SNR 13 943 against the picture's; its timing, judged for spots of SNR 30 and more, then
    scattered by ± 15 %.)"""
    return noise if local is None else max(noise, float(local[v, u]))


def _clear(local: np.ndarray | None, v: int, u: int, value: float, snr: float = LOCAL_SNR) -> bool:
    """Whether a peak of `value` at (v, u) is `snr` over the noise there."""
    return local is None or value >= snr * float(local[v, u])


def judge(laser: str, on: np.ndarray, off: np.ndarray, rig: Rig,
          again: tuple[np.ndarray, np.ndarray] | None = None) -> SpotReport:
    """Where `laser`'s spot is in the difference of `on` (it alone lit) and `off` (all off).

    A spot (or a dark spot) has to stand out of its surroundings, and where `again` (lit, dark),
    another pair of the same, is given, show again where it is. A noisy camera's difference (a
    webcam's JPEG at 352 × 288) holds peaks of 8–14 × its robust noise anywhere in the picture; a
    laser's spot repeats, they do not. The strongest peaks are tried in turn, so a dim spot beside
    a brighter fluke is found."""
    diff, noise = _difference(on, off)
    second = local = None
    if again is not None:
        second = _difference(*again)
        local = _local_noise(_difference(off, again[1])[0])
    lit = _peaks(diff, MIN_SNR * noise)
    dim = _peaks(-diff, MIN_SNR * noise)
    finder = SpotFinder(rig, lasers=[laser])
    own, own_depths = path_of(rig, laser)

    def mine(v: int, u: int) -> bool:
        return distance_to_path(own, np.array([u, v], float))[0] <= OWN_PATH_PX

    # Its own spot before a brighter one elsewhere: a glossy surface throws the beam's light back
    # as a compact spot of its own, brighter than the spot on a dark wall. (A laser knocked off
    # its path has no spot there, and its spot elsewhere is taken.)
    # Off its path a spot has all the picture to be found in, and more flukes to pass for one: it
    # has to clear MIN_SNR over the noise beside it, not LOCAL_SNR.
    spots = [(v, u, p) for v, u, p in lit if _clear(local, v, u, p) and _repeats(second, v, u, 1.0, local)]
    spot = next(((v, u, p) for v, u, p in spots if mine(v, u)),
                next(((v, u, p) for v, u, p in spots if _clear(local, v, u, p, MIN_SNR)), None))
    if spot is None:
        # Lit while "off" puts its spot on its own path: a dark patch elsewhere (flicker bands
        # under a rolling shutter, in step with the frames) is not its doing.
        inverted = any(mine(v, u) and _clear(local, v, u, p) and _repeats(second, v, u, -1.0, local)
                       for v, u, p in dim)
        strongest = max([p / _noise_at(local, noise, v, u) for v, u, p in lit + dim],
                        default=max(float(diff.max()), float(-diff.min())) / noise)
        return SpotReport(laser, None, strongest, {}, None, inverted=inverted,
                          lit_when_off=finder.lit_in_off(off, laser), fleeting=bool(lit or dim) and not inverted)
    v, u, peak = spot
    pixel = np.array(_centroid(diff, v, u, peak))
    # It lit, so only its own spot left in the off frame says it does not (wholly) go off; a red
    # thing elsewhere on its path says nothing of the laser.
    lit_when_off = finder.lit_in_off(off, laser, near=(float(pixel[0]), float(pixel[1])))
    distances, depth = {}, None
    for name in rig.laser_names:
        path, depths = (own, own_depths) if name == laser else path_of(rig, name)
        distances[name], k = distance_to_path(path, pixel)
        if name == laser:
            depth = float(depths[min(k, len(depths) - 1)])
    return SpotReport(laser, (float(pixel[0]), float(pixel[1])), peak / _noise_at(local, noise, v, u), distances, depth,
                      inverted=False, lit_when_off=lit_when_off, broad=_broad(diff, v, u, peak))
