"""The physical floor of ranging: how well a laser spot's position — and so its range — can be known
at all from the frames a zone takes, whatever the estimator.

Two terms, in the image (px), turned into range through the triangulation's derivative:

* **Noise: the Cramér–Rao bound.** A spot of known shape (the renderer's Gaussian: beam footprint,
  lens blur, defocus) lies on a background of room light; each laser-on/laser-off pair gives a
  difference image whose pixels carry the shot noise of both frames, twice the read noise and twice
  the quantisation noise. The Fisher information of the spot's centre θ = (u, v) is
  F = Σ ∂μ/∂θ ∂μ/∂θᵀ / var over pixels and colour channels (one channel per pixel behind a Bayer
  filter); pairs add theirs; clipped pixels carry none. No unbiased estimator's covariance is below
  F⁻¹. The spot's brightness is taken as known: for a symmetric spot it is uncorrelated with the
  position, so knowing it gives nothing away.
* **Speckle.** Laser speckle multiplies the spot by a random pattern fixed to the surface and moves
  its apparent centre; within one view nothing that does not know the pattern can undo that, and
  views with different patterns average it down (covariance / views). For the renderer's speckle
  (``edge.sim.optics.speckle_field``: random phasors whose spatial frequencies fill a disc of radius
  K, intensity blended towards 1 by a contrast c) the centroid's covariance is, to first order,

      C = c² (1 − 1/N) ∫ (Σq)(Σq)ᵀ exp(−qᵀΣq) P(q) d²q

  with Σ the spot's image covariance, N the number of phasors and P the autocorrelation of the
  uniform density on the disc (the spectrum of the intensity's correlation |2 J₁(Kr)/(Kr)|²).
  That is the first-order term, which a Monte Carlo of the renderer's speckle matches exactly; the
  centroid's division by the speckled spot's own brightness makes the true scatter up to ~10 %
  smaller for spots smaller than the speckle grain (tests/test_accuracy_floor.py).

A laser's range floor is σ_z = √(gᵀ (F⁻¹ + C / views) g), g = ∂z/∂(u, v) of its triangulation at
the spot. The zone's floor (:func:`fused_sigma`) uses every laser whose spot lies on the surface the
reference laser hits: a plane whose offset and slopes are unknown, fitted to their depths, gives the
reference's range better than its spot alone (the sloped laser's depth is several times as precise
as the reference's), and that is what an estimator that fuses the lasers must be held to.

Left out on purpose: JPEG and demosaicing (processing a camera chooses: what they cost is what the
benchmark shows against this floor), flicker, and calibration error.

Pure: arrays in, arrays out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge.rig import CameraModel, Laser
from edge.triangulation import triangulate

SUPERSAMPLE = 5  # per pixel side, as the renderer integrates a spot over its pixels
OBSERVABLE_SNR = 6.0  # a spot this far above the noise of the mean difference image can be found
# The mean |error| of an estimator at the floor, in units of the floor's σ: E|x| = σ·√(2/π).
EFFICIENT_RATIO = math.sqrt(2.0 / math.pi)


@dataclass(frozen=True)
class Sensor:
    """The noise of one frame's pixel, in photo-electrons."""

    read_noise_e: float
    quantum_e: float  # variance of the quantisation error (e²): steps²/12 of the ADC and the output
    clip_e: float  # a pixel holding this many or more is clipped
    bayer: bool = False  # an RGGB colour filter: one colour a pixel (R at even rows and columns)

    @classmethod
    def of(cls, full_well_e: float, read_noise_e: float, adc_bits: int, output_bits: int,
           gain: float = 1.0, bayer: bool = False) -> Sensor:
        adc_step = full_well_e / ((2**adc_bits - 1) * gain)
        out_step = full_well_e / ((255 if output_bits == 8 else 65535) * gain)
        return cls(read_noise_e, (adc_step**2 + out_step**2) / 12.0, min(full_well_e, full_well_e / gain), bayer)


