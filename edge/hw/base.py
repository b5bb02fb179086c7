"""The interfaces the sweep is written against; real and simulated parts implement them.

Times are ``time.monotonic_ns()`` everywhere: one clock for frames, laser switches and moves, so
that a frame's exposure can be compared with the moment the lasers changed.

Life cycle, as picamera2 has it: a part is *opened* by constructing it (the device is claimed and
configured, or an error says why not), ``start()``/``stop()`` run and halt it and may alternate any
number of times (a stalled camera is restarted so), and ``close()`` releases the device for good.
``close()`` is idempotent and safe from any state; nothing may be called after it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:  # the eye-safety path (edge lasers off) must not need numpy
    import numpy as np


@dataclass(frozen=True)
class Frame:
    """A camera frame with its timing, kept together always.

    `t_start_ns` is when the first row's exposure began; with a rolling shutter each following row
    starts later, the last one `readout_ns` after the first (an upper bound where the camera does
    not say). So row r is exposed over [t_start + r·readout/(H−1), that + exposure].
    """

    image: np.ndarray  # (H, W, 3) BGR or (H, W) grey, uint8 or uint16
    t_start_ns: int
    exposure_us: float
    readout_ns: int
    sequence: int  # the camera's frame counter
    metadata: Mapping[str, Any] = field(default_factory=dict)

    @property
    def t_end_ns(self) -> int:
        """When the last row's exposure ended."""
        return self.t_start_ns + self.readout_ns + int(self.exposure_us * 1000)


class Camera(Protocol):
    frame_ns: int  # the frame period
    # The stream's four-character code where the camera names one (a webcam's YUYV or MJPG, for
    # JPEG places spots worse); "" where it names none (the Pi camera's frames are edge's own RGB888).
    pixel_format: str

    def start(self) -> None:
        """Deliver frames from now on; again after a stop() (a restart). CameraError if it cannot."""
        ...

    def frame_after(self, t_ns: int, timeout_s: float | None = None) -> Frame:
        """The first frame whose exposure starts at or after `t_ns` (frames are picked by their
        timestamps, never by counting); `timeout_s` None: the camera's own. Raises CameraError on
        timeout."""
        ...

    def stop(self) -> None:
        """Stop delivering frames; start() may follow. Never raises."""
        ...

    def close(self) -> None:
        """Stop and release the camera for good; idempotent. Never raises."""
        ...


class LaserBank(Protocol):
    names: tuple[str, ...]

    def set(self, on: Iterable[str]) -> int:
        """Switch exactly these lasers on and the others off; return the monotonic time (ns) by
        which the new state has taken effect (the GPIO edge plus the driver's settle time)."""
        ...

    def off(self) -> int: ...

    @property
    def lit(self) -> frozenset[str]: ...

    @property
    def last_switch_ns(self) -> int: ...

    def close(self) -> None:
        """Lasers off, pins released."""
        ...


class PanTilt(Protocol):
    def move(self, pan_deg: float, tilt_deg: float) -> tuple[float, float]:
        """Go there and wait until the move has ended; return the position reached (degrees, after
        rounding to whole positions). Raises PtuError when the unit does not deliver."""
        ...

    @property
    def limits_deg(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """((pan min, pan max), (tilt min, tilt max)) in degrees, as the unit reports them."""
        ...

    def position(self) -> tuple[float, float]: ...

    @property
    def resolution_deg(self) -> tuple[float, float]: ...

    def move_time_s(self, pan_from: float, tilt_from: float, pan_to: float, tilt_to: float) -> float:
        """How long such a move takes with the configured speed and acceleration."""
        ...

    def close(self) -> None: ...
