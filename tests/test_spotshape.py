"""spotshape.fit_round: the Gaussian that places a JPEG frame's spot, on windows made here."""

from __future__ import annotations

import cv2
import numpy as np

from edge.spotshape import fit_round, window_powers

R = 7  # a 15 × 15 window, as the finder's for a spot of σ 2 px


def _spot(centre: tuple[float, float], sd: float, peak: float) -> np.ndarray:
    """A round Gaussian spot in a (2R + 1)² window, `centre` (du, dv) from its middle."""
    v, u = np.mgrid[-R : R + 1, -R : R + 1].astype(np.float64)
    return peak * np.exp(-((u - centre[0]) ** 2 + (v - centre[1]) ** 2) / (2.0 * sd * sd))


def test_a_spot_in_white_noise_is_placed_as_its_covariance_says() -> None:
    """In white noise of the variance it is told, the fit's χ² per degree of freedom is about 1 and
    its centres scatter as its covariance says (the σ the finder grows from it)."""
    rng = np.random.default_rng(7)
    noise, errors, sigmas, chi2 = 0.01, [], [], []
    for _ in range(300):
        centre = tuple(rng.uniform(-0.5, 0.5, 2))
        window = _spot(centre, 1.3, 0.2) + rng.normal(0.0, noise, (2 * R + 1, 2 * R + 1))
        # Started where a centroid might put it, with a width a little off.
        start = (centre[0] + rng.normal(0.0, 0.2), centre[1] + rng.normal(0.0, 0.2), 1.3**2 * 1.4)
        fit = fit_round(window, None, np.full(window.shape, noise**2), window_powers(R), start)
        assert fit is not None
        u, v, c, cov = fit
        errors.append((u - centre[0], v - centre[1]))
        sigmas.append(np.sqrt(np.diag(cov)))
        chi2.append(c)
    ratio = np.sqrt(np.mean((np.array(errors) / np.array(sigmas)) ** 2))
    assert 0.85 < ratio < 1.2, ratio
    assert 0.9 < float(np.mean(chi2)) < 1.1, np.mean(chi2)


def test_a_bright_spot_is_placed_to_a_hundredth_of_a_pixel_from_a_start_well_off() -> None:
    window = _spot((0.31, -0.44), 1.6, 0.8)
    fit = fit_round(window, None, np.full(window.shape, 1e-4), window_powers(R), (-0.3, 0.2, 1.0))
    assert fit is not None
    assert abs(fit[0] - 0.31) < 0.01 and abs(fit[1] + 0.44) < 0.01


def test_jpegs_blocks_leave_a_misfit_that_white_noise_does_not() -> None:
    """Through JPEG at quality 50 a small spot becomes a few blocks' coarse frequencies: the fit's χ²
    says the shape is not a Gaussian's by far more than noise of the frame's own level would."""
    rng = np.random.default_rng(3)
    frame = np.full((64, 64), 20.0) + rng.normal(0.0, 1.0, (64, 64))
    v, u = np.mgrid[0:64, 0:64]
    frame += 120.0 * np.exp(-((u - 30.4) ** 2 + (v - 33.2) ** 2) / (2.0 * 1.2**2))
    raw = np.clip(np.rint(frame), 0, 255).astype(np.uint8)
    jpeg = cv2.imdecode(cv2.imencode(".jpg", raw, [cv2.IMWRITE_JPEG_QUALITY, 50])[1], cv2.IMREAD_GRAYSCALE)
    powers, results = window_powers(R), {}
    for name, image in (("raw", raw), ("jpeg", jpeg)):
        window = image[33 - R : 33 + R + 1, 30 - R : 30 + R + 1].astype(np.float64) - 20.0
        var = 1.0 + 0.0 * window  # the frame's own noise, 1 level
        results[name] = fit_round(window, None, var, powers, (0.4, 0.2, 1.5))
    assert results["raw"] is not None and results["jpeg"] is not None
    assert results["raw"][2] < 2.0  # rounding and noise: about what white noise of 1 level leaves
    assert results["jpeg"][2] > 5.0 * results["raw"][2]
    # Yet the blocks move the spot's centre far less than its shape: both near the truth (0.4, 0.2).
    for name in results:
        assert abs(results[name][0] - 0.4) < 0.3 and abs(results[name][1] - 0.2) < 0.3, (name, results[name])


def test_a_window_of_noise_or_a_dark_patch_is_no_spot() -> None:
    """A shadow is never a spot. Noise alone mostly is not either (no positive amplitude, or the
    centre wanders off its start); where it is, its χ² is noise's, with nothing to grow a σ by,
    and the centre stays within the pixel the contract allows."""
    rng = np.random.default_rng(5)
    var = np.full((2 * R + 1, 2 * R + 1), 1e-4)
    dark = -_spot((0.0, 0.0), 1.5, 0.3)
    assert fit_round(dark, None, var, window_powers(R), (0.0, 0.0, 2.0)) is None
    fits = [fit_round(rng.normal(0.0, 0.01, var.shape), None, var, window_powers(R), (0.0, 0.0, 2.0))
            for _ in range(50)]
    kept = [f for f in fits if f is not None]
    assert len(kept) <= 10
    assert all(abs(f[0]) <= 1.0 and abs(f[1]) <= 1.0 and 0.7 < f[2] < 1.4 for f in kept)


def test_pixels_left_out_are_not_fitted() -> None:
    """A clipped core or a neighbour's pixels (`use` False) do not pull the centre; taken in, the
    neighbour's light pulls it (0.1 px here) and leaves a misfit."""
    window = _spot((0.2, 0.1), 1.4, 0.5)
    window[:, -4:] += 0.2  # another light at the window's edge
    use = np.ones(window.shape, bool)
    use[:, -4:] = False
    fit = fit_round(window, use, np.full(window.shape, 1e-4), window_powers(R), (0.0, 0.0, 2.0))
    assert fit is not None and abs(fit[0] - 0.2) < 0.01 and abs(fit[1] - 0.1) < 0.01
    pulled = fit_round(window, None, np.full(window.shape, 1e-4), window_powers(R), (0.0, 0.0, 2.0))
    assert pulled is not None and pulled[0] - 0.2 > 0.05 and pulled[2] > 10.0 * max(fit[2], 1.0)
