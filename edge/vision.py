"""Finding laser spots: difference imaging along each laser's epipolar band, sub-pixel positions.

A laser's spot can only appear on its image path over the working range (the epipolar segment,
derived from the rig), so everything here looks only there: a narrow strip of pixels along each
path, plus a sparse sample of the rest of the frame to measure how the room light changed between
the laser-off and laser-on frames (flicker). That keeps one on/off pair well under a millisecond at
640 × 480 and makes the cost grow with the path length, not the frame size.

Per frame group (on frames and off frames taken at one pose), :meth:`SpotFinder.find` returns the
candidate spots on each laser's path: sub-pixel position (centroid of the background-subtracted,
thresholded difference in a window that follows and fits the spot), its uncertainty from the pixel
noise, and its strength.
Frames may be 8- or 16-bit, grey or BGR; values are scaled to [0, 1] by their type's range.
"""

from __future__ import annotations

import bisect
import functools
import math
from collections import deque
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from edge.framenoise import (
    NEIGHBOURS,
    NOISE_FLOOR_FRACTION,
    PAIRED_CHROMA,
    ScalingLook,
    Texture,
    centroid_growth,
    jpeg_blockiness,
    kth,
    level_bins,
    local_noise,
    noise_by_level,
    noise_texture,
    paired_chroma,
    value_step,
)
from edge.paths import Strips, full_scale
from edge.redsites import SiteLook
from edge.rig import Rig
from edge.spoterror import (
    BLOCK_SIGMA_PX,
    JPEG_COMMON_PX,
    LUMA_DEMOSAIC_PX,
    LUMA_JPEG_COMMON_PX,
    block_snapped,
    demosaic_px,
    misfit_grow,
)
from edge.spotshape import border_index, border_level, fit_gaussian, fit_round, fit_sites, fit_unsaturated, window_kit
from edge.stuck import lit_in_off, lit_spots

# What a colour frame's spot is read from, as weights of its B, G, R channels. `red` suits raw or
# lossless frames of a red pointer; `luma` suits JPEG (MJPEG webcams), which keeps only luminance
# at full resolution and blurs and shifts a small red spot's chroma by up to a pixel.
# `auto` reads luma when the frames' chroma is at half resolution (JPEG 4:2:0), else red.
CHANNEL_WEIGHTS = {"red": (0.0, 0.0, 1.0), "luma": (0.114, 0.587, 0.299)}
CHANNELS = (*CHANNEL_WEIGHTS, "auto")
# Chroma stored at half resolution (JPEG's 4:2:0) and interpolated back leaves the noise of red
# minus green correlated 2 px apart (0.45-0.85 measured, higher at lower quality); full-resolution
# chroma (raw, PNG, a demosaiced Bayer filter) leaves it near 0.1 or below, JPEG 4:4:4 0.3-0.65.
CHROMA_LAG2 = 0.4
# `auto` decides from this many frame groups (the median of their chroma correlations), then keeps it.
AUTO_GROUPS = 8
# JPEG frames: steps across the 8 × 8 blocks' boundaries this many times those inside blocks (1.27-16
# for qualities 51-89 on the tuning family, at most 1.02 for frames never compressed, and for 90).
JPEG_BLOCKINESS = 1.15


# A spot whose detection needs this matched-filter SNR (box filter about a spot's size, against the
# noise measured along the same stretch of its path) is a seed even when its brightest pixel is
# below `min_snr`: a dim spot is found where the noise allows, a bright window's glare is not.
MATCHED_SNR = 5.0
# How far off a laser's path `find` keeps a blob of its strip as a stray (px): two lasers' spots
# run together (the centre and parallel beams, 4 cm apart, on a small camera or far away) make one
# blob between their paths, up to half their spacing from each.
STRAY_REACH_PX = 3.0
# A spot's red pixels tell its width when its log's variance is below this (the prior's is 0.16);
# then other spots at much the same depth, in this view or earlier ones, are held near the widths
# so told, within this much (log px).
_WIDTH_TOLD = 0.1
_SHARED_WIDTH_SPREAD = 0.1
# A spot's width follows its depth: told widths count for a spot at another inverse depth as
# exp(−½ (Δ/scale)²), scale in 1/m; the finder keeps the latest so many (one sweep's zones).
_WIDTH_DEPTH_SCALE = 0.1
_TOLD_KEPT = 64
# A fit of a spot's own-colour pixels that leaves more than SITE_MISFIT × the χ² of the noise has
# not found the spot's shape. JPEG's rounding, which the noise measured in a dim room's background
# does not show, leaves a bright spot's red pixels 13-30 × it (tuning-371, quality 94), where the
# fit still places the spot far better than the demosaiced centroid: there it may leave this much.
SITE_MISFIT = 10.0
SITE_MISFIT_JPEG = 40.0
# Steps of the Gauss–Newton fit of a JPEG frame's spot (`fit_round`): from the centroid it
# settles in 2-4 (tuning 320-959: 2 steps left 10 wrong `ok` where 4 left 6; 8 as 4).
ROUND_FIT_STEPS = 4

# A pixel at this fraction of full scale in a laser-on frame is taken as clipped.
_SATURATED = 0.985


def _scaled_plane(plane: np.ndarray, rows, cols, scale: float) -> np.ndarray:
    """A region of one plane times `scale` (float32): the same float32 product as
    np.multiply(…, dtype=np.float32), whose buffered casting loop costs more than the arithmetic
    on a window this small."""
    out = plane[rows, cols].astype(np.float32)
    out *= scale
    return out


# Not frozen, though never changed once made (`replace` makes a new one): a frozen dataclass's
# __init__ sets each field through object.__setattr__, which made building one cost 4 × as much
# (issue 15: one is made for every spot of every frame group).
@dataclass
class Candidate:
    """A spot found on one laser's path in one frame group."""

    laser: str
    pixel: np.ndarray  # (2,) float64 sub-pixel (u, v)
    sigma_px: float  # 1-σ position uncertainty (px): of the worse-placed axis
    snr: float  # peak of the difference over the noise
    size_px: float  # RMS radius of the spot
    along: float  # inverse depth at the nearest path sample (1/m)
    cross_px: float  # distance from the path, px
    matched_snr: float = 0.0  # the seed's matched-filter SNR against the noise along its path
    misfit: float = 1.0  # χ² per degree of freedom of a Gaussian fitted to the spot (1: it fits)
    # The position's covariance (var u, var v, cov uv; px²), where its axes are placed unequally
    # well: only the part along the laser's path moves the depth. None: sigma_px² on each axis.
    cov_px: tuple[float, float, float] | None = None
    # Behind a Bayer filter, the spot's width as its own-colour pixels' fit found it: (log px, its variance).
    site_width: tuple[float, float] | None = None
    # The part of sigma_px that comes from where the spot falls on the pixel grid (demosaicing's
    # pull toward red pixels): a view nudged by a fraction of a pixel keeps most of it, so it does
    # not average over a zone's views as pixel noise and speckle do (tuning 0-191: two views' errors
    # correlate 0.6 behind a Bayer filter with a small spot, 0.03 without one).
    locked_px: float = 0.0
    # The pixel noise `snr` is against: the local noise along the path where the spot was found
    # (0: not told). Two spots fitted together out of its blob are told their SNR against it too.
    noise: float = 0.0


