"""The range finder: one direction, one range per camera frame.

The lasers alternate frame by frame — off, on, off, on — and every new frame is ranged together
with the one before it (an on frame against the off frame before it, an off frame against the on
frame before it), so each frame gives a range, not each pair. The ranges go through
:class:`RangeFilter`, a short robust filter that ignores a lone outlier yet follows a target that
really moved within a couple of frames.

Published per frame (``range`` topic): the zone result of the newest pair, as geometry.md defines
it (``range_m`` and ``sigma_m`` are that pair's own measurement), plus ``filtered_m`` and
``filtered_sigma_m`` (the filter's output), ``frame`` (the camera's frame number) and ``rate_hz``.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from edge.capture import Capture
from edge.errors import HardwareError
from edge.ranging import FAULT, OK, FrameGroup, Ranger, ZoneResult


@dataclass(frozen=True)
class Filtered:
    range_m: float
    sigma_m: float


@dataclass
class RangeFilter:
    """Median of the last `window` ranges, restarted when the target has clearly moved.

    A median of 5 ignores up to two outliers in a row. A real change shows as the newest `follow`
    readings all lying beyond `k`·σ of the median on the same side: then the window keeps only
    them, so a step is followed after `follow` frames instead of half a window's worth.
    """

    window: int = 5
    follow: int = 2
    k: float = 3.0
    _values: deque = field(default_factory=deque, repr=False)

    def reset(self) -> None:
        self._values.clear()

    def add(self, range_m: float, sigma_m: float) -> Filtered:
        self._values.append((range_m, max(sigma_m, 1e-6)))
        while len(self._values) > self.window:
            self._values.popleft()
        values = list(self._values)
        if len(values) > self.follow:
            centre = statistics.median(v for v, _ in values)
            recent = values[-self.follow:]
            sides = {math.copysign(1.0, v - centre) for v, s in recent if abs(v - centre) > self.k * s}
            if len(sides) == 1 and all(abs(v - centre) > self.k * s for v, s in recent):
                self._values = deque(recent)
                values = recent
        ranges = sorted(v for v, _ in values)
        median = statistics.median(ranges)
        # σ of a median of n readings ≈ 1.25·σ/√n (for n ≥ 3; the mean's for fewer).
        sigma = statistics.median(s for _, s in values) * (1.25 if len(values) >= 3 else 1.0) / math.sqrt(len(values))
        return Filtered(median, sigma)


class Rangefinder:
    """Ranges one direction frame by frame with opened parts (``edge.parts``)."""

    def __init__(self, capture: Capture, ranger: Ranger, lasers: tuple[str, ...]) -> None:
        self.capture = capture
        self.ranger = ranger
        self.lasers = lasers
        self.filter = RangeFilter()

    def run(
        self,
        pan_deg: float,
        tilt_deg: float,
        on_range: Callable[[ZoneResult, Filtered | None, dict], None],
        should_stop: Callable[[], bool],
        max_frames: int | None = None,
    ) -> int:
        """Range until `should_stop()` (checked every frame) or `max_frames`; returns frames used.
        The unit must already point at (pan, tilt). Lasers are off when it returns."""
        self.filter.reset()
        previous = None
        frames = 0
        clock = self.capture.clock
        started = clock.now_ns()
        lit = False
        try:
            while not should_stop() and (max_frames is None or frames < max_frames):
                try:
                    shot = self.capture.take(self.lasers if lit else ())
                except HardwareError as exc:
                    on_range(ZoneResult(-1, pan_deg, tilt_deg, FAULT, detail=str(exc), part=exc.part), None, {})
                    previous = None
                    continue
                frames += 1
                if previous is not None:
                    on, off = (shot, previous) if lit else (previous, shot)
                    group = FrameGroup([on.frame.image], [off.frame.image], on.lasers_on, (pan_deg, tilt_deg))
                    result = self.ranger.range_zone(-1, pan_deg, tilt_deg, [group])
                    filtered = None
                    if result.status == OK and result.range_m is not None:
                        filtered = self.filter.add(result.range_m, result.sigma_m or 0.0)
                    elapsed = (clock.now_ns() - started) / 1e9
                    on_range(result, filtered, {"frame": shot.frame.sequence,
                                                "rate_hz": round((frames - 1) / elapsed, 2) if elapsed > 0 else None})
                previous = shot
                lit = not lit
        finally:
            self.capture.lasers.off()
        return frames


def range_payload(result: ZoneResult, filtered: Filtered | None, extra: dict) -> dict:
    """The ``range`` topic's payload for one frame (see the module notes)."""
    out = result.to_json()
    out["filtered_m"] = None if filtered is None else round(filtered.range_m, 5)
    out["filtered_sigma_m"] = None if filtered is None else round(filtered.sigma_m, 5)
    out.update(extra)
    return out
