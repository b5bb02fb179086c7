"""What the frames' noise is like, from the frames themselves: JPEG's blocks, the step between the
values a camera delivers, the laser-on minus laser-off difference's noise by the room's level, and
the matched filter a spot is detected by. Pure numpy (and one OpenCV box filter), no state:
`edge.vision.SpotFinder` measures these once per frame group, at the pixels `edge.paths.Strips`
reads: how the noise is correlated (`noise_texture`), and how much of it each stretch of a path
holds (`local_noise`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from edge.spotshape import monomials

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
    `local_noise`'s to measure), nor quieter than `least`, nor than a darker bin; a bin with too few
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


# Offsets (du, dv) of the neighbours of each background sample that are read too: the noise's
# correlation at lags 1 and 2 along rows and columns, and (with (1, 1)) all four Bayer phases.
NEIGHBOURS = ((1, 0), (2, 0), (0, 1), (0, 2), (1, 1))
# Red's noise differs this much between the four pixels of a 2 × 2 block only behind a Bayer filter
# (demosaicing interpolates red at three of them, which averages their noise).
BAYER_CONTRAST = 1.25
# Or, where the red pixels' noise is no higher than the greens' (a gradient-led demosaicing, VNG,
# builds red at a green pixel from that pixel's own green, noise and all), the blue pixels' is this
# much lower: their red is the mean of four red pixels. (On the tuning family's raw frames, each
# condition's median: bilinear and edge-aware 0.53–0.75, VNG 0.62–0.85; JPEG at quality 80–90 over a
# filter, whose blocks keep little of its pattern, 0.88–0.96. JPEG's 4:2:0 chroma can still pass for
# a filter, as it can by the louder red pixel: tuning-31, no filter, 0.68 and 1.46.)
BAYER_LOW_CONTRAST = 0.75
# Red's noise spread over neighbours (demosaiced) and yet the same at all four parities, summed over
# a finder's first looks: no colour filter's pixels at this size. A Pi camera's ISP demosaics its
# sensor's 1640 × 1232 and scales that to 640 × 480: every output pixel mixes red from several red
# pixels, and a spot is locked to no grid. Measured over 8 looks (their shares summed, the largest
# over the smallest): behind a filter at the frame's own size (tuning 1792-1983, 51 lossless
# conditions: bilinear, VNG, edge-aware) 1.25-4.2, VNG's the lowest; a 3-colour sensor 1.04-1.14;
# the simulator's Bayer frames at 1640 × 1232 scaled to 640 × 480 by area (office and kitchen, three
# demosaicings, a dim room: tools/isp_scaled.py) 1.02-1.07. A filter taken for scaled frames would
# lose its spots' demosaicing σ: the line sits nearer the scaled frames.
RESAMPLED_CONTRAST = 1.15
# And where the chroma's noise is as uncorrelated 2 px apart as a raw pipeline leaves it (the
# median of the same looks' correlations: `SpotFinder._chroma_correlation`). JPEG at high quality
# can hide a filter's pattern from the noise and still not show its blocks (tuning-10: a bilinear
# filter at quality 90, 4:4:4, contrast 1.06), but correlates the chroma over its blocks: -0.10
# there, 0.09 and 0.18 in two 3-colour conditions at 92 and 65. The scaled frames read -0.003-0.04
# (nine recordings, and one scaled bilinearly and bicubically instead), a 3-colour sensor 0.02.
RESAMPLED_CHROMA = 0.06


# Not frozen (never changed once made but by the finder's own look): a frozen dataclass costs
# 4 × as much to build; see edge.vision.Candidate.
@dataclass
class Texture:
    """How the difference image's noise is structured (`noise_texture`)."""

    # (The defaults: white noise, no Bayer filter.)
    area: float = 1.0  # Σ of its correlation over neighbouring pixels: a centroid's variance grows by it
    sites: float = 1.0  # the same over a Bayer filter's red pixels alone (2 px apart)
    bayer: int | None = None  # the (row, column) parity of red pixels, 2·row + column; None: no filter seen
    demosaiced: bool = False  # red read from a colour frame whose red noise is spread over neighbours
    # Where demosaiced: each (row, column) parity's share of red's noise power (`parity_contrast`).
    parity: tuple[float, float, float, float] | None = None
    # The correlations 1 and 2 px apart along u, then along v (`centroid_growth`); zero: white noise.
    lags: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


