"""Where one laser, switched alone, put its spot — and what that says about how it is built.

The doctor switches each laser on alone and takes a laser-off and a laser-on frame. The spot is
the brightest compact peak of their difference anywhere in the picture (not only along the laser's
path, as ranging looks: the point is to find it where it should not be). Where it lies tells:

- on its own path (within ``ranging.path_tolerance_px``, as ranging keeps spots): all is well;
- on another laser's path: the two lasers' pins are swapped;
- on no path: the rig is not built as configured (not calibrated, or a laser knocked since). Such
  a spot has to show a third time (lit all through), be no stripe and, in JPEG frames that rounded
  most of their difference away, stand above what the laser-off frames change near it (such frames
  flip blocks, whatever the lasers do);
- a spot *darker* in the laser-on frame: the laser lights while its pin is at the "off" level, so
  its driver is active-low and ``active_high`` says otherwise;
- no spot, but one in the laser-off frame on its path: it does not go off (a shorted driver);
  too faint for that frame alone, it is told by turning the head (:func:`stays_put`);
- no spot at all: it does not light (wiring, driver, supply), or nothing in range to light, or (in
  JPEG frames that hold most pixels equal) JPEG rounded a faint or small spot away;
- only a broad glow far from every path: its light reflected (glass, a glossy surface) or
  scattered, its spot out of range or out of sight.

A noisy picture's difference holds peaks as strong as a faint spot's: a spot has to clear the
noise measured beside it (two laser-off frames' difference) and show again in a second pair.

Pure: frames and the rig in, a :class:`SpotReport` (or a :class:`Turn`, and :class:`StaysPut`) out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from edge.framenoise import jpeg_blockiness
from edge.paths import FAR_FACTOR, NEAR_FACTOR
from edge.rig import Rig
from edge.vision import JPEG_BLOCKINESS, SpotFinder

MIN_SNR = 8.0  # a spot's (3 × 3 mean) peak over the difference image's noise
# A spot shows again in a second pair of frames: within REPEAT_PX of where it was, at REPEAT_SNR
# over the noise there. (Its SNR there is its first one, give or take one: a spot of 8 shows at
# 7-9, well over 3.5; a fluke of 8 shows at 0 ± 1.)
REPEAT_PX, REPEAT_SNR = 2, 3.5
# A spot off its own path has to show a third time, in a frame lit all through, against the second
# pair's laser-off frame: at HELD_SHARE of its first SNR or more (lit all through, a spot is at least
# as bright as in the frame taken as lit). A fluke of the first pair's shows there only by chance; the
# second pair's REPEAT_SNR, anywhere in 25 pixels, let some through (tuning-2398: a JPEG fluke of
# SNR 11, 136 px from every path, said "not built as configured").
# So does the second pair, whose lit frame is lit all through too: a change that shows there at less
# than HELD_SHARE of its first SNR is none of the laser's (tuning-14: a fluke of a noisy JPEG 1280 ×
# 720 picture, SNR 8.9 then 3.9, 548 px from every path; tuning-30: a bright patch of a kitchen,
# 11.4 then 4.7, 130 px from the true spot). Of 246 spots off their paths on knocked rigs (tuning
# 2304-2335, 2368-2399 and 2432-2463), none showed there at less.
HELD_SHARE = 0.5
# Nor is a change off its path a spot where it runs on at half its peak or more for STRIPE_PX or
# more along a row or a column, and STRIPE_RATIO × farther than across: a pointer's spot (σ up to
# 2.8 px, as `_broad` allows, in the 3 × 3 mean) is at half its peak for 7 px at most. A dim JPEG
# frame's block flips between two quantised states from frame to frame, and every lit frame can
# hold the same flip: tuning-2381, 8 rows flat across one block, 50 px from every path; tuning-2415,
# 16 columns of a 4:2:0 block, 123 px from it, each "not built as configured".
STRIPE_PX, STRIPE_RATIO = 8, 1.5
# And in JPEG frames that rounded their difference away (`rounded_share`: most pixels equal in the
# two frames) it has to stand NULL_MARGIN × above the largest change that the two laser-off frames
# show within NULL_REACH px of it: what the picture does with no laser at all. Such frames' flipped
# blocks are sparse (the noise beside them, an RMS, is nearly 0) and as strong as the flips the lit
# frames hold (tuning-2377: a cluster 200 px from every path, 5.0 DN where the laser-off frames
# flipped 3.8 DN within 64 px). Not where the frames keep their noise: the largest change is then
# its tail, which MIN_SNR and the repeats already judge, and a knocked laser's spot of SNR 9 stood
# only 1.46 × above it in the Pi camera's lossless frames (tuning-2369), 1.15 × in a noisy webcam's
# JPEG 76 (tuning-2448; 1° off, each).
NULL_MARGIN, NULL_REACH = 1.5, 64
# A dark spot says "active-low" only where the laser-off frame holds a spot there, at GONE_SHARE of
# its depth or more, and the frame taken as lit has lost it, keeping 1 − GONE_SHARE of it at most:
# lit while "off", such a laser's spot is gone when "on". A laser that never goes off keeps its
# spot in both (the centre laser stuck, "active-low" where the line is "does not go off": eye
# safety): evaluation-1269, its clipped spot 10 σ dimmer in the lit frames, which held 0.99 of it;
# evaluation-1291, JPEG's ringing 6 px beside it, where the laser-off frame holds 0.19 of the depth.
GONE_SHARE = 0.5
OWN_PATH_PX = 3.0  # a peak this near a laser's path is taken for its spot first
EDGE_PX = 4  # peaks this near the picture's edge are not looked at
MAX_PEAKS, PEAK_APART = 5, 6  # peaks tried in turn, and how far apart (px) they are told apart
LOCAL_PX = 15  # the square (px) over which the noise beside a peak is measured (see _local_noise)
LOCAL_SNR = 4.0  # a spot's peak over that noise (its RMS, not a robust spread: JPEG's is sparse)
_SAMPLE = 4  # every 4th pixel each way is enough for the noise and the flicker gain


# JPEG frames whose laser-on and laser-off pictures hold this share of their pixels equal, or more,
# had their difference rounded away, and a faint or small spot with it. (Tuning-2381, a dim room in
# JPEG 61: 76 % equal, and the laser's spot, 1-2 px wide and 26 DN before JPEG, left 0 DN. Lossless
# frames of the Pi camera in a dim room: 13 %.)
ROUNDED_SHARE = 0.5


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
    rounded: float | None = None  # no spot, in JPEG frames: the share of pixels the two frames hold equal
    # No spot, but `lit_when_off`: where on its path the laser-off frame showed what may be its spot
    # (u, v; one a peak). The room's own bright flecks show there too: turning the head tells.
    lit_off_at: tuple[tuple[float, float], ...] = ()

    @property
    def nearest(self) -> str | None:
        return min(self.from_path_px, key=self.from_path_px.__getitem__) if self.from_path_px else None


def _plane(image: np.ndarray) -> np.ndarray:
    """The laser's plane of a frame, as delivered: a red laser, the red of BGR (grey as it is)."""
    return image[..., 2] if image.ndim == 3 else image


