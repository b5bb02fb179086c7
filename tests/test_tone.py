"""A camera's tone curve measured from two exposures of a still scene (edge.tone.measure_gamma):
frames made here the way a sensor makes them (shot and read noise on the light, the curve, 8-bit
rounding), the curve known, so the measurement is checked against the truth."""

from __future__ import annotations

import numpy as np
import pytest

from edge.tone import MEASURE_MIN_VALUES, measure_gamma, tone_curve

FULL_WELL_E = 3000.0  # electrons at full scale: a small pixel's


def _room(seed: int, brightest: float) -> np.ndarray:
    """A room's light at the shorter exposure (0-1 of full scale): mostly dark, as a room is at
    the short exposures that keep a laser spot from clipping."""
    return brightest * np.random.default_rng(seed).uniform(0.0, 1.0, (120, 160, 3)) ** 2


def _frames(light: np.ndarray, exposure: float, gamma: float, seed: int, n: int = 4) -> np.ndarray:
    """The mean of `n` 8-bit frames of `light` exposed `exposure` times as long, through the curve."""
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(n):
        electrons = rng.poisson(light * exposure * FULL_WELL_E) + rng.normal(0.0, 3.0, light.shape)
        frames.append(np.round(255.0 * tone_curve(np.clip(electrons / FULL_WELL_E, 0.0, 1.0), gamma)))
    return np.mean(frames, axis=0) / 255.0


@pytest.mark.parametrize("gamma", [1.0, 1.8, 2.2, 2.6])
@pytest.mark.parametrize("ratio", [2.0, 4.0])
def test_two_exposures_of_a_still_scene_tell_the_curve(gamma, ratio):
    light = _room(1, 0.4)
    measured = measure_gamma(_frames(light, 1.0, gamma, 2), _frames(light, ratio, gamma, 3), ratio)
    assert measured is not None
    assert measured.gamma == pytest.approx(gamma, abs=0.05)
    assert measured.values >= MEASURE_MIN_VALUES
    assert measured.misfit < 4.0 / 255.0  # what is left is the frames' noise, not a wrong curve


def test_a_dim_picture_cannot_tell_a_linear_camera_from_a_curved_one_and_says_so():
    """All its values below the knee of the steeper curves, where each curve is a straight line:
    those curves fit as well as a linear one, and the measurement gives the span they cover; the
    values choosing themselves by their own noise had read such a linear camera as gamma 2.56."""
    light = _room(1, 0.055)  # values up to 5.5 % of full scale, as in a dim room at a short exposure
    measured = measure_gamma(_frames(light, 1.0, 1.0, 2), _frames(light, 3.0, 1.0, 3), 3.0,
                             chosen_by=(_frames(light, 1.0, 1.0, 4), _frames(light, 3.0, 1.0, 5)))
    assert measured is not None and measured.low == 1.0 and measured.high >= 2.5
    bright = _room(1, 0.4)
    told = measure_gamma(_frames(bright, 1.0, 1.0, 2), _frames(bright, 3.0, 1.0, 3), 3.0,
                         chosen_by=(_frames(bright, 1.0, 1.0, 4), _frames(bright, 3.0, 1.0, 5)))
    assert told is not None and told.gamma == pytest.approx(1.0, abs=0.05) and told.high - told.low <= 0.2


def test_a_picture_too_dark_to_tell_says_so():
    light = _room(1, 0.02)  # nearly everything below the floor in the shorter exposure
    assert measure_gamma(_frames(light, 1.0, 1.0, 2), _frames(light, 4.0, 1.0, 3), 4.0) is None


def test_a_scene_that_changed_between_the_exposures_shows_as_misfit():
    still = _room(1, 0.4)
    moved = _room(9, 0.4)  # another picture altogether in the longer exposure
    measured = measure_gamma(_frames(still, 1.0, 1.0, 2), _frames(moved, 4.0, 1.0, 3), 4.0)
    assert measured is not None and measured.misfit > 20.0 / 255.0


def test_the_exposures_must_differ_and_the_frames_match():
    frame = _frames(_room(1, 0.4), 1.0, 1.0, 2)
    with pytest.raises(ValueError, match="longer"):
        measure_gamma(frame, frame, 1.0)
    with pytest.raises(ValueError, match="sizes"):
        measure_gamma(frame, frame[:10], 2.0)
