"""Cameras: the simulated one keeps a real frame clock; the Pi camera's timestamps are read right
and its settings fixed; missing hardware is one clear error, never a hang."""

from __future__ import annotations

import sys
import time
import types

import numpy as np
import pytest

from edge.config import load_config
from edge.errors import CameraError, HardwareError
from edge.hw.camera import PICAMERA2_MISSING, CameraSettings, OpenCVCamera, Picamera2Camera
from edge.parts import open_camera, open_lasers
from edge.sim.camera import SimCamera
from edge.sim.gpio import laser_factory
from edge.sim.light import LaserLight
from edge.sim.record import flat_target_scene, true_rig
from edge.sim.render import Renderer

# --- the simulated camera -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def sim_camera():
    config = load_config(None, ["rig.camera.model=\"webcam-cif\""])  # small frames: quick renders
    renderer = Renderer(flat_target_scene(1.5), true_rig(config), config.sim, config.camera)
    wiring = LaserLight(config.rig.wiring(), laser_factory())
    # A queue long enough that a slow render (a busy CI machine) never loses a frame here.
    camera = SimCamera(renderer, wiring, config.camera, queue_frames=10**6)
    camera.start()
    yield camera
    camera.stop()


def test_sim_frames_follow_the_frame_clock(sim_camera):
    cam = sim_camera
    period = cam.frame_ns
    t = time.monotonic_ns()
    f1 = cam.frame_after(t)
    assert f1.t_start_ns >= t and f1.t_start_ns - t <= period
    assert time.monotonic_ns() >= f1.t_end_ns  # delivered only once read out
    assert f1.exposure_us == 10000.0 and f1.readout_ns == round(0.7 * period)
    assert f1.image.shape == (288, 352, 3)
    f2 = cam.frame_after(f1.t_start_ns + 1)
    assert f2.t_start_ns - f1.t_start_ns == period and f2.sequence == f1.sequence + 1
    f3 = cam.frame_after(f2.t_start_ns + period + period // 2)
    assert f3.t_start_ns - f2.t_start_ns == 2 * period and f3.sequence == f2.sequence + 2


def test_sim_frame_after_takes_a_frame_starting_exactly_then(sim_camera):
    cam = sim_camera
    f1 = cam.frame_after(time.monotonic_ns())
    f2 = cam.frame_after(f1.t_start_ns + 3 * cam.frame_ns)
    assert f2.t_start_ns == f1.t_start_ns + 3 * cam.frame_ns
    # Never the same frame twice, even when asked for an earlier time.
    f3 = cam.frame_after(f1.t_start_ns)
    assert f3.sequence > f2.sequence


def test_sim_camera_drops_frames_nobody_collected():
    config = load_config(None, ["rig.camera.model=\"webcam-cif\""])
    renderer = Renderer(flat_target_scene(1.5), true_rig(config), config.sim, config.camera)
    camera = SimCamera(renderer, LaserLight((), laser_factory()), config.camera, queue_frames=2)
    camera.start()
    t = time.monotonic_ns()
    time.sleep(8 * camera.frame_ns / 1e9)
    frame = camera.frame_after(t)  # long gone: the oldest frame still queued instead
    assert frame.t_start_ns >= t + 3 * camera.frame_ns


def test_sim_camera_times_out(sim_camera):
    start = time.monotonic()
    with pytest.raises(HardwareError, match="no frame"):
        sim_camera.frame_after(time.monotonic_ns() + 10**10, timeout_s=0.05)
    assert time.monotonic() - start < 1.0


def test_sim_camera_must_be_started():
    config = load_config(None, ["rig.camera.model=\"webcam-cif\""])
    renderer = Renderer(flat_target_scene(1.5), true_rig(config), config.sim, config.camera)
    camera = SimCamera(renderer, LaserLight((), laser_factory()), config.camera)
    with pytest.raises(HardwareError, match="not started"):
        camera.frame_after(0)


# --- the Pi camera, with picamera2 standing in --------------------------------------------------


def test_picamera2_missing_is_one_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "picamera2", None)  # import fails as if not installed
    with pytest.raises(HardwareError) as info:
        Picamera2Camera(CameraSettings(), (640, 480))
    assert str(info.value) == PICAMERA2_MISSING and "\n" not in str(info.value)


