"""Frames scaled after demosaicing (a Pi camera's ISP: 1640 × 1232 to 640 × 480) against frames
demosaiced at their own size: the finder tells them apart by red's noise at the four parities of a
2 × 2 block, and places the scaled frames' spots without demosaicing's σ."""

from __future__ import annotations

import copy
import functools
from dataclasses import replace

import numpy as np
import pytest

from edge import isp
from edge.config import load_config
from edge.doctor.frames import judge
from edge.doctor.rig import KIND_FRAMES
from edge.framenoise import (
    RESAMPLED_CONTRAST,
    SCALED_FIRST_LOOK,
    SCALED_LOOKS,
    ScalingLook,
    parity_contrast,
    resampled,
)
from edge.sim.isp import RAW_SETTINGS, scaled_frame
from edge.sim.record import scene_for, true_rig
from edge.sim.render import Renderer
from edge.vision import AUTO_GROUPS, SpotFinder

# The sensor at 1640 × 1232 (`RAW_SETTINGS`), without speckle: the σ checked is the pixel noise's.
RAW = [*RAW_SETTINGS, "sim.beam.speckle=0"]
WALL = -90.0  # the office wall, 1.3 m away


@functools.cache
def _raw_views() -> Renderer:
    config = load_config(None, RAW)
    return Renderer(scene_for(config), true_rig(config), config.sim)


def _raw_renderer(bayer: str) -> Renderer:
    """The 1640 × 1232 sensor behind a Bayer filter demosaiced by `bayer`: a copy of one renderer
    that shares its views (ray casting 2 million pixels is most of the time), with its own sensor."""
    renderer = copy.copy(_raw_views())
    renderer.sim = replace(renderer.sim, sensor=replace(renderer.sim.sensor, bayer=bayer))
    return renderer


def _groups(renderer: Renderer, pan: float, count: int, seed: int, scale: bool):
    rng = np.random.default_rng(seed)
    lit = {n: 1.0 for n in renderer.rig.laser_names}
    for _ in range(count):
        on, off = (renderer.render(pan, 0.0, lasers, 0.0, rng) for lasers in (lit, {}))
        yield (scaled_frame(on), scaled_frame(off)) if scale else (on, off)


def test_the_isp_maps_the_sensor_s_camera_onto_the_rig_s() -> None:
    """The crop and scale take `picam-v2-1640`'s principal point to `picam-v2`'s, and its focal
    length to `picam-v2`'s: the two models are one camera."""
    assert isp.scaled_pixel(isp.RAW.cx, isp.RAW.cy) == pytest.approx((isp.OUT.cx, isp.OUT.cy))
    assert isp.RAW.fx / isp.SCALE == pytest.approx(isp.OUT.fx) and isp.CROP_ROWS == 1
    frame = np.zeros((isp.RAW.height, isp.RAW.width, 3), np.uint8)
    frame[isp.CROP_ROWS:-isp.CROP_ROWS] = 200  # the cropped rows are not averaged in
    assert scaled_frame(frame).shape == (isp.OUT.height, isp.OUT.width, 3)
    assert int(scaled_frame(frame).min()) == 200


@pytest.mark.parametrize(("centre", "cov"), [((803.3, 611.8), ((2.0, 0.0), (0.0, 2.0))),
                                             ((420.6, 95.1), ((6.0, 1.5), (1.5, 3.0)))])
def test_a_sensor_s_spot_lands_in_the_scaled_frame_where_and_as_wide_as_the_isp_maps_it(centre, cov) -> None:
    """A spot integrated over the sensor's pixels and scaled as the ISP scales it is the spot that
    `scaled_pixel` and `scaled_covariance` describe, integrated over the frame's pixels (what the
    accuracy family's oracle is told): within 5 % of its peak, pixel by pixel (2-3 % measured: a
    Gaussian stands for the sensor pixels' box). Told the sensor's width unscaled, 370 % off; the
    crop left out, 32-44 %; the frame's own pixel counted twice, 7-16 %."""
    from edge.accuracy.floor import spot_profile

    cov_px = np.array(cov)
    sensor = np.zeros((isp.RAW.height, isp.RAW.width), np.float32)
    x0, y0 = int(centre[0]) - 20, int(centre[1]) - 20
    sensor[y0:y0 + 41, x0:x0 + 41] = spot_profile(np.array(centre), cov_px, x0, y0, 41, 41)[0]
    seen = scaled_frame(sensor) * isp.SCALE**2  # (the mean of SCALE² sensor pixels: their sum)
    u, v = isp.scaled_pixel(*centre)
    w0, v0 = int(u) - 8, int(v) - 8
    said = spot_profile(np.array([u, v]), isp.scaled_covariance(cov_px), w0, v0, 17, 17)[0]
    window = seen[v0:v0 + 17, w0:w0 + 17]
    assert float(np.abs(window - said).max()) < 0.05 * float(said.max())
    assert float(window.sum()) == pytest.approx(1.0, abs=0.01)


def test_parity_contrast_pools_looks_and_tells_no_parity_standing_out() -> None:
    assert parity_contrast([(0.25, 0.25, 0.25, 0.25)]) == pytest.approx(1.0)
    # Two looks whose extremes fall on different parities pool to flatter than either alone.
    looks = [(0.3, 0.25, 0.25, 0.2), (0.2, 0.25, 0.25, 0.3)]
    assert parity_contrast(looks[:1]) == pytest.approx(1.5)
    assert parity_contrast(looks) == pytest.approx(1.0)
    assert resampled(looks, [0.01]) and not resampled(looks[:1], [0.01]) and not resampled([], [0.01])
    assert parity_contrast([(0.4, 0.2, 0.2, 0.2)]) > RESAMPLED_CONTRAST
    # Chroma correlated 2 px apart, as JPEG leaves it (either sign), or not measured: not scaled frames.
    assert not resampled(looks, [-0.1]) and not resampled(looks, [0.1, 0.2]) and not resampled(looks, [])