def _channel(image: np.ndarray) -> np.ndarray:
    return _plane(image).astype(np.float32) / np.float32(SpotFinder.full_scale(image))


def is_jpeg(frame: np.ndarray) -> bool:
    """Are the camera's frames JPEG's (`frame`'s 8 × 8 blocks' edges, as ranging tells them)?"""
    return bool(jpeg_blockiness(frame) > JPEG_BLOCKINESS)


def rounded_share(on: np.ndarray, off: np.ndarray) -> float | None:
    """The share of pixels (every _SAMPLE-th each way) that `on` and `off` hold equal in the
    laser's channel, where the frames are JPEG (`jpeg_blockiness`); None where they are not."""
    if not is_jpeg(off):
        return None
    a, b = (_plane(f)[::_SAMPLE, ::_SAMPLE] for f in (on, off))
    return float(np.count_nonzero(a == b)) / a.size


def _box3(a: np.ndarray) -> np.ndarray:
    """The 3 × 3 mean (edges replicated): a spot covers several pixels, noise does not."""
    p = np.pad(a, 1, mode="edge")
    h, w = a.shape
    return sum((p[i:i + h, j:j + w] for i in range(3) for j in range(3)), np.zeros_like(a)) / np.float32(9)


def placed_to_px(snr: float) -> float:
    """How far across its path a spot of peak `snr` may be placed off by `_centroid` (3 σ of one
    coordinate). Measured on Gaussian spots of σ 0.7–1.5 px in white noise, the placement's 2-D
    error has σ about hypot(1.6 / SNR, 0.08) px: 0.18 px at SNR 9, 0.1 px at SNR 30, where the
    window's pixels take over (a faint spot 1.6 px from its path, where ranging keeps 1.5 px, said
    "not built as configured" on a rig built exactly so: tuning-2399)."""
    return 3.0 * math.hypot(1.6 / max(snr, 1e-9), 0.08) / math.sqrt(2.0)


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
    return float(np.median(_border(diff[v - 4:v + 5, u - 4:u + 5]))) > 0.4 * peak


