"""The configured parts of the rig, opened together and closed together: the composition root.

This is the one place that chooses backends, as gpiozero's pin factories and pyserial's URL
handlers do: the drivers of :mod:`edge.hw` never know whether they drive hardware or the simulator.
For a simulated rig the simulator's parts are peers of the real ones, wired to each other here —
the real PTU-D46 driver talks to the emulated unit on a pseudo-terminal, the real laser driver
switches mock pins, and the simulated camera renders what the unit's pose and those pins say. A
simulated rig also knows the truth: each zone's true range and the room's floor plan.

``open_parts(config)`` opens the pan-tilt unit, the lasers and the camera, starts the camera, and
closes everything however the block ends: the lasers first (eye safety), then the camera (released
once), then the unit.

All parts of a rig keep one time, the rig's clock (:func:`rig_clock`): real time on real parts, and
simulated time for an all-simulated rig unless ``sim.clock = "real"`` (see :mod:`edge.clock`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from edge.clock import REAL, Clock, SimClock
from edge.errors import CameraError
from edge.hw.base import Camera, LaserBank, PanTilt
from edge.hw.lasers import Lasers, LasersConfig, default_factory
from edge.hw.ptu import PanTiltUnit, PtuConfig

if TYPE_CHECKING:  # light at import: `edge lasers off` takes its laser_factory() from here
    from edge.capture import Capture
    from edge.config import Config
    from edge.mapping import Segment
    from edge.sim.ptu_emulator import Emulator
    from edge.sim.render import Renderer

log = logging.getLogger(__name__)


@dataclass
class SimWorld:
    """What ties a simulated rig's parts together: the emulated unit, the mock laser pins, and the
    scene's clock, which starts with the rig (the scene's movers are timed from it)."""

    emulator: Emulator
    factory: Any  # edge.sim.gpio.LaserFactory
    epoch_ns: int  # on the rig's clock
    clock: Clock = REAL
    renderer: Renderer | None = None  # the simulated camera's, once it is open


@dataclass
class Parts:
    config: Config
    ptu: PanTilt
    lasers: LaserBank
    camera: Camera
    capture: Capture
    world: SimWorld | None = None  # a simulated rig's wiring and truth; None on real parts
    button: Any = None  # the blind aid's "how far?" push button (a gpiozero Button), if wired
    truths: dict[int, dict] = field(default_factory=dict)  # zone index → truth (simulator only)
    clock: Clock = REAL  # the rig's: what its parts time themselves on

    @property
    def simulated(self) -> bool:
        """A simulated camera sees the scene: the truth of what it sees is known."""
        return self.world is not None and self.world.renderer is not None

    @property
    def emulator(self) -> Emulator | None:
        """The emulated pan-tilt unit of a simulated rig (tests inject its faults)."""
        return self.world.emulator if self.world is not None else None

    def truth(self, index: int, pan_deg: float, tilt_deg: float) -> dict | None:
        """The simulator's truth for a zone seen from (pan, tilt) now; None on real parts."""
        if self.world is None or self.world.renderer is None:
            return None
        from edge.sim.record import zone_truth

        renderer = self.world.renderer
        t_s = (self.world.clock.now_ns() - self.world.epoch_ns) / 1e9
        spots = renderer.spots(pan_deg, tilt_deg, t_s)
        self.truths[index] = zone_truth(renderer.rig, spots, renderer.rig.camera_to_base(pan_deg, tilt_deg))
        return self.truths[index]

    def foresee(self, views: list[tuple[float, float]]) -> None:
        """The views the rig visits next (the sweep's next zone): a simulated camera renders them
        ahead, on another core; real parts need no such hint."""
        from edge.sim.camera import SimCamera

        if isinstance(self.camera, SimCamera):
            self.camera.foresee(views)

    def room(self) -> list[Segment]:
        """The simulated room's floor plan in the base frame (empty on real parts)."""
        if self.world is None or self.world.renderer is None:
            return []
        from edge.mapping import room_in_base_frame

        renderer = self.world.renderer
        return room_in_base_frame(renderer.scene.floor_plan(), renderer.scene.base_to_world())


def all_simulated(config: Config) -> bool:
    """Every part of the rig is the simulator's: only then can the rig keep simulated time."""
    return (config.camera.backend == "sim" and config.lasers.backend == "sim"
            and config.ptu.port.startswith("sim://"))


def rig_clock(config: Config) -> Clock:
    """The rig's clock: simulated for an all-simulated rig under ``sim.clock = "simulated"`` (the
    default) or ``"paced"``, else real time."""
    if config.sim.clock != "real" and all_simulated(config):
        return SimClock(paced=config.sim.clock == "paced", pace=config.sim.pace)
    return REAL