@dataclass(frozen=True)
class FrameKind:
    """What kind of frames a camera delivers, and what the finder makes of them
    (:meth:`SpotFinder.frame_kind`)."""

    jpeg: bool  # JPEG's: spots snapped to a block's centre line are widened, JPEG_COMMON_PX shared
    blockiness: float  # `jpeg_blockiness` of the laser-off frame it was told by (1: never JPEG)
    colour: bool
    channel: str  # what spots are read from: "red" or "luma" of colour frames, "grey"
    # `auto`'s evidence from this pair: its chroma noise's correlation 2 px along a row (over
    # CHROMA_LAG2: chroma at half resolution); None where none was measured (another channel set,
    # or `auto` already decided) or the chroma shows no noise to tell by.
    chroma_lag2: float | None
    # red interpolated between a colour filter's pixels: spots carry DEMOSAIC_PX (colour JPEG frames
    # read in luma are taken to be: LUMA_DEMOSAIC_PX)
    demosaiced: bool
    bayer_red: tuple[int, int] | None  # (row, column) parity of a Bayer filter's red pixels; None: none seen
    noise: float  # pixel noise (robust σ) of the two frames' difference, full-scale units; 0: none
    area: float  # how far that noise is spread over neighbouring pixels (1: white; a centroid's variance × it)
    paired: bool = False  # colour pixels sharing their chroma in pairs (a YUYV stream: `paired_chroma`)
    # Where red's noise is spread (demosaiced): each (row, column) parity's share of its power, and the
    # chroma noise's correlation 2 px apart (whatever the channel), which looks at several pairs pool
    # to tell frames scaled after demosaicing (`framenoise.resampled`).
    parity: tuple[float, float, float, float] | None = None
    chroma: float | None = None


# A seed of a spot (`SpotFinder._seeds`): its pixel (u, v), peak, strip row, matched-filter SNR and the
# pixel noise there.
Seed = tuple[int, int, float, int, float, float]


