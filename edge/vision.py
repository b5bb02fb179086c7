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

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge.rig import Laser, Rig

# How far beyond the working range the paths are searched, so that a spot just outside it is
# reported as out of range rather than missed: z from NEAR_FACTOR·near to FAR_FACTOR·far.
NEAR_FACTOR = 0.8
FAR_FACTOR = 1.6
# What a colour frame's spot is read from, as weights of its B, G, R channels. `red` suits raw or
# lossless frames of a red pointer; `luma` suits JPEG (MJPEG webcams), which keeps only luminance
# at full resolution and blurs and shifts a small red spot's chroma by up to a pixel.
CHANNEL_WEIGHTS = {"red": (0.0, 0.0, 1.0), "luma": (0.114, 0.587, 0.299)}


# A pixel at this fraction of full scale in a laser-on frame is taken as clipped.
_SATURATED = 0.985


def _fit_unsaturated(
    signal: np.ndarray, saturated: np.ndarray, offs: np.ndarray, floor: float
) -> tuple[float, float] | None:
    """Centre of a spot whose core is clipped, from a Gaussian fitted to its unclipped pixels.

    The centroid of a clipped, pixel-sampled spot is biased by up to ~0.07 px depending on where
    the spot falls within a pixel ("pixel locking"); the wings still carry the position. The fit is
    of ln I = a + b·u + c·v + d·u² + e·v² + f·u·v, weighted by I² (the variance of ln I is σ²/I²).
    Returns (du, dv) relative to the window centre, or None when the fit is not a peak.
    """
    use = ~saturated & (signal > floor)
    if int(use.sum()) < 10:
        return None
    gv, gu = np.meshgrid(offs, offs, indexing="ij")
    u, v, val = gu[use], gv[use], signal[use].astype(np.float64)
    design = np.stack([np.ones_like(u), u, v, u * u, v * v, u * v], axis=1) * val[:, None]
    coef = np.linalg.lstsq(design, np.log(val) * val, rcond=None)[0]
    _, b, c, d, e, f = coef
    hessian = np.array([[2.0 * d, f], [f, 2.0 * e]])
    if d >= 0 or e >= 0 or np.linalg.det(hessian) <= 0:
        return None
    du, dv = np.linalg.solve(hessian, [-b, -c])
    return float(du), float(dv)


@functools.lru_cache(maxsize=16)
def _border_index(size: int) -> np.ndarray:
    """Flat indices of the outermost ring of a size × size window."""
    ring = np.ones((size, size), bool)
    ring[1:-1, 1:-1] = False
    return np.flatnonzero(ring)


@dataclass(frozen=True)
class Candidate:
    """A spot found on one laser's path in one frame group."""

    laser: str
    pixel: np.ndarray  # (2,) float64 sub-pixel (u, v)
    sigma_px: float  # 1-σ position uncertainty from pixel noise (per axis)
    snr: float  # peak of the difference over the noise
    size_px: float  # RMS radius of the spot
    along: float  # inverse depth at the nearest path sample (1/m)
    cross_px: float  # distance from the path, px