def parity_contrast(shares: Sequence[Sequence[float]]) -> float:
    """The four (row, column) parities' shares of red's noise power (`Texture.parity`), summed over
    `shares` (looks at several frames): the largest over the smallest (1: no parity stands out;
    inf where a parity has none)."""
    total = np.sum(np.asarray(shares, dtype=np.float64), axis=0)
    low = float(total.min())
    return float(total.max()) / low if low > 0.0 else math.inf


# The look for scaled frames (`ScalingLook`) decides from this many looks on (as `auto` decides its
# channel from the first 8 groups). Where their chroma shows none of JPEG's correlation but a parity
# still stands out, it goes on, up to SCALED_LOOKS, until the parities even out: 8 looks leave their
# contrast noisy. The accuracy family's ISP conditions (tuning 0-63 and 1792-2111, 31 conditions) read
# 1.01-1.16 over 8 looks and 1.01-1.08 over 32 (tuning-13, 1.16, under the line from its 10th);
# filters at the frame's own size hold steady: at least 1.21 over any 8 to 32 looks (138 lossless
# conditions of tuning 0-63, 640-703 and 1792-2175; VNG lowest, tuning-2111). Chroma that
# shows JPEG ends the look: each look's chroma is noisy (tuning-10, JPEG at quality 90 with a
# filter: -0.18 to 0.15), and a median asked again and again would at last slip inside the line
# (-0.10 over 8 looks, -0.044 over 12).
SCALED_FIRST_LOOK = 8
SCALED_LOOKS = 32


class ScalingLook:
    """A finder's look at whether its colour frames were scaled after demosaicing (`resampled`),
    over its first groups whose red noise is spread: decided from SCALED_FIRST_LOOK looks on, and
    kept once told, or once the chroma has shown JPEG."""

    def __init__(self) -> None:
        self.shares: list[tuple[float, float, float, float]] = []  # each look's `Texture.parity`
        self.chroma: list[float] = []  # the same looks' chroma correlations 2 px apart, where measured
        self.told = False
        self.refused = False  # the chroma showed JPEG's correlation: no more looks

    @property
    def looking(self) -> bool:
        return not (self.told or self.refused) and len(self.shares) < SCALED_LOOKS

    def look(self, shares: tuple[float, float, float, float], chroma: float | None) -> bool:
        """Add one look (its parities' `shares` and chroma correlation `chroma`, None where not
        measured); True when the looks so far tell scaled frames."""
        self.shares.append(shares)
        if chroma is not None:
            self.chroma.append(chroma)
        if len(self.shares) < SCALED_FIRST_LOOK:
            return False
        self.refused = bool(self.chroma) and not raw_chroma(self.chroma)
        self.told = resampled(self.shares, self.chroma)
        return self.told


def raw_chroma(chroma: Sequence[float]) -> bool:
    """Is the chroma's noise as uncorrelated 2 px apart as a raw pipeline leaves it (the median of
    `chroma`, looks' correlations, within RESAMPLED_CHROMA)? False where none was measured."""
    return bool(chroma) and abs(float(np.median(chroma))) <= RESAMPLED_CHROMA


def resampled(shares: Sequence[Sequence[float]], chroma: Sequence[float]) -> bool:
    """Do these looks show red's noise spread over neighbours by no colour filter at this size:
    `shares` (`Texture.parity`) no parity standing out (RESAMPLED_CONTRAST), and `chroma` (their
    chroma noise's correlations 2 px apart) none of JPEG's (RESAMPLED_CHROMA)? False where either
    is empty: no evidence."""
    if not shares or not chroma:
        return False
    return parity_contrast(shares) < RESAMPLED_CONTRAST and raw_chroma(chroma)


