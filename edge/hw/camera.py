"""Cameras: the Pi camera through picamera2 and a USB webcam through OpenCV (the simulated camera,
:mod:`edge.sim.camera`, is their peer; :mod:`edge.parts` chooses among them).

All answer ``frame_after(t_ns)`` with the first frame whose exposure *starts* at or after
`t_ns` on the monotonic clock — frames are picked by their timestamps, never by counting, because
a frame that was being exposed while the lasers switched shows them half on.

Exposure and gain are fixed (a zone's laser-on and laser-off frames must differ by the lasers
alone), and anything that mixes frames is off: on a Pi 5 any noise reduction mode but Off turns on
temporal denoise, which blends the previous frame into the next — laser-on into laser-off. So is
what reshapes a spot or mixes the colours it is read from: sharpening, and (through the sensor's
tuning file) the colour matrix and defective-pixel correction.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from edge.errors import CameraError
from edge.hw.base import Frame
from edge.schema import require
from edge.tone import TOE, require_gamma, tone_curve

log = logging.getLogger(__name__)

PICAMERA2_MISSING = (
    "picamera2 is not installed: on Raspberry Pi OS `sudo apt install python3-picamera2` and make "
    "the venv with --system-site-packages"
)
# The Pi Camera v2 (IMX219) binned 2 × 2 over its whole field of view: the raw mode that keeps the
# field of view the `picam-v2*` camera models describe, and that sensor's name in libcamera.
PICAM_V2_BINNED = (1640, 1232)
PICAM_V2_SENSOR = "imx219"


def lens_dioptres_problem(dioptres: float) -> str | None:
    """What is wrong with a focus motor's lens position (dioptres), if anything: the one check of
    camera.lens_dioptres and of the key recordings and calibration files keep."""
    if 0.0 <= dioptres <= 32.0:
        return None
    return f"must be 0-32 dioptres (0: infinity; 1: 1 m), got {dioptres:g}"


@dataclass(frozen=True)
class CameraSettings:
    """How the camera is driven (``[camera]``): the same for the real camera and the simulated one.

    A zone's laser-on and laser-off frames must be taken with the same fixed exposure and gain, so
    that their difference shows the lasers and nothing else.
    """

    backend: Literal["sim", "picamera2", "opencv"] = "sim"
    device: str = "0"  # opencv: a device index or path (/dev/video0)
    exposure_us: float = 10000.0
    analogue_gain: float = 1.0
    frame_rate_hz: float = 30.0
    # Webcams give no exposure timestamps: the time from the end of a frame's exposure to its
    # delivery, measured once, stands in for them (t_start = delivery − latency − exposure).
    latency_ms: float = 0.0
    timeout_s: float = 1.0  # no frame for this long is a camera fault
    # picamera2: the tone curve the ISP is set to, value = light^(1/gamma) (edge.tone; 1: linear),
    # in place of its tuning file's own curve, with adaptive contrast off; ranging.frame_gamma
    # must be the same, so that ranging undoes it exactly (the tuning file's own curve it could
    # not). 1 keeps the frames linear, as every figure of the accuracy bench is measured on.
    gamma: float = 1.0
    # picamera2, a camera with a focus motor (Camera Module 3): where the lens is held, in
    # dioptres (1 / the distance in focus, m; 0 = infinity). Never autofocus: the lens would move
    # between zones, and the focal length with it (a calibration holds for one lens position).
    # At 1 dioptre a Camera Module 3 (4.74 mm, f/1.8) binned to 640 × 480 blurs a spot by under a
    # pixel from 0.6 to 2.6 m, 1.3 px at 5 m, 5 px at 0.25 m (thin-lens arithmetic; near spots are
    # bright). Cameras without a motor ignore it.
    lens_dioptres: float = 1.0
    # opencv: the webcam's stream. "auto" takes what OpenCV's V4L2 backend picks: uncompressed
    # (YUYV) first, where the webcam streams it at the rig's size, else JPEG (MJPG). "YUYV" insists
    # on uncompressed frames; "MJPG" asks for JPEG, which streams larger frames faster but places
    # spots worse (of the observable zones in the accuracy family's colour frames, 77 % ranged in JPEG
    # frames, 94 % in uncompressed ones).
    pixel_format: Literal["auto", "YUYV", "MJPG"] = "auto"

    def __post_init__(self) -> None:
        # Physical ranges: sensors' analogue gain tops out at 16-64x, no frame takes a second.
        require(1.0 <= self.analogue_gain <= 64.0, "analogue_gain", "must be 1-64")
        require(self.exposure_us >= 1.0, "exposure_us", "must be at least 1 µs")
        require(0.1 <= self.frame_rate_hz <= 1000.0, "frame_rate_hz",
                f"must be 0.1-1000 frames a second, got {self.frame_rate_hz:g}")
        require(
            self.exposure_us <= 1e6 / self.frame_rate_hz,
            "exposure_us",
            f"must fit in one frame time ({1e6 / self.frame_rate_hz:.0f} µs)",
        )
        require(0 <= self.latency_ms <= 1000, "latency_ms", "must be 0-1000 ms")
        require(0 < self.timeout_s <= 60, "timeout_s", "must be more than 0 and at most 60 s")
        require_gamma(self.gamma, "gamma")
        lens = lens_dioptres_problem(self.lens_dioptres)
        require(lens is None, "lens_dioptres", lens or "")

    @property
    def frame_ns(self) -> int:
        return int(round(1e9 / self.frame_rate_hz))


class Picamera2Camera:
    """The Pi camera through picamera2 (implements :class:`edge.hw.base.Camera`)."""

    def __init__(
        self,
        settings: CameraSettings,
        size: tuple[int, int],
        *,
        raw_size: tuple[int, int] | None = None,
        sensor: str | None = None,
        camera_num: int = 0,
        colour_gains: tuple[float, float] = (1.0, 1.0),
    ) -> None:
        """`raw_size`: the sensor mode to read (None: libcamera's pick). `sensor`: the sensor whose
        field of view and pixels the rig's camera model describes (libcamera's name, as `imx219`),
        read in `raw_size`; CameraError where the camera is another or reads another mode, for
        every range would be off by their difference (None: not checked)."""
        try:
            from picamera2 import Picamera2
        except ImportError:
            raise CameraError(PICAMERA2_MISSING) from None
        self.settings = settings
        self.frame_ns = settings.frame_ns
        self.size = size
        self.pixel_format = ""  # (Camera's: no code names the frames edge configures, RGB888)
        self.skipped = 0  # frames read and discarded by frame_after
        self.closed = False
        self._first_t: int | None = None
        self._flush = True  # picamera2 picks frames by timestamp itself (capture_request(flush=))
        model = _sensor_model(Picamera2, camera_num)
        tuning = _tuning_for_ranging(Picamera2, model, settings.gamma)
        try:
            self._cam = Picamera2(camera_num) if tuning is None else Picamera2(camera_num, tuning=tuning)
        except Exception as exc:
            raise CameraError(f"camera: cannot open Pi camera {camera_num}: {exc}") from None
        frame_us = int(round(1e6 / settings.frame_rate_hz))
        self.controls: dict[str, Any] = {
            "AeEnable": False,
            "ExposureTime": int(round(settings.exposure_us)),
            "AnalogueGain": float(settings.analogue_gain),
            "FrameDurationLimits": (frame_us, frame_us),
            "NoiseReductionMode": _noise_reduction_off(),
            # No sharpening (rpi.sharpen's strength is the control's): its unsharp mask, thresholded
            # and limited by brightness, rings round a spot and reshapes it by how bright it is.
            "Sharpness": 0.0,
            # Fixed white balance: AWB would re-colour laser-on frames (a red spot) differently.
            "AwbEnable": False,
            "ColourGains": tuple(colour_gains),
        }
        self.lens_dioptres = self._hold_lens(settings.lens_dioptres)
        try:
            # RGB888 is [B, G, R] in memory: OpenCV's BGR, as the rest of the project expects.
            kwargs: dict[str, Any] = {"main": {"size": tuple(size), "format": "RGB888"}, "controls": self.controls}
            if raw_size is not None:
                kwargs["raw"] = {"size": tuple(raw_size)}
            self._cam.configure(self._cam.create_video_configuration(**kwargs))
        except Exception as exc:
            self._close_quietly()
            raise CameraError(f"camera: cannot configure the Pi camera: {exc}") from None
        problem = _mode_problem(self._cam, model, sensor, raw_size)
        if problem is not None:
            self._close_quietly()
            raise CameraError(problem)
        # The readout (row 0 to the last row) is not in the metadata. The shortest frame duration
        # of the sensor mode bounds it (that is the readout plus the least vertical blanking).
        # FrameDuration − exposure would not bound it: a longer exposure does not make the rows read
        # out faster, it only makes successive frames' row windows overlap.
        self.min_frame_ns: int | None = None
        limits = getattr(self._cam, "camera_controls", {}).get("FrameDurationLimits")
        if limits:
            self.min_frame_ns = int(limits[0]) * 1000

    def _hold_lens(self, dioptres: float) -> float | None:
        """Where a focus motor's lens is held (None: the camera has none): manual focus, at
        `dioptres`; CameraError, naming the key, beyond the lens's range."""
        available = getattr(self._cam, "camera_controls", {})
        if "AfMode" not in available or "LensPosition" not in available:
            return None
        low, high = (float(x) for x in available["LensPosition"][:2])
        if not low <= dioptres <= high:
            self._close_quietly()
            raise CameraError(f"camera.lens_dioptres: {dioptres:g} is beyond this lens's "
                              f"{low:g}-{high:g} dioptres")
        self.controls["AfMode"] = _af_manual()
        self.controls["LensPosition"] = float(dioptres)
        return float(dioptres)

    def start(self) -> None:
        if self.closed:
            raise CameraError("camera: the Pi camera was closed; open it again")
        try:
            self._cam.start()
        except Exception as exc:
            raise CameraError(f"camera: cannot start the Pi camera: {exc}") from None

    def stop(self) -> None:
        if self.closed:
            return
        try:
            self._cam.stop()
        except Exception as exc:
            log.warning("camera: stop failed: %s", exc)

    def close(self) -> None:
        """Stop and release the camera (libcamera keeps it claimed until then); once only."""
        if self.closed:
            return
        self.stop()
        self.closed = True
        self._close_quietly()

    def _close_quietly(self) -> None:
        try:
            self._cam.close()
        except Exception as exc:
            log.debug("camera: close failed: %s", exc)

    def __enter__(self) -> Picamera2Camera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def frame_after(self, t_ns: int, timeout_s: float | None = None) -> Frame:
        """The first frame whose exposure starts at or after `t_ns`; HardwareError on timeout."""
        timeout_s = self.settings.timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise CameraError(f"camera: no frame starting after {t_ns} within {timeout_s:g} s")
            # flush: picamera2 itself releases the frames that started earlier (it tests
            # SensorTimestamp − ExposureTime, as below); flush=0 would mean "no flush".
            try:
                if self._flush:
                    request = self._cam.capture_request(wait=left, flush=max(int(t_ns), 1))
                else:
                    request = self._cam.capture_request(wait=left)
            except TypeError as exc:
                if not self._flush:
                    raise CameraError(f"camera: capture failed: {exc}") from None
                # An older picamera2 without flush: the check below then skips early frames.
                log.info("picamera2 has no capture_request(flush=...): skipping early frames here")
                self._flush = False
                continue
            except TimeoutError:
                raise CameraError(f"camera: no frame starting after {t_ns} within {timeout_s:g} s") from None
            except Exception as exc:
                raise CameraError(f"camera: capture failed: {exc}") from None
            try:
                image = request.make_array("main")
                metadata = dict(request.get_metadata())
            finally:
                request.release()
            frame = self._frame(image, metadata)
            if frame.t_start_ns >= t_ns:
                return frame
            self.skipped += 1

    def _frame(self, image: np.ndarray, metadata: dict[str, Any]) -> Frame:
        try:
            sensor_ns = int(metadata["SensorTimestamp"])
            exposure_us = float(metadata["ExposureTime"])
        except KeyError as exc:
            raise CameraError(f"camera: frame metadata lacks {exc.args[0]}") from None
        # SensorTimestamp marks the first row's readout (the end of its exposure), not its start.
        t_start = sensor_ns - int(round(exposure_us * 1000))
        period_ns = int(metadata.get("FrameDuration", 1e6 / self.settings.frame_rate_hz)) * 1000
        readout_ns = min(period_ns, self.min_frame_ns) if self.min_frame_ns else period_ns
        if self._first_t is None:
            self._first_t = t_start
        sequence = int(round((t_start - self._first_t) / self.frame_ns))
        width, height = self.size
        image = np.ascontiguousarray(image[:height, :width, :3])  # drop any stride padding
        return Frame(image, t_start, exposure_us, readout_ns, sequence, metadata)


