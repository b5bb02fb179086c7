"""The cameras' life cycle (edge.hw.base): start and stop alternate any number of times (a stalled
camera is restarted so), and close() releases the device exactly once, at the end of open_parts
whatever the backend. The webcam runs on a stand-in for OpenCV's VideoCapture; the driver is real."""

from __future__ import annotations

import sys
import threading
import time
import types

import cv2
import numpy as np
import pytest

from edge.config import load_config
from edge.errors import CameraError
from edge.hw.camera import CameraSettings, OpenCVCamera
from edge.parts import open_parts


class _FakeCapture:
    """Just what OpenCVCamera uses of cv2.VideoCapture: frames every 5 ms, and a record of every
    capture opened, the properties set on it and how often each was released. Its device streams
    `formats` (a size each) as V4L2 through OpenCV does: a size set keeps the format that streams
    it, else takes the first that does in OpenCV's order (uncompressed before JPEG)."""

    opened: list[_FakeCapture] = []
    formats: dict[str, set[tuple[int, int]]] = {"YUYV": {(64, 48)}, "MJPG": {(64, 48), (1280, 720)}}

    def __init__(self, source, api=None) -> None:
        self.releases = 0
        self.reads = 0
        self.sets: list[tuple[int, float]] = []
        self.fourcc, self.size = "YUYV", (64, 48)
        self.asked = list(self.size)
        self._lock = threading.Lock()
        _FakeCapture.opened.append(self)

    def isOpened(self) -> bool:  # noqa: N802 (OpenCV's name)
        return self.releases == 0

    def set(self, prop, value) -> bool:
        self.sets.append((prop, value))
        if prop == cv2.CAP_PROP_FOURCC:
            code = "".join(chr((int(value) >> (8 * i)) & 0xFF) for i in range(4))
            if self.size not in self.formats.get(code, ()):
                return False
            self.fourcc = code
        elif prop in (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT):
            # (OpenCV asks the device for a size once it has been told both)
            self.asked[prop == cv2.CAP_PROP_FRAME_HEIGHT] = int(value)
            size = (self.asked[0], self.asked[1])
            streams = [f for f, sizes in self.formats.items() if size in sizes]
            if streams:
                self.size = size
                if self.fourcc not in streams:
                    self.fourcc = streams[0]
        return True

    def get(self, prop) -> float:
        if prop == cv2.CAP_PROP_FOURCC:
            return float(cv2.VideoWriter_fourcc(*self.fourcc))
        return 0.0

    def read(self):
        time.sleep(0.005)
        with self._lock:
            if self.releases:
                return False, None
            self.reads += 1
            return True, np.full((48, 64, 3), self.reads % 256, np.uint8)

    def release(self) -> None:
        with self._lock:
            self.releases += 1


@pytest.fixture
def fake_cv2(monkeypatch):
    _FakeCapture.opened = []
    monkeypatch.setattr(cv2, "VideoCapture", _FakeCapture)
    return _FakeCapture


def _settings() -> CameraSettings:
    return CameraSettings(backend="opencv", device="0", frame_rate_hz=100.0, exposure_us=1000.0, timeout_s=1.0)


def test_a_webcam_delivers_again_after_a_restart(fake_cv2):
    camera = OpenCVCamera(_settings(), (64, 48))
    camera.start()
    first = camera.frame_after(time.monotonic_ns())
    camera.stop()  # what the service's camera restart does: stop, then start
    camera.start()
    again = camera.frame_after(time.monotonic_ns())
    assert again.sequence > first.sequence  # frames flow again, numbered on from before
    assert len(fake_cv2.opened) == 2 and fake_cv2.opened[0].releases == 1  # the device was opened anew
    camera.close()
    camera.close()
    assert [c.releases for c in fake_cv2.opened] == [1, 1]
    with pytest.raises(CameraError, match="closed"):
        camera.start()


def test_a_webcam_opened_and_never_started_is_released_once(fake_cv2):
    OpenCVCamera(_settings(), (64, 48)).close()
    assert [c.releases for c in fake_cv2.opened] == [1]


def test_a_stopped_webcam_gives_no_frame(fake_cv2):
    camera = OpenCVCamera(_settings(), (64, 48))
    camera.start()
    camera.stop()
    with pytest.raises(CameraError, match="no frame"):
        camera.frame_after(time.monotonic_ns(), timeout_s=0.1)
    camera.close()