def _border(win: np.ndarray) -> np.ndarray:
    """The pixels of a square window's edge: the room about the spot at its middle."""
    return np.concatenate([win[0], win[-1], win[1:-1, 0], win[1:-1, -1]])


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
             local: np.ndarray | None, snr: float = REPEAT_SNR) -> bool:
    """Whether the change at (v, u) shows again, with the same sign, in the difference `again`
    (`snr` over the noise there, within REPEAT_PX)."""
    if again is None:
        return True
    diff, noise = again
    near = (slice(max(v - REPEAT_PX, 0), v + REPEAT_PX + 1), slice(max(u - REPEAT_PX, 0), u + REPEAT_PX + 1))
    floor = noise if local is None else np.maximum(local[near], noise)
    return bool(((sign * diff[near]) >= snr * floor).any())


def _noise_at(local: np.ndarray | None, noise: float, v: int, u: int) -> float:
    """The noise a peak at (v, u) is measured against: the picture's, or the noise beside it where
    that is larger. (JPEG can round a flat wall's difference to exactly 0, and a spot there read
    SNR 13 943 against the picture's; its timing, judged for spots of SNR 30 and more, then
    scattered by ± 15 %.)"""
    return noise if local is None else max(noise, float(local[v, u]))


def _clear(local: np.ndarray | None, v: int, u: int, value: float, snr: float = LOCAL_SNR) -> bool:
    """Whether a peak of `value` at (v, u) is `snr` over the noise there."""
    return local is None or value >= snr * float(local[v, u])


def _run(line: np.ndarray, at: int, least: float) -> int:
    """How many pixels of `line`, through `at`, lie at `least` or more without a break."""
    below = np.flatnonzero(line < least)
    before, after = below[below < at], below[below > at]
    return int((after[0] if after.size else line.size) - (before[-1] + 1 if before.size else 0))


def _stripe(diff: np.ndarray, v: int, u: int, peak: float) -> bool:
    """Whether the change of `peak` at (v, u) is a stripe along a row or a column, not a spot (see
    STRIPE_PX)."""
    half = 0.5 * peak
    along_u = _run(diff[v, max(u - 3 * STRIPE_PX, 0):u + 3 * STRIPE_PX + 1], min(u, 3 * STRIPE_PX), half)
    along_v = _run(diff[max(v - 3 * STRIPE_PX, 0):v + 3 * STRIPE_PX + 1, u], min(v, 3 * STRIPE_PX), half)
    longer, shorter = max(along_u, along_v), min(along_u, along_v)
    return longer >= STRIPE_PX and longer >= STRIPE_RATIO * shorter


def _excess(frame: np.ndarray, v: int, u: int) -> float:
    """What `frame` shows at (v, u) over the room 4 px around it: its laser plane's 3 × 3 mean
    there, less the median of the 9 × 9 square's border (`_difference`'s units)."""
    win = _box3(_channel(frame[v - 5:v + 6, u - 5:u + 6]))[1:-1, 1:-1]
    return float(win[4, 4]) - float(np.median(_border(win)))


def _gone_when_lit(on: np.ndarray, off: np.ndarray, v: int, u: int, dark: float) -> bool:
    """Whether a dark spot of depth `dark` at (v, u) is an active-low driver's: its spot lit in the
    laser-off frame `off` (by GONE_SHARE of that depth or more) and gone from the frame taken as
    lit, `on` (which keeps no more than 1 − GONE_SHARE of it)."""
    h, w = off.shape[:2]
    if not (5 <= v < h - 5 and 5 <= u < w - 5):
        return True
    lit_off = _excess(off, v, u)
    return lit_off >= GONE_SHARE * dark and _excess(on, v, u) <= (1.0 - GONE_SHARE) * lit_off