# The colour matrix ranging asks the ISP for (rpi.ccm's rows R', G', B' of columns R, G, B): none.
IDENTITY_CCM = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def _sensor_model(picamera2: Any, camera_num: int) -> str:
    """libcamera's name of camera `camera_num`'s sensor (as `imx219`), "?" where it tells none."""
    try:
        return str(picamera2.global_camera_info()[camera_num]["Model"])
    except Exception:
        return "?"


def _mode_problem(cam: Any, model: str, sensor: str | None, raw_size: tuple[int, int] | None) -> str | None:
    """What is wrong, for ranging, with the sensor and the mode the camera `cam` was configured in,
    where the rig's camera model describes `sensor` read at `raw_size` (None: nothing to check)."""
    if sensor is None:
        return None
    fix = ("set rig.camera's fx, fy, cx and cy (and dist) to this camera's own, measured with OpenCV's "
           "calibrateCamera, which also turns this check off")
    if model not in ("?", sensor):
        return (f"camera: this Pi camera's sensor is an {model}, not the {sensor} whose field of view and pixels "
                f"rig.camera.model describes: every range would be off by their difference; {fix}")
    try:
        read = tuple(cam.camera_configuration()["raw"]["size"])
    except Exception:
        return None  # (a picamera2 that tells no raw size: nothing to check against)
    if raw_size is not None and read != tuple(raw_size):
        return (f"camera: the Pi camera reads its sensor at {read[0]}x{read[1]}, not at {raw_size[0]}x{raw_size[1]} "
                f"over its whole field of view as rig.camera.model describes (another field of view, or "
                f"another binning); update picamera2 and libcamera (sudo apt full-upgrade), or {fix}")
    return None