def test_open_parts_closes_the_webcam_once(fake_cv2):
    config = load_config(None, ['camera.backend="opencv"', "camera.frame_rate_hz=100.0", "camera.exposure_us=1000.0"])
    with open_parts(config) as parts:
        frame = parts.camera.frame_after(time.monotonic_ns())
        assert frame.image.shape == (48, 64, 3)
        assert not parts.simulated and parts.truth(0, 0.0, 0.0) is None
    assert [c.releases for c in fake_cv2.opened] == [1]


def test_open_parts_closes_the_pi_camera_once(monkeypatch):
    calls: list[str] = []

    class FakePicamera2:
        camera_controls: dict = {}

        def __init__(self, num: int = 0) -> None:
            calls.append("open")

        def create_video_configuration(self, **kwargs):
            return kwargs

        def configure(self, config) -> None:
            pass

        def start(self) -> None:
            calls.append("start")

        def stop(self) -> None:
            calls.append("stop")

        def close(self) -> None:
            calls.append("close")

    module = types.ModuleType("picamera2")
    module.Picamera2 = FakePicamera2  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "picamera2", module)
    monkeypatch.setitem(sys.modules, "libcamera", None)
    with open_parts(load_config(None, ['camera.backend="picamera2"'])):
        assert calls == ["open", "start"]
    assert calls == ["open", "start", "stop", "close"]


def test_open_parts_closes_the_simulated_camera():
    with open_parts(load_config(None, ["rig.camera.model=\"webcam-cif\""])) as parts:
        assert parts.simulated and parts.emulator is not None
        camera = parts.camera
        assert not camera.closed  # type: ignore[attr-defined]
    assert camera.closed  # type: ignore[attr-defined]


def test_a_webcam_says_which_stream_it_delivers_and_takes_the_one_asked_for(fake_cv2):
    """`auto` takes what OpenCV picks (uncompressed first) and says so; MJPG is asked for before the
    size, so that the size is one of that stream's."""
    camera = OpenCVCamera(_settings(), (64, 48))
    assert camera.pixel_format == "YUYV"
    camera.close()
    camera = OpenCVCamera(CameraSettings(**{**_settings().__dict__, "pixel_format": "MJPG"}), (64, 48))
    assert camera.pixel_format == "MJPG"
    props = [prop for prop, _ in fake_cv2.opened[-1].sets]
    assert props.index(cv2.CAP_PROP_FOURCC) < props.index(cv2.CAP_PROP_FRAME_WIDTH)
    camera.close()


def test_a_webcam_that_will_not_stream_uncompressed_at_the_size_is_one_clear_error(fake_cv2):
    """At 1280 x 720 the device streams JPEG alone: `auto` takes it (and says so), while asking for
    YUYV is an error that names the setting and how to list what the device streams; the device is
    released."""
    camera = OpenCVCamera(_settings(), (1280, 720))
    assert camera.pixel_format == "MJPG"
    camera.close()
    yuyv = CameraSettings(**{**_settings().__dict__, "pixel_format": "YUYV"})
    with pytest.raises(CameraError) as err:
        OpenCVCamera(yuyv, (1280, 720))
    assert str(err.value) == ("camera: video device '0' streams MJPG at 1280x720, not YUYV as camera.pixel_format asks "
                              "(v4l2-ctl -d 0 --list-formats-ext lists what it streams)")
    assert fake_cv2.opened[-1].releases == 1


def test_a_webcam_whose_backend_does_not_say_its_stream_is_taken_as_it_comes(fake_cv2, monkeypatch, caplog):
    """A backend that reports no FOURCC cannot be held to the stream asked for: a warning, not a
    failure, and the doctor names no stream."""
    monkeypatch.setattr(fake_cv2, "get", lambda self, prop: 0.0)
    yuyv = CameraSettings(**{**_settings().__dict__, "pixel_format": "YUYV"})
    with caplog.at_level("WARNING"):
        camera = OpenCVCamera(yuyv, (64, 48))
    assert camera.pixel_format == "" and "does not say which stream it gives; YUYV was asked for" in caplog.text
    camera.close()