def _above_null(null: np.ndarray | None, v: int, u: int, peak: float) -> bool:
    """Whether a peak of `peak` at (v, u) stands NULL_MARGIN × above the largest change of `null`
    (two laser-off frames' difference) within NULL_REACH px."""
    if null is None:
        return True
    near = null[max(v - NULL_REACH, 0):v + NULL_REACH + 1, max(u - NULL_REACH, 0):u + NULL_REACH + 1]
    return peak >= NULL_MARGIN * max(float(near.max()), -float(near.min()))


def _held(through: tuple[np.ndarray, float] | None, v: int, u: int, snr: float, local: np.ndarray | None) -> bool:
    """Whether a spot of `snr` at (v, u) shows in `through`, the difference of a frame lit all
    through and a laser-off frame (the frame lit all through, or the second pair), at HELD_SHARE
    of that SNR (and REPEAT_SNR) or more."""
    if through is None:
        return True
    return _repeats(through, v, u, 1.0, local, max(REPEAT_SNR, HELD_SHARE * snr))


def judge(laser: str, on: np.ndarray, off: np.ndarray, rig: Rig,
          again: tuple[np.ndarray, np.ndarray] | None = None, through: np.ndarray | None = None,
          blame_px: float = OWN_PATH_PX) -> SpotReport:
    """Where `laser`'s spot is in the difference of `on` (it alone lit) and `off` (all off).

    A spot (or a dark spot) has to stand out of its surroundings, and where `again` (lit, dark),
    another pair of the same, is given, show again where it is. A noisy camera's difference (a
    webcam's JPEG at 352 × 288) holds peaks of 8–14 × its robust noise anywhere in the picture; a
    laser's spot repeats, they do not. The strongest peaks are tried in turn, so a dim spot beside
    a brighter fluke is found.

    `through`, where given, is a third frame with the laser lit all through: a spot off the
    laser's own path, which would blame the build or the wiring, has to show in it too (less
    `again`'s laser-off frame, else `off`; `_held`), and in the second pair at as much; so does a
    spot on its path whose centroid lies more than `blame_px` from it (the verdict's reach:
    `ranging.path_tolerance_px`)."""
    diff, noise = _difference(on, off)
    second = local = held = null = None
    if again is not None:
        second = _difference(*again)
        null = _difference(off, again[1])[0]
        local = _local_noise(null)
    rounded = rounded_share(on, off)
    if rounded is None or rounded < ROUNDED_SHARE:
        null = None  # (the frames keep their noise: see NULL_MARGIN)
    if through is not None:
        held = _difference(through, off if again is None else again[1])
    lit = _peaks(diff, MIN_SNR * noise)
    dark = -diff  # (a dark spot: lit while "off")
    dim = _peaks(dark, MIN_SNR * noise)
    finder = SpotFinder(rig, lasers=[laser])
    own, own_depths = path_of(rig, laser)

    def mine(v: int, u: int) -> bool:
        return distance_to_path(own, np.array([u, v], float))[0] <= OWN_PATH_PX

    def held_through(v: int, u: int, p: float,
                     frames: tuple[tuple[np.ndarray, float] | None, ...] = (held, second)) -> bool:  # (`_held`)
        snr = p / _noise_at(local, noise, v, u)
        return all(_held(lit_through, v, u, snr, local) for lit_through in frames)

    def sure(v: int, u: int, p: float) -> bool:
        # A spot by its own path whose line will blame the build all the same (its centroid past
        # `blame_px`) shows in the second pair at HELD_SHARE of its SNR too: a bright patch of a
        # kitchen, its brightest pixel 3 px from the path and its centroid 3.6 px, SNR 11.4 then
        # 4.7 there, read "not built as configured" (tuning-30). A knocked laser's faint spots
        # there showed at 0.8-0.9 × their SNR (tuning-2373, 2440, 2398: 3.3, 3.4 and 2.4 px off, SNR
        # 5.6-7.8). Not lit all through as well: JPEG rounded tuning-2398's spot away there (1.7).
        at = np.array(_centroid(diff, v, u, p), float)
        return distance_to_path(own, at)[0] <= blame_px or held_through(v, u, p, (second,))

    # Its own spot before a brighter one elsewhere: a glossy surface throws the beam's light back
    # as a compact spot of its own, brighter than the spot on a dark wall. (A laser knocked off
    # its path has no spot there, and its spot elsewhere is taken.)
    # Off its path a spot has all the picture to be found in, and more flukes to pass for one: it
    # has to clear MIN_SNR over the noise beside it, not LOCAL_SNR.
    spots = [(v, u, p) for v, u, p in lit if _clear(local, v, u, p) and _repeats(second, v, u, 1.0, local)]
    spot = next(((v, u, p) for v, u, p in spots if mine(v, u) and sure(v, u, p)),
                next(((v, u, p) for v, u, p in spots if _clear(local, v, u, p, MIN_SNR) and held_through(v, u, p)
                      and not _stripe(diff, v, u, p) and _above_null(null, v, u, p)), None))
    if spot is None:
        # Lit while "off" puts its spot on its own path: a dark patch elsewhere (flicker bands
        # under a rolling shutter, in step with the frames) is not its doing. Where JPEG rounded
        # the difference away it has to stand above what the laser-off frames do alone, as a spot
        # off its path has: a knocked laser's spot 5 px off its path rang dark onto it, 2.8 DN in
        # a 320-px JPEG where the laser-off frames flipped 2.3 DN ("active-low", whose remedy
        # lights a laser while it is off: tuning-2544, knocked 1°).
        # Nor is a dark stripe a laser's spot, which is a spot's shape, dark or lit: the lit frames'
        # flicker (3 % darker, by chance) tipped one band of a dim 320-px JPEG into its lower
        # quantised state in all three, 19 → 14 DN across 10 px (tuning-2628, its pose 4: "active-low").
        inverted = any(mine(v, u) and _clear(local, v, u, p) and _repeats(second, v, u, -1.0, local)
                       and _above_null(null, v, u, p) and not _stripe(dark, v, u, p)
                       and _gone_when_lit(on, off, v, u, p) for v, u, p in dim)
        strongest = max([p / _noise_at(local, noise, v, u) for v, u, p in lit + dim],
                        default=max(float(diff.max()), float(-diff.min())) / noise)
        lit_off_at = tuple(finder.lit_spots(off, laser))
        return SpotReport(laser, None, strongest, {}, None, inverted=inverted,
                          lit_when_off=bool(lit_off_at), fleeting=bool(lit or dim) and not inverted,
                          rounded=rounded, lit_off_at=lit_off_at)
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