def _tuning_for_ranging(picamera2: Any, model: str, gamma: float) -> dict | None:
    """The camera's own tuning file (by its sensor's model), changed where the ISP would reshape
    what ranging measures; None, with a warning, where it cannot be read (the ISP then applies its
    own curve, which ranging cannot undo exactly, and its own colour matrix).

    - ``rpi.contrast``: `gamma`'s tone curve (:func:`edge.tone.tone_curve`), adaptive contrast off.
    - ``rpi.ccm``: no colour mixing. The matrix mixes the channels with large negative terms (the
      IMX219's at 4650 K takes 2.18 R − 0.71 G − 0.47 B for red): red then carries the other
      channels' noise and their demosaicing, and a red spot drives green and blue below zero,
      where they clip. One identity matrix at every colour temperature, and no fall of saturation
      with the light (its lux table).
    - ``rpi.dpc``: no defective-pixel correction (strength 0). It pulls a pixel that stands out
      from its same-colour neighbours back to them, as a small spot's peak red pixel does;
      a truly hot pixel is in the laser-off frame too, and the difference cancels it.

    A stage that the file lacks is not run, so there is nothing to change there."""
    try:
        tuning = picamera2.load_tuning_file(f"{model}.json")
    except Exception as exc:
        log.warning("camera: cannot read the %s tuning file to set its tone curve and colour matrix (%s); "
                    "frames keep the ISP's own gamma curve and colour matrix", model, exc)
        return None

    def stage(name: str) -> dict | None:
        try:
            found = picamera2.find_tuning_algo(tuning, name)
        except Exception:
            return None
        return found if isinstance(found, dict) else None

    contrast = stage("rpi.contrast")
    if contrast is None:
        log.warning("camera: the %s tuning file has no tone curve (rpi.contrast): frames are linear", model)
    else:
        contrast["ce_enable"] = 0
        contrast["gamma_curve"] = curve_points(gamma)
    ccm = stage("rpi.ccm")
    if ccm is not None:
        ccm.pop("saturation", None)
        ccm["ccms"] = [{"ct": 5000, "ccm": list(IDENTITY_CCM)}]
    dpc = stage("rpi.dpc")
    if dpc is not None:
        dpc["strength"] = 0
    return tuning