@dataclass(frozen=True)
class _Band:
    laser: str
    v: np.ndarray  # (L, W) int pixel rows of the strip
    u: np.ndarray  # (L, W) int pixel columns
    path: np.ndarray  # (L, 2) path pixels (float)
    tangent: np.ndarray  # (L, 2) unit direction of the path
    inv_depth: np.ndarray  # (L,)
    step: float  # mean spacing of the path samples, px


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
        cam = rig.camera
        self.min_snr = min_snr
        self.max_spot_px = max_spot_px
        self.halfwidth = band_halfwidth_px
        self.path_tolerance = path_tolerance_px
        if channel not in CHANNEL_WEIGHTS:
            raise ValueError(f"channel must be one of {', '.join(CHANNEL_WEIGHTS)}, got {channel!r}")
        self._weights = CHANNEL_WEIGHTS[channel]  # (B, G, R) of a colour frame
        names = list(lasers) if lasers is not None else list(rig.laser_names)
        self.bands = {name: self._band(rig.laser(name)) for name in names}
        # Sparse background sample for the flicker gain: a grid over the frame minus the bands.
        step = max(4, int(math.sqrt(cam.width * cam.height / 1200)))
        gv, gu = np.mgrid[step // 2 : cam.height : step, step // 2 : cam.width : step]
        keep = np.ones(gv.shape, bool)
        for band in self.bands.values():
            for (pu, pv) in band.path[:: max(1, len(band.path) // 64)]:
                keep &= (np.abs(gu - pu) > 12) | (np.abs(gv - pv) > 12)
        self._bg_v, self._bg_u = gv[keep], gu[keep]
        # Every strip pixel in one gather: cheaper than one gather per laser.
        self._all_v = np.concatenate([b.v.ravel() for b in self.bands.values()] + [self._bg_v])
        self._all_u = np.concatenate([b.u.ravel() for b in self.bands.values()] + [self._bg_u])
        self._strip_width = next(iter(self.bands.values())).v.shape[1]
        self._rows: dict[str, slice] = {}  # each laser's path samples among all strips' rows
        start = 0
        for name, band in self.bands.items():
            self._rows[name] = slice(start, start + band.v.shape[0])
            start += band.v.shape[0]
        start *= self._strip_width
        self._bg_slice = slice(start, start + self._bg_v.size)
        # Window half-size for localisation; it grows for big spots.
        self._radius = 4
        self._flat: dict[int, list[tuple[np.ndarray, float]]] = {}

    def _band(self, laser: Laser) -> _Band:
        cam = self.rig.camera
        lo, hi = self.rig.range_limits_m
        lo, hi = lo * NEAR_FACTOR, hi * FAR_FACTOR
        # Sample the path about every half pixel: find its length first, then resample.
        coarse = self.rig.camera.project(laser.point_at_depth(1.0 / np.linspace(1 / lo, 1 / hi, 64)))
        length = float(np.linalg.norm(np.diff(coarse, axis=0), axis=1).sum())
        n = max(8, int(length * 2))
        inv = np.linspace(1 / lo, 1 / hi, n)
        path = cam.project(laser.point_at_depth(1.0 / inv))
        tangent = np.gradient(path, axis=0)
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        offsets = np.arange(-math.ceil(self.halfwidth), math.ceil(self.halfwidth) + 1)
        pts = path[:, None, :] + offsets[None, :, None] * normal[:, None, :]
        u = np.clip(np.rint(pts[..., 0]), 0, cam.width - 1).astype(np.intp)
        v = np.clip(np.rint(pts[..., 1]), 0, cam.height - 1).astype(np.intp)
        step = float(np.linalg.norm(np.diff(path, axis=0), axis=1).mean())
        return _Band(laser.name, v, u, path, tangent, inv, step)

    @staticmethod
    def laser_channel(image: np.ndarray) -> np.ndarray:
        """The channel that carries a red laser: red of BGR, or grey. A view, not a copy."""
        return image[..., 2] if image.ndim == 3 else image

    def lit_in_off(self, off: np.ndarray, laser: str) -> bool:
        """Whether `laser`'s spot shows in a laser-off frame (a laser that does not go off): a
        compact peak of red excess (red over the mean of green and blue; grey frames: brightness)
        along its path, well above the path's own level."""
        band = self.bands[laser]
        if off.ndim == 3:
            img = off.astype(np.float32)
            excess = img[..., 2] - 0.5 * (img[..., 0] + img[..., 1])
        else:
            excess = off.astype(np.float32)
        profile = excess[band.v, band.u].max(axis=1)  # (L,) along the path
        level = float(np.median(profile))
        spread = 1.4826 * float(np.median(np.abs(profile - level)))
        return float(profile.max()) - level > max(8.0 * spread, 0.15 * self.full_scale(off))

    @staticmethod
    def full_scale(image: np.ndarray) -> float:
        return 65535.0 if image.dtype == np.uint16 else 255.0 if image.dtype == np.uint8 else 1.0

    def _flat_index(self, image: np.ndarray) -> list[tuple[np.ndarray, float]]:
        """(indices into ``image.ravel()``, weight) per channel read, for every strip and
        background pixel."""
        channels = image.shape[2] if image.ndim == 3 else 1
        index = self._flat.get(channels)
        if index is None:
            pixel = self._all_v.astype(np.intp) * self.rig.camera.width + self._all_u
            if channels == 1:
                index = [(pixel, 1.0)]
            else:
                index = [(pixel * channels + c, w) for c, w in enumerate(self._weights) if w]
            self._flat[channels] = index
        return index

    def _gather(self, frames: Sequence[np.ndarray]) -> np.ndarray:
        acc: np.ndarray | None = None
        for image in frames:
            flat = np.ascontiguousarray(image).reshape(-1)
            for index, weight in self._flat_index(image):
                values = np.take(flat, index).astype(np.float32)
                if weight != 1.0:
                    values *= np.float32(weight)
                acc = values if acc is None else acc + values
        if acc is None:
            raise ValueError("no frames to gather: a pose needs at least one laser-on and one laser-off frame")
        return acc * np.float32(1.0 / (len(frames) * self.full_scale(frames[0])))

    def _plane(self, image: np.ndarray, rows, cols) -> np.ndarray:
        """The read channel of a region of `image`, float32."""
        if image.ndim == 2:
            return image[rows, cols].astype(np.float32)
        if self._weights == (0.0, 0.0, 1.0):
            return image[rows, cols, 2].astype(np.float32)
        return image[rows, cols, :3].astype(np.float32) @ np.array(self._weights, np.float32)

    def _window(self, frames: Sequence[np.ndarray], rows, cols) -> np.ndarray:
        acc = self._plane(frames[0], rows, cols)
        for image in frames[1:]:
            acc += self._plane(image, rows, cols)
        return acc * np.float32(1.0 / (len(frames) * self.full_scale(frames[0])))

    def find(
        self,
        on: Sequence[np.ndarray],
        off: Sequence[np.ndarray],
        lasers: Sequence[str] | None = None,
        max_candidates: int = 3,
    ) -> dict[str, list[Candidate]]:
        """Candidate spots per laser from laser-on and laser-off frames of one pose.

        Several frames of each kind are averaged (same pose: same speckle, less pixel noise).
        `lasers`: the lasers that were on (default: all of this finder's).
        """
        names = [n for n in (lasers if lasers is not None else self.bands) if n in self.bands]
        on_vals = self._gather(on)
        off_vals = self._gather(off)
        # Room light may differ between the frames (flicker): scale the off frame to the on frame
        # by least squares on pixels where no laser can land.
        bon, boff = on_vals[self._bg_slice], off_vals[self._bg_slice]
        denom = float(boff @ boff)
        gain = float(bon @ boff) / denom if denom > 0 else 1.0
        diff = on_vals - np.float32(gain) * off_vals
        # Pixel noise of the difference, robustly (MAD), from the background sample.
        bg = diff[self._bg_slice]
        if bg.size:
            mid = bg.size // 2
            centre = float(np.partition(bg, mid)[mid])
            dev = np.abs(bg - np.float32(centre))
            noise = 1.4826 * float(np.partition(dev, mid)[mid])
        else:
            noise = 0.0
        noise = max(noise, 0.5 / (self.full_scale(on[0]) * math.sqrt(len(on))))  # quantisation
        # Shot noise grows with the signal: estimate its scale from the background, whose
        # difference noise is (mostly) the shot noise of two frames of it.
        shot = noise**2 / (2.0 * max(float(boff.mean()) if boff.size else 0.0, 1e-3))
        # Every strip has the same width: one reduction finds each path sample's brightest pixel.
        width = self._strip_width
        strips = diff[: self._bg_slice.start].reshape(-1, width)
        best = strips.argmax(axis=1)
        profile = strips[np.arange(strips.shape[0]), best]
        seeds = {}
        for name in names:
            rows = self._rows[name]
            seeds[name] = self._seeds(
                self.bands[name], profile[rows], best[rows], on, off, gain, noise, max_candidates
            )
        # Every seed of every laser: a neighbouring spot, whichever laser's, must not pull a
        # spot's centroid (the centre and parallel spots are 4 px apart at 5 m).
        everywhere = [(u, v) for ss in seeds.values() for u, v, _, _ in ss]
        found: dict[str, list[Candidate]] = {}
        for name, ss in seeds.items():
            out = []
            for u, v, peak, row in ss:
                others = [(a, b) for a, b in everywhere if 2.5 < math.hypot(a - u, b - v) < 4 * self._radius]
                cand = self._refine(self.bands[name], (u, v), row, others, on, off, gain, noise, shot, peak)
                if cand is not None:
                    out.append(cand)
            found[name] = out
        return found

    def _seeds(self, band, profile, best, on, off, gain, noise, max_candidates) -> list[tuple[int, int, float, int]]:
        """Peaks along a laser's strip above the detection threshold, strongest first, one per
        blob: (u, v, peak, strip row). `profile` is each path sample's brightest value across the
        strip and `best` where across it that is."""
        above = profile > self.min_snr * noise
        if not above.any():
            return []
        # Local maxima inside the path (its ends lie beyond the working range's margins).
        mid = profile[1:-1]
        peaks = 1 + np.flatnonzero(above[1:-1] & (mid >= profile[:-2]) & (mid > profile[2:]))
        peaks = peaks[np.argsort(profile[peaks])[::-1]]
        seeds: list[tuple[int, int, float, int]] = []
        for i in peaks:
            j = int(best[i])
            u, v, peak = int(band.u[i, j]), int(band.v[i, j]), float(profile[i])
            if any(not self._apart((u, v), (su, sv), min(peak, sp), on, off, gain) for su, sv, sp, _ in seeds):
                continue  # the same blob seen from another path sample
            seeds.append((u, v, peak, int(i)))
            if len(seeds) >= max_candidates:
                break
        return seeds

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

    def _refine(self, band, seed, row, others, on, off, gain, noise, shot, peak) -> Candidate | None:
        """Sub-pixel position of the spot at `seed`: the centroid of the background-subtracted,
        thresholded difference in a window, which is unbiased for a symmetric spot; the window
        grows for big (near, defocused, saturated) spots so that it never clips one, and pixels
        nearer another candidate are left to that one."""
        cam = self.rig.camera
        r = self._radius
        cu, cv = float(seed[0]), float(seed[1])
        for _ in range(3):
            u0, v0 = int(round(cu)), int(round(cv))
            if u0 - r < 0 or v0 - r < 0 or u0 + r >= cam.width or v0 + r >= cam.height:
                return None  # too close to the image border to localise honestly
            rows, cols = slice(v0 - r, v0 + r + 1), slice(u0 - r, u0 + r + 1)
            lit = self._window(on, rows, cols)
            win = lit - np.float32(gain) * self._window(off, rows, cols)
            border = win.ravel()[_border_index(2 * r + 1)]
            level = float(np.partition(border, border.size // 2)[border.size // 2])
            # Subtracting a level a little above the background and clipping at zero keeps the
            # noise of the empty pixels out; its bias is a tiny fraction of threshold/peak.
            signal = np.maximum(win - np.float32(level + 2.0 * noise), 0.0)
            offs = np.arange(-r, r + 1, dtype=np.float32)
            if others:
                gu, gv = np.meshgrid(offs + u0, offs + v0)
                mine = (gu - seed[0]) ** 2 + (gv - seed[1]) ** 2
                for ou, ov in others:
                    signal = np.where((gu - ou) ** 2 + (gv - ov) ** 2 < mine, 0.0, signal)
            col, line = signal.sum(axis=0), signal.sum(axis=1)
            mass = float(col.sum())
            if mass <= 0.0:
                return None
            du, dv = float(col @ offs) / mass, float(line @ offs) / mass
            cu, cv = u0 + du, v0 + dv
            var_x = float(col @ (offs - du) ** 2) / mass
            var_y = float(line @ (offs - dv) ** 2) / mass
            size = math.sqrt((var_x + var_y) / 2)
            need = max(self._radius, int(math.ceil(3.5 * size)))
            if need <= r and abs(du) <= 1.0 and abs(dv) <= 1.0:
                break
            r = min(need, 3 * self._radius)  # recentre, and widen for a big spot
        if size > self.max_spot_px:
            return None  # a lamp or a screen, not a pointer's spot
        saturated = lit >= _SATURATED
        if saturated.any():
            fitted = _fit_unsaturated(signal, saturated, offs, 3.0 * noise)
            if fitted is not None and abs(fitted[0] - du) < 0.5 and abs(fitted[1] - dv) < 0.5:
                du, dv = fitted
                cu, cv = u0 + du, v0 + dv
        # Position variance from pixel noise: Σ (x − x̄)² σ² / (Σ I)² over the pixels used, σ²
        # including the spot's own shot noise.
        # The difference's noise already holds the background's shot noise; the spot adds its own
        # (`shot` is per unit of the averaged frames' signal).
        var_pix = np.where(signal > 0, noise**2 + signal * shot, 0.0)
        var_u = float(((offs - du) ** 2) @ var_pix.sum(axis=0)) / mass**2
        var_v = float(((offs - dv) ** 2) @ var_pix.sum(axis=1)) / mass**2
        # Where along the path, and how far from it, from the strip row the seed came from.
        pu, pv = float(band.path[row, 0]), float(band.path[row, 1])
        tu, tv = float(band.tangent[row, 0]), float(band.tangent[row, 1])
        along = (cu - pu) * tu + (cv - pv) * tv
        cross = abs((cu - pu) * tv - (cv - pv) * tu)
        if cross > self.path_tolerance:
            return None  # not on this laser's path: another light, or another laser's spot
        k = min(max(row + int(round(along / band.step)), 0), len(band.inv_depth) - 1)
        return Candidate(
            band.laser,
            np.array([cu, cv]),
            math.sqrt(max(var_u, var_v)),
            peak / noise,
            size,
            float(band.inv_depth[k]),
            cross,
        )
