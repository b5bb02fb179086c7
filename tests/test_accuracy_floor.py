"""The physical floor against cases with known answers: the Cramér–Rao bound of a Gaussian spot in
white noise (and a least-squares fit that reaches it), the speckle term against a Monte Carlo of the
renderer's own speckle, the triangulation's derivative, and the fused floor of spots on a plane."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.accuracy import floor as fl
from edge.rig import default_rig
from edge.sim import optics


def _fit(image: np.ndarray, start: np.ndarray, cov: np.ndarray, total: float, x0: int, y0: int) -> np.ndarray:
    """Least-squares centre of a Gaussian spot of known shape and brightness (Gauss–Newton)."""
    h, w = image.shape
    c = start.copy()
    for _ in range(6):
        model, d = fl.spot_profile(c, cov, x0, y0, w, h)
        jac = (total * d).reshape(2, -1).T
        c = c + np.linalg.lstsq(jac, (image - total * model).ravel(), rcond=None)[0]
    return c


def test_crb_of_a_gaussian_spot_in_white_noise_is_reached_by_least_squares() -> None:
    cov = np.array([[1.0, 0.2], [0.2, 0.8]])
    total, noise = 2000.0, 10.0
    centre, x0, y0, w, h = np.array([10.3, 9.7]), 2, 2, 16, 16
    g, dg = fl.spot_profile(centre, cov, x0, y0, w, h)
    assert g.sum() == pytest.approx(1.0, abs=1e-3)  # the window holds the whole spot
    crb = np.linalg.inv(np.einsum("ihw,jhw->ij", total * dg, total * dg) / noise**2)  # σ² / Σ ∂I ∂Iᵀ
    # pair_information says the same when the noise is white: a background far brighter than the
    # spot, its shot noise σ² / 2 per frame.
    room = np.full((h, w, 1), noise**2 / 2 * 1e6)
    spot = fl.Spot(centre, cov, total * 1e3, np.array([1.0]), room, x0, y0)
    fisher, _, clipped = fl.pair_information(spot, fl.Sensor(0.0, 0.0, math.inf))
    assert clipped == 0
    assert np.linalg.inv(fisher) == pytest.approx(crb, rel=2e-3)
    rng = np.random.default_rng(1)
    fits = np.array([_fit(total * g + rng.normal(0.0, noise, g.shape), centre + rng.normal(0, 0.05, 2),
                          cov, total, x0, y0) for _ in range(300)])
    assert np.abs(fits.mean(axis=0) - centre).max() < 0.006  # unbiased
    assert fits.std(axis=0) == pytest.approx(np.sqrt(np.diag(crb)), rel=0.15)


def test_clipped_pixels_carry_no_information_and_the_snr_grows_with_pairs() -> None:
    cov = np.eye(2) * 0.7**2
    room = np.full((11, 11, 1), 200.0)
    sensor = fl.Sensor.of(10000.0, 3.0, 10, 8)
    assert sensor.clip_e == 10000.0
    assert sensor.quantum_e == pytest.approx(((10000 / 1023) ** 2 + (10000 / 255) ** 2) / 12)
    dim = fl.Spot(np.array([5.2, 4.9]), cov, 5000.0, np.array([1.0]), room, 0, 0)
    bright = fl.Spot(dim.centre_px, cov, 200000.0, np.array([1.0]), room, 0, 0)
    f_dim, snr2_dim, c_dim = fl.pair_information(dim, sensor)
    f_bright, _, c_bright = fl.pair_information(bright, sensor)
    f_deep, _, c_deep = fl.pair_information(bright, fl.Sensor(sensor.read_noise_e, sensor.quantum_e, 1e9))
    assert c_dim == 0 and c_bright > 0 and c_deep == 0
    assert np.trace(f_bright) < 0.5 * np.trace(f_deep)  # its core is clipped: only the wings tell
    one = fl.spot_floor([dim], sensor, np.zeros((2, 2)), 1, np.array([1.0, 0.0]))
    four = fl.spot_floor([dim] * 4, sensor, np.zeros((2, 2)), 1, np.array([1.0, 0.0]))
    assert one.snr == pytest.approx(math.sqrt(snr2_dim))
    assert four.snr == pytest.approx(2 * one.snr) and four.noise_m == pytest.approx(one.noise_m / 2)
    assert one.observable
    assert not fl.spot_floor([], sensor, np.zeros((2, 2)), 0, np.array([1.0, 0.0])).observable


def test_bayer_filter_leaves_a_quarter_of_the_red_pixels() -> None:
    cov = np.eye(2) * 1.5**2  # wide enough that each quarter of the pixels sees the same
    room = np.full((15, 15, 3), 100.0)
    spot = fl.Spot(np.array([7.0, 7.0]), cov, 20000.0, np.array([0.0, 0.0, 1.0]), room, 0, 0)
    full, _, _ = fl.pair_information(spot, fl.Sensor(5.0, 0.0, math.inf))
    bayer, _, _ = fl.pair_information(spot, fl.Sensor(5.0, 0.0, math.inf, bayer=True))
    assert np.trace(bayer) == pytest.approx(np.trace(full) / 4, rel=0.1)


def _centroid_shifts(sd: float, contrast: float, grain: float, draws: int) -> tuple[np.ndarray, np.ndarray]:
    """The renderer's speckle (optics.speckle_field) on a Gaussian spot: the centroid's shifts to
    first order (what the formula integrates) and in full, (draws, 2) each."""
    x = np.arange(-4.0 * sd, 4.0 * sd + 1e-9, 0.25)
    gx, gy = np.meshgrid(x, x)
    g = np.exp(-0.5 * (gx**2 + gy**2) / sd**2)
    g /= g.sum()
    linear, full = [], []
    for i in range(draws):
        s = optics.speckle_field(np.random.default_rng([5, i]), gx, gy, contrast, grain)
        linear.append([(gx * g * (s - 1)).sum(), (gy * g * (s - 1)).sum()])
        m = (g * s).sum()
        full.append([(gx * g * s).sum() / m, (gy * g * s).sum() / m])
    return np.array(linear), np.array(full)


@pytest.mark.parametrize(("sd", "contrast", "grain"), [(0.7, 0.45, 1.0), (1.2, 0.6, 1.5)])
def test_speckle_term_matches_a_monte_carlo_of_the_renderers_speckle(sd: float, contrast: float, grain: float) -> None:
    cov = fl.speckle_covariance(np.eye(2) * sd**2, contrast, optics.SPECKLE_KMAX / grain, optics.SPECKLE_WAVES)
    predicted = math.sqrt(cov[0, 0])
    assert cov[0, 1] == pytest.approx(0.0, abs=1e-9) and cov[1, 1] == pytest.approx(cov[0, 0])
    # 200 draws: each axis's spread is known to ±5 %, both together to ±3.5 %.
    linear, full = (shifts.std(axis=0).mean() for shifts in _centroid_shifts(sd, contrast, grain, 200))
    assert linear == pytest.approx(predicted, rel=0.1)
    # The centroid divides by the speckled spot's brightness, which steadies it a little.
    assert 0.8 * predicted < full < 1.05 * predicted
    assert fl.speckle_covariance(np.eye(2), 0.0, 2.2, 48).sum() == 0.0


def test_depth_gradient_of_the_centre_laser_is_z_squared_over_f_b() -> None:
    rig = default_rig()
    cam, center = rig.camera, rig.laser("center")
    for z in (0.5, 2.0, 4.0):
        pixel = cam.project(center.point_at_depth(z))
        g = fl.depth_gradient(center, cam, pixel)
        assert g[0] == pytest.approx(-(z**2) / (cam.fx * 0.035), rel=1e-3)
        assert abs(g[1]) < 1e-6 * abs(g[0])  # moving across the epipolar line changes nothing


def _wall_spots() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The default rig's spots on a wall facing it 2 m away: beams, normal, points and floors."""
    rig = default_rig()
    d = np.array([laser.d for laser in rig.lasers])
    points = np.array([laser.point_at_depth(2.0) for laser in rig.lasers])
    return d, np.array([0.0, 0.0, -1.0]), points, np.array([0.02, 0.02, 0.005])