def curve_points(gamma: float) -> list[int]:
    """`gamma`'s tone curve as the ISP takes it: x0, y0, x1, y1, … in 16-bit units, denser in the
    shadows where the curve bends most (a straight line for 1)."""
    if gamma == 1.0:
        return [0, 0, 65535, 65535]
    xs = sorted({0, round(TOE * 65535), *(round(65535 * (i / 32) ** 2) for i in range(1, 33))})
    ys = tone_curve(np.array(xs, dtype=np.float32) / 65535.0, gamma) * 65535.0
    return [v for x, y in zip(xs, ys.tolist()) for v in (x, int(round(y)))]


def _af_manual() -> Any:
    try:
        from libcamera import controls

        return controls.AfModeEnum.Manual
    except Exception:  # libcamera's enum not importable: its value
        return 0


def _noise_reduction_off() -> Any:
    try:
        from libcamera import controls

        return controls.draft.NoiseReductionModeEnum.Off
    except Exception:  # libcamera's enum not importable: its value
        return 0


def fourcc_code(text: str) -> int:
    """A four-character code ("YUYV") as the number OpenCV's CAP_PROP_FOURCC takes."""
    return sum(ord(c) << (8 * i) for i, c in enumerate(text[:4]))


def fourcc_text(code: float) -> str:
    """OpenCV's CAP_PROP_FOURCC (a number) as its four characters ("YUYV"); "" where it is 0 or not
    text (a backend that does not say)."""
    n = int(code)
    text = "".join(chr((n >> (8 * i)) & 0xFF) for i in range(4)).strip()
    return text if n > 0 and text.isprintable() and text.isascii() else ""


