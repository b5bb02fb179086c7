"""The simulated camera: the renderer behind a real frame clock and a rolling shutter.

:class:`SimCamera` behaves like the Pi camera as far as timing goes. Once started, frames begin
every frame period on the rig's clock (:mod:`edge.clock`), whether anyone asks for them or not. Row r of a
frame starts its exposure ``r·readout/(H−1)`` after row 0 and is exposed for the configured time;
the frame is delivered when its last row has been read. ``frame_after(t)`` sleeps until the first
frame starting at or after `t` has been delivered, then renders it: the pose comes from
``pose_at(t)`` (the pan-tilt unit's emulator), and each laser's brightness in each row from what
its GPIO pin actually did during that row's exposure (:class:`edge.sim.light.LaserLight`). So a
laser switched mid-frame lights only some rows of its spot, as on the real sensor.

Rendering takes the computer's time (a new view 50–70 ms, a frame of a known view about 10 ms);
frame times follow the rig's clock regardless: on the real clock a slow computer delivers frames
late (and drops them), on a simulated one time waits for the renderer. Given ``heading`` (where
the unit is going: the emulator's), a thread renders the view there while the unit is still
moving, as a real camera would simply have it; ``foresee(views)`` (the sweep's, a zone ahead)
has it render the views the rig will visit next, so that on a simulated clock, where a move takes
no time of the computer's, the next zone's view is rendered on another core meanwhile. A camera
keeps only a short queue of delivered frames: a frame delivered more than ``queue_frames`` periods
before the request is gone (dropped, as a real camera drops frames nobody collects).
"""

from __future__ import annotations

import inspect
import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from edge.clock import REAL, Clock
from edge.config import Config
from edge.errors import CameraError, ConfigError
from edge.hw.base import Frame
from edge.hw.camera import CameraSettings
from edge.sim.light import LaserLight
from edge.sim.render import Renderer
from edge.sim.settings import CameraFault

log = logging.getLogger(__name__)

PoseAt = Callable[[int], tuple[float, float]]