def noise_texture(block: np.ndarray, centre: float, noise: float, red_of_colour: bool,
                  parity: tuple[list[int], np.ndarray, list[float]]) -> Texture:
    """How the difference image's noise is correlated, from `block`, the difference at background
    samples (its first row) and their neighbours at NEIGHBOURS (a row each; `centre` their median,
    `noise` their σ): JPEG's blocks and a demosaicing's interpolation spread one pixel's noise over
    its neighbours, so that a spot's position is less certain than white noise would make it; and
    where red is read from colour frames (`red_of_colour`), whether a Bayer filter is behind them
    and which pixels saw red (their noise is the sensor's; demosaicing averages the others').
    `parity`: the block's rows that give each (row, column) parity, a one-hot matrix of each of
    their values' parity, and each parity's count (`edge.paths.Strips`)."""
    if not block.size or noise <= 0.0:
        return Texture()
    lim = 5.0 * noise
    block = block.reshape(1 + len(NEIGHBOURS), -1) - centre
    samples = np.minimum(np.maximum(block, -lim, out=block), lim, out=block)
    d0 = samples[0]
    dots = samples.dot(d0)  # (6,): the variance, then each neighbour's covariance
    var0 = float(dots[0])
    if var0 <= 0.0:
        return Texture()
    rho = dict(zip(NEIGHBOURS, (dots[1:] / var0).tolist()))
    along_u = 1.0 + 2.0 * rho[(1, 0)] + 2.0 * rho[(2, 0)]
    along_v = 1.0 + 2.0 * rho[(0, 1)] + 2.0 * rho[(0, 2)]
    area = min(max(along_u * along_v, 1.0), 25.0)
    bayer = None
    shares = None
    demosaiced = red_of_colour and max(rho[(1, 0)], rho[(0, 1)]) > 0.15
    if demosaiced:
        # The four (row, column) parities: the sample's own and its neighbours' flips.
        rows, onehot, count = parity
        sq = samples[rows]
        power = ((sq * sq).ravel() @ onehot).tolist()
        power = [p / c for p, c in zip(power, count)]
        total = sum(power)
        if total > 0.0:
            shares = (power[0] / total, power[1] / total, power[2] / total, power[3] / total)
        low, mid1, mid2, high = sorted(power)
        if low > 0 and high > BAYER_CONTRAST * 0.5 * (mid1 + mid2):
            bayer = power.index(high)
        elif 0 < low < BAYER_LOW_CONTRAST * 0.5 * (mid1 + mid2):
            bayer = power.index(low) ^ 3  # (the red pixel is the blue one's diagonal neighbour)
    # The red pixels of a Bayer filter are 2 px apart: their noise is correlated only as far.
    sites = min(max((1.0 + 2.0 * max(rho[(2, 0)], 0.0)) * (1.0 + 2.0 * max(rho[(0, 2)], 0.0)), 1.0), 25.0)
    lags = (rho[(1, 0)], rho[(2, 0)], rho[(0, 1)], rho[(0, 2)])
    return Texture(area, sites, bayer, demosaiced, shares, lags)