def test_the_look_for_scaled_frames_goes_on_while_its_first_looks_leave_a_parity_standing_out() -> None:
    # Scaled frames whose first looks happen to leave red's noise louder at one parity (tuning-13:
    # 1.16 over 8 looks) are told once more looks have evened it out (1.08 over 32).
    scaled = ScalingLook()
    told = [scaled.look((0.28, 0.24, 0.24, 0.24) if i < SCALED_FIRST_LOOK else (0.25, 0.25, 0.25, 0.25), 0.01)
            for i in range(SCALED_LOOKS)]
    first = told.index(True)
    assert SCALED_FIRST_LOOK <= first < SCALED_LOOKS - 1 and not any(told[:first])
    assert scaled.told and not scaled.looking  # kept once told
    # A filter at the frame's own size leaves one parity louder look after look (VNG, the least
    # so: 1.3): never told, and not looked at past SCALED_LOOKS.
    own = ScalingLook()
    assert not any(own.look((0.3, 0.23, 0.24, 0.23), 0.01) for _ in range(SCALED_LOOKS))
    assert not own.looking and len(own.shares) == SCALED_LOOKS
    # Nor are evenly spread looks told before SCALED_FIRST_LOOK of them, nor with JPEG's chroma.
    early, jpeg = ScalingLook(), ScalingLook()
    assert not any(early.look((0.25, 0.25, 0.25, 0.25), 0.0) for _ in range(SCALED_FIRST_LOOK - 1))
    assert not any(jpeg.look((0.25, 0.25, 0.25, 0.25), -0.1) for _ in range(SCALED_FIRST_LOOK))
    # Chroma that showed JPEG ends the look: noisy looks after it could pull the median inside the
    # line at last (tuning-10, JPEG at quality 90 behind a filter, did at its 12th look).
    assert jpeg.refused and not jpeg.looking


@pytest.mark.parametrize("bayer", ["bilinear", "vng", "ea"])
def test_frames_scaled_after_demosaicing_lose_demosaicings_sigma_and_keep_their_accuracy(bayer: str) -> None:
    renderer = _raw_renderer(bayer)
    rig = true_rig(load_config())  # the 640 × 480 camera the frames come out of
    finder = SpotFinder(rig)
    before = []
    for i, (on, off) in enumerate(_groups(renderer, WALL, AUTO_GROUPS, seed=1, scale=True)):
        spots = finder.find([on], [off])
        before += [c[0].sigma_px for c in spots.values() if c]
        assert finder.frame_kind(on, off).demosaiced == (i < AUTO_GROUPS - 1)  # told by the last of them
    assert min(before[:-3]) > 0.3  # demosaicing's σ until then
    z, errors = [], []
    for pan in (WALL - 6.0, WALL + 2.5, WALL + 7.0):
        truth = renderer.spots(pan, 0.0)
        for on, off in _groups(renderer, pan, 2, seed=2, scale=True):
            for name, cands in finder.find([on], [off]).items():
                pixel = isp.scaled_pixel(*truth[name].pixel)
                error = float(np.hypot(*(cands[0].pixel - pixel)))
                errors.append(error)
                z.append(error / cands[0].sigma_px)
    assert len(errors) == 18
    # Placed as claimed (the σ of the pixel noise alone: speckle is off), and nearly as well as the
    # 1640 × 1232 frames' demosaicing, averaged over 2.6 × 2.6 of their pixels, allows.
    assert np.sqrt(np.mean(np.square(z))) < 1.5
    assert np.sqrt(np.mean(np.square(errors))) < 0.08


@pytest.mark.parametrize("bayer", ["bilinear", "vng", "ea"])
def test_frames_demosaiced_at_their_own_size_keep_their_filter(bayer: str) -> None:
    config = load_config(None, [f"sim.sensor.bayer={bayer}", "sim.beam.speckle=0"])
    renderer = Renderer(scene_for(config), true_rig(config), config.sim)
    finder = SpotFinder(renderer.rig)
    shares = []
    for on, off in _groups(renderer, WALL, AUTO_GROUPS + 2, seed=3, scale=False):
        finder.find([on], [off])
        kind = finder.frame_kind(on, off)
        assert kind.demosaiced
        shares.append(kind.parity)
    assert parity_contrast(shares[:AUTO_GROUPS]) > RESAMPLED_CONTRAST * 1.05


@pytest.mark.parametrize("channel", ["auto", "red"])
def test_the_doctor_names_frames_scaled_after_demosaicing(channel: str) -> None:
    """Whatever channel ranging is set to read (red: `auto` measures no chroma), as the finder tells."""
    renderer = _raw_renderer("ea")
    rng = np.random.default_rng(4)
    frames = [scaled_frame(renderer.render(WALL, 0.0, {}, 0.0, rng)) for _ in range(KIND_FRAMES)]  # (as the doctor)
    config = load_config(None, [f"ranging.channel={channel}"])
    line = judge(frames, config.rig.build(), config)
    assert "scaled after demosaicing" in line and "640x480 colour" in line, line
    own = load_config(None, ["sim.sensor.bayer=ea"])
    at_size = Renderer(scene_for(own), true_rig(own), own.sim)
    frames = [at_size.render(WALL, 0.0, {}, 0.0, rng) for _ in range(KIND_FRAMES)]
    assert "demosaiced from a Bayer filter, red at even rows and columns" in judge(frames, config.rig.build(), config)

