"""The live simulator through the Pi camera's ISP (`sim.sensor.isp`): the rig's 640 × 480 camera
rendered as its 1640 × 1232 sensor and scaled, so that `edge run`, `edge demo` and `edge doctor` on
the simulator meet the frames the product's own camera hands over."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from edge import isp
from edge.config import load_config
from edge.doctor.frames import judge
from edge.doctor.rig import KIND_FRAMES
from edge.errors import ConfigError
from edge.sim.isp import sensor_parts
from edge.sim.record import scene_for, true_rig
from edge.sim.render import Renderer
from edge.vision import SpotFinder

LIVE = ["sim.sensor.isp=true", 'sim.sensor.bayer="ea"']
WALL = -90.0  # the office wall, 1.3 m away


@functools.cache
def _live() -> Renderer:
    config = load_config(None, LIVE)
    return Renderer(scene_for(config), true_rig(config), config.sim, config.camera)


def test_the_live_isp_hands_over_640x480_frames_whose_spots_lie_where_the_isp_maps_the_sensor_s() -> None:
    """The truth is the sensor's spot, scaled (`edge.isp.scaled_pixel`), and the finder places
    each laser's spot on it to a fifth of a pixel; the doctor, from as many laser-off frames as it
    reads, names them scaled after demosaicing, as it should on a Pi."""
    renderer = _live()
    sensor = renderer._sensor
    assert sensor is not None and (sensor.rig.camera.width, sensor.rig.camera.height) == (1640, 1232)
    rng = np.random.default_rng(2)
    lit = {n: 1.0 for n in renderer.rig.laser_names}
    on, off = renderer.render(WALL, 0.0, lit, 0.0, rng), renderer.render(WALL, 0.0, {}, 0.0, rng)
    assert on.shape == (480, 640, 3) and on.dtype == np.uint8
    truth = renderer.spots(WALL, 0.0)
    raw = sensor.spots(WALL, 0.0)
    found = SpotFinder(renderer.rig).find([on], [off])
    for name, spot in truth.items():
        assert spot.visible and spot.pixel is not None
        assert spot.pixel == pytest.approx(isp.scaled_pixel(*raw[name].pixel), abs=1e-9)
        assert found[name], name
        assert np.hypot(*(found[name][0].pixel - spot.pixel)) < 0.2, (name, found[name][0].pixel, spot.pixel)
    frames = [renderer.render(WALL, 0.0, {}, 0.0, rng) for _ in range(KIND_FRAMES)]
    config = load_config(None, LIVE)
    line = judge(frames, config.rig.build(), config)
    assert "scaled after demosaicing" in line, line


def test_a_laser_switched_mid_frame_lights_the_rows_of_the_scaled_frame_it_lit_on_the_sensor() -> None:
    """The rolling shutter's light per frame row (what `SimCamera` works out) reaches the sensor's
    rows that the ISP scales into each frame row: lit from row 300 on, the sloped laser's spot
    (row 333) is there in full and the parallel's (row 223) not at all."""
    renderer = _live()
    rows = np.zeros(480)
    rows[300:] = 1.0
    noiseless = functools.partial(renderer.render, WALL, 0.0, t_s=0.0, rng=np.random.default_rng(0), noise=False)
    dark = noiseless({}).astype(np.float64)[..., 2]
    lit = noiseless({"sloped": 1.0, "parallel": 1.0}).astype(np.float64)[..., 2] - dark
    half = noiseless({"sloped": rows, "parallel": rows}).astype(np.float64)[..., 2] - dark
    truth = renderer.spots(WALL, 0.0)

    def light(image: np.ndarray, name: str) -> float:
        u, v = (int(round(c)) for c in truth[name].pixel)
        return float(image[v - 6 : v + 7, u - 6 : u + 7].sum())

    assert light(lit, "sloped") > 100 and light(lit, "parallel") > 100
    assert light(half, "sloped") == pytest.approx(light(lit, "sloped"), rel=0.02)
    assert abs(light(half, "parallel")) < 0.02 * light(lit, "parallel")


def test_each_frame_row_takes_the_sensor_rows_whose_centres_it_holds() -> None:
    _, _, rows = sensor_parts(load_config(None).rig.build(), load_config(None).sim)
    assert rows.shape == (1232,) and np.all(np.diff(rows) >= 0) and rows[0] == 0 and rows[-1] == 479
    for v in range(480):
        centre = isp.sensor_pixel(0.0, float(v))[1]
        assert rows[int(round(centre))] == v


def test_the_sensor_sees_the_room_as_the_640x480_camera_does_per_area() -> None:
    """Each sensor pixel gets 1/2.5625² of the light and the well, and the blur and speckle grain
    are 2.5625 × wider in its pixels; the rest of the simulator is the configuration's."""
    config = load_config(None, LIVE)
    rig, sim, _ = sensor_parts(config.rig.build(), config.sim)
    s2 = isp.SCALE**2
    assert rig.camera == isp.sensor_camera(config.rig.build().camera)
    assert sim.ambient.white_e_per_ms == pytest.approx(config.sim.ambient.white_e_per_ms / s2)
    assert sim.sensor.full_well_e == pytest.approx(config.sim.sensor.full_well_e / s2)
    assert sim.optics.psf_sigma_px == pytest.approx(config.sim.optics.psf_sigma_px * isp.SCALE)
    assert sim.beam.speckle_grain == pytest.approx(config.sim.beam.speckle_grain * isp.SCALE)
    assert not sim.sensor.isp and sim.sensor.bayer == "ea" and sim.beam.e_per_ms_at_1m == config.sim.beam.e_per_ms_at_1m


@pytest.mark.parametrize("sets, says", [
    (['rig.camera.model="picam-v2-1640"'], "sim.sensor.isp: the Pi camera's ISP hands over 640x480 frames"),
    (["sim.sensor.jpeg_quality=80"], "sim.sensor.isp: the Pi camera's ISP hands over uncompressed frames"),
    (["sim.sensor.yuyv=true"], "sim.sensor.isp: the Pi camera's ISP hands over uncompressed frames"),
    (["sim.sensor.colour=false"], "sim.sensor.isp: the Pi camera's sensor is a colour one"),
])
def test_the_live_isp_refuses_what_the_pi_camera_never_hands_over(sets: list[str], says: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_config(None, ["sim.sensor.isp=true", *sets])
    assert says in str(err.value) and "\n" not in str(err.value)


def test_the_sensor_s_own_numbers_are_refused_through_the_isp() -> None:
    """What the accuracy family's truth reads is the sensor's: asked of the ISP's renderer, a
    one-line error rather than numbers of the wrong camera."""
    with pytest.raises(ConfigError, match="sim.sensor.isp: the simulator gives a spot's model of the sensor only"):
        _live().spot_model(WALL, 0.0, "center")