# --- a laser that does not go off, told by turning the head ---------------------------------------
#
# A laser stuck on lights its spot in the laser-off frames too, so the difference of laser-on and
# laser-off frames holds nothing and the laser reads as one that does not light. Its spot may be
# too faint, or the room too red, for the off frame alone to show it (`SpotFinder.lit_in_off`).
# Turned a little, the room moves across the picture and the spot does not: it rides with the
# camera. Two laser-off frames, the second turned back onto the first (the rotation's homography:
# the room cancels, far more than a wall's parallax), leave the spot twice: as itself where it is,
# and as a dark copy where the turn carried it.

TURN_SHIFT_PX = 16.0  # how far the room moves across the picture in the turn
TURN_SNR = 6.0  # each of the spot and its dark copy over the noise beside it
TURN_MATCH = 0.5  # and the copy at least half as strong as the spot (the same light, turned)
TURN_RING = (21, 9)  # the square (px) the noise beside a peak is measured over, less its middle
TURN_FLOOR = 0.2  # the noise beside a peak, taken as no less than this much of the picture's
ROOM_MOVED = 0.7  # turned back, the room's difference is at most this much of the frames' unturned
ROOM_EDGES = 100  # (sampled pixels where the frames differ unturned: fewer, and the room cannot tell)


@dataclass(frozen=True)
class StaysPut:
    """A spot on a laser's path that stays put in the picture while the head turns (or none)."""

    pixel: tuple[float, float] | None
    snr: float  # of the strongest peak on the path (of the spot, if one stays put)
    from_path_px: dict[str, float] | None = None  # the spot's distance from each laser's path

    def suspects(self, laser: str) -> list[str]:
        """Which lasers the spot found on `laser`'s path may be: `laser`, and any other whose path
        passes it about as near (within a third of OWN_PATH_PX: far away two paths run a few pixels
        apart); none where another's passes it clearly nearer (its spot: its own line says so)."""
        d = self.from_path_px or {}
        if self.pixel is None or laser not in d:
            return []
        if any(d[n] < d[laser] - OWN_PATH_PX / 3 for n in d if n != laser):
            return []
        return [laser, *(n for n in d if n != laser and d[n] <= d[laser] + OWN_PATH_PX / 3)]