def test_fused_floor_of_spots_on_a_plane() -> None:
    d, facing, points, sig = _wall_spots()
    assert fl.fused_sigma(points[:1], sig[:1], d[:1], facing) == pytest.approx(0.02)
    # Centre and parallel alone: the plane's slope along y takes the second spot.
    assert fl.fused_sigma(points[:2], sig[:2], d[:2], facing) == pytest.approx(0.02)
    # With the sloped laser the line z = a + g·y is overdetermined: weighted least squares.
    y = points[:, 1] - points[0, 1]
    a = np.stack([np.ones(3), y], axis=1)
    expected = math.sqrt(np.linalg.inv(a.T @ (a / sig[:, None] ** 2))[0, 0])
    assert fl.fused_sigma(points, sig, d, facing) == pytest.approx(expected)
    assert expected < 0.02
    assert fl.fused_sigma(points, np.array([math.inf, 0.02, 0.005]), d, facing) == math.inf


def test_fusion_weights_carry_the_lasers_depth_errors_to_the_reference_s_range() -> None:
    d, facing, points, sig = _wall_spots()
    w = fl.fusion_weights(points, sig, d, facing)
    # A wall 1 cm nearer in every laser's depth is a wall 1 cm nearer: the fit passes that on whole.
    assert w.sum() == pytest.approx(1.0)
    assert math.sqrt(float(((w * sig) ** 2).sum())) == pytest.approx(fl.fused_sigma(points, sig, d, facing))
    # Errors that only tilt the wall about the reference's point leave its range alone: the slope is free.
    assert float(w @ (points[:, 1] - points[0, 1])) == pytest.approx(0.0, abs=1e-12)
    alone = fl.fusion_weights(points[:1], sig[:1], d[:1], facing)
    assert alone.tolist() == [1.0]
    lost = fl.fusion_weights(points, np.array([math.inf, 0.02, 0.005]), d, facing)
    assert not lost.any()
    no_parallel = fl.fusion_weights(points, np.array([0.02, math.inf, 0.005]), d, facing)
    assert no_parallel[1] == 0.0 and no_parallel.sum() == pytest.approx(1.0)
