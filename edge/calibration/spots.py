"""The board's spots in a calibration recording's zones: found, placed and told apart.

Spots are found without the nominal rig's narrow epipolar bands (a laser a degree off puts its spot
10 px from where the rig says): a whole-frame laser-on minus laser-off difference, thresholded,
split into connected blobs, each localised by an iterated Gaussian-windowed centroid, corrected for
the pixel locking that clipping gives a bright spot (:mod:`edge.calibration.locate`); spots a few
pixels apart (which pull each other's centroids, or merge into one) are fitted together as a sum of
Gaussians, and each is then located by its centroid once the others' fitted spots are taken away.
Each spot's σ from the sensor's noise is measured around it from the frames' scatter. A zone's
spots are merged over its frame groups (:func:`zone_blobs`); :mod:`edge.calibration.fit` gives
them to lasers and fits the rays.

Pure: a recording or frames in, pixels out.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from edge.calibration.locate import (
    CLIPPED_FRACTION,
    WINDOW_SIGMA_PX,
    background_free,
    clipping_correction,
    pixel_gaussian,
    windowed_centroid,
)
from edge.recording import Recording
from edge.replay import zone_groups
from edge.vision import SpotFinder

log = logging.getLogger(__name__)

THRESHOLD_SIGMAS = 8.0  # blob threshold over the difference image's robust noise
MAX_SPOT_PX = 6.0  # RMS radius (per axis) above which a blob is a lamp or a screen, not a spot


@dataclass(frozen=True)
class Blob:
    """A spot found in a zone: mean position over the frame groups that showed it."""

    pixel: np.ndarray  # (2,) sub-pixel (u, v)
    lasers: frozenset[str]  # lasers on in every group where it showed: the only candidates
    sigma_px: np.ndarray | None = None  # (2,) 1-σ of `pixel` per axis from the sensor's noise
    clipped: bool = False  # clipped the sensor (CLIPPED_PIXELS or more) in most groups that showed it


def _mean(frames: Sequence[np.ndarray]) -> np.ndarray:
    acc = sum(SpotFinder.laser_channel(f).astype(np.float32) for f in frames)
    return np.asarray(acc * np.float32(1.0 / (len(frames) * SpotFinder.full_scale(frames[0]))))


def _variance(on: Sequence[np.ndarray], off: Sequence[np.ndarray], noise: float) -> np.ndarray | float:
    """Each pixel's noise variance in the mean difference image, measured from the scatter of the
    frames around their means (the spot's own shot noise included), or `noise`² for all pixels
    when one on or one off frame cannot show it."""
    if len(on) < 2 or len(off) < 2:
        return noise * noise
    scale = np.float32(1.0 / SpotFinder.full_scale(on[0]))
    var = np.zeros(on[0].shape[:2], np.float32)
    for frames in (on, off):
        stack = np.stack([SpotFinder.laser_channel(f).astype(np.float32) * scale for f in frames])
        var += stack.var(axis=0, ddof=1) / np.float32(len(frames))
    return var


def _difference(on: Sequence[np.ndarray], off: Sequence[np.ndarray]) -> tuple[np.ndarray, float, np.ndarray]:
    """Laser-on minus gain·laser-off, the gain absorbing room-light flicker; its noise; and the
    headroom (H, W): the difference a pixel shows where every on frame clipped."""
    a, b = _mean(on), _mean(off)
    keep = a < np.percentile(a, 99.0)  # the brightest 1 % holds the spots (and lamps)
    gain = float((a[keep] * b[keep]).sum() / max(float((b[keep] ** 2).sum()), 1e-12))
    diff = a - np.float32(gain) * b
    level = np.float32(np.median(diff))
    diff -= level
    noise = 1.4826 * float(np.median(np.abs(diff)))
    floor = 0.5 / (SpotFinder.full_scale(on[0]) * math.sqrt(len(on)))  # quantisation
    return diff, max(noise, floor), np.float32(1.0) - np.float32(gain) * b - level


def _clipped(on: Sequence[np.ndarray]) -> np.ndarray:
    """(H, W) bool: where any on frame's laser channel is at full scale."""
    top = np.max(np.stack([SpotFinder.laser_channel(f) for f in on]), axis=0)
    return np.asarray(top >= CLIPPED_FRACTION * SpotFinder.full_scale(on[0]))


def _refine(diff: np.ndarray, seed: tuple[int, int], var: np.ndarray | float = 0.0,
            clip: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """Iterated Gaussian-windowed centroid (mean shift) around `seed`: the mode of the spot
    smoothed by the window, unbiased for a symmetric spot, barely pulled by a neighbour. And its
    1-σ per axis from the pixels' noise variance `var` (an image, or one value for all): the
    centroid c = Σ gᵢ sᵢ xᵢ / Σ gᵢ sᵢ moves by gᵢ (xᵢ − c) / Σ gᵢ sᵢ per unit of pixel i's signal.
    (A Gaussian least-squares fit of the spot was tried instead: on spots at rest, whose error is
    the speckle's, it located them worse, 0.073/0.093 px rms against 0.061/0.081 px.) With `clip`
    (where the on frames clipped, and the headroom: see :func:`_difference`), a spot with clipped
    pixels has its centroid's pixel locking corrected (:func:`edge.calibration.locate.clipping_correction`)."""
    h = int(math.ceil(3 * WINDOW_SIGMA_PX)) + 3
    u0, v0 = seed
    if u0 < h or v0 < h or u0 + h >= diff.shape[1] or v0 + h >= diff.shape[0]:
        return None  # too near the border to localise honestly
    box = (slice(v0 - h, v0 + h + 1), slice(u0 - h, u0 + h + 1))
    win = diff[box].astype(np.float64)
    signal = background_free(win)
    gv, gu = np.mgrid[v0 - h: v0 + h + 1, u0 - h: u0 + h + 1]
    found = windowed_centroid(signal, gu, gv, (float(u0), float(v0)))
    if found is None:
        return None
    cu, cv = found
    if abs(cu - u0) > h - 3 or abs(cv - v0) > h - 3:
        return None  # wandered off: not a compact spot
    g = np.exp(-((gu - cu) ** 2 + (gv - cv) ** 2) / (2.0 * WINDOW_SIGMA_PX**2))
    total = float((g * signal).sum())
    v = (np.asarray(var, dtype=np.float64)[box] if np.ndim(var) else float(var))
    sigma = np.sqrt([float((g * g * (gu - cu) ** 2 * v).sum()), float((g * g * (gv - cv) ** 2 * v).sum())]) / total
    if clip is not None and clip[0][box].any():
        correction = clipping_correction(win, clip[0][box], clip[1][box].astype(np.float64), gu, gv, (cu, cv))
        if correction is None:
            log.debug("clipped spot at (%.1f, %.1f): its model does not fit, centroid left as it is", cu, cv)
        else:
            cu, cv = cu + float(correction[0]), cv + float(correction[1])
    return np.array([cu, cv]), sigma


def find_spots(on: Sequence[np.ndarray], off: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Spot pixels anywhere in the frame, from laser-on and laser-off frames of one pose; a clipped
    spot's centroid uncorrected (to a tenth of a pixel: what watching for rest needs, at the frame
    rate)."""
    return [pixel for pixel, _ in located_spots(on, off, corrected=False)]


def located_spots(on: Sequence[np.ndarray], off: Sequence[np.ndarray], corrected: bool = True
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Spot pixels anywhere in the frame with each one's 1-σ per axis (2,) from the frames' noise;
    with `corrected`, a clipped spot's centroid corrected for its pixel locking (see :func:`_refine`)."""
    diff, noise, headroom = _difference(on, off)
    var = _variance(on, off, noise)
    clipped = _clipped(on)
    clip = (clipped, headroom) if corrected and clipped.any() else None
    mask = (diff > THRESHOLD_SIGMAS * noise).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    smooth = cv2.GaussianBlur(diff, (0, 0), WINDOW_SIGMA_PX)
    peaks = smooth >= cv2.dilate(smooth, np.ones((5, 5), np.uint8))
    # Sharper maxima, for two spots so close (2-4 px) that the smoothed picture shows one.
    sharp = cv2.GaussianBlur(diff, (0, 0), SHARP_SIGMA_PX)
    sharp_peaks = sharp >= cv2.dilate(sharp, np.ones((3, 3), np.uint8))
    # ... but not on a clipped plateau, flat but for the laser-off frames' noise, whose maxima are
    # that noise's (a spot at 0.4 m was split in two 2.8 px apart).
    plateau = cv2.dilate(clipped.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    found: list[tuple[np.ndarray, np.ndarray]] = []
    seeds: list[np.ndarray] = []  # the sharper maxima
    for k in range(1, count):
        x, y, w, h, area = (int(c) for c in stats[k])
        if area < 2:
            continue  # a lone pixel over 8 σ: not a spot's footprint
        box = (slice(y, y + h), slice(x, x + w))
        inside = labels[box] == k
        sig = np.where(inside, diff[box], 0.0).astype(np.float64)
        gv, gu = np.mgrid[y: y + h, x: x + w]
        total = float(sig.sum())
        mu, mv = float((sig * gu).sum()) / total, float((sig * gv).sum()) / total
        size = math.sqrt(float((sig * ((gu - mu) ** 2 + (gv - mv) ** 2)).sum()) / total / 2)
        if size > MAX_SPOT_PX:
            log.debug("blob at (%.0f, %.0f) has RMS radius %.1f px: not a laser spot", mu, mv, size)
            continue
        # Several local maxima in one blob: spots close enough to touch; each refined on its own.
        vs, us = np.nonzero(peaks[box] & inside)
        order = np.argsort(-smooth[box][vs, us])[:4]
        for v, u in zip(vs[order] + y, us[order] + x):
            spot = _refine(diff, (int(u), int(v)), var, clip)
            if spot is not None and all(np.linalg.norm(spot[0] - p) > 1.0 for p, _ in found):
                found.append(spot)
        vs, us = np.nonzero(sharp_peaks[box] & inside & ~plateau[box])
        values = sharp[box][vs, us]
        for j in np.argsort(-values)[:4]:
            if values[j] >= SPLIT_FRACTION * values.max():
                seeds.append(np.array([float(us[j] + x), float(vs[j] + y)]))
    return _deblended(diff, _split_merged(diff, found, seeds, var, clip), var, clip)


# Spots nearer than this pull each other's windowed centroids (0.4 px at 3.5 px apart: the `center`
# and `parallel` spots of a rig built a few tenths of a degree off, at 3-4 m); they are located
# together instead, as a sum of Gaussians.
DEBLEND_PX = 7.0
SPOT_RADIUS_PX = 2.5  # how far from a spot's centre its clipped pixels are counted
SHARP_SIGMA_PX = 0.6  # the smoothing that still shows two spots 2.5 px apart as two maxima
SPLIT_PX = 2.0  # a sharper maximum this far from every located spot may be a second spot...
SPLIT_FRACTION = 0.3  # ... if it is at least this bright relative to the blob's brightest


@dataclass(frozen=True)
class _Group:
    """Spots fitted together: a sum of pixel-integrated Gaussians of one width on a flat
    background, on the window of the difference image from (u0, v0)."""

    amplitudes: np.ndarray  # (k,)
    centres: np.ndarray  # (k, 2) px
    width: float  # σ px
    sigma_px: np.ndarray  # (k, 2) each centre's 1-σ from the pixels' noise
    box: tuple[slice, slice]  # the window (rows, columns)

    def model(self, j: int) -> np.ndarray:
        """Member j's spot on the window (h, w)."""
        us = np.arange(self.box[1].start, self.box[1].stop, dtype=float)
        vs = np.arange(self.box[0].start, self.box[0].stop, dtype=float)
        pu = pixel_gaussian(us, float(self.centres[j, 0]), self.width)[0]
        pv = pixel_gaussian(vs, float(self.centres[j, 1]), self.width)[0]
        return float(self.amplitudes[j]) * np.outer(pv, pu)


def _group_model(theta: np.ndarray, k: int, us: np.ndarray, vs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sum of k pixel-integrated Gaussians (A_1..A_k, (u, v)_1..k, σ, background) on the
    window (h, w), and its Jacobian (h·w, 3k + 2)."""
    sigma = theta[3 * k]
    model = np.full((len(vs), len(us)), theta[3 * k + 1])
    J = np.zeros((model.size, 3 * k + 2))
    for j in range(k):
        a, mu, mv = theta[j], theta[k + 2 * j], theta[k + 2 * j + 1]
        pu, du, su = pixel_gaussian(us, mu, sigma)
        pv, dv, sv = pixel_gaussian(vs, mv, sigma)
        model += a * np.outer(pv, pu)
        J[:, j] = np.outer(pv, pu).ravel()
        J[:, k + 2 * j] = a * np.outer(pv, du).ravel()
        J[:, k + 2 * j + 1] = a * np.outer(dv, pu).ravel()
        J[:, 3 * k] += a * (np.outer(pv, su) + np.outer(sv, pu)).ravel()
    J[:, 3 * k + 1] = 1.0
    return model, J


def _fit_group(diff: np.ndarray, seeds: list[np.ndarray], var: np.ndarray | float,
               clip: tuple[np.ndarray, np.ndarray] | None = None) -> _Group | None:
    """Spots close together as one picture: a sum of pixel-integrated Gaussians of one shared
    width on a flat background, by Levenberg-Marquardt from `seeds` (windowed centroids, or maxima
    of the sharper picture; plain Gauss-Newton steps ran away in one fit in five of spots 2-6 px
    apart under speckle); a clipped pixel (`clip`: see :func:`_refine`) counts only where the
    model falls below it. None if it does not settle."""
    pts = np.array(seeds)
    h = 4
    u0, v0 = (np.floor(pts.min(axis=0)).astype(int) - h).tolist()
    u1, v1 = (np.ceil(pts.max(axis=0)).astype(int) + h).tolist()
    if u0 < 0 or v0 < 0 or u1 >= diff.shape[1] or v1 >= diff.shape[0]:
        return None
    box = (slice(v0, v1 + 1), slice(u0, u1 + 1))
    win = diff[box].astype(np.float64).ravel()
    clipped = np.zeros(win.shape, bool) if clip is None else clip[0][box].ravel()
    us, vs = np.arange(u0, u1 + 1, dtype=float), np.arange(v0, v1 + 1, dtype=float)
    v_pix = (np.asarray(var, dtype=np.float64)[box] if np.ndim(var) else np.full((len(vs), len(us)), float(var)))
    k = len(seeds)

    def residuals(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        model, J = _group_model(theta, k, us, vs)
        r = win - model.ravel()
        count = ~clipped | (r > 0)  # a clipped pixel is a lower bound
        return np.where(count, r, 0.0), J * count[:, None], count

    amp = [max(float(diff[int(round(p[1])), int(round(p[0]))]), 1e-6) * 2.0 * math.pi * 0.36 for p in pts]
    theta = np.array([*amp, *pts.ravel(), 0.6, 0.0])  # A_1..A_k, (u, v)_1..k, σ, background
    r, J, count = residuals(theta)
    cost, lam = float(r @ r), 1e-3
    for _ in range(60):
        jtj, grad = J.T @ J, J.T @ r
        while lam < 1e8:
            step = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-12), grad)
            trial = theta + step
            trial[3 * k] = min(max(trial[3 * k], 0.3), 4.0)
            r2, J2, count2 = residuals(trial)
            if float(r2 @ r2) <= cost:
                theta, r, J, count, cost, lam = trial, r2, J2, count2, float(r2 @ r2), lam * 0.3
                break
            lam *= 10.0
        else:
            break  # no step lowers the cost: a minimum
        if np.abs(step[k: 3 * k]).max() < 1e-5:
            break
    centres = theta[k: 3 * k].reshape(k, 2)
    if np.linalg.norm(centres - pts, axis=1).max() > 2.0 or min(theta[:k]) <= 0:
        return None
    # The fit's covariance with each pixel's noise: (JᵀJ)⁻¹ Jᵀ V J (JᵀJ)⁻¹.
    J = J[count]
    inv = np.linalg.pinv(J.T @ J)
    cov = inv @ (J.T * v_pix.ravel()[count]) @ J @ inv
    sig = np.sqrt(np.maximum(np.diag(cov)[k: 3 * k], 0.0)).reshape(k, 2)
    return _Group(theta[:k].copy(), centres.copy(), float(theta[3 * k]), sig, box)


def _located_together(diff: np.ndarray, seeds: list[np.ndarray], var: np.ndarray | float,
                      clip: tuple[np.ndarray, np.ndarray] | None) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Spots close together: fitted together (:func:`_fit_group`), then each located as a spot on
    its own is (:func:`_refine`) once the others' fitted spots are taken from the picture. The
    windowed centroid is what speckle moves least: on spots 4-9 px apart at rest it located them
    to 0.08 px rms, the sum of Gaussians to 0.095 px. Where a centroid fails or strays from the
    fit by more than a pixel, the fit's position stays. None if the fit does not settle."""
    group = _fit_group(diff, seeds, var, clip)
    if group is None:
        return None
    out = []
    for j in range(len(seeds)):
        rest = diff.copy()
        for other in range(len(seeds)):
            if other != j:
                rest[group.box] -= group.model(other).astype(rest.dtype)
        head = None if clip is None else (clip[0], clip[1] - (diff - rest))
        fit = group.centres[j]
        spot = _refine(rest, (int(round(fit[0])), int(round(fit[1]))), var, head)
        if spot is None or float(np.linalg.norm(spot[0] - fit)) > 1.0:
            out.append((fit.copy(), group.sigma_px[j].copy()))
        else:
            out.append(spot)
    return out


def closest_gap(pixels: Sequence[np.ndarray]) -> float:
    """The smallest distance between any two of `pixels` (px; inf for fewer than two)."""
    return min((float(np.linalg.norm(a - b)) for i, a in enumerate(pixels) for b in pixels[i + 1:]),
               default=math.inf)


def clusters(points: list[np.ndarray], within: float) -> list[list[int]]:
    """Indices of `points` grouped by chains of neighbours nearer than `within`."""
    n = len(points)
    group = list(range(n))

    def root(i: int) -> int:
        while group[i] != i:
            i = group[i]
        return i

    for i in range(n):
        for j in range(i + 1, n):
            if np.linalg.norm(points[i] - points[j]) < within:
                group[root(j)] = root(i)
    return [[i for i in range(n) if root(i) == r] for r in sorted({root(i) for i in range(n)})]


def _split_merged(diff: np.ndarray, found: list[tuple[np.ndarray, np.ndarray]], seeds: list[np.ndarray],
                  var: np.ndarray | float, clip: tuple[np.ndarray, np.ndarray] | None = None
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where the sharper picture shows more maxima (at least SPLIT_PX apart) than spots were
    located near them, spots so close that the windowed centroid merged them: located together
    from those maxima (:func:`_located_together`), if that keeps them apart."""
    out = list(found)
    for cluster in clusters(seeds, DEBLEND_PX):
        distinct: list[np.ndarray] = []
        for i in cluster:
            if all(np.linalg.norm(seeds[i] - q) >= SPLIT_PX for q in distinct):
                distinct.append(seeds[i])
        if len(distinct) < 2:
            continue
        near = [k for k, (p, _) in enumerate(out)
                if min(float(np.linalg.norm(p - q)) for q in distinct) < DEBLEND_PX]
        if not near or len(distinct) <= len(near):
            continue
        apart = _located_together(diff, distinct, var, clip)
        if apart is None or any(np.linalg.norm(a[0] - b[0]) < SPLIT_PX
                                for i, a in enumerate(apart) for b in apart[i + 1:]):
            continue
        out = [spot for k, spot in enumerate(out) if k not in near] + apart
    return out


def _deblended(diff: np.ndarray, found: list[tuple[np.ndarray, np.ndarray]], var: np.ndarray | float,
               clip: tuple[np.ndarray, np.ndarray] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """`found` with spots nearer than DEBLEND_PX to another located together
    (:func:`_located_together`); where that fails they stay as they were."""
    out = list(found)
    for members in clusters([p for p, _ in found], DEBLEND_PX):
        if len(members) < 2:
            continue
        fitted = _located_together(diff, [found[i][0] for i in members], var, clip)
        if fitted is None:
            log.debug("spots at %s could not be told apart", [found[i][0].round(1).tolist() for i in members])
            continue
        for i, spot in zip(members, fitted):
            out[i] = spot
    return out


# A spot with this many clipped pixels or more is a clipped one: its plateau hides the speckle that
# moves an unclipped spot's centroid (at rest, simulator: 0.06 px rms against 0.09 px; a spot with
# one clipped pixel scatters 0.08 px, nearly as an unclipped one).
CLIPPED_PIXELS = 2


def zone_blobs(recording: Recording, zone_index: int) -> list[Blob]:
    """The zone's spots, found per frame group (each pose, each set of lasers) and merged: a spot
    must show in at least half the groups that could show it (else flicker or noise)."""
    zone = recording.zones[zone_index]
    groups, _ = zone_groups(recording, zone)
    tracks: list[dict[str, Any]] = []
    for g in groups:
        clipped = _clipped(g.on)
        for pixel, sigma in located_spots(g.on, g.off):
            u, v = int(round(float(pixel[0]))), int(round(float(pixel[1])))
            r = int(math.ceil(SPOT_RADIUS_PX))
            hit = int(clipped[max(v - r, 0): v + r + 1, max(u - r, 0): u + r + 1].sum()) >= CLIPPED_PIXELS
            for t in tracks:
                if np.linalg.norm(np.mean(t["px"], axis=0) - pixel) < 1.5:
                    t["px"].append(pixel)
                    t["sigma"].append(sigma)
                    t["clipped"].append(hit)
                    t["lasers"] &= set(g.lasers)
                    break
            else:
                tracks.append({"px": [pixel], "sigma": [sigma], "clipped": [hit], "lasers": set(g.lasers)})
    blobs = []
    for t in tracks:
        could = sum(1 for g in groups if t["lasers"] & set(g.lasers))
        n = len(t["px"])
        if t["lasers"] and n >= max(1, math.ceil(could / 2)):
            sigma = np.sqrt(np.sum(np.square(t["sigma"]), axis=0)) / n  # of the mean of n
            blobs.append(Blob(np.mean(t["px"], axis=0), frozenset(t["lasers"]), sigma,
                              2 * sum(t["clipped"]) > n))
    return blobs


def located_together(recording: Recording, zone_index: int, lasers: Sequence[str], seeds: Sequence[np.ndarray]
                     ) -> list[np.ndarray] | None:
    """The spots of `lasers` in the zone, so close that they may show as one blob, located
    together from `seeds` (one pixel each: where a rig says they are) in every frame group that
    has them all on (:func:`_located_together`), and averaged; None where no group tells them
    apart (a pixel or more)."""
    zone = recording.zones[zone_index]
    got = []
    for g in zone_groups(recording, zone)[0]:
        if not set(lasers) <= set(g.lasers):
            continue
        diff, noise, headroom = _difference(g.on, g.off)
        clipped = _clipped(g.on)
        spots = _located_together(diff, [np.asarray(p, dtype=float) for p in seeds],
                                  _variance(g.on, g.off, noise), (clipped, headroom) if clipped.any() else None)
        if spots is not None and closest_gap([p for p, _ in spots]) >= 1.0:
            got.append(np.array([p for p, _ in spots]))
    return None if not got else list(np.mean(got, axis=0))