class _FakeRequest:
    def __init__(self, image: np.ndarray, metadata: dict) -> None:
        self.image, self.metadata, self.released = image, metadata, False

    def make_array(self, name: str) -> np.ndarray:
        assert name == "main"
        return self.image

    def get_metadata(self) -> dict:
        return self.metadata

    def release(self) -> None:
        self.released = True


class _FakePicamera2:
    """Just what Picamera2Camera uses. Its queue holds requests; flush is recorded, not applied,
    so that the camera's own check of the start time is exercised too."""

    last: _FakePicamera2 | None = None

    # The stages edge changes, as libcamera's own IMX219 file has them (src/ipa/rpi/vc4/data/imx219.json;
    # its tone curve shortened; the Pi 5's file has the same colour matrices and "rpi.dpc": {"strength": 1}).
    tuning_files = {"imx219.json": {"version": 2.0, "algorithms": [
        {"rpi.black_level": {"black_level": 4096}},
        {"rpi.dpc": {}},
        {"rpi.contrast": {"ce_enable": 1, "gamma_curve": [0, 0, 1024, 5040, 65535, 65535]}},
        {"rpi.ccm": {"ccms": [
            {"ct": 2860, "ccm": [
                2.12089, -0.52461, -0.59629, -0.85342, 2.80445, -0.95103, -0.26897, -1.14788, 2.41685]},
            {"ct": 2960, "ccm": [
                2.26962, -0.54174, -0.72789, -0.77008, 2.60271, -0.83262, -0.26036, -1.51254, 2.77289]},
            {"ct": 3603, "ccm": [
                2.18644, -0.66148, -0.52496, -0.77828, 2.69474, -0.91645, -0.25239, -0.83059, 2.08298]},
            {"ct": 4650, "ccm": [
                2.18174, -0.70887, -0.47287, -0.70196, 2.76426, -1.06231, -0.25157, -0.71978, 1.97135]},
            {"ct": 5858, "ccm": [
                2.32392, -0.88421, -0.43971, -0.63821, 2.58348, -0.94527, -0.28541, -0.54112, 1.82653]},
            {"ct": 7580, "ccm": [
                2.21175, -0.53242, -0.67933, -0.57875, 3.07922, -1.50047, -0.27709, -0.73338, 2.01048]},
        ]}},
        {"rpi.sharpen": {"threshold": 0.75, "limit": 0.5, "strength": 1.0}},
    ]}}

    def __init__(self, camera_num: int = 0, tuning: dict | None = None) -> None:
        _FakePicamera2.last = self
        self.tuning = tuning
        self.camera_controls = {"FrameDurationLimits": (23_000, 1_000_000, 33_333)}
        self.queue: list[_FakeRequest] = []
        self.flushes: list[int] = []

    sensor = "imx219"  # libcamera's name of the sensor
    mode: tuple[int, int] | None = None  # the raw mode libcamera picks (None: the one asked for)

    @classmethod
    def global_camera_info(cls) -> list[dict]:
        return [{"Model": cls.sensor, "Num": 0}]

    @classmethod
    def load_tuning_file(cls, name: str) -> dict:
        import copy

        if name not in cls.tuning_files:
            raise RuntimeError(f"Tuning file {name} not found")
        return copy.deepcopy(cls.tuning_files[name])

    @staticmethod
    def find_tuning_algo(tuning: dict, name: str) -> dict:
        return next(algo for algo in tuning["algorithms"] if name in algo)[name]

    def create_video_configuration(self, main, controls, raw=None):
        return {"main": main, "controls": dict(controls), "raw": raw}

    def configure(self, config) -> None:
        self.config = config

    def camera_configuration(self) -> dict:
        asked = (self.config.get("raw") or {}).get("size", (1640, 1232))
        return {**self.config, "raw": {"size": self.mode or asked, "format": "SBGGR10_CSI2P"}}

    def start(self) -> None:
        self.started = True

    def stop(self) -> None:
        self.started = False

    def close(self) -> None:
        pass

    def capture_request(self, wait=None, flush=None):
        self.flushes.append(flush)
        if not self.queue:
            raise TimeoutError
        return self.queue.pop(0)