def turn_deg(rig: Rig) -> float:
    """The pan turn (degrees) that moves the room TURN_SHIFT_PX across the picture."""
    return float(np.degrees(np.arctan(TURN_SHIFT_PX / rig.camera.fx)))


def _turned_back(rig: Rig, image: np.ndarray, here: np.ndarray, turned: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`image`, taken with the camera at rotation `turned` (camera to base), seen from `here`:
    each pixel of `here`'s picture takes the value of the pixel that looked the same way from
    `turned`; and which pixels of it were seen at all."""
    cam = rig.camera
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    rays = cam.rays(np.stack([u, v], axis=-1)) @ (turned.T @ here).T  # here's rays, in turned's frame
    seen = rays[..., 2] > 1e-3
    rays[~seen] = (0.0, 0.0, 1.0)
    pix = cam.project(rays)
    seen &= cam.contains(pix, 1.0)
    mapped = cv2.remap(image, pix[..., 0].astype(np.float32), pix[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
    return mapped, seen


def _ring_noise(diff: np.ndarray) -> np.ndarray:
    """Per pixel, the RMS of `diff` over TURN_RING[0]² pixels around it less the TURN_RING[1]² at
    its middle: the noise beside a spot, not the spot's own light (a defocused one's included)."""
    square = diff * diff
    (wide, narrow) = TURN_RING
    outer = cv2.blur(square, (wide, wide), borderType=cv2.BORDER_REFLECT) * np.float32(wide**2)
    inner = cv2.blur(square, (narrow, narrow), borderType=cv2.BORDER_REFLECT) * np.float32(narrow**2)
    return np.sqrt(np.maximum(outer - inner, 0.0) / np.float32(wide**2 - narrow**2))


@dataclass(frozen=True)
class Turn:
    """Two laser-off frames taken with the camera at rotations `here` and `turned` (camera to base,
    3 × 3), the second turned back onto the first (`turn`): what every laser's `stays_put` reads."""

    here: np.ndarray
    turned: np.ndarray
    diff: np.ndarray  # the first less the second turned back, 3 × 3 mean, its slow swell taken out
    seen: np.ndarray  # the first's pixels the second saw too
    local: np.ndarray  # the noise beside each pixel (_ring_noise)
    least: float  # the least noise a peak is judged against


def turn(off_here: np.ndarray, off_turned: np.ndarray, rig: Rig, here: np.ndarray, turned: np.ndarray
         ) -> Turn | None:
    """The frames of a turn, turned back (`Turn`); None where the room did not move as the turn
    says (then every bright thing on a path would stay put), or nothing is seen from both."""
    a = _channel(off_here)
    b, seen = _turned_back(rig, _channel(off_turned), here, turned)
    sample = (slice(None, None, _SAMPLE), slice(None, None, _SAMPLE))
    inside = seen[sample]
    if not inside.any():
        return None
    level = float(np.median(b[sample][inside]))
    gain = float(np.median(a[sample][inside])) / level if level > 1e-6 else 1.0
    diff = _box3(a - np.float32(gain) * b)
    diff[~seen] = 0.0
    # Less its level around (TURN_RING[0] px): the lens's vignetting and the sensor's shading stay
    # put with the camera and leave a slow swell where the room is turned back onto itself.
    diff -= cv2.blur(diff, (TURN_RING[0], TURN_RING[0]), borderType=cv2.BORDER_REFLECT)
    # The room must have moved as the turn says (not so with a real camera beside an emulated
    # head): where the room has edges, the frames turned back must cancel them far better than
    # the frames as taken. A room with nothing to move tells nothing, and fools nothing either.
    turned_back = np.abs(diff[sample][inside])
    unturned = np.abs(_box3(a - _channel(off_turned))[sample][inside])
    spread = 1.4826 * min(float(np.median(turned_back)), float(np.median(unturned)))
    edges = np.maximum(turned_back, unturned) > 3.0 * spread
    if np.count_nonzero(edges) >= ROOM_EDGES and float(turned_back[edges].mean()) > (
            ROOM_MOVED * float(unturned[edges].mean())):
        return None
    # Judged by the noise beside each peak: a bright room's shot noise, elsewhere in the picture,
    # raised the picture's to 4 × that beside a dim stuck spot on a dark wall (tuning-128). Not
    # below TURN_FLOOR of the picture's (JPEG rounds a flat wall's difference to nothing); the
    # dark copy where the turn carried the spot is what no fluke of the room's makes.
    noise = max(1.4826 * float(np.median(turned_back)), 1e-6)
    return Turn(here, turned, diff, seen, _ring_noise(diff), TURN_FLOOR * noise)