def open_ptu(settings: PtuConfig, clock: Clock = REAL,
             faults: tuple[Any, ...] = ()) -> tuple[PanTiltUnit, Emulator | None]:
    """An initialised unit; for ``sim://`` the emulator on a pty, opened through the real driver,
    broken from the start as `faults` (``sim.ptu_faults``) say.

    The unit owns the emulator it was opened on: ``unit.close()`` stops it too.
    """
    if not settings.port.startswith("sim://"):
        return PanTiltUnit.open(settings, clock=clock), None
    from edge.sim.ptu_emulator import Emulator

    # The emulated unit has the wide pan range (±180°) so that the default 64-zone full turn is
    # reachable; a standard D46-17 stops at ±159° and the sweep marks the zones beyond as faults.
    emulator = Emulator(pan_limits=(-3500, 3500), clock=clock)
    for fault in faults:  # edge.sim.settings.PtuFault: a unit without power, or at another baud rate
        if fault.kind == "silent":
            emulator.inject("hang")
        else:
            emulator.inject("garble", count=1 << 30)
    try:
        unit = PanTiltUnit.open(dataclasses.replace(settings, port=emulator.port), on_close=emulator.close,
                                clock=clock)
    except BaseException:
        emulator.close()
        raise
    return unit, emulator


def laser_factory(settings: LasersConfig, clock: Clock = REAL) -> Any:
    """The gpiozero pin factory of ``[lasers] backend``: the default one for ``gpio``, the
    simulator's mock laser pins (their changes timed on `clock`) for ``sim``."""
    if settings.backend == "sim":
        from edge.sim.gpio import laser_factory as sim_factory

        return sim_factory(settings.sim_wires or None, clock)
    return default_factory()


def open_lasers(config: Config, factory: Any = None, clock: Clock = REAL) -> Lasers:
    """The configured lasers (``[lasers]``, pins and polarity from ``[[rig.lasers]]``), all off."""
    factory = factory if factory is not None else laser_factory(config.lasers, clock)
    return Lasers(config.rig.wiring(), config.lasers, factory, clock)


def open_camera(config: Config, factory: Any = None, clock: Clock = REAL, **sim: Any) -> Camera:
    """The configured camera (``[camera] backend``), not yet started.

    The simulated camera watches the simulated lasers' pins: give their pin `factory`, and as `sim`
    what else :class:`edge.sim.camera.SimCamera` takes (``pose_at``, ``heading``, …).
    """
    settings = config.camera
    model = config.rig.build().camera
    if settings.backend == "picamera2":
        from edge.hw.camera import PICAM_V2_BINNED, PICAM_V2_SENSOR, Picamera2Camera
        from edge.rig import CAMERA_MODELS

        named = config.rig.camera.model
        raw = PICAM_V2_BINNED if named.startswith("picam-v2") else None
        # (A model's own numbers are its sensor's: numbers of the user's own are checked by nobody.)
        sensor = PICAM_V2_SENSOR if raw is not None and model == CAMERA_MODELS[named] else None
        return Picamera2Camera(settings, (model.width, model.height), raw_size=raw, sensor=sensor)
    if settings.backend == "opencv":
        from edge.hw.camera import OpenCVCamera

        return OpenCVCamera(settings, (model.width, model.height))
    if factory is None:
        raise CameraError("camera: the simulated camera needs the simulated lasers' pin factory")
    from edge.sim.camera import SimCamera

    return SimCamera.from_config(config, factory, clock=clock, **sim)


@contextlib.contextmanager
def open_parts(config: Config, clock: Clock | None = None) -> Iterator[Parts]:
    """The configured parts, started, on `clock` (default: :func:`rig_clock`); lasers off and
    everything closed when the block ends."""
    from edge.capture import Capture

    clock = clock if clock is not None else rig_clock(config)
    if config.sim.clock != "real" and not clock.simulated and any(
            (config.camera.backend == "sim", config.lasers.backend == "sim", config.ptu.port.startswith("sim://"))):
        log.info("the rig has real parts: it runs on real time (sim.clock applies to an all-simulated rig)")
    with contextlib.ExitStack() as stack:
        unit, emulator = open_ptu(config.ptu, clock, config.sim.ptu_faults)
        stack.callback(unit.close)
        pins = laser_factory(config.lasers, clock)  # the rig's GPIO: real, or the simulator's mock pins
        lasers = open_lasers(config, pins, clock)
        stack.callback(lasers.close)
        button = None
        if config.blindaid.speak_button_pin:
            from gpiozero import Button

            button = Button(config.blindaid.speak_button_pin, pull_up=True, bounce_time=0.05, pin_factory=pins)
            stack.callback(button.close)
        world = None
        sim: dict[str, Any] = {}
        if emulator is not None:
            world = SimWorld(emulator, pins, clock.now_ns(), clock)
            sim = {"pose_at": emulator.pose, "heading": emulator.heading,
                   "pose_step_deg": emulator.resolution_arcsec / 3600.0, "scene_epoch_ns": world.epoch_ns}
        camera = open_camera(config, pins, clock, **sim)
        stack.callback(camera.close)
        stack.callback(lasers.close)  # runs first: lasers off before anything else closes
        if world is not None:
            from edge.sim.camera import SimCamera

            world.renderer = camera.renderer if isinstance(camera, SimCamera) else None
        camera.start()
        yield Parts(config, unit, lasers, camera, Capture(camera, lasers, config, clock=clock), world, button=button,
                    clock=clock)
