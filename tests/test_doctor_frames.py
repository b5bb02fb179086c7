"""`edge doctor`'s frames line: what kind of frames the camera delivers and what ranging makes of
them, on the simulated camera's kinds of frames (lossless through a Bayer filter, JPEG, plain,
grey); frames delivered twice and frames the camera smoothed fail, with a remedy for the backend;
and asking the finder changes nothing that ranging then finds."""

from __future__ import annotations

import contextlib
from dataclasses import replace

import cv2
import numpy as np
import pytest

from edge.config import load_config
from edge.doctor.checklist import Problem
from edge.doctor.frames import SMOOTHED_AREA, judge
from edge.doctor.rig import RigChecks
from edge.doctor.settings import from_config
from edge.ranging import Ranger
from edge.sim.record import scene_for, true_rig
from edge.sim.render import Renderer


def _frames_line(*overrides: str) -> str:
    """The frames line of the simulated rig (the camera's line first, as the doctor runs them)."""
    config = load_config(None, list(overrides))
    with contextlib.ExitStack() as stack:
        checks = RigChecks(config, from_config(config), stack)
        checks.camera_check()
        return checks.frames_check()


def test_a_bayer_filter_behind_lossless_frames_is_named_with_its_red_pixels():
    # The renderer's filter is RGGB: red at even rows and even columns. (Bilinear demosaicing
    # reads the same; VNG's pattern shows in fewer pairs, and the line says in how many.)
    line = _frames_line('sim.sensor.bayer="ea"')
    assert line.startswith("640x480 colour, not JPEG")
    assert "demosaiced from a Bayer filter, red at even rows and columns: spots are placed by their red pixels" in line
    assert "ranging reads red (auto: the chroma at full resolution" in line


def test_a_yuyv_stream_is_named_and_its_red_never_taken_for_a_bayer_filters():
    """A webcam's YUYV stream over a Bayer sensor: each two pixels of a row share their chroma, so no
    pixel keeps its own red, and the line says spots are placed by the interpolated red, where the
    same sensor's frames uncompressed are placed by their red pixels."""
    line = _frames_line('sim.sensor.bayer="ea"', "sim.sensor.yuyv=true")
    assert line.startswith("640x480 colour, not JPEG")
    assert "each two pixels of a row share one chroma (a YUYV stream, YUV 4:2:2)" in line
    assert "placed by their red pixels" not in line and "chroma at full resolution" not in line
    assert "share one chroma" not in _frames_line('sim.sensor.bayer="ea"')


def test_jpeg_frames_are_named_and_read_by_their_luma():
    line = _frames_line("sim.sensor.jpeg_quality=60")
    assert line.startswith("640x480 colour, JPEG (blockiness ")
    assert "ranging reads luma (auto: the chroma at half resolution" in line
    # (JPEG keeps too little of the noise to show a filter: luma's red is taken as demosaiced.)
    assert "taken as behind a Bayer filter, as colour webcams are: each spot carries its 0.25 px" in line


def test_a_webcams_jpeg_frames_are_met_with_what_to_ask_it_for_instead():
    """A webcam whose frames are JPEG is told to ask for YUYV, with what JPEG costs; the Pi camera's
    frames (or the simulator's) are never JPEG for a setting to mend, and are not told."""
    from edge.doctor.frames import WEBCAM_JPEG

    config = load_config(None, ["sim.sensor.jpeg_quality=60"])
    renderer = Renderer(scene_for(config), true_rig(config), config.sim)
    rng = np.random.default_rng(5)
    frames = [renderer.render(-90.0, 0.0, {}, 0.0, rng) for _ in range(3)]
    webcam = replace(config, camera=replace(config.camera, backend="opencv"))
    assert 'camera.pixel_format = "YUYV"' in WEBCAM_JPEG and "77 %" in WEBCAM_JPEG
    assert WEBCAM_JPEG in judge(frames, config.rig.build(), webcam)
    assert WEBCAM_JPEG not in judge(frames, config.rig.build(), config)
    with contextlib.ExitStack() as stack:  # (the camera's line names the stream, as a webcam's does)
        checks = RigChecks(config, from_config(config), stack)
        assert checks.camera_check().startswith("sim 640x480 MJPG: ")
    lossless = load_config(None, ["sim.sensor.yuyv=true"])
    plain = Renderer(scene_for(lossless), true_rig(lossless), lossless.sim)
    frames = [plain.render(-90.0, 0.0, {}, 0.0, rng) for _ in range(3)]
    line = judge(frames, lossless.rig.build(), replace(lossless, camera=replace(lossless.camera, backend="opencv")))
    assert line.startswith("640x480 colour, not JPEG") and WEBCAM_JPEG not in line


def test_frames_through_a_tone_curve_are_read_as_ranging_reads_them():
    """With `ranging.frame_gamma`, ranging tells JPEG by the frame as delivered and reads the
    frames made linear: the line says what those are."""
    line = _frames_line("sim.sensor.gamma=2.2", "ranging.frame_gamma=2.2", "sim.sensor.jpeg_quality=80")
    assert line.startswith("640x480 colour, JPEG (blockiness ")
    assert "levels of 65535 in linear light" in line