def _request(sensor_ts: int, exposure_us: int = 10_000) -> _FakeRequest:
    image = np.zeros((480, 640, 3), np.uint8)
    image[..., 0] = 200  # byte 0 of RGB888 is blue
    md = {"SensorTimestamp": sensor_ts, "ExposureTime": exposure_us, "FrameDuration": 33_333}
    return _FakeRequest(image, md)


@pytest.fixture
def fake_picamera2(monkeypatch):
    module = types.ModuleType("picamera2")
    module.Picamera2 = _FakePicamera2
    monkeypatch.setitem(sys.modules, "picamera2", module)
    monkeypatch.setitem(sys.modules, "libcamera", None)  # the enum's plain value is used
    return _FakePicamera2


def test_picamera2_fixed_settings(fake_picamera2):
    overrides = ["camera.backend=\"picamera2\"", "camera.exposure_us=8000.0", "camera.analogue_gain=2.0"]
    config = load_config(None, overrides)
    cam = open_camera(config)
    fake = fake_picamera2.last
    controls = fake.config["controls"]
    assert controls["AeEnable"] is False and controls["AwbEnable"] is False
    assert controls["ExposureTime"] == 8000 and controls["AnalogueGain"] == 2.0
    assert controls["FrameDurationLimits"] == (33_333, 33_333)
    assert controls["NoiseReductionMode"] == 0  # Off: no temporal denoise mixing frames
    assert controls["Sharpness"] == 0.0  # no unsharp mask ringing round a spot
    assert fake.config["main"] == {"size": (640, 480), "format": "RGB888"}
    assert fake.config["raw"] == {"size": (1640, 1232)}  # the binned full field of view
    assert isinstance(cam, Picamera2Camera)


def test_picamera2_refuses_a_sensor_or_mode_other_than_the_camera_model_describes(fake_picamera2, monkeypatch):
    """`picam-v2` is a Camera Module 2 (IMX219) read at 1640 × 1232 over its whole field: a Camera
    Module 3 in its place, or another sensor mode, would put every spot at other pixels than the
    model says, and every range off (one line naming both, and the way out). A camera model whose
    numbers the user set (their own camera's, measured) is theirs to answer for."""
    config = load_config(None, ['camera.backend="picamera2"'])
    monkeypatch.setattr(fake_picamera2, "sensor", "imx708")
    with pytest.raises(CameraError) as err:
        open_camera(config)
    message = str(err.value)
    assert "imx708" in message and "imx219" in message and "rig.camera.model" in message and "\n" not in message
    own = load_config(None, ['camera.backend="picamera2"', "rig.camera.fx=508.0", "rig.camera.fy=508.0"])
    assert isinstance(open_camera(own), Picamera2Camera)
    monkeypatch.setattr(fake_picamera2, "sensor", "imx219")
    monkeypatch.setattr(fake_picamera2, "mode", (640, 480))  # the IMX219's cropped 640 × 480 mode
    with pytest.raises(CameraError, match="reads its sensor at 640x480, not at 1640x1232"):
        open_camera(config)
    monkeypatch.setattr(fake_picamera2, "mode", None)
    assert isinstance(open_camera(config), Picamera2Camera)


