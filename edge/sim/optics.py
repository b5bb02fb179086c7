"""What one laser spot looks like on the sensor: footprint, brightness, blur and speckle.

Pure functions used by the renderer. The model, in short:

* The beam is Gaussian with a 1/e² radius that grows linearly with distance; on a surface hit at
  incidence angle i its footprint stretches by 1/cos i along the beam's in-plane direction.
* That footprint is mapped into the image with the projection's Jacobian (so perspective, surface
  slant and lens distortion shape the spot), then blurred by the lens (a fixed PSF plus a defocus
  disc that grows away from the focus distance).
* Brightness follows a Lambertian surface plus a Phong lobe for glossy ones, 1/d² from the camera,
  and is expressed in photo-electrons.
* Laser speckle is a fully developed speckle field (random phasors summed over the pupil) that
  multiplies the spot. Its seed is tied to where the spot sits on the surface, so it stays put while
  the spot stays put and changes when the spot moves. It shifts the spot's centroid by about 0.1 px
  (1 σ, per axis) at f/2, which is about 0.5 % of range at 1 m for one laser of the default rig.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Supersampling per pixel side when integrating a spot over pixels; 5 keeps centroid bias of the
# narrowest spot (σ = 0.5 px) far below 0.01 px.
SUPERSAMPLE = 5
# Speckle: number of random phasors and the highest spatial frequency (rad/px) of the field; the
# contrast below was tuned (tests/test_render.py measures it) for ~0.1 px centroid jitter at f/2.
_SPECKLE_WAVES = 48
_SPECKLE_KMAX = 2.2
SPECKLE_CONTRAST_F2 = 0.45


@dataclass(frozen=True)
class SpotImage:
    """A spot's photo-electrons in an image window: ``electrons[r, c]`` is pixel
    ``(x0 + c, y0 + r)``; shape (h, w), float64."""

    x0: int
    y0: int
    electrons: np.ndarray


def beam_radius(waist_m: float, divergence_rad: float, distance_m: float) -> float:
    """1/e² radius of a Gaussian beam at `distance_m` from its waist (far-field approximation)."""
    return math.hypot(waist_m, divergence_rad * distance_m)


def surface_footprint(
    beam_dir: np.ndarray, normal: np.ndarray, sigma_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The spot's footprint on a plane as two orthogonal in-plane axes (3,) and their 1-σ lengths.

    Returns (axis1, axis2, sigmas (2,)): the footprint stretches by 1/cos(i) along `axis1`, the
    beam's direction projected onto the surface.
    """
    cos_i = abs(float(beam_dir @ normal))
    along = beam_dir - (beam_dir @ normal) * normal
    n_along = float(np.linalg.norm(along))
    if n_along < 1e-9:  # beam along the normal: any in-plane axis will do
        helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        along = np.cross(normal, helper)
        n_along = float(np.linalg.norm(along))
    axis1 = along / n_along
    axis2 = np.cross(normal, axis1)
    stretch = 1.0 / max(cos_i, 0.05)  # grazing beams: cap the smear at 20×
    return axis1, axis2, np.array([sigma_m * stretch, sigma_m])


def image_covariance(
    jacobian: np.ndarray, sigmas_m: np.ndarray, psf_sigma_px: float, defocus_px: float
) -> np.ndarray:
    """Covariance (2, 2) in px² of the spot image: footprint through the projection Jacobian
    (2, 2: pixels per metre along the two footprint axes), plus lens PSF and defocus disc."""
    s = np.diag(np.asarray(sigmas_m) ** 2)
    blur = psf_sigma_px**2 + (defocus_px / 4.0) ** 2  # a uniform disc of diameter D has σ = D/4
    return jacobian @ s @ jacobian.T + blur * np.eye(2)


def defocus_diameter_px(
    f_px: float, focal_length_mm: float, f_number: float, focus_m: float, depth_m: float
) -> float:
    """Diameter of the blur disc (px) of a point at `depth_m` when the lens is focused at `focus_m`."""
    aperture_m = focal_length_mm * 1e-3 / f_number
    return f_px * aperture_m * abs(1.0 / depth_m - 1.0 / focus_m)


def reflected_fraction(
    albedo: float,
    gloss: float,
    shininess: float,
    beam_dir: np.ndarray,
    normal: np.ndarray,
    to_camera: np.ndarray,
) -> float:
    """Light sent to the camera relative to a white matte surface seen squarely (both at 1 m).

    `beam_dir`: unit direction of travel of the beam; `normal`: unit normal facing the beam's
    source; `to_camera`: unit vector from the spot to the camera.
    """
    cos_i = max(0.0, -float(beam_dir @ normal))
    cos_e = max(0.0, float(to_camera @ normal))
    diffuse = (1.0 - gloss) * albedo * cos_i * cos_e
    mirror = beam_dir - 2.0 * float(beam_dir @ normal) * normal
    lobe = max(0.0, float(mirror @ to_camera)) ** shininess
    specular = gloss * (shininess + 2.0) / 2.0 * lobe
    return diffuse + specular