class SpotFinder:
    """Spot detection for one rig and frame size; build once, call :meth:`find` per group."""

    def __init__(
        self,
        rig: Rig,
        band_halfwidth_px: float = 3.0,
        min_snr: float = 6.0,
        max_spot_px: float = 6.0,
        lasers: Sequence[str] | None = None,
        channel: str = "red",
        path_tolerance_px: float = 1.5,
    ):
        self.rig = rig
        self.min_snr = min_snr
        self.max_spot_px = max_spot_px
        self.halfwidth = band_halfwidth_px
        self.path_tolerance = path_tolerance_px
        if channel not in CHANNELS:
            raise ValueError(f"channel must be one of {', '.join(CHANNELS)}, got {channel!r}")
        self._auto = channel == "auto"
        self._chroma_lag2: list[float] = []  # `auto`'s measurements so far
        # Colour frames whose pixels share their chroma in pairs (a webcam's YUYV stream), told by
        # the first AUTO_GROUPS groups (`paired_chroma`, their median): then no red pixel keeps its
        # own value, and spots are never placed by a Bayer filter's red pixels. The looks are
        # counted whether or not they told anything, so that frames with no chroma noise to tell
        # by (a monochrome sensor delivered as colour) are not looked at group after group.
        self._pair_steps: list[float] = []
        self._pair_looks = 0
        self._paired = False
        # Colour frames whose red noise is spread over neighbours by no colour filter at this size
        # (a Pi camera's ISP scales what it demosaiced), told by the first groups whose red noise is
        # spread (`ScalingLook`: their parities and the chroma's correlation): then spots are placed
        # as in frames without a filter, with none of demosaicing's σ, and no filter is looked for.
        self._scaling = ScalingLook()
        self._weights = CHANNEL_WEIGHTS["red" if self._auto else channel]  # (B, G, R) of a colour frame
        names = list(lasers) if lasers is not None else list(rig.laser_names)
        self.strips = Strips(rig, names, band_halfwidth_px)  # the pixels it reads of each frame
        self.bands = self.strips.bands
        # Window half-size for localisation; it grows for big spots.
        self._radius = 4
        self._jpeg: bool | None = None  # are the frames JPEG's? (from the first laser-off frame)
        self._demosaiced = False  # were the frames of the last `find` demosaiced? (grid_px)
        self._aside = False  # is `find` reading another channel than the finder's, for one search?
        # The full scale of the camera's own values where they were linearised before the finder
        # saw them (`delivered`): their quantisation, not the linear values', floors the noise.
        self._delivered_scale: float | None = None
        self._step: float | None = None  # the step between the values a frame can hold (value_step)
        # Behind a Bayer filter: the widths that spots' red pixels told, with where (inverse depth).
        self._told: deque[tuple[float, float, float]] = deque(maxlen=_TOLD_KEPT)
        # A Bayer filter that the noise does not show, as bright spots tell it (edge.redsites).
        self._sites = SiteLook()

    @staticmethod
    def laser_channel(image: np.ndarray) -> np.ndarray:
        """The channel that carries a red laser: red of BGR, or grey. A view, not a copy."""
        return image[..., 2] if image.ndim == 3 else image

    def lit_in_off(self, off: np.ndarray, laser: str, near: tuple[float, float] | None = None) -> bool:
        """Whether `laser`'s spot shows in a laser-off frame (`edge.stuck.lit_in_off` along its strip)."""
        return lit_in_off(self.bands[laser], off, self.max_spot_px, near)

    def lit_spots(self, off: np.ndarray, laser: str) -> list[tuple[float, float]]:
        """Where `laser`'s spot may show in a laser-off frame (`edge.stuck.lit_spots` along its strip)."""
        return lit_spots(self.bands[laser], off, self.max_spot_px)

    def delivered(self, frame: np.ndarray) -> None:
        """Told, before the first frames of a sweep are found in, a frame as the camera delivered
        it where the frames the finder is given were made linear from it (ranging's
        `frame_gamma`): whether it is JPEG's, and the step of its values, are read from it."""
        self._delivered_scale = self.full_scale(frame)
        # Through a curve, the gaps between delivered values are the curve's (a steep toe spreads
        # the shadows' few levels apart), not the sensor's: one level of the delivered scale, as
        # before the values' step was measured.
        self._step = 1.0
        self.told_by(frame)  # (JPEG or not; the step is told above)

    def told_by(self, frame: np.ndarray) -> None:
        """Told, once, by a laser-off frame as the camera delivered it, whether the frames are
        JPEG's and the step of their values (1 where `delivered` told it first): `find` tells
        them by its first; frames turned back onto others (`edge.motion`), whose interpolation
        hides both, are told by the frame before it."""
        if self._jpeg is None:
            self._jpeg = jpeg_blockiness(frame) > JPEG_BLOCKINESS
        if self._step is None:
            self._step = value_step(frame)

    full_scale = staticmethod(full_scale)

    def _plane(self, image: np.ndarray, rows, cols) -> np.ndarray:
        """The read channel of a region of `image`, float32."""
        if image.ndim == 2:
            return image[rows, cols].astype(np.float32)
        if self._weights == (0.0, 0.0, 1.0):
            return image[rows, cols, 2].astype(np.float32)
        return image[rows, cols, :3].astype(np.float32) @ np.array(self._weights, np.float32)

    def _one_plane(self, frames: Sequence[np.ndarray]) -> bool:
        """Is the read channel of `frames` one plane of one frame (grey, or red read alone)?"""
        return len(frames) == 1 and (frames[0].ndim == 2 or self._weights == CHANNEL_WEIGHTS["red"])

    def _scaled(self, frames: Sequence[np.ndarray], rows, cols, scale: float) -> np.ndarray:
        """The read channel of a region, summed over `frames` and times `scale` (float32)."""
        if self._one_plane(frames):
            return _scaled_plane(self.laser_channel(frames[0]), rows, cols, scale)
        acc = self._plane(frames[0], rows, cols)
        for image in frames[1:]:
            acc += self._plane(image, rows, cols)
        acc *= scale
        return acc

    def _window(self, frames: Sequence[np.ndarray], rows, cols) -> np.ndarray:
        acc = self._plane(frames[0], rows, cols)
        for image in frames[1:]:
            acc += self._plane(image, rows, cols)
        return acc * np.float32(1.0 / (len(frames) * self.full_scale(frames[0])))

    def _quantum(self, frame: np.ndarray, laser_off: np.ndarray, frames: int = 1) -> float:
        """The noise floor that quantisation sets (full scale) on a difference of `frames` frames
        of each kind averaged: half the step between the values the camera delivers (`value_step`
        of `laser_off` until `find` has told it once)."""
        step = self._step if self._step is not None else value_step(laser_off)
        return 0.5 * step / ((self._delivered_scale or self.full_scale(frame)) * math.sqrt(frames))

    def _choosing_channel(self, frame: np.ndarray) -> bool:
        """Is `auto` still measuring colour frames' chroma to choose its channel? (Not once spots
        told a Bayer filter: red then.)"""
        return self._auto and len(self._chroma_lag2) < AUTO_GROUPS and frame.ndim == 3 and self._sites.parity is None

    def _pairs_told(self, steps: list[float], on: np.ndarray, off: np.ndarray) -> bool:
        """Do colour frames share their chroma in pixel pairs, by the `paired_chroma` of the
        groups so far, `steps`, and of this one (added to `steps`)?"""
        ratio = paired_chroma(on, off, *self.strips.near_samples())
        if ratio is not None:
            steps.append(ratio)
        return bool(steps) and float(np.median(steps)) < PAIRED_CHROMA

    def _scaling_told(self, texture: Texture, rho: float | None, on: np.ndarray, off: np.ndarray) -> bool:
        """Look, in the first groups whose red noise is spread (`texture.parity`), at whether the
        frames were scaled after demosaicing (`ScalingLook`), with the chroma correlation `rho`
        where `auto` measured it for this pair already; True when this look told it (`_texture`
        then takes no filter). JPEG and YUYV frames are not looked at, nor frames whose bright
        spots' red bends told a filter (`SiteLook` sees past the noise)."""
        if (texture.parity is None or self._jpeg or self._paired or self._sites.parity is not None
                or not self._scaling.looking):
            return False
        return self._scaling.look(texture.parity, rho if rho is not None else self._chroma_correlation(on, off))

    @staticmethod
    def _auto_weights(told: Sequence[float]) -> tuple[float, float, float]:
        """`auto`'s channel from the chroma correlations `told` so far: luma where their median
        says the chroma is at half resolution, else red."""
        return CHANNEL_WEIGHTS["luma" if float(np.median(told)) > CHROMA_LAG2 else "red"]

    def _difference(self, on: Sequence[np.ndarray], off: Sequence[np.ndarray]
                    ) -> tuple[np.ndarray, np.ndarray, float, float]:
        """The read channel's laser-on minus laser-off difference at every strip and background
        pixel (`Strips.gather`'s order): (the difference, the laser-off values as scaled, the scale, the
        laser-off background's mean level before it). Room light may differ between the frames
        (flicker): the off frames are scaled to the on frames by least squares on pixels where no
        laser can land."""
        background = self.strips.background
        on_vals = self.strips.gather(on, self._weights)
        off_vals = self.strips.gather(off, self._weights)
        bon, boff = on_vals[background], off_vals[background]
        # (ndarray.dot: the same BLAS dot as @, with less overhead; so below)
        denom = float(boff.dot(boff))
        gain = float(bon.dot(boff)) / denom if denom > 0 else 1.0
        # (np.add.reduce: ndarray.sum's own reduction, without its Python wrapper)
        off_level = float(np.add.reduce(boff)) / boff.size if boff.size else 0.0  # (before boff is scaled below)
        # on − gain·off, in place: two fewer arrays of every strip and background pixel
        off_vals *= gain
        return np.subtract(on_vals, off_vals, out=on_vals), off_vals, gain, off_level

    def _spread(self, diff: np.ndarray) -> tuple[float, np.ndarray, float]:
        """The background samples of `_difference`: their median, each one's absolute deviation
        from it (in their order) and the pixel noise, robustly (MAD; 0 where there are none)."""
        bg = diff[self.strips.background]
        if not bg.size:
            return 0.0, bg, 0.0
        mid = bg.size // 2
        work = bg.copy()
        centre = kth(work, mid)
        # The deviations in the partitioned copy's buffer; their median from a copy of them.
        deviation = np.abs(np.subtract(bg, centre, out=work), out=work)
        return centre, deviation, 1.4826 * kth(deviation.copy(), mid)

    def find(
        self,
        on: Sequence[np.ndarray],
        off: Sequence[np.ndarray],
        lasers: Sequence[str] | None = None,
        max_candidates: int = 3,
        near: Mapping[str, tuple[float, float]] | None = None,
        threshold: float = 1.0,
        channel: str | None = None,
        strays: list[Candidate] | None = None,
        wanted: Collection[str] | None = None,
    ) -> dict[str, list[Candidate]]:
        """Candidate spots per laser from laser-on and laser-off frames of one pose.

        Several frames of each kind are averaged (same pose: same speckle, less pixel noise).
        `lasers`: the lasers that were on (default: all of this finder's). Behind a Bayer filter,
        spots are placed twice: the second time with the width that spots at much the same depth
        told, in this view or earlier ones (`_shared_width`).

        A search where a spot is expected: `near` gives lasers' stretches of path to look in alone
        (inverse depths lo … hi, 1/m), and `threshold` scales both detection thresholds (min_snr
        and MATCHED_SNR; 1: as everywhere), which a short stretch's few chances of noise allow
        lower than a whole path's.

        `channel` ("red" or "luma"): colour frames read from it for this search alone, whatever
        the finder reads them from; nothing the finder learns of the frames (`auto`'s choice, a
        Bayer filter's red pixels, spots' widths) is learnt from such a search.

        `strays`, where given, gets the blobs that a laser's strip holds but that lie off its path
        (by more than `path_tolerance`, within STRAY_REACH_PX): two lasers' spots run together into
        one blob lie between their paths, and only a fit of both can place them (`edge.deblend`).

        `wanted`: of the lasers that were on, those whose spots are returned (default: all). The
        others' spots are still looked for, and kept out of the wanted spots' windows: a search
        for one laser alone let its neighbour's spot, 5 px off on a 320-px camera, pull its window
        off its path (tuning-1152 zone 1: a spot of SNR 60 in red `no_spot`).
        """
        if channel is not None and channel not in CHANNEL_WEIGHTS:
            raise ValueError(f"channel must be one of {', '.join(CHANNEL_WEIGHTS)}, got {channel!r}")
        if channel is not None and on[0].ndim == 3 and CHANNEL_WEIGHTS[channel] != self._weights:
            kept = self._weights, self._demosaiced, self._aside
            self._weights, self._aside = CHANNEL_WEIGHTS[channel], True
            try:
                return self.find(on, off, lasers, max_candidates, near, threshold, strays=strays, wanted=wanted)
            finally:
                self._weights, self._demosaiced, self._aside = kept
        names = [n for n in (lasers if lasers is not None else self.bands) if n in self.bands]
        rho: float | None = None  # this pair's chroma correlation, where `auto` measured it
        if not self._aside and self._choosing_channel(on[0]):
            rho = self._chroma_correlation(on[0], off[0])
            if rho is not None:
                self._chroma_lag2.append(rho)
                self._weights = self._auto_weights(self._chroma_lag2)
        self.told_by(off[0])  # (JPEG or not, and the values' step: once, by the first laser-off frame)
        if not self._aside and on[0].ndim == 3 and not self._jpeg and self._pair_looks < AUTO_GROUPS:
            self._pair_looks += 1
            self._paired = self._pairs_told(self._pair_steps, on[0], off[0])
        diff, off_vals, gain, off_level = self._difference(on, off)
        centre, deviation, noise = self._spread(diff)
        quantum = self._quantum(on[0], off[0], len(on))
        noise = max(noise, quantum)  # quantisation
        # Shot noise grows with the signal: estimate its scale from the background, whose
        # difference noise is (mostly) the shot noise of two frames of it.
        shot = noise**2 / (2.0 * max(off_level, 1e-3))
        colour, jpeg = on[0].ndim == 3, bool(self._jpeg)
        texture = self._texture(diff, centre, noise, colour, jpeg)
        if not self._aside and self._scaling_told(texture, rho, on[0], off[0]):
            texture = self._texture(diff, centre, noise, colour, jpeg)  # (once: as every frame from now on)
        self._demosaiced = texture.demosaiced
        seeds = self._detect(diff, off_vals, deviation, noise, quantum, names, near, threshold, on, off, gain,
                             max_candidates)
        refined = self._place(seeds, on, off, gain, shot, texture, strays, wanted)
        if texture.bayer is not None:  # (only then are spots placed by their red pixels)
            self._place_again(refined)
        elif (self._sites.looking and on[0].ndim == 3 and not self._aside and not self._paired
              and not self._scaling.told):
            told = self._sites.look([c for out in refined.values() for _, c in out], on, off, gain)
            if told and self._auto:  # (then red is read, if the channel is `auto`'s to choose)
                self._weights = CHANNEL_WEIGHTS["red"]
        return {name: [self._unsnapped(c) for _, c in out] for name, out in refined.items()}

    def _detect(self, diff: np.ndarray, off_vals: np.ndarray, deviation: np.ndarray, noise: float, quantum: float,
                names: Sequence[str], near: Mapping[str, tuple[float, float]] | None, threshold: float,
                on: Sequence[np.ndarray], off: Sequence[np.ndarray], gain: float, max_candidates: int
                ) -> dict[str, list[Seed]]:
        """`find`'s seeds: on each of `names`' paths, the peaks of the difference `diff` (`_difference`,
        with the laser-off values `off_vals`) that stand above the noise where they lie, strongest
        first (`_seeds`). `deviation` and `noise` are `_spread`'s, `quantum` the values' step."""
        # Every strip has the same width: one reduction finds each path sample's brightest pixel.
        layout = self.strips
        background, width = layout.background, layout.strip_width
        strips = diff[: background.start].reshape(width, -1)  # (width, samples)
        profile = np.maximum.reduce(strips, axis=0)  # (ndarray.max's reduction, without its Python wrapper)
        # The noise a spot stands above, by how bright the room is where it falls: the laser-off
        # frame along each path's centre line (no laser there; the levels only pick a bin).
        table = noise_by_level(off_vals[background], np.minimum(deviation, 5.0 * noise, out=deviation), noise,
                                max(quantum, NOISE_FLOOR_FRACTION * noise))
        floor = None
        if table is not None:
            room = off_vals[: background.start].reshape(width, -1)[width // 2]
            floor = table.take(level_bins(room))
        local_pix, matched, box = local_noise(strips, noise, floor, layout.stretch_counts)
        # A seed is a bright pixel (`min_snr` over the noise along that stretch of the path), or a
        # dim spot that the matched filter finds (MATCHED_SNR): every path's at once.
        bright = profile / (np.float32(self.min_snr) * local_pix)
        dim = matched * (1.0 / MATCHED_SNR)
        score = np.maximum(bright, dim)
        mid = score[1:-1]
        # (ndarray.nonzero: np.flatnonzero's indices without its two Python-level wrappers)
        peaks = ((mid > threshold) & (mid >= score[:-2]) & (mid > score[2:])).nonzero()[0] + 1
        listed = peaks.tolist()
        seeds = {}
        for name in names:
            rows = layout.rows[name]
            # Local maxima inside the path (its ends lie beyond the working range's margins).
            first, stop = rows.start + 1, rows.stop - 1
            if near is not None and name in near:
                first, stop = layout.stretch_of(name, *near[name], first, stop)
            mine = peaks[bisect.bisect_left(listed, first) : bisect.bisect_left(listed, stop)]
            seeds[name] = self._seeds(
                self.bands[name], rows.start, mine, score, bright, dim, strips, box, profile, local_pix,
                matched, on, off, gain, max_candidates,
            ) if mine.size else []
        return seeds

    def _place(self, seeds: Mapping[str, Sequence[Seed]],
               on: Sequence[np.ndarray], off: Sequence[np.ndarray], gain: float, shot: float, texture: Texture,
               strays: list[Candidate] | None, wanted: Collection[str] | None = None
               ) -> dict[str, list[tuple[Callable[..., Candidate | None], Candidate]]]:
        """`find`'s spots: each seed of the `wanted` lasers (default: all) placed by `_refine`, with
        the call that placed it (`_place_again` calls it again); blobs off their path go to `strays`
        where it is given."""
        # Every seed of every laser: a neighbouring spot, whichever laser's, must not pull a
        # spot's centroid (the centre and parallel spots are 4 px apart at 5 m).
        everywhere = [(u, v) for ss in seeds.values() for u, v, _, _, _, _ in ss]
        scales = self._scales(on, off, gain)
        planes = self._planes(on, off)
        refined: dict[str, list[tuple[Callable[..., Candidate | None], Candidate]]] = {}  # (how it was refined)
        for name, ss in seeds.items():
            if wanted is not None and name not in wanted:
                continue  # (its seeds only keep the wanted spots' windows to themselves)
            out: list[tuple[Callable[..., Candidate | None], Candidate]] = []
            for u, v, peak, row, mf, here in ss:
                others = [(a, b) for a, b in everywhere if 2.5 < math.hypot(a - u, b - v) < 4 * self._radius
                          ] if len(everywhere) > 1 else []
                refine = functools.partial(self._refine, self.bands[name], (u, v), row, others, on, off, gain, here,
                                           shot, peak, mf, texture, scales, planes)
                cand = refine() if strays is None else refine(reach=STRAY_REACH_PX)
                if cand is None:
                    continue
                if cand.cross_px > self.path_tolerance:
                    assert strays is not None  # (only then is a blob off the path kept)
                    strays.append(cand)
                else:
                    out.append((refine, cand))
            refined[name] = out
        return refined

    def _place_again(self, refined: dict[str, list[tuple[Callable[..., Candidate | None], Candidate]]]) -> None:
        """Behind a Bayer filter: each spot that its red pixels placed, placed again (in `refined`,
        each candidate with the call that refined it) with the width that spots at its depth
        told, in this view or earlier ones (see _shared_width); this view's told widths join the
        finder's."""
        told = [(c.along, *c.site_width) for out in refined.values() for _, c in out
                if c.site_width is not None and c.site_width[1] < _WIDTH_TOLD]
        pool = [*self._told, *told]
        if not self._aside:
            self._told.extend(told)
        for out in refined.values():
            for i, (refine, c) in enumerate(out):
                width = None if c.site_width is None else self._shared_width(pool, c.along)
                if width is not None:
                    out[i] = (refine, refine(width=width) or c)

    @staticmethod
    def _shared_width(told: Sequence[tuple[float, float, float]], along: float) -> tuple[float, float] | None:
        """Behind a Bayer filter: the width (log px, and how far a spot may stray from it) of a spot
        at inverse depth `along`, from spots whose red pixels told theirs, `told` (inverse depth,
        log width, its variance), those at much the same depth counting most; None if none is
        near. The lasers share the optics, and a spot's width follows its depth: a small spot
        lights one or two red pixels, which fix its centre only with a width that they cannot
        tell, and other spots can."""
        near = [math.exp(-0.5 * ((a - along) / _WIDTH_DEPTH_SCALE) ** 2) for a, _, _ in told]
        if not near or max(near) < 0.1:
            return None  # none within two scales of this depth
        weights = [n / var for n, (_, _, var) in zip(near, told)]
        mean = sum(w * t for w, (_, t, _) in zip(weights, told)) / sum(weights)
        return mean, _SHARED_WIDTH_SPREAD

    def _unsnapped(self, cand: Candidate) -> Candidate:
        """JPEG frames: a spot placed on an 8 × 8 block's centre line is one whose light JPEG kept
        only as the block's mean along that axis, and where in the block it was is lost: its σ
        along that axis is the block's. (Tuning-12, quality 51: spots of a 352 px camera 0.6 px
        from the truth, snapped to u = 179.5 and claiming 0.2 px, made a range 10 % off.)"""
        if not self._jpeg:
            return cand
        snapped = block_snapped(cand.pixel.tolist())
        if not any(snapped):
            return cand
        # Per axis: a spot snapped across its laser's path is placed as well as ever along it.
        var_u, var_v = (max(cand.sigma_px, BLOCK_SIGMA_PX) ** 2 if s else cand.sigma_px**2 for s in snapped)
        return replace(cand, sigma_px=max(cand.sigma_px, BLOCK_SIGMA_PX), cov_px=(var_u, var_v, 0.0))

    def grid_px(self, size: float, own_values: bool = False) -> tuple[float, float]:
        """What demosaicing adds to the σ of a spot of RMS radius `size` in the frames of the last
        `find`, and its part locked to the pixel grid (`demosaic_px`; LUMA_DEMOSAIC_PX, all locked,
        for colour frames read in luma; 0, 0 where they were not demosaiced): for `find`'s own
        spots, and for spots placed outside it (edge.deblend)."""
        if not self._demosaiced:
            return 0.0, 0.0
        if self._luma_demosaiced:
            return LUMA_DEMOSAIC_PX, LUMA_DEMOSAIC_PX
        return demosaic_px(size, own_values)

    @property
    def _luma_demosaiced(self) -> bool:
        """Were the last `find`'s frames colour JPEG read in luma, taken as demosaiced (`_texture`)?
        Their spots carry LUMA_DEMOSAIC_PX and share LUMA_JPEG_COMMON_PX. (Lossless frames read in
        luma are demosaiced only where the spots told a filter, whose pixels' own values then place
        them: `demosaic_px`'s term, as in red.)"""
        return bool(self._jpeg) and self._demosaiced and self._weights == CHANNEL_WEIGHTS["luma"]

    @property
    def common_px(self) -> float:
        """The part of every spot's position error that the frames' pipeline shares among the
        lasers' spots (px): JPEG_COMMON_PX in JPEG frames (LUMA_JPEG_COMMON_PX in colour ones read
        in luma), 0 in others (or before any frame)."""
        if not self._jpeg:
            return 0.0
        return LUMA_JPEG_COMMON_PX if self._luma_demosaiced else JPEG_COMMON_PX

    @property
    def spot_radius_px(self) -> float:
        """The half-size of the window a spot is placed in (px)."""
        return float(self._radius)

    def window_difference(self, on: Sequence[np.ndarray], off: Sequence[np.ndarray], pixel: np.ndarray, r: int
                          ) -> tuple[np.ndarray, tuple[int, int]] | None:
        """The read channel of the on frames less the off frames' in a (2r + 1)² window centred
        at `pixel`, in full-scale units, and the window's top-left pixel (u, v); None where the
        window leaves the image."""
        cam = self.rig.camera
        u0, v0 = int(round(float(pixel[0]))), int(round(float(pixel[1])))
        if u0 - r < 0 or v0 - r < 0 or u0 + r >= cam.width or v0 + r >= cam.height:
            return None
        rows, cols = slice(v0 - r, v0 + r + 1), slice(u0 - r, u0 + r + 1)
        return self._window(on, rows, cols) - self._window(off, rows, cols), (u0 - r, v0 - r)

    def light_at(self, on: Sequence[np.ndarray], off: Sequence[np.ndarray], pixel: np.ndarray) -> float:
        """The laser light in a spot-sized window at `pixel`: the on frames' read channel less the
        off frames', less the window border's median (the room), summed; in full-scale units. 0 where
        the window leaves the image."""
        cut = self.window_difference(on, off, pixel, self._radius)
        if cut is None:
            return 0.0
        win = cut[0]
        level = float(np.median(win.take(border_index(2 * self._radius + 1))))
        return float(win.sum()) - level * win.size

    @property
    def channel(self) -> str:
        """What colour frames are read from now: ``red`` or ``luma`` (``auto`` has chosen one)."""
        return "luma" if self._weights == CHANNEL_WEIGHTS["luma"] else "red"

    def _chroma_correlation(self, on: np.ndarray, off: np.ndarray) -> float | None:
        """The correlation 2 px along a row of the difference image's chroma noise (red minus
        green) at the background samples: high when chroma was stored at half resolution (or, less
        so, coarsely quantised: JPEG at 4:4:4 and low quality can pass for it, where luma places a
        spot about a quarter worse than red). None when the chroma shows no noise to tell by."""
        near_v, near_u = self.strips.near_samples()
        lag = NEIGHBOURS.index((2, 0))
        width, channels = self.rig.camera.width, on.shape[2]
        v = np.concatenate([near_v, near_v])
        u = np.concatenate([near_u, near_u + NEIGHBOURS[lag][0]])
        pixel = (v.astype(np.intp) * width + u) * channels
        flat_on, flat_off = on.reshape(-1), off.reshape(-1)
        chroma = [flat_on.take(pixel + c).astype(np.float64) - flat_off.take(pixel + c) for c in (2, 1)]
        c = (chroma[0] - chroma[1]).reshape(2, -1)
        c -= np.median(c)
        # Mean absolute deviation: JPEG leaves most of an 8-bit frame's chroma differences at 0,
        # where the median's would be 0 too.
        scale = float(np.abs(c).mean())
        if scale <= 0.0:
            return None  # JPEG has quantised the noise away (or there is none): no evidence
        c = np.clip(c, -6.0 * scale, 6.0 * scale)
        var = float(c[0] @ c[0])
        return float(c[0] @ c[1]) / var if var > 0 else None

    def _texture(self, diff: np.ndarray, centre: float, noise: float, colour: bool, jpeg: bool) -> Texture:
        """`noise_texture` of the difference at the background samples and their neighbours, with
        the red pixels' parity that bright spots told (`edge.redsites.SiteLook`)
        where the noise shows no Bayer filter; colour frames that were JPEG (`jpeg`) read in luma
        are taken as demosaiced (LUMA_DEMOSAIC_PX)."""
        strips = self.strips
        texture = noise_texture(diff[strips.near_block], centre, noise,
                                colour and self._weights == CHANNEL_WEIGHTS["red"], strips.parity)
        if self._paired and colour:
            # Red is the pair's chroma over each pixel's luma: no pixel keeps its own. (Tuning 0-63
            # made YUYV: placed by red pixels, |error| ÷ floor 2.27 and 94 % of `ok` zones within
            # 2σ; by the centroid, 1.96 and 98 %.)
            texture.bayer = None
        elif self._scaling.told and colour:
            # No filter's pixels at this size: its red noise is spread, but a spot is locked to no
            # grid. (Office and kitchen, Bayer frames at 1640 × 1232 scaled to 640 × 480: placed
            # as demosaiced, σ 0.5 px against the 3-colour sensor's 0.02 for the same errors.)
            texture.bayer, texture.demosaiced = None, False
        elif texture.bayer is None and self._sites.parity is not None and colour:
            texture.bayer, texture.demosaiced = self._sites.parity, True
        elif colour and jpeg and self._weights == CHANNEL_WEIGHTS["luma"]:
            texture.demosaiced = True  # (JPEG hides the filter that luma's red carries: LUMA_DEMOSAIC_PX)
        return texture

    def _seeds(self, band, start, peaks, score, bright, dim, strips, box, profile, pixel_noise, matched, on, off,
               gain, max_candidates) -> list[Seed]:
        """The peaks (`peaks`: path samples of all strips, those of `band`'s path, which starts at
        sample `start`) strongest first, one per blob: (u, v, peak, strip row, matched-filter SNR,
        the noise there). `strips` is (width, path samples), `box` its matched filter (the box's
        columns 1 … width − 2), `profile` each path sample's brightest value across the strip;
        `bright` and `dim` each peak's detection score as a bright pixel and by the matched filter
        (1: at the threshold), `score` the larger."""
        if peaks.size > 1:
            peaks = peaks[score[peaks].argsort()[::-1]][: 4 * max_candidates]  # (np.argsort, without its wrapper)
        seeds: list[Seed] = []
        # (Values read with .item(): plain Python numbers, which compare and convert far faster than
        # numpy's scalars; float32 to float is exact, so every comparison is as before.)
        for i in peaks.tolist():
            by_pixel = bright.item(i) >= dim.item(i)
            j = int(strips[:, i].argmax()) if by_pixel else 1 + int(box[:, i].argmax())
            u, v = band.u.item(i - start, j), band.v.item(i - start, j)
            peak = max(profile.item(i), strips.item(j, i))
            # (`seeds and`: no generator for a path's first peak)
            if seeds and bright.item(i) < 1.0 and any(math.hypot(u - su, v - sv) < 3 * self._radius
                                                      for su, sv, _, _, _, _ in seeds):
                continue  # a faint blob beside a spot: its shoulder or ghost, and no spot of its own
            if seeds and any(not self._apart((u, v), (su, sv), min(peak, sp), on, off, gain)
                             for su, sv, sp, _, _, _ in seeds):
                continue  # the same blob seen from another path sample
            seeds.append((u, v, peak, i - start, matched.item(i), pixel_noise.item(i)))
            if len(seeds) >= max_candidates:
                break
        return seeds

    def _green_sites(self, on, off, rows, cols, scales: tuple[float, float], sites: np.ndarray, noise: float,
                     shot: float, mine: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Behind a Bayer filter, a spot's window in the green plane at the green pixels `sites`,
        which keep their own value through the demosaicing: (difference above the window border's
        median, the usable green pixels, their noise variances), for `fit_sites`; None for grey
        frames, and for JPEG's, whose blocks keep no pixel's own value (their 4:2:0 chroma can pass
        for a Bayer filter's pattern: `_texture`). The noise is red's: the room's light and the
        sensor are much the same in both."""
        if on[0].ndim != 3 or self._jpeg:
            return None
        scale, off_scale = scales
        lit = sum([image[rows, cols, 1].astype(np.float32) for image in on]) * scale
        dark = sum([image[rows, cols, 1].astype(np.float32) for image in off]) * off_scale
        win = lit - dark
        above = win - border_level(win, border_index(win.shape[0]))
        usable = sites & (lit < _SATURATED)
        if mine is not None:
            usable &= mine
        return above, usable, noise**2 + np.maximum(above, 0.0) * shot

    def _apart(self, a, b, peak, on, off, gain) -> bool:
        """Are the peaks at pixels `a` and `b` two spots? Only if the difference image dips below
        half the weaker peak somewhere between them (a big saturated spot has several maxima)."""
        gap = math.hypot(a[0] - b[0], a[1] - b[1])
        if gap <= 2.0:
            return False
        if gap > 12.0:
            return True
        t = np.linspace(0.0, 1.0, int(gap * 2) + 2)[1:-1]
        u = np.rint(a[0] + t * (b[0] - a[0])).astype(np.intp)
        v = np.rint(a[1] + t * (b[1] - a[1])).astype(np.intp)
        line = self._window(on, v, u) - np.float32(gain) * self._window(off, v, u)
        return float(line.min()) < 0.5 * peak

    def _scales(self, on, off, gain) -> tuple[float, float]:
        """What the laser-on and laser-off frames' sums are multiplied by for `_refine`'s windows
        (as float32: numpy casts these to the windows' type)."""
        return 1.0 / (len(on) * self.full_scale(on[0])), gain / (len(off) * self.full_scale(off[0]))

    def _planes(self, on: Sequence[np.ndarray], off: Sequence[np.ndarray]) -> tuple[np.ndarray, ...]:
        """The planes (on, off) `_refine` reads its windows from, when there is one frame of each
        kind and its read channel is one of its planes (grey, or red): views, not copies. Empty
        otherwise (`_scaled` then sums and weighs the frames)."""
        if not (self._one_plane(on) and self._one_plane(off)):
            return ()
        return self.laser_channel(on[0]), self.laser_channel(off[0])

    def _refine(self, band, seed, row, others, on, off, gain, noise, shot, peak, matched=0.0,
                texture: Texture | None = None, scales: tuple[float, float] | None = None,
                planes: tuple[np.ndarray, ...] | None = None, width: tuple[float, float] | None = None,
                reach: float | None = None) -> Candidate | None:
        """Sub-pixel position of the spot at `seed`: the centroid of the background-subtracted,
        thresholded difference in a window, which is unbiased for a symmetric spot; the window
        grows for big (near, defocused, saturated) spots so that it never clips one, and pixels
        nearer another candidate are left to that one. Behind a Bayer filter, a Gaussian fitted to
        the red pixels alone (a centroid of the demosaiced red locks onto them).

        Its σ comes from the noise measured around it: the pixel noise and the spot's own shot
        noise, grown by the noise's correlation (`texture`), and by the χ² of a Gaussian fitted to
        the spot when the spot is not the smooth blob that the noise alone would leave (speckle,
        JPEG's blocks, demosaicing).

        `scales` and `planes` are `_scales` and `_planes` of the frames, which `find` works out
        once for all its windows (None: work them out here). `reach`: how far from the path a
        spot may lie and be kept (default `path_tolerance`; `find`'s strays go farther)."""
        texture = texture or Texture()
        cam = self.rig.camera
        r = self._radius
        cu, cv = float(seed[0]), float(seed[1])
        scale, off_scale = scales or self._scales(on, off, gain)
        if planes is None:
            planes = self._planes(on, off)
        mine: np.ndarray | None = None
        for _ in range(3):
            u0, v0 = int(round(cu)), int(round(cv))
            if u0 - r < 0 or v0 - r < 0 or u0 + r >= cam.width or v0 + r >= cam.height:
                return None  # too close to the image border to localise honestly
            rows, cols = slice(v0 - r, v0 + r + 1), slice(u0 - r, u0 + r + 1)
            if planes:  # (`_scaled`'s one-plane case, without telling it again per window)
                lit = _scaled_plane(planes[0], rows, cols, scale)
                dark = _scaled_plane(planes[1], rows, cols, off_scale)
                win = np.subtract(lit, dark, out=dark)
            else:
                lit = self._scaled(on, rows, cols, scale)
                win = lit - self._scaled(off, rows, cols, off_scale)
            kit = window_kit(r)
            level = border_level(win, kit.border)
            # Subtracting a level a little above the background and clipping at zero keeps the
            # noise of the empty pixels out; its bias is a tiny fraction of threshold/peak.
            signal = win - (level + 2.0 * noise)
            np.maximum(signal, 0.0, out=signal)
            offs = kit.offsets
            rw = r  # this window's half-size (r may grow below for the next one)
            if others:
                gu, gv = offs[None, :] + u0 - seed[0], offs[:, None] + v0 - seed[1]
                dist = gu * gu + gv * gv
                mine = np.ones(signal.shape, bool)
                for ou, ov in others:
                    mine &= (gu + (seed[0] - ou)) ** 2 + (gv + (seed[1] - ov)) ** 2 >= dist
                signal *= mine
            # Σ w, Σ w·x, Σ w·x², Σ w·y, Σ w·y² of the weights by one product (each numpy call
            # costs more than the arithmetic on a window this small; ndarray.dot: np.dot's product
            # without its dispatcher, with less overhead than @; given float64 it skips its own
            # slower conversion). The float64 weights are kept for the count of the pixels used.
            weights = signal.ravel().astype(np.float64)
            mass, mx, mxx, my, myy = kit.powers.dot(weights).tolist()
            if mass <= 0.0:
                return None
            du, dv = mx / mass, my / mass
            cu, cv = u0 + du, v0 + dv
            var_x = max(mxx / mass - du * du, 0.0)
            var_y = max(myy / mass - dv * dv, 0.0)
            size = math.sqrt((var_x + var_y) / 2)
            need = max(self._radius, int(math.ceil(3.5 * size)))
            if need <= r and abs(du) <= 1.0 and abs(dv) <= 1.0:
                break
            r = min(need, 3 * self._radius)  # recentre, and widen for a big spot
        if size > self.max_spot_px:
            return None  # a lamp or a screen, not a pointer's spot
        saturated = lit >= _SATURATED
        clipped = np.count_nonzero(saturated) > 0  # (cheaper than .any() on a few dozen pixels)
        above = win - level  # background-subtracted, not thresholded
        unsaturated = ~saturated if clipped else None
        usable = None if unsaturated is None else unsaturated if mine is None else unsaturated & mine
        if usable is None and mine is not None:
            usable = mine
        misfit = 1.0
        cov = None
        site_width = None  # (log px, variance) where a fit of a Bayer filter's own-colour pixels placed the spot
        if texture.bayer is not None:
            rr, rc = divmod(texture.bayer, 2)
            row_red = (v0 - rw + np.arange(2 * rw + 1)) % 2 == rr
            col_red = (u0 - rw + np.arange(2 * rw + 1)) % 2 == rc
            red = row_red[:, None] & col_red[None, :]
            var_all = noise**2 + np.maximum(above, 0.0) * shot  # each pixel's noise variance
            green = self._green_sites(on, off, rows, cols, (scale, off_scale), row_red[:, None] != col_red[None, :],
                                      noise, shot, mine)
            fit = fit_sites(above, red if usable is None else red & usable, var_all, offs, du, dv, size, width,
                             green)
            # A fit that leaves far more than noise, or knows the centre to worse than a pixel, has
            # not found the spot's shape: the centroid then.
            # (Nor does one whose covariance is not positive: an ill-conditioned fit.)
            most = SITE_MISFIT_JPEG if self._jpeg else SITE_MISFIT
            if fit is not None and fit[3] < most and float(np.trace(fit[2])) < 1.0 and min(np.diag(fit[2])) > 0.0:
                du, dv, cov, misfit, log_width, var_log_width = fit
                site_width = (log_width, var_log_width)
                misfit = max(misfit, 1.0)
                cu, cv = u0 + du, v0 + dv
                cov = cov * texture.sites * misfit_grow(misfit, self._jpeg)
        else:
            # The spot's core only: a neighbouring spot's wing (the centre and parallel spots are
            # 4 px apart at 5 m) is not this spot's misfit. (u² + v² − 2·du·u − 2·dv·v, from the
            # window's monomials, against the core's radius² − du² − dv².)
            # Both fits below take only `usable` pixels 3 σ above the background, and need 10 of
            # them: with fewer (a small spot, or a clipped one, whose strong pixels are mostly
            # clipped), neither is tried. (The fit of a clipped spot's unclipped pixels takes those
            # of `signal` over 3 σ: 5 σ above the background, all of them among these. For the
            # float32 values to say otherwise, σ would have to be below their rounding.)
            strong = above.ravel() > 3.0 * noise
            use = strong if usable is None else strong & usable.ravel()
            fits = np.count_nonzero(use) >= 10
            gauss = None
            if fits:
                ring = kit.monomials.dot(np.array([0.0, -2.0 * du, -2.0 * dv, 1.0, 1.0, 0.0]))
                use &= ring <= (2.5 * max(size, 0.7)) ** 2 - du * du - dv * dv
                gauss = fit_gaussian(above, use, rw)
            if gauss is not None:
                _, idx, model = gauss
                val = above.ravel()[idx]
                dof = idx.size - 6
                if dof >= 3:
                    chi2 = float((((val - model) ** 2) / (noise**2 + val * shot)).sum())
                    misfit = max(1.0, chi2 / dof)
            if clipped and fits:
                assert unsaturated is not None  # (clipped)
                fitted = fit_unsaturated(signal, unsaturated, rw, 3.0 * noise)
                if fitted is not None and abs(fitted[0] - du) < 0.5 and abs(fitted[1] - dv) < 0.5:
                    du, dv = fitted
                    cu, cv = u0 + du, v0 + dv
            if fits and self._jpeg:
                # JPEG keeps a spot as a few blocks' coarse frequencies, with ringing about them: a
                # centroid of what stands above the threshold follows the blocks, and the core's
                # fit in logarithms sees none of it. A Gaussian weighed pixel by pixel over the
                # whole window places the spot better; its σ is the fit's, grown by the noise's
                # correlation and by its χ², where the spot is not the blob that noise alone would
                # leave (as the Bayer branch's). On the tuning family's JPEG frames (tuning
                # 320-959) mean |error| ÷ floor 2.41 → 2.25, coverage +22, wrong `ok` 5 → 4; on
                # raw frames it placed spots no better, and is not run there.
                fitted_round = fit_round(above, usable, noise**2 + np.maximum(above, 0.0) * shot, kit.powers,
                                         (du, dv, max(size * size, 0.25)), ROUND_FIT_STEPS)
                if fitted_round is not None and fitted_round[2] < SITE_MISFIT_JPEG:
                    du, dv, chi2_round, cov_round = fitted_round
                    cu, cv = u0 + du, v0 + dv
                    misfit = max(misfit, chi2_round)
                    if float(np.trace(cov_round)) < 1.0 and min(np.diag(cov_round)) > 0.0:
                        cov = cov_round * texture.area * misfit_grow(misfit, self._jpeg)
        if cov is not None:
            var_u, var_v = float(cov[0, 0]), float(cov[1, 1])
        else:
            # Position variance from pixel noise: Σ (x − x̄)² σ² / (Σ I)² over the pixels used, σ²
            # including the spot's own shot noise (`shot` is per unit of the averaged frames'
            # signal), grown by the noise's correlation and the fit's misfit. By moments: σ² is
            # noise² on each pixel used and shot × its signal, and Σ (x − x̄)² w = Σ x² w − 2 x̄ Σ x w + x̄² Σ w.
            # The same sums over the pixels used (signal ≥ 0: its sign is 1 there, 0 elsewhere;
            # sums of small integers, exact however they are added).
            used = np.sign(weights)
            n0, nx, nxx, ny, nyy = kit.powers.dot(used).tolist()
            grow = misfit_grow(misfit, self._jpeg) / mass**2
            # The noise's correlation grows a centroid's variance less than a sum's (`area`). Not
            # JPEG's: its blocks move a centroid by more than its noise's correlation 1 and 2 px
            # apart says (tests/test_vision.py: the office's JPEG spots, placed by the centroid
            # where the fit fails, went past 2σ), and `area` holds them.
            grow_u = grow_v = texture.area
            if texture.area > 1.0 and not self._jpeg:
                grow_u, grow_v = centroid_growth(used.reshape(signal.shape), du, dv, texture.lags)
                grow_u, grow_v = min(grow_u, texture.area), min(grow_v, texture.area)
            # Σ (x − x̄)² w, ≥ 0 in exact arithmetic; a one-pixel spot can round it a hair below
            noise2 = noise**2
            var_u = grow * grow_u * (noise2 * max(nxx - 2.0 * du * nx + du * du * n0, 0.0)
                                     + shot * max(mxx - 2.0 * du * mx + du * du * mass, 0.0))
            var_v = grow * grow_v * (noise2 * max(nyy - 2.0 * dv * ny + dv * dv * n0, 0.0)
                                     + shot * max(myy - 2.0 * dv * my + dv * dv * mass, 0.0))
        demosaic, locked = (self.grid_px(size, own_values=site_width is not None and not self._jpeg)
                            if texture.demosaiced else (0.0, 0.0))
        var_u += demosaic**2
        var_v += demosaic**2
        # Where along the path, and how far from it, from the strip row the seed came from.
        pu, pv, tu, tv, _ = band.samples[row]
        along = (cu - pu) * tu + (cv - pv) * tv
        cross = abs((cu - pu) * tv - (cv - pv) * tu)
        if cross > (self.path_tolerance if reach is None else reach):
            return None  # not on this laser's path: another light, or another laser's spot
        k = min(max(row + int(round(along / band.step)), 0), len(band.samples) - 1)
        return Candidate(
            band.laser,
            np.array([cu, cv]),
            math.sqrt(max(var_u, var_v)),
            peak / noise,
            size,
            band.samples[k][4],
            cross,
            matched,
            misfit,
            site_width=site_width,
            locked_px=locked,
            noise=noise,
        )

    def frame_kind(self, first: np.ndarray, second: np.ndarray) -> FrameKind:
        """What kind of frames these are and what :meth:`find` makes of them, from two frames of
        one kind at one pose (two laser-off frames: their difference is pure noise); for
        `edge doctor`, where nobody can see it otherwise.

        `find`'s own steps, `second` taken as its laser-off frame and `first` as its laser-on:
        JPEG or not as its first laser-off frame tells it (or `delivered` told it), the channel
        `auto` would read after this pair (from the groups it measured so far and this one), the
        difference's noise and texture at the background samples. It changes none of the
        finder's decisions: `find` decides as if this had never been called."""
        colour = first.ndim == 3
        blockiness = jpeg_blockiness(second)
        jpeg = self._jpeg if self._jpeg is not None else blockiness > JPEG_BLOCKINESS
        weights, rho = self._weights, None
        if self._choosing_channel(first):
            rho = self._chroma_correlation(first, second)
            told = [*self._chroma_lag2, *([] if rho is None else [rho])]
            if told:
                weights = self._auto_weights(told)
        paired = self._paired
        if colour and not jpeg and self._pair_looks < AUTO_GROUPS:
            paired = self._pairs_told([*self._pair_steps], first, second)
        # `_difference` and `_texture` read the channel from the finder: this pair's, and back after.
        kept, self._weights = self._weights, weights
        kept_paired, self._paired = self._paired, paired
        try:
            diff = self._difference([first], [second])[0]
            centre, _, noise = self._spread(diff)
            # (The texture as find measures it, with the noise floored at the values' step.)
            texture = self._texture(diff, centre, max(noise, self._quantum(first, second)), colour, jpeg)
        finally:
            self._weights, self._paired = kept, kept_paired
        channel = "grey" if not colour else "luma" if weights == CHANNEL_WEIGHTS["luma"] else "red"
        bayer_red = None if texture.bayer is None else divmod(texture.bayer, 2)
        chroma = rho if rho is not None or texture.parity is None else self._chroma_correlation(first, second)
        return FrameKind(jpeg, blockiness, colour, channel, rho, texture.demosaiced, bayer_red, noise, texture.area,
                         paired, texture.parity, chroma)