def test_picamera2_holds_a_focus_motors_lens_where_it_is_told(fake_picamera2, monkeypatch):
    """A Camera Module 3 autofocuses by default in most programs: its lens, and the focal length
    with it, would move between zones. edge holds it (manual focus) at camera.lens_dioptres, and
    refuses a position the lens cannot reach; a camera without a focus motor is left alone."""
    plain = Picamera2Camera(CameraSettings(), (640, 480))
    assert plain.lens_dioptres is None
    assert "AfMode" not in fake_picamera2.last.config["controls"]
    monkeypatch.setattr(fake_picamera2, "focus", {"AfMode": (0, 2, 0), "LensPosition": (0.0, 15.0, 1.0)},
                        raising=False)
    original = fake_picamera2.__init__

    def with_motor(self, *args, **kwargs):
        original(self, *args, **kwargs)
        self.camera_controls |= type(self).focus

    monkeypatch.setattr(fake_picamera2, "__init__", with_motor)
    cam = Picamera2Camera(CameraSettings(lens_dioptres=2.5), (640, 480))
    controls = fake_picamera2.last.config["controls"]
    assert cam.lens_dioptres == 2.5
    assert controls["AfMode"] == 0 and controls["LensPosition"] == 2.5  # 0: libcamera's Manual
    with pytest.raises(HardwareError, match=r"camera.lens_dioptres: 20 is beyond this lens's 0-15 dioptres"):
        Picamera2Camera(CameraSettings(lens_dioptres=20.0), (640, 480))


def test_picamera2_frames_keep_their_colours_apart_and_their_pixels_as_measured(fake_picamera2):
    """The ISP's colour matrix would make ranging's red 2.18 R − 0.71 G − 0.47 B, and its defective-pixel
    correction pulls a small spot's peak red pixel back to its neighbours: both off, by the tuning file."""
    from edge.hw.camera import IDENTITY_CCM

    Picamera2Camera(CameraSettings(), (640, 480))
    tuning = fake_picamera2.last.tuning
    find = fake_picamera2.find_tuning_algo
    ccm = find(tuning, "rpi.ccm")
    assert [entry["ccm"] for entry in ccm["ccms"]] == [list(IDENTITY_CCM)] and "saturation" not in ccm
    assert find(tuning, "rpi.dpc") == {"strength": 0}
    assert find(tuning, "rpi.sharpen") == {"threshold": 0.75, "limit": 0.5, "strength": 1.0}  # the rest kept
    # The sensor's own file is not changed: the next camera opened reads it as it was.
    assert len(find(fake_picamera2.tuning_files["imx219.json"], "rpi.ccm")["ccms"]) == 6


def test_picamera2_opens_with_a_tuning_file_that_has_no_colour_stages(fake_picamera2, monkeypatch):
    """A mono sensor's file has no colour matrix, an old one may have no DPC: nothing to turn off."""
    grey = {"version": 2.0, "algorithms": [{"rpi.black_level": {"black_level": 4096}},
                                           {"rpi.contrast": {"ce_enable": 1, "gamma_curve": [0, 0, 65535, 65535]}}]}
    monkeypatch.setattr(fake_picamera2, "tuning_files", {"imx219.json": grey})
    cam = Picamera2Camera(CameraSettings(), (640, 480))
    assert cam.closed is False
    assert [next(iter(stage)) for stage in fake_picamera2.last.tuning["algorithms"]] == ["rpi.black_level",
                                                                                        "rpi.contrast"]


