"""The configured parts of the rig, opened together and closed together.

``open_parts(config)`` brings up the pan-tilt unit, the lasers and the camera named by the
configuration — real ones, or the simulated ones wired to each other (the emulated unit's pose and
the mock laser pins drive the simulated camera) — and closes them, lasers first, however the block
ends. For a simulated rig it also knows the truth: each zone's true range and the room's floor plan.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from edge.capture import Capture
from edge.config import Config
from edge.hw.base import Camera, LaserBank, PanTilt
from edge.mapping import Segment


@dataclass
class Parts:
    config: Config
    ptu: PanTilt
    lasers: LaserBank
    camera: Camera
    capture: Capture
    emulator: Any = None  # the PTU emulator when ptu.port is sim://
    truths: dict[int, dict] = field(default_factory=dict)  # zone index → truth (simulator only)

    @property
    def simulated(self) -> bool:
        return getattr(self.camera, "renderer", None) is not None

    def truth(self, index: int, pan_deg: float, tilt_deg: float) -> dict | None:
        """The simulator's truth for a zone seen from (pan, tilt) now; None on real parts."""
        renderer = getattr(self.camera, "renderer", None)
        if renderer is None:
            return None
        from edge.sim.record import zone_truth

        t_s = (time.monotonic_ns() - self.camera.scene_epoch_ns) / 1e9
        spots = renderer.spots(pan_deg, tilt_deg, t_s)
        self.truths[index] = zone_truth(renderer.rig, spots, renderer.rig.camera_to_base(pan_deg, tilt_deg))
        return self.truths[index]

    def room(self) -> list[Segment]:
        """The simulated room's floor plan in the base frame (empty on real parts)."""
        renderer = getattr(self.camera, "renderer", None)
        if renderer is None:
            return []
        from edge.mapping import room_in_base_frame

        return room_in_base_frame(renderer.scene.floor_plan(), renderer.scene.base_to_world())


@contextlib.contextmanager
def open_parts(config: Config) -> Iterator[Parts]:
    """The configured parts, started; lasers off and everything closed when the block ends."""
    from edge.hw.camera import open_camera
    from edge.hw.lasers import open_lasers
    from edge.hw.ptu import open_ptu

    with contextlib.ExitStack() as stack:
        unit, emulator = open_ptu(config.ptu)
        stack.callback(unit.close)
        lasers = open_lasers(config)
        stack.callback(lasers.close)  # runs before the unit's: lasers off first
        world = None
        if emulator is not None:
            # The simulated scene's clock (its movers) starts with the rig, not with the machine.
            world = {"factory": lasers.factory, "pose_at": emulator.pose, "heading": emulator.heading,
                     "pose_step_deg": emulator.resolution_arcsec / 3600.0, "scene_epoch_ns": time.monotonic_ns()}
        camera = open_camera(config, world)
        camera.start()
        stack.callback(camera.stop)
        yield Parts(config, unit, lasers, camera, Capture(camera, lasers, config), emulator)