def _ceil_div(a: int, b: int) -> int:
    return -((-a) // b)


class SimCamera:
    """A simulated camera on a real frame clock (implements :class:`edge.hw.base.Camera`)."""

    def __init__(
        self,
        renderer: Renderer,
        light: LaserLight,
        settings: CameraSettings,
        *,
        pose_at: Callable[..., tuple[float, float]] | None = None,
        pose_deg: tuple[float, float] = (0.0, 0.0),
        heading: Callable[[], tuple[float, float]] | None = None,
        pose_step_deg: float | None = None,
        readout_fraction: float = 0.7,
        queue_frames: int = 2,
        seed: int = 0,
        scene_epoch_ns: int = 0,
        noise: bool = True,
        clock: Clock = REAL,
    ) -> None:
        if not 0.0 <= readout_fraction < 1.0:
            raise ValueError(f"readout_fraction must be in [0, 1), got {readout_fraction}")
        self.renderer = renderer
        self.clock = clock
        self.closed = False
        # The stream a webcam would name (edge.hw.camera.OpenCVCamera.pixel_format) for the frames
        # the sensor is set to make; "" for the Pi camera's, which no such code names.
        sensor = renderer.sim.sensor
        self.pixel_format = "MJPG" if sensor.jpeg_quality else "YUYV" if sensor.yuyv else ""
        self.light = light
        self.settings = settings
        self.frame_ns = settings.frame_ns
        self.exposure_ns = int(round(settings.exposure_us * 1000))
        # The time from row 0's exposure start to the last row's: a sensor reads its rows out one
        # after another over most of the frame period.
        self.readout_ns = int(round(readout_fraction * self.frame_ns))
        self.pose_at: PoseAt = _as_pose_at(pose_at) if pose_at is not None else _standing(pose_deg)
        self.queue_frames = queue_frames
        self.seed = seed
        # Scene time (movers) is (t − epoch)/1e9 s: by default the clock's own time.
        self.scene_epoch_ns = scene_epoch_ns
        self.noise = noise
        height = renderer.rig.camera.height
        self._row_offsets = (np.arange(height, dtype=np.int64) * self.readout_ns) // max(height - 1, 1)
        self.heading = heading
        self.pose_step_deg = pose_step_deg  # the unit's resolution: views as the unit will report them
        self.faults: tuple[CameraFault, ...] = ()  # played from the first start
        self._foreseen: list[tuple[float, float]] = []  # views to render ahead, next first
        self._wake = threading.Condition()
        self._epoch: int | None = None
        self._corrupted = 0
        self._prefetcher: threading.Thread | None = None
        self._stopping = threading.Event()
        self._t0: int | None = None
        self._last_k = -1
        self.frames_rendered = 0

    @classmethod
    def from_config(cls, config: Config, lasers_factory, **kwargs) -> SimCamera:
        """The camera of `config`'s simulated rig in its scene, watching the laser pins of
        `lasers_factory` (the mock factory the simulated lasers were opened on)."""
        from edge.sim.record import scene_for, true_rig

        renderer = Renderer(scene_for(config), true_rig(config), config.sim, config.camera)
        readout_ns = config.sim.sensor.readout_ms * 1e6
        if readout_ns >= config.camera.frame_ns:
            raise ConfigError(
                f"sim.sensor.readout_ms: {config.sim.sensor.readout_ms:g} ms does not fit in a frame of "
                f"{config.camera.frame_ns / 1e6:.3g} ms (camera.frame_rate_hz); make it shorter"
            )
        kwargs.setdefault("readout_fraction", readout_ns / config.camera.frame_ns)
        lasers = config.rig.build().lasers
        for i, fault in enumerate(config.sim.laser_faults):
            if fault.laser not in {laser.name for laser in lasers}:
                raise ConfigError(f"{config.source}: sim.laser_faults[{i}].laser: no laser {fault.laser!r} "
                                  f"(the rig has {', '.join(laser.name for laser in lasers)})")
        light = LaserLight(config.rig.wiring(), lasers_factory, settle_ns=int(round(config.lasers.settle_ms * 1e6)),
                           broken={f.laser: f.kind for f in config.sim.laser_faults if f.kind != "slow"},
                           lag_ns={f.laser: int(round(f.lag_ms * 1e6)) for f in config.sim.laser_faults
                                   if f.kind == "slow"})
        kwargs.setdefault("seed", config.sim.seed)
        camera = cls(renderer, light, config.camera, **kwargs)
        camera.faults = config.sim.camera_faults
        return camera

    # --- the Camera interface --------------------------------------------------------------------

    def start(self) -> None:
        if self._t0 is None:
            self._t0 = self.clock.now_ns()
            if self._epoch is None:
                self._epoch = self._t0  # fault times count from the first start, not a restart
            self._last_k = -1
            log.debug("simulated camera started: %d ns frames, readout %d ns", self.frame_ns, self.readout_ns)
        if self.heading is not None and self._prefetcher is None:
            self._stopping.clear()
            self._prefetcher = threading.Thread(target=self._prefetch, args=(self.heading,),
                                                name="sim-camera prefetch", daemon=True)
            self._prefetcher.start()

    def stop(self) -> None:
        self._t0 = None
        if self._prefetcher is not None:
            with self._wake:
                self._stopping.set()
                self._wake.notify_all()
            self._prefetcher.join()
            self._prefetcher = None

    def close(self) -> None:
        """Nothing to release: a stopped simulated camera holds no device."""
        self.stop()
        self.closed = True

    def foresee(self, views: list[tuple[float, float]]) -> None:
        """The (pan, tilt) views the rig will visit next, in order: rendered ahead by the prefetch
        thread, replacing any not yet begun."""
        step = self.pose_step_deg
        if step:  # as the unit will report them: whole positions times its resolution
            views = [(float(round(p / step)) * step, float(round(t / step)) * step) for p, t in views]
        with self._wake:
            self._foreseen = list(views)
            self._wake.notify_all()

    def _prefetch(self, heading: Callable[[], tuple[float, float]]) -> None:
        last = None
        while True:
            with self._wake:
                if not self._foreseen and not self._stopping.is_set():
                    self._wake.wait(0.004)  # the heading is polled: the unit says nothing of a move
                if self._stopping.is_set():
                    return
                foreseen = self._foreseen.pop(0) if self._foreseen else None
            try:
                pose = heading()
                if pose != last:  # where the unit is going first: it is needed soonest
                    last = pose
                    self.renderer.prefetch(*pose)
                if foreseen is not None:
                    self.renderer.prefetch(*foreseen)
            except Exception as exc:  # the frame's own render will meet (and report) it again
                log.debug("prefetch failed: %s", exc)
                last = None

    def frame_start_ns(self, k: int) -> int:
        """When frame k's first row starts its exposure."""
        if self._t0 is None:
            raise CameraError("camera: not started")
        return self._t0 + k * self.frame_ns

    def frame_after(self, t_ns: int, timeout_s: float | None = None) -> Frame:
        """The first frame whose exposure starts at or after `t_ns`, once it has been read out.
        Raises HardwareError when that takes longer than `timeout_s` (default: the settings')."""
        if self._t0 is None:
            raise CameraError("camera: not started")
        timeout_s = self.settings.timeout_s if timeout_s is None else timeout_s
        fault = self._fault_now()
        if fault is not None and fault.kind == "hang":
            end = self._fault_end_ns(fault)
            if self.clock.simulated:  # a hung call holds the computer too: systemd's watchdog must see it
                time.sleep(max(end - self.clock.now_ns(), 0) / 1e9)
            self.clock.sleep_until_ns(end)  # no timeout: that is what a hang is
        elif fault is not None and fault.kind == "stall":
            self.clock.sleep_until_ns(min(self._fault_end_ns(fault), self.clock.now_ns() + int(timeout_s * 1e9)))
            if self.clock.now_ns() < self._fault_end_ns(fault):
                raise CameraError(f"camera: no frame starting after {t_ns} within {timeout_s:g} s")
        now = self.clock.now_ns()
        deadline = now + int(timeout_s * 1e9)
        span = self.readout_ns + self.exposure_ns  # first row's start to last row's end
        k = max(_ceil_div(int(t_ns) - self._t0, self.frame_ns), 0, self._last_k + 1)
        # Frames delivered too long ago have been dropped from the queue.
        oldest = _ceil_div(now - self.queue_frames * self.frame_ns - self._t0 - span, self.frame_ns)
        k = max(k, oldest)
        ready = self.frame_start_ns(k) + span
        if ready > deadline:
            self.clock.sleep_until_ns(deadline)
            raise CameraError(f"camera: no frame starting after {t_ns} within {timeout_s:g} s")
        self.clock.sleep_until_ns(ready)
        self._last_k = k
        frame = self._render(k)
        if fault is not None and fault.kind == "corrupt" and self._corrupted < fault.count:
            self._corrupted += 1
            # A torn buffer: the frame's rows cut short.
            frame = Frame(frame.image[: frame.image.shape[0] // 3], frame.t_start_ns, frame.exposure_us,
                          frame.readout_ns, frame.sequence, frame.metadata)
        return frame

    def _fault_now(self) -> CameraFault | None:
        """The configured fault under way now, if any (times from when the camera started)."""
        if not self.faults or self._t0 is None or self._epoch is None:  # _epoch: set with _t0
            return None
        since = (self.clock.now_ns() - self._epoch) / 1e9
        for fault in self.faults:
            if fault.kind == "corrupt":
                if fault.at_s <= since and self._corrupted < fault.count:
                    return fault
            elif fault.at_s <= since < fault.at_s + fault.seconds:
                return fault
        return None

    def _fault_end_ns(self, fault: CameraFault) -> int:
        assert self._epoch is not None  # a fault is under way only once the camera has started
        return self._epoch + int((fault.at_s + fault.seconds) * 1e9)

    # --- internals -----------------------------------------------------------------------------

    def _render(self, k: int) -> Frame:
        t_start = self.frame_start_ns(k)
        fractions = self.light.row_fractions(t_start + self._row_offsets, self.exposure_ns)
        lasers_on = {name: f for name, f in fractions.items() if f.any()}
        pan, tilt = self.pose_at(t_start + (self.readout_ns + self.exposure_ns) // 2)
        rng = np.random.default_rng([self.seed & 0xFFFFFFFF, k])
        t_s = (t_start - self.scene_epoch_ns) / 1e9
        image = self.renderer.render(pan, tilt, lasers_on, t_s, rng, noise=self.noise)
        self.frames_rendered += 1
        metadata = {
            "simulated": True,
            "pan_deg": float(pan),
            "tilt_deg": float(tilt),
            # Per laser: the least and most of an exposure any row saw it lit (truth, for tests).
            "laser_fraction_range": {n: (float(f.min()), float(f.max())) for n, f in fractions.items()},
        }
        sensor = self.renderer.sim.sensor
        if sensor.colour_matrix and self.renderer.channels == 3 and not (sensor.jpeg_quality or sensor.yuyv):
            # As libcamera tells the matrix the Pi camera's ISP applied; a webcam's JPEG or YUYV
            # frames come with nothing of the kind (as the accuracy family takes its JPEG frames to be).
            metadata["ColourCorrectionMatrix"] = sensor.colour_matrix
        return Frame(image, t_start, self.settings.exposure_us, self.readout_ns, k, metadata)


def _standing(pose_deg: tuple[float, float]) -> PoseAt:
    """A unit that never moves."""
    return lambda _t: pose_deg


def _as_pose_at(pose: Callable[..., tuple[float, float]]) -> PoseAt:
    """`pose(t_ns)`, or a pose of now such as the PTU emulator's ``pose()`` (then read when the
    frame is rendered, just after its readout: exact whenever the unit stood still for it)."""
    try:
        takes_time = bool(inspect.signature(pose).parameters)
    except (TypeError, ValueError):  # no signature to read: assume the documented form
        takes_time = True
    return pose if takes_time else (lambda _t: pose())

