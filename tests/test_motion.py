"""The room moving between a zone's laser-on and laser-off frames (`edge.motion`): a rig on a robot
that turns, worn by someone walking, or on a head still ringing. The frames are the simulator's,
the laser-off frame rendered with the camera turned a little from the laser-on frame's pose (the
lasers ride with the camera: only the room moves)."""

from __future__ import annotations

import functools

import cv2
import numpy as np
import pytest

from edge.config import load_config
from edge.errors import ConfigError
from edge.motion import Turn
from edge.ranging import Ranger
from edge.sim.record import scene_for, true_rig
from edge.sim.render import Renderer
from edge.tracks import FrameGroup

# Views of the office: walls, the desk and the cabinets, 0.9–3.6 m away.
PANS = (-168.75, -140.625, -112.5, -84.375, -56.25, -28.125, 0.0, 28.125, 56.25, 84.375, 112.5, 140.625)


@functools.cache
def _office() -> Renderer:
    config = load_config(None)
    return Renderer(scene_for(config), true_rig(config), config.sim, config.camera)


def _pair(pan: float, turned: tuple[float, float], seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A laser-on frame at (pan, 0) and a laser-off frame with the camera turned by `turned` (pan,
    tilt degrees) from it."""
    renderer = _office()
    rng = np.random.default_rng(seed)
    lit = renderer.render(pan, 0.0, {n: 1.0 for n in renderer.rig.laser_names}, 0.0, rng)
    dark = renderer.render(pan + turned[0], turned[1], {}, 0.0, rng)
    return lit, dark


def _truth(pan: float) -> float | None:
    spot = _office().spots(pan, 0.0)["center"]
    return spot.depth_m if spot.visible else None


def test_still_frames_are_not_moved_and_a_turn_of_a_twentieth_of_a_degree_is() -> None:
    """The gate never fires on frames of one pose, and fires on every view turned 0.05° (half a
    pixel), 0.5° and 3° (28 px)."""
    ranger = Ranger(_office().rig)
    for i, pan in enumerate(PANS):
        assert not ranger.steadier.moved(*_pair(pan, (0.0, 0.0), i)), pan
        for turned in ((0.05, 0.0), (0.0, -0.5), (3.0, 1.0)):
            assert ranger.steadier.moved(*_pair(pan, turned, i)), (pan, turned)


@pytest.mark.parametrize("turned", [(0.1, 0.0), (-0.3, 0.2), (1.0, -0.5)])
def test_the_turn_is_found_to_a_few_thousandths_of_a_degree(turned: tuple[float, float]) -> None:
    """The fitted rotation, in pan and tilt, against the one rendered; and the laser-off frame
    turned back matches the laser-on frame's room far better than before (away from the spots)."""
    ranger = Ranger(_office().rig)
    for pan in (-112.5, 0.0, 84.375):
        lit, dark = _pair(pan, turned, 3)
        turn = ranger.steadier.turn(lit, dark)
        angles = np.degrees(cv2.Rodrigues(turn.rotation)[0].ravel())
        # (the camera's y axis is pan's; its x axis tilt's, the other way round)
        assert angles[1] == pytest.approx(turned[0], abs=0.005), pan
        assert -angles[0] == pytest.approx(turned[1], abs=0.005), pan
        back = ranger.steadier.turned_back(dark, turn)
        rows = slice(40, 440)
        left = slice(40, 250)  # (the laser paths run down the middle)
        before = np.abs(lit[rows, left, 2].astype(float) - dark[rows, left, 2]).mean()
        after = np.abs(lit[rows, left, 2].astype(float) - back[rows, left, 2]).mean()
        assert after < 0.6 * before, (pan, before, after)


def test_the_half_size_picture_leads_where_the_smaller_ones_disagree() -> None:
    """Phase correlation at pyramid levels 2 and 3 costs half of level 1's, which is made only
    where they disagree (or led to no sure turn). This pair turned 2° put level 3, surer by its
    peak than level 2, 8 px off; a fit from there once took a minimum 1 px from the turn. Level 1
    leads, and the turn is found as well as any."""
    lit, dark = _pair(112.74456521739131, (2.0, 0.8), 19200)
    steadier = Ranger(_office().rig).steadier
    starts = list(steadier._shifts(steadier._plane(lit), steadier._plane(dark)))
    assert len(starts) == 4 and starts[-1] == (0.0, 0.0)  # (levels 1, 2, 3, then none)
    turn = steadier.turn(lit, dark)
    centre = steadier._mapped(turn.rotation, np.array([[steadier.cam.cx, steadier.cam.cy]]))[0]
    moved = centre - (steadier.cam.cx, steadier.cam.cy)
    assert np.hypot(*(np.array(starts[0]) - moved)) < 2.0  # the half-size picture's, near the turn
    assert np.hypot(*(np.array(starts[1]) - moved)) > 5.0  # level 3's, 8 px off, next
    angles = np.degrees(cv2.Rodrigues(turn.rotation)[0].ravel())
    assert angles[1] == pytest.approx(2.0, abs=0.005) and -angles[0] == pytest.approx(0.8, abs=0.005)
    # Where the smaller two agree, theirs come first (level 1 only if asked for).
    lit, dark = _pair(0.0, (0.5, 0.2), 3)
    shifts = steadier._shifts(steadier._plane(lit), steadier._plane(dark))
    first, second = next(shifts), next(shifts)
    assert np.hypot(first[0] - second[0], first[1] - second[1]) <= 3.0


def _sweep(turned: tuple[float, float], steady: bool) -> tuple[int, list[float]]:
    """How many of PANS' zones are `ok`, and their |error| ÷ range."""
    ranger = Ranger(_office().rig)
    if not steady:
        ranger.steadied = lambda groups: list(groups)  # type: ignore[method-assign]  # (the frames as they come)
    ok, errors = 0, []
    for i, pan in enumerate(PANS):
        lit, dark = _pair(pan, turned, 10 + i)
        names = tuple(_office().rig.laser_names)
        result = ranger.range_zone(i, pan, 0.0, [FrameGroup([lit], [dark], names, (pan, 0.0))])
        truth = _truth(pan)
        if result.status == "ok" and truth is not None:
            ok += 1
            errors.append(abs(result.range_m - truth) / truth)
    return ok, errors


def test_ranging_with_the_room_turned_a_degree_is_as_good_as_with_it_still() -> None:
    """A turn of 1° between the frames (9 px: a walker's head, a robot turning 30°/s) lost a third
    of the zones and put others percents off; turned back, as many zones are `ok` as with still
    frames, and as close."""
    still_ok, still_errors = _sweep((0.0, 0.0), steady=True)
    raw_ok, raw_errors = _sweep((1.0, 0.4), steady=False)
    ok, errors = _sweep((1.0, 0.4), steady=True)
    assert raw_ok < still_ok - 2  # (the harm, without the steadier)
    assert ok >= still_ok - 1
    assert max(errors) < 0.02 and np.mean(errors) < 1.5 * np.mean(still_errors) + 0.001


def test_still_frames_range_exactly_as_without_the_steadier() -> None:
    """The gate costs still frames nothing but its look: the same results to the bit."""
    with_steadier, errors = _sweep((0.0, 0.0), steady=True)
    without, errors_without = _sweep((0.0, 0.0), steady=False)
    assert with_steadier == without and errors == errors_without


def test_a_swaying_platform_is_configured_and_checked() -> None:
    """`sim.sway` turns the simulated rig's view with the rig's time; bad values name their key."""
    config = load_config(None, ["sim.sway.deg=2.0", "sim.sway.hz=0.5"])
    assert config.sim.sway.turn(0.5) == pytest.approx((2.0, 0.5 * 2.0 * np.sin(1.618 * np.pi / 2 + 1.0)))
    renderer = Renderer(scene_for(config), true_rig(config), config.sim, config.camera)
    still = _office().render(0.0, 0.0, {}, 0.5, np.random.default_rng(1), noise=False)
    swayed = renderer.render(0.0, 0.0, {}, 0.5, np.random.default_rng(1), noise=False)
    turned = _office().render(2.0, 0.5 * 2.0 * np.sin(1.618 * np.pi / 2 + 1.0), {}, 0.5,
                              np.random.default_rng(1), noise=False)
    assert np.array_equal(swayed, turned) and not np.array_equal(swayed, still)
    for bad, key in (("sim.sway.deg=-1", "deg"), ("sim.sway.hz=0", "hz")):
        with pytest.raises(ConfigError, match=key):
            load_config(None, [bad])


def test_a_turn_that_does_not_steady_the_room_is_not_taken() -> None:
    """The gate's own look decides, after the fit: a still pair turned by a made-up 1 px turn
    (what a fit to JPEG's blocks of a still dark room once found) is less steady than it was, and
    a turned pair turned back by its fitted turn is steadier."""
    ranger = Ranger(_office().rig)
    steadier = ranger.steadier
    lit, dark = _pair(-84.375, (0.0, 0.0), 4)
    made_up = cv2.Rodrigues(np.radians([0.0, 0.11, 0.0]))[0]  # (1 px at 530 px focal length)
    wrong = steadier.turned_back(dark, Turn(made_up, 1.0, 0.0))
    assert not steadier._steadier(lit, wrong, steadier._score(lit, dark))
    lit, dark = _pair(-84.375, (0.3, 0.1), 4)
    turn = steadier.turn(lit, dark)
    assert turn.shift_px > 2.0 and steadier._steadier(lit, steadier.turned_back(dark, turn), steadier._score(lit, dark))


def test_a_group_whose_turns_are_all_refused_keeps_every_laser_off_frame() -> None:
    """A lamp that brightens a corner of the room between the frames (60 levels at its middle,
    fading over 90 px) fires the gate, and no turn explains it: the group, one laser-on frame and
    two laser-off frames, is read as it came (both off frames, not one per on frame)."""
    steadier = Ranger(_office().rig).steadier
    v, u = np.mgrid[0:480, 0:640]
    glow = 60.0 * np.exp(-((u - 160) ** 2 + (v - 120) ** 2) / (2 * 90.0**2))
    for pan in (-84.375, 0.0, 56.25):
        lit, dark = _pair(pan, (0.0, 0.0), 6)
        _, other = _pair(pan, (0.0, 0.0), 7)
        lamp = np.clip(dark + glow[..., None], 0, 255).astype(np.uint8)
        assert steadier.moved(lit, lamp), pan
        assert steadier.turn(lit, lamp).shift_px == 0.0, pan
        assert steadier.steady([lit], [lamp, other]) is None, pan


def test_a_turn_seen_through_a_wide_lens_is_followed_to_the_corners() -> None:
    """A wide webcam's barrel (k1 = −0.25) moves the picture's corners less than its centre as the
    camera turns, which no homography follows: the turn is fitted through the lens, and where it
    carries a pixel matches, corners and centre, where the room truly went (the renderer's own
    rays), and the frame turned back matches the lit frame's room."""
    config = load_config(None, ["rig.camera.dist=[-0.25, 0.0, 0.0, 0.0, 0.0]", "sim.sway.jolt_deg=1.0"])
    renderer = Renderer(scene_for(config), true_rig(config), config.sim, config.camera)
    ranger = Ranger(renderer.rig)
    cam = renderer.rig.camera
    corners = np.array([[40.0, 40.0], [cam.width - 41.0, 40.0], [40.0, cam.height - 41.0],
                        [cam.width - 41.0, cam.height - 41.0], [cam.cx, cam.cy]])
    for pan, seed in ((-112.5, 1), (0.0, 2)):
        lit = renderer.render(pan, 0.0, {n: 1.0 for n in renderer.rig.laser_names}, 0.0, np.random.default_rng(seed))
        turned = renderer.jolt({}, np.random.default_rng(seed + 10))
        dark = renderer.render(pan, 0.0, {}, 0.0, np.random.default_rng(seed + 10))
        turn = ranger.steadier.turn(lit, dark)
        truth = renderer.turned_pixels(pan, 0.0, turned, corners)
        found = ranger.steadier._mapped(turn.rotation, corners)
        assert np.hypot(*(found - truth).T).max() < 0.1, (pan, found - truth)
        back = ranger.steadier.turned_back(dark, turn)
        rows, left = slice(40, 440), slice(40, 250)  # (the laser paths run down the middle)
        before = np.abs(lit[rows, left, 2].astype(float) - dark[rows, left, 2]).mean()
        after = np.abs(lit[rows, left, 2].astype(float) - back[rows, left, 2]).mean()
        assert after < 0.5 * before, (pan, before, after)


def test_a_lens_that_folds_back_at_the_corners_is_fitted_on_the_pixels_that_have_rays() -> None:
    """A strong barrel's distorted radius peaks and folds back: an 800 × 600 camera at f = 538 px
    with k1 = −0.2 has corners past the peak, where no ray leads (the accuracy family draws such
    lenses). Those pixels are left out of the fit and mapped as by the homography; every sample the
    fit reads has a ray that leads back to it, and a frame turned back holds no wild values."""
    from edge.motion import RAY_TOLERANCE_PX, Steadier
    from edge.rig import CameraModel

    cam = CameraModel(800, 600, 538.0, 538.0, 399.5, 299.5, (-0.2, 0.0, 0.0, 0.0, 0.0))
    steadier = Steadier(cam, [])
    corners = np.array([[0.0, 0.0], [799.0, 599.0]])
    centre = np.array([[399.5, 299.5], [600.0, 300.0]])
    assert not steadier._rays(corners[:, 0], corners[:, 1])[1].any()
    assert steadier._rays(centre[:, 0], centre[:, 1])[1].all()
    assert np.isfinite(steadier._fit_rays).all() and len(steadier._fit_rays) > 6000
    rays, _ = steadier._rays(steadier._fit_u, steadier._fit_v)
    back = cam.project(rays)  # (each read sample's ray leads back to its pixel)
    assert np.abs(back - np.column_stack([steadier._fit_u, steadier._fit_v])).max() < RAY_TOLERANCE_PX
    rotation = cv2.Rodrigues(np.array([0.003, 0.008, 0.0]))[0]
    assert np.allclose(steadier._mapped(rotation, corners), steadier._by_homography(rotation, corners))
    room = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 255, (600, 800), dtype=np.uint8), (0, 0), 2.0)
    assert np.isfinite(steadier.turned_back(room, Turn(rotation, 5.0, 1.0)).astype(float)).all()