@pytest.mark.parametrize("colour", [True, False])
def test_plain_frames_are_neither_jpeg_nor_demosaiced(colour):
    line = _frames_line(f"sim.sensor.colour={str(colour).lower()}")
    assert line.startswith(f"640x480 {'colour' if colour else 'grey'}, not JPEG")
    assert "Bayer" not in line and "demosaiced," not in line
    assert ("no demosaicing seen" in line) == colour
    assert "reads grey" in line or colour
    area = float(line.split("spread over ")[1].split(" px²")[0])
    assert 1.0 <= area < SMOOTHED_AREA
    assert 0.5 < float(line.split("difference noise ")[1].split()[0]) < 3.0  # levels of 255


@pytest.fixture(scope="module")
def grey():
    """The office straight ahead, every laser off, from the simulated grey camera: four frames
    one after another, and the configuration."""
    config = load_config(None, ["sim.sensor.colour=false"])
    renderer = Renderer(scene_for(config), true_rig(config), config.sim, config.camera)
    rng = np.random.default_rng(3)
    return [renderer.render(0.0, 0.0, {}, i / 30.0, rng) for i in range(4)], config


@pytest.mark.parametrize("backend, words", [("picamera2", "NoiseReductionMode off and Sharpness 0"),
                                            ("opencv", "v4l2-ctl -d /dev/video0 -c sharpness=0")])
def test_frames_the_camera_smoothed_fail_with_what_turns_that_off(grey, backend, words):
    """A Gaussian blur of σ 0.7 px stands in for an ISP's denoising: the noise of grey frames,
    which neither JPEG nor a colour filter spreads, is then spread over several pixels."""
    frames, config = grey
    config = replace(config, camera=replace(config.camera, backend=backend))
    rig = config.rig.build()
    assert "spread over" in judge(frames, rig, config)  # as delivered: ok
    blurred = [cv2.GaussianBlur(f, (0, 0), 0.7) for f in frames]
    with pytest.raises(Problem, match="the camera smooths them") as smoothed:
        judge(blurred, rig, config)
    assert words in smoothed.value.remedy


@pytest.mark.parametrize("backend, words", [("picamera2", "fresh frame"), ("opencv", "buffer")])
def test_frames_delivered_twice_fail(grey, backend, words):
    frames, config = grey
    config = replace(config, camera=replace(config.camera, backend=backend))
    rig = config.rig.build()
    with pytest.raises(Problem, match="1 of 3 pairs of consecutive laser-off frames are the same frame") as twice:
        judge([frames[0], frames[1], frames[1], frames[2]], rig, config)
    assert words in twice.value.remedy and "lens" not in twice.value.remedy
    black = np.zeros_like(frames[0])
    with pytest.raises(Problem, match="blank") as blank:
        judge([black] * 4, rig, config)
    assert blank.value.remedy.startswith("take the cap off the lens")


def test_asking_the_finder_what_the_frames_are_changes_nothing_it_finds():
    """frame_kind takes `find`'s steps without its decisions (JPEG, `auto`'s channel): a finder
    asked first finds the same spots, to the last digit, as one that was not."""
    config = load_config(None, ["sim.sensor.jpeg_quality=60"])
    rig = config.rig.build()
    renderer = Renderer(scene_for(config), true_rig(config), config.sim, config.camera)
    rng = np.random.default_rng(5)
    lit = {name: 1.0 for name in rig.laser_names}
    groups = [([renderer.render(-90.0, 0.0, lit, i, rng)], [renderer.render(-90.0, 0.0, {}, i, rng)]) for i in range(3)]
    asked, fresh = Ranger(rig, config.ranging).finder, Ranger(rig, config.ranging).finder
    kind = asked.frame_kind(groups[0][1][0], groups[1][1][0])
    assert kind.jpeg and kind.channel == "luma" and kind.chroma_lag2 is not None
    assert asked.channel == "red"  # (`auto` starts at red and decides in `find` alone)
    for on, off in groups:
        ours, theirs = asked.find(on, off), fresh.find(on, off)
        assert ours.keys() == theirs.keys()
        for name in ours:
            assert [c.pixel.tolist() for c in ours[name]] == [c.pixel.tolist() for c in theirs[name]]
            assert [(c.sigma_px, c.snr, c.size_px) for c in ours[name]] == [(c.sigma_px, c.snr, c.size_px)
                                                                          for c in theirs[name]]
        assert any(ours.values())
    assert asked.channel == fresh.channel == "luma"


@pytest.mark.parametrize(("adc_bits", "says"), [(8, "values 257 apart: the sensor's 8 bits"),
                                                (10, "values 64 apart: the sensor's 10 bits"),
                                                (16, "(16-bit)")])
def test_16_bit_frames_say_how_far_apart_their_values_are(adc_bits, says):
    """A sensor's 8 or 10 bits carried in 16-bit frames are that far apart, and ranging's noise is
    no finer than that: the line says so; a 16-bit sensor's values are 1 apart."""
    line = _frames_line("sim.sensor.output_bits=16", f"sim.sensor.adc_bits={adc_bits}", "sim.sensor.colour=false")
    assert line.startswith("640x480 grey (16-bit")
    assert says in line