def test_picamera2_frames_come_through_the_configured_tone_curve(fake_picamera2, monkeypatch, caplog):
    from edge.hw.camera import curve_points
    from edge.tone import tone_curve

    Picamera2Camera(CameraSettings(), (640, 480))  # gamma 1: linear
    tuning = fake_picamera2.last.tuning
    contrast = fake_picamera2.find_tuning_algo(tuning, "rpi.contrast")
    assert contrast["gamma_curve"] == [0, 0, 65535, 65535] and contrast["ce_enable"] == 0
    assert fake_picamera2.find_tuning_algo(tuning, "rpi.black_level") == {"black_level": 4096}  # the rest kept
    Picamera2Camera(CameraSettings(gamma=2.2), (640, 480))
    curve = fake_picamera2.find_tuning_algo(fake_picamera2.last.tuning, "rpi.contrast")["gamma_curve"]
    assert curve == curve_points(2.2)
    xs, ys = np.array(curve[0::2]), np.array(curve[1::2])
    assert xs[0] == ys[0] == 0 and xs[-1] == ys[-1] == 65535 and np.all(np.diff(xs) > 0)
    assert np.all(np.diff(ys) >= 0)
    # What ranging undoes (edge.tone) is what the ISP applies, between the points too (it
    # interpolates them linearly): within a level of an 8-bit frame.
    x = np.linspace(0.0, 1.0, 4001)
    isp = np.interp(x * 65535, xs, ys) / 65535
    assert np.abs(isp - tone_curve(x.astype(np.float32), 2.2)).max() < 1.0 / 255
    # A sensor without a tuning file still opens, with its ISP's curve, and says so.
    monkeypatch.setattr(fake_picamera2, "tuning_files", {})
    with caplog.at_level("WARNING"):
        cam = Picamera2Camera(CameraSettings(gamma=2.2), (640, 480))
    assert fake_picamera2.last.tuning is None and cam.closed is False
    assert "imx219 tuning file" in caplog.text and "gamma curve" in caplog.text


def test_picamera2_timestamps_and_frame_choice(fake_picamera2):
    cam = Picamera2Camera(CameraSettings(), (640, 480))
    fake = fake_picamera2.last
    t = 5_000_000_000
    early, good = _request(t + 5_000_000), _request(t + 12_000_000)  # exposure 10 ms
    fake.queue += [early, good]
    frame = cam.frame_after(t, timeout_s=0.5)
    # SensorTimestamp is the first row's readout: the exposure began ExposureTime before it.
    assert frame.t_start_ns == t + 2_000_000 and frame.exposure_us == 10_000
    assert cam.skipped == 1 and early.released and good.released  # started before t: dropped
    assert fake.flushes[0] == t  # picamera2 is asked to pick by timestamp itself
    # Readout bounded by the mode's shortest frame (23 ms), tighter than the 33 ms period.
    assert frame.readout_ns == 23_000_000
    assert frame.metadata["SensorTimestamp"] == t + 12_000_000
    assert frame.image.shape == (480, 640, 3) and tuple(frame.image[0, 0]) == (200, 0, 0)  # BGR
    with pytest.raises(HardwareError, match="no frame"):
        cam.frame_after(t, timeout_s=0.05)


# --- the webcam -----------------------------------------------------------------------------------


def test_opencv_missing_device_is_an_error_not_a_hang():
    start = time.monotonic()
    with pytest.raises(HardwareError, match="video device"):
        OpenCVCamera(CameraSettings(backend="opencv", device="/dev/video-edge-test-missing"), (640, 480))
    assert time.monotonic() - start < 6.0


def test_open_camera_sim_sees_the_simulated_lasers():
    config = load_config(None, ["sim.scene=\"office\""])
    with open_lasers(config) as lasers:
        camera = open_camera(config, lasers.factory, pose_at=lambda t_ns: (10.0, 0.0))
        camera.start()
        lasers.set(lasers.names)
        frame = camera.frame_after(lasers.last_switch_ns + 2_000_000, timeout_s=2.0)
        assert frame.metadata["pan_deg"] == 10.0
        assert frame.metadata["laser_fraction_range"]["center"] == (1.0, 1.0)
        dark_from = lasers.off()
        # A pose of now, as the PTU emulator's pose() gives it, will do too.
        camera = open_camera(config, lasers.factory, pose_at=lambda: (-5.0, 2.0))
        camera.start()
        frame = camera.frame_after(dark_from, timeout_s=2.0)
        assert (frame.metadata["pan_deg"], frame.metadata["tilt_deg"]) == (-5.0, 2.0)
        assert frame.metadata["laser_fraction_range"]["center"] == (0.0, 0.0)
        assert open_camera(config, lasers.factory).frame_ns == config.camera.frame_ns


def test_sim_backend_needs_the_lasers_factory():
    with pytest.raises(HardwareError, match="simulated lasers"):
        open_camera(load_config(None))