def moves_with_room(seen_turning: Turn, pixel: tuple[float, float]) -> bool:
    """Does what the laser-off frames hold at `pixel` move with the room in the turn: seen from
    both of its frames, and their difference there (the second turned back) under TURN_SNR × the
    noise beside it? A laser's spot rides with the camera and stands there (`stays_put`); a red
    thing of the room's cancels. False near the picture's edge, or where the turn saw it once."""
    t = seen_turning
    u, v = int(round(pixel[0])), int(round(pixel[1]))
    h, w = t.diff.shape
    if not (EDGE_PX <= u < w - EDGE_PX and EDGE_PX <= v < h - EDGE_PX) or not t.seen[v - 2:v + 3, u - 2:u + 3].all():
        return False
    peak = float(t.diff[v - 2:v + 3, u - 2:u + 3].max())
    return peak < TURN_SNR * max(t.least, float(t.local[v, u]))


def stays_put(laser: str, seen_turning: Turn, rig: Rig) -> StaysPut:
    """Whether `laser`'s spot shows in the laser-off frames of a turn: a spot on its path in the
    first that stays put in the picture while the room moves, so that the second frame turned
    back onto the first holds it, dark, where the turn carried it. Both must stand TURN_SNR over
    the noise beside them, the copy no less than TURN_MATCH of the spot."""
    t = seen_turning
    diff, local, least = t.diff, t.local, t.least
    own, _ = path_of(rig, laser)
    mask = np.zeros(diff.shape, np.uint8)
    cv2.polylines(mask, [np.round(own).astype(np.int32)], False, 1, thickness=2 * int(OWN_PATH_PX) + 1)
    work = np.where((mask > 0) & t.seen, diff, -np.inf)
    best = StaysPut(None, 0.0)
    h, w = diff.shape
    cam = rig.camera
    for _ in range(MAX_PEAKS):
        v, u = divmod(int(np.argmax(work)), w)
        peak = float(work[v, u])
        if not np.isfinite(peak) or peak <= 0.0:
            break
        work[max(v - PEAK_APART, 0):v + PEAK_APART + 1, max(u - PEAK_APART, 0):u + PEAK_APART + 1] = -np.inf
        snr = peak / max(least, float(local[v, u]))
        best = best if best.snr >= snr else StaysPut(None, snr)
        if snr < TURN_SNR:
            continue  # (a fainter peak may stand where the room is quieter)
        # Where the turned frame's spot, at this pixel of its own picture, lies in here's.
        ray = cam.rays(np.array([u, v], float)) @ (t.here.T @ t.turned).T
        if ray[2] <= 1e-3:
            continue
        cu, cv = cam.project(ray)
        iu, iv = int(round(float(cu))), int(round(float(cv)))
        if not (EDGE_PX <= iu < w - EDGE_PX and EDGE_PX <= iv < h - EDGE_PX):
            continue
        near = diff[iv - 2:iv + 3, iu - 2:iu + 3]
        dv, du = divmod(int(np.argmin(near)), near.shape[1])
        copy = -float(near[dv, du])
        if copy >= TURN_MATCH * peak and copy >= TURN_SNR * max(least, float(local[iv - 2 + dv, iu - 2 + du])):
            pixel = _centroid(diff, v, u, peak)
            paths = {n: distance_to_path(own if n == laser else path_of(rig, n)[0], np.array(pixel))[0]
                     for n in rig.laser_names}
            return StaysPut(pixel, snr, from_path_px=paths)
    return best
