"""Finding laser spots: difference imaging along each laser's epipolar band, sub-pixel positions.

A laser's spot can only appear on its image path over the working range (the epipolar segment,
derived from the rig), so everything here looks only there: a narrow strip of pixels along each
path, plus a sparse sample of the rest of the frame to measure how the room light changed between
the laser-off and laser-on frames (flicker). That keeps one on/off pair well under a millisecond at
640 × 480 and makes the cost grow with the path length, not the frame size.

Per frame group (on frames and off frames taken at one pose), :meth:`SpotFinder.find` returns the
candidate spots on each laser's path: sub-pixel position (iteratively Gaussian-windowed centroid on
the background-subtracted difference), its uncertainty from the pixel noise, and its strength.
Frames may be 8- or 16-bit, grey or BGR; values are scaled to [0, 1] by their type's range.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge.rig import Laser, Rig

# How far beyond the working range the paths are searched, so that a spot just outside it is
# reported as out of range rather than missed: z from NEAR_FACTOR·near to FAR_FACTOR·far.
NEAR_FACTOR = 0.8
FAR_FACTOR = 1.6


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
    inv_depth: np.ndarray  # (L,)


class SpotFinder:
    """Spot detection for one rig and frame size; build once, call :meth:`find` per group."""

    def __init__(
        self,
        rig: Rig,
        band_halfwidth_px: float = 3.0,
        min_snr: float = 6.0,
        window_sigma_px: float = 1.5,
        max_spot_px: float = 6.0,
        lasers: Sequence[str] | None = None,
    ):
        self.rig = rig
        cam = rig.camera
        self.min_snr = min_snr
        self.window_sigma = window_sigma_px
        self.max_spot_px = max_spot_px
        self.halfwidth = band_halfwidth_px
        names = list(lasers) if lasers is not None else list(rig.laser_names)
        self.bands = {name: self._band(rig.laser(name)) for name in names}
        # Sparse background sample for the flicker gain: a grid over the frame minus the bands.
        step = max(4, int(math.sqrt(cam.width * cam.height / 3000)))
        gv, gu = np.mgrid[step // 2 : cam.height : step, step // 2 : cam.width : step]
        keep = np.ones(gv.shape, bool)
        for band in self.bands.values():
            for (pu, pv) in band.path[:: max(1, len(band.path) // 64)]:
                keep &= (np.abs(gu - pu) > 12) | (np.abs(gv - pv) > 12)
        self._bg_v, self._bg_u = gv[keep], gu[keep]
        # Every strip pixel in one gather: cheaper than one gather per laser.
        self._all_v = np.concatenate([b.v.ravel() for b in self.bands.values()] + [self._bg_v])
        self._all_u = np.concatenate([b.u.ravel() for b in self.bands.values()] + [self._bg_u])
        self._slices: dict[str, slice] = {}
        start = 0
        for name, band in self.bands.items():
            self._slices[name] = slice(start, start + band.v.size)
            start += band.v.size
        self._bg_slice = slice(start, start + self._bg_v.size)
        r = int(math.ceil(3 * window_sigma_px))
        self._win = np.arange(-r - 2, r + 3)

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
        return _Band(laser.name, v, u, path, inv)

    @staticmethod
    def laser_channel(image: np.ndarray) -> np.ndarray:
        """The channel that carries a red laser: red of BGR, or grey. A view, not a copy."""
        return image[..., 2] if image.ndim == 3 else image

    @staticmethod
    def full_scale(image: np.ndarray) -> float:
        return 65535.0 if image.dtype == np.uint16 else 255.0 if image.dtype == np.uint8 else 1.0

    def _gather(self, frames: Sequence[np.ndarray], v: np.ndarray, u: np.ndarray) -> np.ndarray:
        acc = None
        for image in frames:
            values = self.laser_channel(image)[v, u].astype(np.float32)
            acc = values if acc is None else acc + values
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
        on_vals = self._gather(on, self._all_v, self._all_u)
        off_vals = self._gather(off, self._all_v, self._all_u)
        # Room light may differ between the frames (flicker): scale the off frame to the on frame
        # by least squares on pixels where no laser can land.
        bon, boff = on_vals[self._bg_slice], off_vals[self._bg_slice]
        denom = float(boff @ boff)
        gain = float(bon @ boff) / denom if denom > 0 else 1.0
        diff = on_vals - np.float32(gain) * off_vals
        # Pixel noise of the difference, robustly, from the background sample.
        bg = diff[self._bg_slice]
        noise = 1.4826 * float(np.median(np.abs(bg - np.median(bg)))) if bg.size else 0.0
        noise = max(noise, 0.5 / (self.full_scale(on[0]) * math.sqrt(len(on))))  # quantisation
        # Shot noise grows with the signal: estimate electrons-per-unit from the background, whose
        # difference noise is (mostly) the shot noise of two frames of it.
        shot = noise**2 / (2.0 * max(float(np.mean(boff)) if boff.size else 0.0, 1e-3))
        found: dict[str, list[Candidate]] = {}
        for name in names:
            band = self.bands[name]
            strip = diff[self._slices[name]].reshape(band.v.shape)
            found[name] = self._candidates(band, strip, on, off, gain, noise, shot, max_candidates)
        return found

    def _candidates(self, band, strip, on, off, gain, noise, shot, max_candidates) -> list[Candidate]:
        level = float(np.median(strip))
        profile = strip.max(axis=1) - level
        threshold = self.min_snr * noise
        left = np.r_[-np.inf, profile[:-1]]
        right = np.r_[profile[1:], -np.inf]
        peaks = np.flatnonzero((profile > threshold) & (profile >= left) & (profile > right))
        if peaks.size == 0:
            return []
        peaks = peaks[np.argsort(profile[peaks])[::-1]]
        out: list[Candidate] = []
        for i in peaks:
            j = int(np.argmax(strip[i]))
            seed = (int(band.u[i, j]), int(band.v[i, j]))
            if any(abs(seed[0] - c.pixel[0]) <= 2 and abs(seed[1] - c.pixel[1]) <= 2 for c in out):
                continue  # the same blob seen from the next path sample
            cand = self._refine(band, seed, on, off, gain, noise, shot, float(profile[i]))
            if cand is not None:
                out.append(cand)
            if len(out) >= max_candidates:
                break
        return out

    def _refine(self, band, seed, on, off, gain, noise, shot, peak) -> Candidate | None:
        cam = self.rig.camera
        u0, v0 = seed
        us, vs = u0 + self._win, v0 + self._win
        if us[0] < 0 or vs[0] < 0 or us[-1] >= cam.width or vs[-1] >= cam.height:
            return None  # too close to the image border to localise honestly
        gu, gv = np.meshgrid(us, vs)
        win = self._gather(on, gv, gu) - np.float32(gain) * self._gather(off, gv, gu)
        border = np.concatenate([win[0], win[-1], win[1:-1, 0], win[1:-1, -1]])
        signal = np.clip(win - float(np.median(border)), 0.0, None).astype(np.float64)
        # Iteratively Gaussian-windowed centroid: unbiased for a symmetric spot, and a neighbour
        # spot a few pixels away barely pulls it.
        cu, cv = float(u0), float(v0)
        s2 = 2.0 * self.window_sigma**2
        for _ in range(6):
            w = np.exp(-((gu - cu) ** 2 + (gv - cv) ** 2) / s2) * signal
            total = float(w.sum())
            if total <= 0:
                return None
            nu, nv = float((w * gu).sum() / total), float((w * gv).sum() / total)
            done = abs(nu - cu) < 1e-3 and abs(nv - cv) < 1e-3
            cu, cv = nu, nv
            if done:
                break
        weights = np.exp(-((gu - cu) ** 2 + (gv - cv) ** 2) / s2)
        total = float((weights * signal).sum())
        # Position variance from pixel noise: Σ w² (x − x̄)² σ² / (Σ w I)², σ² including the
        # spot's own shot noise.
        var_pix = noise**2 + signal * (shot / len(on))
        var_u = float((weights**2 * (gu - cu) ** 2 * var_pix).sum()) / total**2
        var_v = float((weights**2 * (gv - cv) ** 2 * var_pix).sum()) / total**2
        size = math.sqrt(float((signal * ((gu - cu) ** 2 + (gv - cv) ** 2)).sum()) / max(float(signal.sum()), 1e-12) / 2)
        if size > self.max_spot_px:
            return None  # a lamp or a screen, not a pointer's spot
        # Where along the path, and how far from it.
        d = band.path - np.array([cu, cv])
        k = int(np.argmin((d**2).sum(axis=1)))
        cross = float(np.sqrt((d[k] ** 2).sum()))
        if k not in (0, len(band.path) - 1):
            t = band.path[k + 1] - band.path[k - 1]
            t /= np.linalg.norm(t)
            cross = abs(float(d[k, 0] * t[1] - d[k, 1] * t[0]))
        if cross > self.halfwidth + 0.5:
            return None
        return Candidate(
            band.laser,
            np.array([cu, cv]),
            math.sqrt(max(var_u, var_v)),
            peak / noise,
            size,
            float(band.inv_depth[k]),
            cross,
        )