@functools.lru_cache(maxsize=16)
def _pair_index(n: int) -> tuple[np.ndarray, np.ndarray]:
    """For an n × n window, flat, with a 0 and a 1 appended (at n², n² + 1): each pixel's partner
    in the window's pixels (the 1: the pixel alone) and in its pairs of pixels 1 and 2 apart along
    rows, then along columns (the 0 where the partner lies outside), the pair at its first pixel,
    (5, n²); and (1, x, y, x², y²) of every pixel (n², 5), offsets from the centre (`monomials`')."""
    v, u = np.divmod(np.arange(n * n), n)
    zero, one = n * n, n * n + 1
    partner = [np.full(n * n, one)]
    for du, dv in ((1, 0), (2, 0), (0, 1), (0, 2)):
        inside = (u + du < n) & (v + dv < n)
        partner.append(np.where(inside, (v + dv) * n + u + du, zero))
    return np.stack(partner), np.ascontiguousarray(monomials(n // 2)[:, :5])


def centroid_growth(used: np.ndarray, du: float, dv: float, lags: tuple[float, float, float, float]
                    ) -> tuple[float, float]:
    """How much the noise's correlation (`lags`, `Texture.lags`) grows the variance of a centroid
    over the pixels `used` (a (2r + 1)² window, 1 where used, 0 not; the centroid at (du, dv) from
    its centre): per axis (u, v), at least 1. `Texture.area` is the growth of a sum over many
    pixels; a centroid weighs its pixels by their offset from it, which changes sign across the
    spot, so that neighbours' shared noise partly cancels along its own axis (over 5 pixels in a
    row, the correlation 1 px apart grows it 0.4 × as much as a sum's; over 3, not at all).

    A pixel's weight on the u axis is its offset x − du: over the pairs of used pixels s apart,
    Σ (x − du)(x + s − du) along a row, Σ (x − du)² down a column, and so on, which the moments of
    each kind of pair give (one product of all five kinds: numpy's calls, not the arithmetic on a
    few dozen pixels, are what this costs)."""
    partner, mono = _pair_index(used.shape[0])
    flat = np.concatenate([used.ravel(), (0.0, 1.0)])
    pairs = flat.take(partner)
    pairs *= flat[:-2]
    moments = pairs.dot(mono).tolist()  # per kind: Σ 1, Σ x, Σ y, Σ x², Σ y² at the pair's first pixel

    def about_u(k: int) -> float:
        c, sx, _, sxx, _ = moments[k]
        return sxx - 2.0 * du * sx + du * du * c

    def about_v(k: int) -> float:
        c, _, sy, _, syy = moments[k]
        return syy - 2.0 * dv * sy + dv * dv * c

    ru1, ru2, rv1, rv2 = lags
    (c1, x1, _, _, _), (c2, x2, _, _, _), (c3, _, y3, _, _), (c4, _, y4, _, _) = moments[1:]
    total_u, total_v = about_u(0), about_v(0)
    grown = []
    for total, along_u, along_v in (
        (total_u, ru1 * (about_u(1) + x1 - du * c1) + ru2 * (about_u(2) + 2.0 * (x2 - du * c2)),
         rv1 * about_u(3) + rv2 * about_u(4)),
        (total_v, ru1 * about_v(1) + ru2 * about_v(2),
         rv1 * (about_v(3) + y3 - dv * c3) + rv2 * (about_v(4) + 2.0 * (y4 - dv * c4))),
    ):
        grown.append(1.0 if total <= 0.0 else max((1.0 + 2.0 * along_u / total) * (1.0 + 2.0 * along_v / total), 1.0))
    return grown[0], grown[1]


# Each two pixels of a row that share one chroma pair (a webcam's YUYV stream, YUV 4:2:2, as
# OpenCV decodes it) differ in chroma by rounding alone, and a pair's second pixel from the next
# pair's first by the noise: `paired_chroma`, the mean step within pairs over the mean step across
# them. On the simulator's frames (three aims each): YUYV 0.18-0.26, and 0-0.08 in a dim room,
# where rounding is all the noise there is; uncompressed 4:4:4, with or without a Bayer filter,
# 0.92-1.07. (JPEG reads 0.07-0.26 at 4:2:0 and 0.65-0.72 at 4:4:4: it is told by its blocks first.)
PAIRED_CHROMA = 0.5


def paired_chroma(on: np.ndarray, off: np.ndarray, v: np.ndarray, u: np.ndarray) -> float | None:
    """The chroma (red minus green) of the difference of colour frames `on` and `off`, about the
    pixels (v, u): its mean absolute step between the two pixels of a pair that starts at an even
    column, over that from the pair's second pixel to the next pair's first (PAIRED_CHROMA); None
    where it shows no step to tell by."""
    start = (u - u % 2).astype(np.intp)
    keep = start + 2 < on.shape[1]
    rows, start = v[keep].astype(np.intp), start[keep]
    cols = start[:, None] + np.arange(3)
    rows = np.broadcast_to(rows[:, None], cols.shape)
    if not start.size:
        return None
    diff = on[rows, cols].astype(np.float32) - off[rows, cols].astype(np.float32)
    step = np.abs(np.diff(diff[..., 2] - diff[..., 1], axis=1))  # (within a pair, across to the next)
    within, across = step.mean(axis=0).tolist()
    return within / across if across > 0.0 else None


# Path samples (about half a pixel apart) whose noise `local_noise` measures together.
STRETCH = 48


def local_noise(strips: np.ndarray, noise: float, floor: np.ndarray | None,
                counts: Sequence[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Along every path, in stretches of STRETCH samples (about 24 px): the level and noise (mean
    absolute deviation) of the strip's pixels and of a box filter of 3 columns × 5 samples (about
    a spot's size: a matched filter). A textured surface leaves more of JPEG's and the room's
    noise in the difference than the flat background does, and a bright window's glare more
    still: each stretch is judged by its own. `strips` is (width, path samples); `floor`, per
    path sample, the least noise there (`noise_by_level`: less where the room is dark), else
    `noise`, the picture's; `counts`, how many samples each stretch has (the last takes the rest:
    `edge.paths.Strips.stretch_counts`). Returns, per path sample, the pixel noise (at least the
    floor) and the box's SNR at its best column; and the box filter (width − 2, path samples)."""
    width, n = strips.shape
    box = spot_box(strips)
    block = STRETCH
    nb = max(1, n // block)
    cut = nb * block
    # Mean absolute deviation, each value clipped at 4 × the flat background's: a robust and
    # cheap scale (a spot's own pixels barely move it); × 1.2533 is σ for Gaussian noise.
    # The pixel noise from the strip's outermost columns, 3 px from the path: beside a spot,
    # not on it, so that a spot does not raise its own threshold.
    pix = np.abs(strips[:: width - 1, :cut]).reshape(2, nb, -1)
    flt = box[:, :cut].reshape(width - 2, nb, -1)
    per = 2 * pix.shape[2]
    # (np.add.reduce and np.maximum.reduce: ndarray.sum's and .max's own reductions, without
    # their Python wrappers)
    pix_noise = np.add.reduce(np.minimum(pix, 6.0 * noise, out=pix), axis=(0, 2)) * (1.2533 / per)
    box_floor = np.float32(noise * BOX_PIXELS**0.5)
    per = flt.shape[0] * flt.shape[2]
    box_level = np.add.reduce(flt, axis=(0, 2)) * (1.0 / per)
    dev = flt - box_level[None, :, None]
    np.abs(dev, out=dev)
    box_noise = np.add.reduce(np.minimum(dev, 4.0 * box_floor, out=dev), axis=(0, 2)) * (1.2533 / per)
    # Each stretch's value repeated over its samples: the same as .take() of each sample's
    # stretch, for half the instructions (a run of copies, not an index read per sample).
    # Halfway (geometrically) between the flat background's noise and the stretch's: enough to
    # keep JPEG's ghosts on a textured surface below the threshold, not so much that a spot's
    # own neighbourhood hides it.
    if floor is None:
        local_pix = np.sqrt(np.maximum(pix_noise, noise) * noise).repeat(counts)
        local_box = np.maximum(box_noise, box_floor).repeat(counts)
    else:
        local_pix = np.sqrt(np.maximum(pix_noise.repeat(counts), floor) * floor)
        local_box = np.maximum(box_noise.repeat(counts), floor * np.float32(BOX_PIXELS**0.5))
    score = (np.maximum.reduce(box, axis=0) - box_level.repeat(counts)) / local_box
    return local_pix, score, box
