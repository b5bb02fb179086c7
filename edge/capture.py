"""Frames in step with the lasers: never a frame that was exposed while they switched.

The straightforward way — switch the lasers, take the next frame — gets a frame that was already
being exposed when the lasers switched: with a rolling shutter its rows above some line saw the
old state and those below the new one, so a spot comes out partly lit, or not at all, and its
centroid and brightness are wrong. :class:`Capture` instead switches, learns when the new state
has taken effect (the GPIO write plus the driver's settle time), and takes the first frame whose
*first* row started exposing after that; since every later row starts later, the whole frame saw
only the new state. The lasers do not switch again before that frame has been read out (the next
switch happens after it is delivered; a watchdog switch in between is detected and the frame
taken again). Frames skipped because they straddled a switch are counted in ``dropped``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from typing import NamedTuple

import numpy as np

from edge.clock import REAL, Clock
from edge.config import Config
from edge.errors import CameraError, LaserError
from edge.hw.base import Camera, Frame, LaserBank

log = logging.getLogger(__name__)

# A frame rejected this many times in a row (the lasers kept switching under it) is a fault.
_MAX_RETAKES = 3


def _names(lasers_on: Iterable[str]) -> frozenset[str]:
    return frozenset((lasers_on,) if isinstance(lasers_on, str) else lasers_on)


class Shot(NamedTuple):
    """A frame with the lasers that were on for all of it and when they last switched (the
    recording's ``lasers_on`` and ``laser_switch_ns``)."""

    frame: Frame
    lasers_on: tuple[str, ...]
    laser_switch_ns: int


class Capture:
    """Takes frames with given lasers on, synchronised to the lasers' switching."""

    def __init__(
        self, camera: Camera, lasers: LaserBank, config: Config | None = None, *, timeout_s: float | None = None,
        on_frame: Callable[[Frame], None] | None = None, clock: Clock = REAL,
    ) -> None:
        self.camera = camera
        self.lasers = lasers
        self.clock = clock  # the rig's: the camera's frames and the lasers' switches are timed on it
        # Told of every frame the camera delivers, used or not: a sign of life (the blind aid's).
        self.on_frame = on_frame
        # How long to wait for one frame: `timeout_s`, else [camera] timeout_s.
        self.timeout_s = timeout_s if timeout_s is not None else (config or Config()).camera.timeout_s
        self.dropped = 0  # frames not used because their exposure overlapped a laser switch
        # (width, height) every frame must have; from the configured rig's camera.
        self.frame_size: tuple[int, int] | None = None
        if config is not None:
            cam = config.rig.build().camera
            self.frame_size = (cam.width, cam.height)

    def _order(self, names: Iterable[str]) -> tuple[str, ...]:
        wanted = set(names)
        return tuple(n for n in self.lasers.names if n in wanted)

    def take(self, lasers_on: Iterable[str], not_before_ns: int | None = None) -> Shot:
        """Switch to exactly `lasers_on` and return the first frame exposed wholly in that state
        and wholly after `not_before_ns` (default: now — a frame begun before the call may show
        the unit before it stopped moving)."""
        on = _names(lasers_on)
        not_before = self.clock.now_ns() if not_before_ns is None else int(not_before_ns)
        for _ in range(_MAX_RETAKES + 1):
            before = self.lasers.last_switch_ns
            effective = self.lasers.set(on)
            switch_ns = self.lasers.last_switch_ns
            frame = self.camera.frame_after(max(effective, not_before), self.timeout_s)
            if self.on_frame is not None:
                self.on_frame(frame)
            self._check(frame)
            if switch_ns != before:
                self.dropped += self._straddlers(frame, switch_ns, effective)
            later = self.lasers.last_switch_ns
            # A later switch (the watchdog's) only spoils the frame if it came before its end.
            if frame.t_start_ns >= effective and (later == switch_ns or later >= frame.t_end_ns):
                return Shot(frame, self._order(on), switch_ns)
            self.dropped += 1
            log.warning("frame %d overlapped a laser switch at %d: taking another", frame.sequence, later)
        raise LaserError(f"capture: the lasers kept switching during the exposure ({_MAX_RETAKES + 1} tries)")

    def _check(self, frame: Frame) -> None:
        """A frame of the wrong size or type is a torn or foreign buffer: a camera fault."""
        want = self.frame_size
        image = frame.image
        if want is not None and (image.shape[1], image.shape[0]) != want:
            raise CameraError(f"camera: frame {frame.sequence} is {image.shape[1]}x{image.shape[0]}, "
                              f"expected {want[0]}x{want[1]} (a torn or corrupt frame)")
        if image.dtype not in (np.uint8, np.uint16):
            raise CameraError(f"camera: frame {frame.sequence} has pixels of type {image.dtype}, "
                              "expected uint8 or uint16")

    def _straddlers(self, frame: Frame, switch_ns: int, effective_ns: int) -> int:
        """How many frames just before `frame` were being exposed while the switch at `switch_ns`
        took effect (so were skipped for it), reckoned back along the frame clock."""
        span = frame.t_end_ns - frame.t_start_ns
        period = self.camera.frame_ns or span
        # Frame j before this one starts at t − j·period; it straddled if it started before the
        # switch took effect and ended after the switch began.
        j_min = max((frame.t_start_ns - effective_ns) // period + 1, 1)
        j_max = -((switch_ns - span - frame.t_start_ns) // period) - 1
        return max(0, j_max - j_min + 1)

    def naive_take(self, lasers_on: Iterable[str]) -> Shot:
        """The straightforward way, kept to show why :meth:`take` exists: switch, then take the
        next frame the camera delivers — most often one whose exposure the switch cut through."""
        on = _names(lasers_on)
        self.lasers.set(on)
        switch_ns = self.lasers.last_switch_ns
        # The next frame delivered is the one in progress: it began within a frame period before.
        frame = self.camera.frame_after(switch_ns - self.camera.frame_ns, self.timeout_s)
        return Shot(frame, self._order(on), switch_ns)

    def zone(
        self,
        pairs: int,
        nudge: Callable[[int], None] | None = None,
        lasers_on: Iterable[str] | None = None,
    ) -> list[Shot]:
        """`pairs` laser-off/laser-on frame pairs: off, on, off, on, … Before pair i ≥ 1,
        ``nudge(i)`` (if given) moves the unit a little (fresh speckle) and returns when it has
        stopped; frames are taken only after it returns. The lasers are off at the end, always."""
        on = tuple(self.lasers.names if lasers_on is None else lasers_on)
        shots: list[Shot] = []
        try:
            for i in range(pairs):
                not_before = None
                if i and nudge is not None:
                    self.lasers.off()  # no beam on while the unit moves
                    nudge(i)
                    not_before = self.clock.now_ns()
                shots.append(self.take((), not_before))
                shots.append(self.take(on))
        finally:
            self.lasers.off()
        return shots