class OpenCVCamera:
    """A USB webcam through OpenCV (implements :class:`edge.hw.base.Camera`).

    A webcam gives no exposure timestamps. A thread reads frames as they arrive (so that none waits
    in the driver's queue and its delivery time means something) and dates each one back:
    ``t_start = delivery − latency_ms − exposure``; the readout is bounded by the frame period.

    Life cycle: constructing it opens the device (so that a wrong ``[camera] device`` is an error at
    once); ``start()`` runs a reading thread on it; ``stop()`` ends that thread, which releases the
    device; a later ``start()`` opens the device again — the usual cure for a webcam that stalled.
    ``close()`` stops for good. Every open happens in a thread of its own with a deadline, so that a
    driver that blocks cannot hang the caller.
    """

    def __init__(
        self, settings: CameraSettings, size: tuple[int, int] | None = None, *, open_timeout_s: float = 5.0
    ) -> None:
        self.settings = settings
        self.frame_ns = settings.frame_ns
        self.size = size
        self.open_timeout_s = open_timeout_s
        self.exposure_ns = int(round(settings.exposure_us * 1000))
        self.latency_ns = int(round(settings.latency_ms * 1e6))
        self.skipped = 0
        self.exposure_fixed = False
        self.closed = False
        self._frames: deque[tuple[int, int, np.ndarray]] = deque(maxlen=4)  # (t_start, seq, image)
        self._cond = threading.Condition()
        self._stopping = threading.Event()
        self._error: str | None = None
        self._sequence = 0  # frame counter, kept across restarts so that sequences only grow
        self._taken = -1  # sequence of the last frame handed out
        self._thread: threading.Thread | None = None
        # The stream's four-character code as the device gave it ("YUYV", "MJPG"; "" where the
        # backend does not say): the doctor prints it, for JPEG places spots worse.
        self.pixel_format = ""
        self._cap: Any = self._open_in_time()  # opened, not yet read: start() reads it

    def _open_in_time(self) -> Any:
        outcome: dict[str, Any] = {}

        def open_it() -> None:
            try:
                outcome["cap"] = self._open()
            except CameraError as exc:
                outcome["error"] = str(exc)
            except Exception as exc:
                outcome["error"] = f"camera: cannot open video device {self.settings.device!r}: {exc}"

        opener = threading.Thread(target=open_it, name="webcam open", daemon=True)
        opener.start()
        opener.join(self.open_timeout_s)
        if opener.is_alive():
            raise CameraError(f"camera: opening video device {self.settings.device!r} took over "
                              f"{self.open_timeout_s:g} s")
        if "error" in outcome:
            raise CameraError(outcome["error"])
        return outcome["cap"]

    def _open(self) -> Any:
        import cv2

        device = self.settings.device
        source: int | str = int(device) if device.isdigit() else device
        # V4L2 directly on Linux: other backends may probe slowly for a missing device.
        v4l2 = sys.platform.startswith("linux") and (isinstance(source, int) or device.startswith("/dev/"))
        api = cv2.CAP_V4L2 if v4l2 else cv2.CAP_ANY
        cap = cv2.VideoCapture(source, api)
        if not cap.isOpened():
            cap.release()
            raise CameraError(
                f"camera: cannot open video device {device!r} ([camera] device; is the webcam plugged in?)"
            )
        asked = self.settings.pixel_format
        if asked != "auto":  # (before the size: V4L2 then picks the size among that format's)
            cap.set(cv2.CAP_PROP_FOURCC, fourcc_code(asked))
        if self.size:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.size[0])
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.size[1])
        self.pixel_format = fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        if asked != "auto" and not self.pixel_format:  # (a backend that does not say: nothing to hold it to)
            log.warning("camera: video device %r does not say which stream it gives; %s was asked for", device, asked)
        elif asked != "auto" and self.pixel_format != asked:
            cap.release()
            size = f" at {self.size[0]}x{self.size[1]}" if self.size else ""
            raise CameraError(
                f"camera: video device {device!r} streams {self.pixel_format}{size}, not {asked} "
                f"as camera.pixel_format asks (v4l2-ctl -d {device} --list-formats-ext lists what it streams)"
            )
        cap.set(cv2.CAP_PROP_FPS, self.settings.frame_rate_hz)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        # Manual exposure: V4L2 says 1 (others 0.25); its absolute exposure is in 100 µs units.
        manual = cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1) or cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 0.25)
        self.exposure_fixed = bool(manual and cap.set(cv2.CAP_PROP_EXPOSURE, self.settings.exposure_us / 100.0))
        if not self.exposure_fixed:
            log.warning("camera: the driver refused a fixed exposure; frame timing and brightness may drift")
        cap.set(cv2.CAP_PROP_AUTO_WB, 0)
        return cap

    def start(self) -> None:
        if self.closed:
            raise CameraError("camera: the webcam was closed; open it again")
        if self._thread is not None and self._thread.is_alive():
            return
        cap, self._cap = self._cap, None
        if cap is None:  # a restart: the last run released the device
            cap = self._open_in_time()
        with self._cond:
            self._error = None
            self._frames.clear()
        self._stopping.clear()
        self._thread = threading.Thread(target=self._read, args=(cap,), name="webcam", daemon=True)
        self._thread.start()

    def _read(self, cap: Any) -> None:
        """The reading thread of one run: owns `cap` and releases it when the run ends."""
        try:
            failures = 0
            while not self._stopping.is_set():
                ok, image = cap.read()
                delivered = time.monotonic_ns()
                if not ok:
                    failures += 1
                    if failures >= 10:
                        with self._cond:
                            self._error = f"camera: video device {self.settings.device!r} stopped delivering frames"
                            self._cond.notify_all()
                        return
                    time.sleep(0.01)
                    continue
                failures = 0
                t_start = delivered - self.latency_ns - self.exposure_ns
                with self._cond:
                    self._frames.append((t_start, self._sequence, image))
                    self._sequence += 1
                    self._cond.notify_all()
        finally:
            cap.release()

    def stop(self) -> None:
        self._stopping.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=2.0)
            if thread.is_alive():  # stuck in the driver: it releases the device when it returns
                log.warning("camera: the webcam's reading thread did not end within 2 s")

    def close(self) -> None:
        if self.closed:
            return
        self.stop()
        self.closed = True
        cap, self._cap = self._cap, None
        if cap is not None:  # opened but never started
            cap.release()

    def frame_after(self, t_ns: int, timeout_s: float | None = None) -> Frame:
        """The first frame whose (estimated) exposure start is at or after `t_ns`."""
        timeout_s = self.settings.timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                while self._frames:
                    t_start, seq, image = self._frames.popleft()
                    if seq <= self._taken:
                        continue
                    if t_start >= t_ns:
                        self._taken = seq
                        delivered = t_start + self.latency_ns + self.exposure_ns
                        # The readout is unknown: the frame period bounds it.
                        return Frame(image, t_start, self.settings.exposure_us, self.frame_ns, seq,
                                     {"delivered_ns": delivered})
                    self.skipped += 1
                if self._error:
                    raise CameraError(self._error)
                left = deadline - time.monotonic()
                if left <= 0:
                    raise CameraError(f"camera: no frame starting after {t_ns} within {timeout_s:g} s")
                self._cond.wait(left)