def speckle_field(
    rng: np.random.Generator, x: np.ndarray, y: np.ndarray, contrast: float, grain: float = 1.0
) -> np.ndarray:
    """A speckle intensity pattern of mean 1 at points (x, y) in px relative to the spot centre.

    A sum of random phasors with spatial frequencies uniform in a disc (the pupil) gives fully
    developed speckle (exponential intensity statistics); `contrast` blends it towards 1 to stand for
    the averaging over the pixel and the laser's finite coherence. `grain` scales the speckle size
    (1 at f/2; it grows in proportion to the f-number).
    """
    if contrast <= 0.0:
        return np.ones_like(x)
    kx, ky, phase = _speckle_waves(rng, grain)
    arg = x[..., None] * kx + y[..., None] * ky + phase
    field = np.abs(np.exp(1j * arg).sum(axis=-1)) ** 2 / _SPECKLE_WAVES
    return 1.0 + contrast * (field - 1.0)


def speckle_grid(
    rng: np.random.Generator, xs: np.ndarray, ys: np.ndarray, contrast: float, grain: float = 1.0
) -> np.ndarray:
    """:func:`speckle_field` on the grid ``meshgrid(xs, ys)`` (rows ys, columns xs), the same
    pattern from the same draws. A phasor is separable, exp(i(x·kx + y·ky + φ)) =
    exp(i(y·ky + φ)) · exp(i·x·kx), so the sum over the phasors is one small complex matrix
    product instead of an exponential per point and phasor: the renderer's spots are grids."""
    if contrast <= 0.0:
        return np.ones((len(ys), len(xs)))
    kx, ky, phase = _speckle_waves(rng, grain)
    rows = np.exp(1j * (np.asarray(ys)[:, None] * ky + phase))
    columns = np.exp(1j * (np.asarray(xs)[:, None] * kx))
    field = np.abs(rows @ columns.T) ** 2 / _SPECKLE_WAVES
    return 1.0 + contrast * (field - 1.0)


def _speckle_waves(rng: np.random.Generator, grain: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The phasors' spatial frequencies (kx, ky, rad/px) and phases, drawn in this order."""
    k = (_SPECKLE_KMAX / grain) * np.sqrt(rng.random(_SPECKLE_WAVES))
    angle = rng.random(_SPECKLE_WAVES) * 2.0 * math.pi
    phase = rng.random(_SPECKLE_WAVES) * 2.0 * math.pi
    return k * np.cos(angle), k * np.sin(angle), phase


def render_spot(
    centre_px: np.ndarray,
    covariance: np.ndarray,
    total_e: float,
    width: int,
    height: int,
    speckle_rng: np.random.Generator | None = None,
    speckle_contrast: float = 0.0,
    speckle_grain: float = 1.0,
) -> SpotImage | None:
    """Integrate a Gaussian spot (times speckle) over the pixels it covers.

    `centre_px` (2,) is where the spot's centre projects; pixel centres are at integers (OpenCV).
    Returns None if the spot's window lies wholly outside the image.
    """
    cov = np.asarray(covariance, dtype=np.float64)
    radius = int(math.ceil(4.0 * math.sqrt(float(np.linalg.eigvalsh(cov)[-1])))) + 1
    cu, cv = float(centre_px[0]), float(centre_px[1])
    x0, x1 = max(0, int(round(cu)) - radius), min(width, int(round(cu)) + radius + 1)
    y0, y1 = max(0, int(round(cv)) - radius), min(height, int(round(cv)) + radius + 1)
    if x0 >= x1 or y0 >= y1:
        return None
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    xs = (np.arange(x0, x1)[:, None] + offsets[None, :]).ravel() - cu
    ys = (np.arange(y0, y1)[:, None] + offsets[None, :]).ravel() - cv
    gx, gy = np.meshgrid(xs, ys)
    inv = np.linalg.inv(cov)
    q = inv[0, 0] * gx * gx + 2.0 * inv[0, 1] * gx * gy + inv[1, 1] * gy * gy
    density = np.exp(-0.5 * q) / (2.0 * math.pi * math.sqrt(float(np.linalg.det(cov))))
    if speckle_rng is not None and speckle_contrast > 0.0:
        density = density * speckle_grid(speckle_rng, xs, ys, speckle_contrast, speckle_grain)
    h, w = y1 - y0, x1 - x0
    per_pixel = density.reshape(h, SUPERSAMPLE, w, SUPERSAMPLE).mean(axis=(1, 3))
    return SpotImage(x0, y0, per_pixel * total_e)