@dataclass(frozen=True)
class Spot:
    """One laser's spot on the sensor in one view, before noise: a Gaussian of `covariance` (2, 2)
    px² centred at `centre_px` (2,) holding `total_e` photo-electrons, seen by each channel with
    `response` (C,), on the room light `background` (h, w, C) electrons of the pixels from
    (x0, y0)."""

    centre_px: np.ndarray
    covariance: np.ndarray
    total_e: float
    response: np.ndarray
    background: np.ndarray
    x0: int
    y0: int


def spot_profile(centre: np.ndarray, cov: np.ndarray, x0: int, y0: int, w: int, h: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A unit Gaussian spot integrated over the pixels of an (h, w) window from (x0, y0), and its
    derivatives with respect to the centre: (h, w) and (2, h, w)."""
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    xs = (np.arange(x0, x0 + w)[:, None] + offsets[None, :]).ravel() - float(centre[0])
    ys = (np.arange(y0, y0 + h)[:, None] + offsets[None, :]).ravel() - float(centre[1])
    gx, gy = np.meshgrid(xs, ys)
    inv = np.linalg.inv(cov)
    ax, ay = inv[0, 0] * gx + inv[0, 1] * gy, inv[1, 0] * gx + inv[1, 1] * gy  # Σ⁻¹(x − c)
    density = np.exp(-0.5 * (gx * ax + gy * ay)) / (2.0 * math.pi * math.sqrt(float(np.linalg.det(cov))))

    def per_pixel(a: np.ndarray) -> np.ndarray:
        return a.reshape(h, SUPERSAMPLE, w, SUPERSAMPLE).mean(axis=(1, 3))

    return per_pixel(density), np.stack([per_pixel(density * ax), per_pixel(density * ay)])


def _bayer_channel(x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """Which of B, G, R (0, 1, 2) each pixel of the window sees through an RGGB filter: (h, w)."""
    rows = (y0 + np.arange(h))[:, None] % 2
    cols = (x0 + np.arange(w))[None, :] % 2
    return np.where((rows == 0) & (cols == 0), 2, np.where((rows == 1) & (cols == 1), 0, 1))


def pair_information(spot: Spot, sensor: Sensor) -> tuple[np.ndarray, float, int]:
    """What one laser-on/laser-off pair tells of the spot: the Fisher information (2, 2) of its
    centre in px⁻², the squared matched-filter SNR of the difference image, and its clipped pixels."""
    h, w, channels = spot.background.shape
    g, dg = spot_profile(spot.centre_px, spot.covariance, spot.x0, spot.y0, w, h)
    if sensor.bayer and channels == 3:
        ch = _bayer_channel(spot.x0, spot.y0, w, h)
        room = np.take_along_axis(spot.background, ch[..., None], axis=2)[..., 0]
        gain = spot.total_e * np.asarray(spot.response)[ch]  # (h, w)
        signal, dsignal = gain * g, gain[None] * dg
    else:
        room = spot.background  # (h, w, C)
        gain_c = spot.total_e * np.asarray(spot.response)  # (C,)
        signal = g[..., None] * gain_c
        dsignal = dg[..., None] * gain_c  # (2, h, w, C)
    lit = room + signal
    # The difference of two frames: both frames' shot noise, read and quantisation noise twice.
    var = room + lit + 2.0 * (sensor.read_noise_e**2 + sensor.quantum_e)
    var = np.maximum(var, 1e-12)
    usable = lit < sensor.clip_e
    weight = np.where(usable, 1.0 / var, 0.0)
    fisher = np.array([[float((dsignal[i] * dsignal[j] * weight).sum()) for j in range(2)] for i in range(2)])
    seen = np.minimum(lit, sensor.clip_e) - np.minimum(room, sensor.clip_e)
    snr2 = float((seen * seen / var).sum())
    return fisher, snr2, int((~usable).sum())


def speckle_covariance(cov: np.ndarray, contrast: float, kmax: float, waves: int, grid: int = 201) -> np.ndarray:
    """Covariance (2, 2) px² of the centroid shift that speckle of `contrast`, with spatial
    frequencies filling a disc of radius `kmax` rad/px from `waves` phasors, gives a Gaussian spot
    of image covariance `cov` (the formula in the module notes, integrated on a grid)."""
    if contrast <= 0.0:
        return np.zeros((2, 2))
    cov = np.asarray(cov, dtype=np.float64)
    k = float(kmax)
    # The integrand lives where |q| < 2K (P's support) and qᵀΣq is of order 1 or less.
    extent = min(2.0 * k, 8.0 / math.sqrt(float(np.linalg.eigvalsh(cov)[0])))
    q = np.linspace(-extent, extent, grid)
    step = q[1] - q[0]
    qx, qy = np.meshgrid(q, q)
    d = np.minimum(np.hypot(qx, qy), 2.0 * k)
    # Overlap of two discs of radius K whose centres are d apart, over the disc's area squared.
    overlap = 2.0 * k * k * np.arccos(d / (2.0 * k)) - 0.5 * d * np.sqrt(np.maximum(4.0 * k * k - d * d, 0.0))
    spectrum = overlap / (math.pi * k * k) ** 2
    sx, sy = cov[0, 0] * qx + cov[0, 1] * qy, cov[1, 0] * qx + cov[1, 1] * qy
    weight = spectrum * np.exp(-(qx * sx + qy * sy)) * step * step
    c = np.array([[(weight * sx * sx).sum(), (weight * sx * sy).sum()],
                  [(weight * sy * sx).sum(), (weight * sy * sy).sum()]])
    return contrast**2 * (1.0 - 1.0 / waves) * c


def depth_gradient(laser: Laser, camera: CameraModel, pixel: np.ndarray, h: float = 0.05) -> np.ndarray:
    """∂z/∂(u, v) (2,) in m/px of `laser`'s triangulated depth at `pixel`, by central differences."""
    p = np.asarray(pixel, dtype=np.float64)
    steps = np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    z = triangulate(laser, camera, p[None, :] + steps)[:, 2]
    return np.array([(z[0] - z[1]) / (2 * h), (z[2] - z[3]) / (2 * h)])


@dataclass(frozen=True)
class Floor:
    """The floor of one laser's spot in one zone."""

    snr: float  # matched-filter SNR of the zone's mean difference image
    noise_cov_px: np.ndarray  # (2, 2) the Cramér–Rao bound over all of the zone's pairs (inf: none)
    speckle_cov_px: np.ndarray  # (2, 2) speckle's, for one view
    views: int  # distinct speckle patterns among the pairs
    gradient: np.ndarray  # (2,) ∂z/∂(u, v), m/px
    clipped: int  # clipped pixels of the spot, over all pairs

    @property
    def observable(self) -> bool:
        return self.snr >= OBSERVABLE_SNR

    def _range(self, cov: np.ndarray) -> float:
        if not np.isfinite(cov).all():
            return math.inf
        return math.sqrt(max(float(self.gradient @ cov @ self.gradient), 0.0))

    @property
    def noise_m(self) -> float:
        return self._range(self.noise_cov_px)

    @property
    def speckle_m(self) -> float:
        return self._range(self.speckle_cov_px / max(self.views, 1))

    @property
    def sigma_m(self) -> float:
        """The range floor (1 σ, m): noise and speckle together."""
        return self._range(self.noise_cov_px + self.speckle_cov_px / max(self.views, 1))

    def to_json(self) -> dict:
        def num(x: float, nd: int = 7) -> float | None:
            return round(x, nd) if math.isfinite(x) else None

        return {
            "snr": round(self.snr, 2),
            "sigma_m": num(self.sigma_m),
            "noise_m": num(self.noise_m),
            "speckle_m": num(self.speckle_m),
            "noise_px": num(math.sqrt(float(np.trace(self.noise_cov_px)) / 2.0), 5)
            if np.isfinite(self.noise_cov_px).all() else None,
            "speckle_px": round(math.sqrt(float(np.trace(self.speckle_cov_px)) / 2.0), 5),
            "views": self.views,
            "clipped": self.clipped,
        }


def spot_floor(spots: Sequence[Spot], sensor: Sensor, speckle_cov_px: np.ndarray, views: int,
               gradient: np.ndarray) -> Floor:
    """The floor of a spot seen in `spots` (one per laser-on/laser-off pair) with `views` distinct
    speckle patterns among them."""
    fisher = np.zeros((2, 2))
    snr2 = 0.0
    clipped = 0
    for spot in spots:
        f, s2, c = pair_information(spot, sensor)
        fisher += f
        snr2 += s2
        clipped += c
    if len(spots) and np.linalg.det(fisher) > 1e-12 * max(float(np.trace(fisher)) ** 2, 1e-300):
        noise = np.linalg.inv(fisher)
    else:
        noise = np.full((2, 2), math.inf)
    # The mean of n pairs' differences: the squared SNRs of the pairs add.
    return Floor(math.sqrt(snr2), noise, np.asarray(speckle_cov_px, dtype=np.float64), views,
                 np.asarray(gradient, dtype=np.float64), clipped)


def fusion_weights(points: np.ndarray, sigmas_m: np.ndarray, directions: np.ndarray, normal: np.ndarray,
                   min_spread_m: float = 0.01) -> np.ndarray:
    """How the reference laser's range follows from the depths of spots that all lie on one plane:
    weights w (n,), the reference's error being Σ wᵢ δzᵢ of the lasers' depth errors δzᵢ (0 for a
    laser of infinite σ). Zeros when the reference spot itself cannot be located.

    `points` (n, 3): the spots' true points, camera frame, the reference's first; `sigmas_m` (n,):
    each laser's range floor; `directions` (n, 3): the lasers' beams; `normal` (3,): the plane's
    normal, camera frame. The plane z = a + g·(y − y_ref) + h·(x − x_ref) has an unknown offset a and
    slopes g, h — a slope only where the points spread at least `min_spread_m` along it (else it
    cannot be measured, and hardly matters). A laser's depth error δz_i moves its point along its beam
    d_i, which is δz_i·(1 − (g·d_y + h·d_x)/d_z) off the plane; weighted least squares fits the
    offset, and the reference's depth follows from it the same way back.
    """
    pts = np.asarray(points, dtype=np.float64)
    sig = np.asarray(sigmas_m, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    weights = np.zeros(len(pts))
    if not (math.isfinite(float(sig[0])) and sig[0] > 0):
        return weights
    n = np.asarray(normal, dtype=np.float64)
    g, h = (-n[1] / n[2], -n[0] / n[2]) if abs(n[2]) > 1e-9 else (0.0, 0.0)
    signed = 1.0 - (g * d[:, 1] + h * d[:, 0]) / d[:, 2]
    across = np.where(signed < 0.0, -1.0, 1.0) * np.maximum(np.abs(signed), 1e-9)
    keep = np.flatnonzero(np.isfinite(sig) & (sig > 0))
    pts, eff = pts[keep], np.abs(sig * across)[keep]
    dx, dy = pts[:, 0] - pts[0, 0], pts[:, 1] - pts[0, 1]
    cols = [np.ones(len(pts))]
    if np.ptp(dy) >= min_spread_m:
        cols.append(dy)
    if np.ptp(dx) >= min_spread_m:
        cols.append(dx)
    design = np.stack(cols[: len(pts)], axis=1)  # no more unknowns than spots
    info = design.T @ (design / eff[:, None] ** 2)
    if np.linalg.cond(info) < 1e12:
        # The fitted offset is row 0 of (DᵀWD)⁻¹DᵀW applied to the off-plane errors δzᵢ·acrossᵢ.
        offset = (np.linalg.inv(info) @ (design / eff[:, None] ** 2).T)[0]
        weights[keep] = offset * across[keep] / across[0]
    else:
        weights[0] = 1.0
    return weights


def fused_sigma(points: np.ndarray, sigmas_m: np.ndarray, directions: np.ndarray, normal: np.ndarray,
                min_spread_m: float = 0.01) -> float:
    """The floor of the reference laser's range from the depths of spots that all lie on one plane
    (:func:`fusion_weights`, whose arguments these are): √Σ (wᵢ σᵢ)²."""
    sig = np.asarray(sigmas_m, dtype=np.float64)
    w = fusion_weights(points, sig, directions, normal, min_spread_m)
    if not w.any():
        return math.inf  # the reference spot itself cannot be located
    used = w != 0.0
    return math.sqrt(float(((w[used] * sig[used]) ** 2).sum()))
