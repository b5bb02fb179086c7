"""The doctor's checks of the rig's parts, each tried the way the service uses it: the pan-tilt
unit, the camera, each laser (switched alone, seen by the camera), the calibration.

The parts are opened one by one (not through :func:`edge.parts.open_parts`, which stops at the first
that fails): a silent pan-tilt unit must not keep the camera and the lasers from being checked.
Everything opened is closed by the caller's exit stack, the lasers first. On a simulated rig the
parts are the simulator's, wired together as ``open_parts`` wires them, on the rig's clock.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import statistics
from typing import TYPE_CHECKING, Any, NamedTuple

from edge.doctor.checklist import Line, NotRun, Problem
from edge.doctor.settings import Settings
from edge.errors import EdgeError

if TYPE_CHECKING:
    from edge.capture import Capture, Shot
    from edge.config import Config
    from edge.doctor.spots import SpotReport, Turn
    from edge.hw.base import Camera, Frame
    from edge.hw.camera import CameraSettings
    from edge.hw.lasers import Lasers
    from edge.hw.ptu import PanTiltUnit
    from edge.rig import Rig
    from edge.sim.ptu_emulator import Emulator

FRAMES = 8  # frames taken to measure the camera's rate and exposure
RATE_TOLERANCE = 0.03  # the shortest frame interval within 3 % of the configured period
WEBCAM_RATE_TOLERANCE = 0.25  # a webcam's frames are dated on delivery: they jitter
EXPOSURE_TOLERANCE = 0.05  # sensors round the exposure to whole lines
SWITCH_LEAD_MS = 2.0  # a laser is switched on this long before a frame starts (a real sleep wakes late)
LIT_AFTER_FRAMES = 3  # a frame this many after the first lit one saw the laser on all through
# A fainter spot's light in one frame is not known to the few percent its timing is judged by: in JPEG
# frames (a webcam's at quality 60, the simulator's at 50) spots of SNR 16-21 read 82-121 % lit.
TIMING_MIN_SNR = 30.0
TIMING_SWITCHES = 2  # switchings whose light is averaged for the timing (see RigChecks.laser)
# In JPEG frames more: JPEG rounds a small spot's blocks anew in every frame, and a spot of SNR 30-50
# read 0.76-1.85 of its light, switching to switching, where the pixels' noise said ±0.05 (a
# rig knocked 1°, evaluation 1142, 320 × 240 at quality 52: two switchings both near 0.76, and a
# false "the light comes 10.9 ms late"; tuning-2497 at 84 %). Their scatter then says how well
# the mean is known (`Shares.mean`), which two cannot tell.
TIMING_SWITCHES_JPEG = 4
LENS_TOLERANCE = 0.05  # dioptres: a focus motor reports back where it is, to its step
# An identity colour matrix comes back within 0.001 of it (libcamera's saturation step rounds);
# a camera's own mixes by 0.4-1.5.
COLOUR_MATRIX_TOLERANCE = 0.02
TONE_FRAMES = 8  # frames averaged at each exposure for the tone curve (flicker averages out)
TURN_FRAMES = 4  # laser-off frames averaged at each of the two aims that tell a spot that stays put
# Laser-off frames taken one after another for the frames line (28 pairs of pure noise). Four left
# the parities of a Pi camera's scaled frames noisy: of the accuracy family's 31 ISP conditions
# (tuning 0-63, 1792-2111), 4 frames named 4 of them demosaiced, 8 none; of 112 Bayer filters at
# their own size (lossless, or JPEG at quality 88 or more), neither took one for scaled frames. On
# the evaluation family (never tuned on): of 43 ISP conditions, 4 frames named 7 demosaiced and 8
# named 1; of 119 such filters, both called one scaled (evaluation-578, JPEG at quality 93), which
# ranging, with its spots' red bends and more looks, never does.
KIND_FRAMES = 8


def _ptu_remedy(message: str) -> str:
    if "garbled" in message:
        return ("set ptu.baudrate to the unit's rate (9600 from the factory), check the cable's "
                "wiring; `edge ptu status` talks to the unit alone")
    if "cannot open" in message:
        return "check ptu.port (ls /dev/ttyUSB* /dev/serial/by-id/), the adapter, and group dialout"
    if "speed" in message:
        return "set ptu.speed_deg_s within what the unit allows"
    return ("check the unit's power supply (12-30 V), the serial cable and adapter, ptu.port and ptu.baudrate "
            "(9600 from the factory); `edge ptu status` talks to the unit alone")


def _camera_remedy(settings: Settings) -> str:
    if settings.camera_backend == "picamera2":
        return ("check the ribbon cable (contacts towards the board on a Pi 4), that nothing else holds the "
                "camera (sudo systemctl stop edge), and rpicam-hello --list-cameras; camera.timeout_s")
    if settings.camera_backend == "opencv":
        return "check the webcam's cable and camera.device (v4l2-ctl --list-devices); camera.timeout_s"
    return "the simulated camera's faults: remove [[sim.camera_faults]]"


class _Switching(NamedTuple):
    """The frames of one switching of a laser (RigChecks._switch)."""

    dark: Shot  # laser-off, before
    off: Shot  # laser-off, the frame before the switch
    on: Shot  # the first frame taken as lit
    full: Frame  # lit all through
    again: Frame  # lit all through, the next one
    after: Shot  # the first frame taken as dark after switching it off


class RigChecks:
    """The rig's checks on one configuration; parts opened are closed by `stack`."""

    def __init__(self, config: Config | None, settings: Settings, stack: contextlib.ExitStack,
                 missing: str | None = None) -> None:
        self.config = config
        self.settings = settings
        self.stack = stack
        self.missing = missing  # why the typed configuration (and so numpy's checks) is unavailable
        self.clock = settings.clock()
        self.unit: PanTiltUnit | None = None
        self.emulator: Emulator | None = None
        self.camera: Camera | None = None
        self.camera_problem: str | None = None
        self.lasers: Lasers | None = None
        self.lasers_problem: str | None = None
        self.capture: Capture | None = None
        self.rig: Rig | None = None  # the rig ranging believes (calibrated, if it is)
        self._pins: Any = None  # the lasers' pin factory (the simulated camera watches it)
        self._sim: dict[str, Any] = {}  # what the simulated camera is opened with
        self._turn: Turn | None = None  # the head's turn, every laser off (`_take_turn`)
        self._turn_taken = False
        self._spots: dict[str, SpotReport] = {}  # each laser's, as its line judged it (`_not_swapped`)
        self._spotted: dict[str, tuple[_Switching, SpotReport, SpotReport]] = {}  # (`_spot`, taken ahead)

    def _typed(self) -> Config:
        if self.config is None:
            raise NotRun("needs numpy, which cannot be imported (see packages)")
        return self.config

    # ---- calibration ----

    def calibration(self) -> str:
        config = self._typed()
        from edge.calibration.in_use import NOMINAL, believed_rig, calibration_file

        self.rig = config.rig.build()
        try:
            believed = believed_rig(config, service=True)
        except EdgeError as exc:
            raise Problem(str(exc), "run `edge calibrate` again, or fix rig.calibration's path") from None
        self.rig = believed.rig
        if believed.health.startswith("fault"):
            raise Problem(believed.health.removeprefix("fault: "),
                          "calibrate again (cmd/calibrate or `edge calibrate`): the rig changed since")
        if believed.health == NOMINAL:
            return (f"none ({calibration_file(config, service=True)} does not exist): ranging uses the "
                    "configured rig; the laser lines show whether the rig is built as configured")
        return believed.health

    # ---- the pan-tilt unit ----

    def ptu(self) -> str:
        from edge.parts import open_ptu

        settings = self.settings
        try:
            unit, emulator = open_ptu(settings.ptu, self.clock, settings.sim.ptu_faults)
        except EdgeError as exc:
            raise Problem(str(exc), _ptu_remedy(str(exc))) from None
        self.stack.callback(unit.close)
        self.unit, self.emulator = unit, emulator
        (pn, px), (tn, tx) = unit.limits_deg
        step_pan, step_tilt = unit.resolution_deg
        pan, tilt = min(10.0, 0.5 * px, -0.5 * pn), min(5.0, 0.5 * tx, -0.5 * tn)
        reached = []
        try:
            for target in ((pan, tilt), (-pan, 0.0)):
                unit.move(*target)
                at = unit.position()
                if abs(at[0] - target[0]) > step_pan or abs(at[1] - target[1]) > step_tilt:
                    raise Problem(f"sent to pan {target[0]:+g}°, tilt {target[1]:+g}°, it reports "
                                  f"pan {at[0]:+.3f}°, tilt {at[1]:+.3f}°",
                                  "check that nothing blocks the head and that its supply holds under load")
                reached.append(f"{target[0]:+g}°/{target[1]:+g}°")
            aim = self._aim()
            unit.move(*aim)
        except EdgeError as exc:
            raise Problem(str(exc), _ptu_remedy(str(exc))) from None
        where = " (emulated)" if emulator is not None else ""
        return (f"{unit.model} on {settings.ptu.port}{where}: {unit.res_arcsec[0]:.4f}″ a position, "
                f"pan {pn:+.2f}…{px:+.2f}°, tilt {tn:+.2f}…{tx:+.2f}°; reached pan/tilt {' and '.join(reached)}, "
                f"now aimed at {aim[0]:+g}°/{aim[1]:+g}° for the laser checks")

    def _aim(self) -> tuple[float, float]:
        """Where the lasers are checked: where the range finder points (``[rangefinder]``)."""
        if self.config is None:
            return 0.0, 0.0
        return self.config.rangefinder.pan_deg, self.config.rangefinder.tilt_deg

    # ---- the camera and the lasers ----

    def _open_camera_and_lasers(self) -> None:
        config = self._typed()
        from edge.capture import Capture
        from edge.parts import laser_factory, open_camera, open_lasers

        pins = None
        try:
            pins = laser_factory(config.lasers, self.clock)
            self.lasers = open_lasers(config, pins, self.clock)
            self.stack.callback(self.lasers.close)
        except EdgeError as exc:  # the pin factory's line says why; the camera may still be tried
            self.lasers_problem = str(exc)
        sim: dict[str, Any] = {}
        if self.emulator is not None:
            sim = {"pose_at": self.emulator.pose, "heading": self.emulator.heading,
                   "pose_step_deg": self.emulator.resolution_arcsec / 3600.0, "scene_epoch_ns": self.clock.now_ns()}
        elif config.camera.backend == "sim":
            sim = {"pose_deg": self._aim(), "scene_epoch_ns": self.clock.now_ns()}
        self._pins, self._sim = pins, sim
        try:
            camera = open_camera(config, pins, self.clock, **sim)
        except EdgeError as exc:
            self.camera_problem = str(exc)
            remedy = "see packages" if "not installed" in str(exc) else _camera_remedy(self.settings)
            raise Problem(str(exc), remedy) from None
        self.stack.callback(camera.close)
        if self.lasers is not None:
            self.stack.callback(self.lasers.close)  # runs before the camera closes: lasers off first
            self.capture = Capture(camera, self.lasers, config, clock=self.clock)
        self.camera = camera

    def camera_check(self) -> str:
        config = self._typed()
        self._open_camera_and_lasers()
        camera = self.camera
        assert camera is not None
        try:
            camera.start()
            frames = [camera.frame_after(self.clock.now_ns())]
            while len(frames) < FRAMES:
                frames.append(camera.frame_after(frames[-1].t_start_ns + 1))
        except EdgeError as exc:
            # The driver's words carry the time asked for, in ns: of no use to a person here.
            why = (f"no frame within {config.camera.timeout_s:g} s of asking (camera.timeout_s)"
                   if str(exc).startswith("camera: no frame") else str(exc))
            self.camera_problem = why
            raise Problem(why, _camera_remedy(self.settings)) from None
        try:
            return self._judge_frames(frames, config)
        except Problem as exc:
            self.camera_problem = exc.detail
            raise

    def _judge_frames(self, frames: list[Frame], config: Config) -> str:
        settings = config.camera
        model = config.rig.build().camera
        shape = frames[0].image.shape
        if (shape[1], shape[0]) != (model.width, model.height):
            raise Problem(f"frames are {shape[1]}x{shape[0]}, the rig's camera is {model.width}x{model.height}",
                          "set rig.camera.model (or width and height) to the camera's mode")
        intervals = [(b.t_start_ns - a.t_start_ns) / 1e6 for a, b in zip(frames, frames[1:])]
        period = 1e3 / settings.frame_rate_hz
        # The shortest interval is the sensor's cadence: a frame we were too slow to collect doubles one.
        shortest = min(intervals)
        tolerance = WEBCAM_RATE_TOLERANCE if settings.backend == "opencv" else RATE_TOLERANCE
        if abs(shortest / period - 1) > tolerance:
            raise Problem(f"frames every {shortest:.1f} ms at best, not {period:.1f} ms "
                          f"({settings.frame_rate_hz:g} fps as camera.frame_rate_hz says)",
                          "the sensor mode cannot keep that rate: shorten camera.exposure_us below the frame "
                          "period, or lower camera.frame_rate_hz")
        exposures = [f.exposure_us for f in frames]
        got = statistics.median(exposures)
        if max(exposures) - min(exposures) > EXPOSURE_TOLERANCE * got:
            raise Problem(f"the exposure changes from frame to frame ({min(exposures):.0f}–{max(exposures):.0f} µs): "
                          "auto exposure is on", "the camera must take AeEnable = False: update picamera2 "
                          "(sudo apt full-upgrade) or, for a webcam, v4l2-ctl -c auto_exposure=1")
        if abs(got / settings.exposure_us - 1) > EXPOSURE_TOLERANCE:
            raise Problem(f"the exposure came back as {got:.0f} µs, not {settings.exposure_us:g} µs",
                          "the sensor mode limits it: keep camera.exposure_us below the frame period")
        gains = [float(f.metadata["AnalogueGain"]) for f in frames if "AnalogueGain" in f.metadata]
        gain = ""
        if gains:
            g = statistics.median(gains)
            if max(gains) - min(gains) > 0.05 * g or abs(g / settings.analogue_gain - 1) > 0.05:
                raise Problem(f"the analogue gain came back as {min(gains):.2f}–{max(gains):.2f}, not "
                              f"{settings.analogue_gain:g}", "the camera must take a fixed AnalogueGain: "
                              "update picamera2 (sudo apt full-upgrade)")
            gain = f", gain {g:.2f}"
        _colours_kept_apart(frames)
        median = statistics.median(intervals)
        stream = self.camera.pixel_format if self.camera is not None else ""  # (a webcam's: YUYV, MJPG)
        return (f"{config.camera.backend} {shape[1]}x{shape[0]}{' ' + stream if stream else ''}: "
                f"{len(frames)} frames every {median:.1f} ms "
                f"({1e3 / median:.1f} fps; {settings.frame_rate_hz:g} configured), exposure {got:.0f} µs fixed "
                f"({settings.exposure_us:g} asked){gain}{_lens(frames, settings.lens_dioptres)}")

    def frames_check(self) -> str:
        """What kind of frames the camera delivers and what ranging makes of them
        (:mod:`edge.doctor.frames`), from KIND_FRAMES laser-off frames where the unit aims."""
        config = self._typed()
        if self.camera_problem is not None or self.camera is None:
            raise NotRun("needs frames from the camera (see camera)")
        if self.capture is None or self.lasers is None:
            raise NotRun(f"needs the lasers' pins, to take frames with every laser off ({self.lasers_problem}; "
                         "see pin factory)")
        from edge.doctor.frames import judge

        try:
            images = [self.capture.take(()).frame.image for _ in range(KIND_FRAMES)]
        except EdgeError as exc:
            raise Problem(str(exc), _camera_remedy(self.settings)) from None
        finally:
            self.lasers.off()
        return judge(images, self.rig if self.rig is not None else config.rig.build(), config)

    def laser(self, name: str, index: int) -> str:
        config = self._typed()
        if self.camera_problem is not None or self.camera is None:
            raise NotRun("needs frames from the camera (see camera)")
        if self.capture is None:
            raise NotRun(f"needs the lasers' pins ({self.lasers_problem}; see pin factory)")
        from edge.doctor.spots import is_jpeg
        from edge.doctor.timing import Shares, judge_timing, light_shares

        rig = self.rig if self.rig is not None else config.rig.build()
        first, report, later = self._spotted.pop(name) if name in self._spotted else self._spot(name, rig, config)
        seen_off = (report.pixel,) if report.pixel is not None else report.lit_off_at
        if report.lit_when_off and seen_off and all(self._room_lit(p, rig) for p in seen_off):
            report = dataclasses.replace(report, lit_when_off=False)
        if report.pixel is None and not report.inverted and not report.lit_when_off:
            if later.pixel is not None and later.from_path_px[name] <= config.ranging.path_tolerance_px:
                report = later  # it lights, but late: the timing below says by how much
        if report.pixel is None and not report.inverted and not report.lit_when_off:
            self._stays_put(name, rig, config)  # (raises where the laser does not go off)
        self._spots[name] = report
        line = _verdict(report, index, config, self._aim(), self._not_swapped(report, rig, config))
        assert report.pixel is not None  # (_verdict raised otherwise)
        if later.snr < TIMING_MIN_SNR:  # (lit all through: a late laser's first frame is fainter)
            return (f"{line}; its timing not judged: the spot is too faint to weigh to a few percent (SNR "
                    f"{later.snr:.0f} lit all through, {TIMING_MIN_SNR:g} needed: aim at a nearer or paler wall)")
        # Its light weighed in TIMING_SWITCHES switchings, averaged: a spot just over the SNR
        # needed, on a bright band of a textured wall behind a Bayer filter, read a healthy
        # laser's dark frame at 0 ± 6 % in one, and 16 % (a false 'goes off later') one time in
        # about a hundred lines.
        switchings = TIMING_SWITCHES_JPEG if is_jpeg(first.off.frame.image) else TIMING_SWITCHES
        cycles = [first] + [self._switch(name, config) for _ in range(switchings - 1)]
        each = [light_shares(c.on.frame.image, c.full.image, c.again.image, c.after.frame.image, c.off.frame.image,
                             report.pixel, config.ranging.frame_gamma) for c in cycles]
        if any(s is None for s in each):
            return f"{line}; its timing not judged (the spot is at the picture's edge)"
        shares = Shares.mean([s for s in each if s is not None])
        # When the spot's row began its exposure (a rolling shutter starts rows one after another).
        frame, settle_ns = first.on.frame, int(round(config.lasers.settle_ms * 1e6))
        row_ns = frame.t_start_ns + int(report.pixel[1] * frame.readout_ns / max(rig.camera.height - 1, 1))
        slack_ms = (row_ns - (first.on.laser_switch_ns + settle_ns)) / 1e6
        return f"{line}; {judge_timing(shares, slack_ms, frame.exposure_us / 1e3, config.lasers.settle_ms)}"

    def _spot(self, name: str, rig: Rig, config: Config) -> tuple[_Switching, SpotReport, SpotReport]:
        """Laser `name` switched alone (`_switch`), and where its spot was: in the frame taken as
        lit, and in one lit all through (`edge.doctor.spots.judge`)."""
        from edge.doctor.spots import judge

        first = self._switch(name, config)
        second = (first.again.image, first.dark.frame.image)  # shares no frame with either pair below
        off = first.off.frame.image
        report = judge(name, first.on.frame.image, off, rig, second, through=first.full.image,
                       blame_px=config.ranging.path_tolerance_px)
        later = judge(name, first.full.image, off, rig, second)  # lit all through: the spot's whole light
        return first, report, later

    def _not_swapped(self, report: SpotReport, rig: Rig, config: Config) -> tuple[str, float] | None:
        """Where `report`'s spot lies on another laser's path (as swapped wires put it), that laser
        and how far from this spot its own lay, switched alone, where that says the wires are not
        swapped: swapped, its spot would lie on this laser's path; a laser knocked off its path
        puts its own spot on the other's. (Knocked 1°, tuning 2560-2591: 3 of 192 lines said
        'swapped' of a centre laser whose spot lay 2.2-5.6 px off its path, on the parallel's,
        4.5-9 px from the parallel's own spot.) None otherwise."""
        name, other_name = report.laser, _on_others_path(report, config.ranging.path_tolerance_px)
        if other_name is None or report.pixel is None:  # (_on_others_path: only where it has a spot)
            return None
        other = self._spots.get(other_name)
        if other is None:  # (not judged yet: its own line takes these frames when it comes)
            self._spotted[other_name] = self._spot(other_name, rig, config)
            other = self._spotted[other_name][1]
        if other.pixel is None or other.nearest == name:
            return None
        gap = math.dist(report.pixel, other.pixel)
        return (other_name, gap) if gap > SAME_SPOT_PX else None

    def _room_lit(self, pixel: tuple[float, float], rig: Rig) -> bool:
        """Is what the laser-off frame showed at a laser's spot (`pixel`) the room's, not the
        laser's: does it move with the room when the head turns (`moves_with_room`)? A red thing
        on the path where the spot falls (a colour webcam's matrix makes a warm object's red
        stand out) read as a spot that does not go off: tuning-2325, the centre and parallel
        lasers both. So, where no spot lit, did a bright fleck of the room on the path (a textured
        cloth in a dim grey frame: tuning-2455; an orange pot's edge: tuning-2453). Where the head
        cannot turn the picture, it is not told: the laser's."""
        from edge.doctor.spots import moves_with_room

        turned = self._the_turn(rig)
        return turned is not None and moves_with_room(turned, pixel)

    def _stays_put(self, name: str, rig: Rig, config: Config) -> None:
        """A Problem if `name`'s spot, every laser off, stays put in the picture while the room
        moves with the head's turn (a laser that does not go off, its spot too faint for the off
        frame alone to show). Nothing where the head cannot turn the picture, or no spot stays."""
        from edge.doctor.spots import stays_put

        turned = self._the_turn(rig)
        if turned is None:
            return
        put = stays_put(name, turned, rig)
        suspects = put.suspects(name)
        if not suspects or put.pixel is None:
            return
        pins = {w.name: w.pin for w in config.rig.wiring()}
        where = (f"with every laser switched off, a spot on its path at ({put.pixel[0]:.1f}, "
                 f"{put.pixel[1]:.1f}) stays put in the picture while the unit turns (SNR {put.snr:.0f})")
        if len(suspects) == 1:
            raise Problem(f"does not go off: {where}", _stuck_remedy(pins[name]))
        also = " or ".join(f"laser {n}" for n in suspects[1:])
        raise Problem(f"it or {also} does not go off: {where}, on {also}'s path too",
                      f"{_stuck_remedy(pins[name])}; and {also}'s, on "
                      + ", ".join(f"GPIO{pins[n]}" for n in suspects[1:]))

    def _the_turn(self, rig: Rig) -> Turn | None:
        """The head's turn, every laser off: taken once, for every laser's line that asks."""
        if not self._turn_taken:
            self._turn, self._turn_taken = self._take_turn(rig), True
        return self._turn

    def _take_turn(self, rig: Rig) -> Turn | None:
        """Every laser off, TURN_FRAMES frames where the unit aims and as many turned a little in
        pan (`spots.turn_deg`), each set averaged, turned back onto each other (`spots.turn`):
        taken once for every laser's line (all lasers are off in them). None where the head
        cannot turn the camera, or the picture did not move with it."""
        from edge.doctor.spots import turn, turn_deg

        if self.unit is None or self.capture is None or self.lasers is None:
            return None
        if self.emulator is not None and self._typed().camera.backend != "sim":
            return None  # the emulated head turns no real camera
        pan, tilt = self._aim()
        (_, most), _ = self.unit.limits_deg
        step = turn_deg(rig)
        try:
            self.lasers.off()
            here = _mean([self.capture.take(()).frame.image for _ in range(TURN_FRAMES)])
            at = self.unit.move(pan + step if pan + step <= most else pan - step, tilt)
            turned = _mean([self.capture.take(()).frame.image for _ in range(TURN_FRAMES)])
        except EdgeError as exc:
            raise Problem(str(exc), _ptu_remedy(str(exc))) from None
        finally:
            self.lasers.off()
            with contextlib.suppress(EdgeError):
                self.unit.move(pan, tilt)
        return turn(here, turned, rig, rig.camera_to_base(pan, tilt).R, rig.camera_to_base(*at).R)

    def _switch(self, name: str, config: Config) -> _Switching:
        """Laser `name` switched on just before a frame starts, and off again, and the frames: two
        dark ones before, the first taken as lit, two lit all through, the first taken as dark
        after. The lasers are off when it returns, whatever happened."""
        assert self.capture is not None and self.camera is not None and self.lasers is not None
        capture, camera = self.capture, self.camera
        period = config.camera.frame_ns
        try:
            dark = capture.take(())  # the dark half of the second pair a spot has to repeat in
            off = capture.take(())
            # Switched on just before a frame starts: the frame taken as lit then starts as soon
            # after the switch as the lasers' timing allows, the tightest a sweep meets.
            lead_ns = int(SWITCH_LEAD_MS * 1e6) + int(round(config.lasers.settle_ms * 1e6))
            start = off.frame.t_start_ns + period
            while start - lead_ns <= self.clock.now_ns():
                start += period
            self.clock.sleep_until_ns(start - lead_ns)
            on = capture.take((name,))
            full = camera.frame_after(on.frame.t_start_ns + LIT_AFTER_FRAMES * period)
            again = camera.frame_after(full.t_start_ns + 1)
            after = capture.take(())
        except EdgeError as exc:
            raise Problem(str(exc), _camera_remedy(self.settings)) from None
        finally:
            self.lasers.off()
        return _Switching(dark, off, on, full, again, after)

    def tone_curve(self) -> str:
        """The camera's tone curve from the laser-off scene at two exposures (edge.doctor.tone),
        after the lasers' checks: the camera is reopened at the second exposure, as the
        service would open it (one camera at a time: libcamera holds it until it is closed)."""
        config = self._typed()
        if self.camera_problem is not None or self.camera is None:
            raise NotRun("needs frames from the camera (see camera)")
        from dataclasses import replace

        from edge.doctor.tone import TooDark, brighter_gain, judge, other_exposure_us

        if getattr(self.camera, "exposure_fixed", True) is False:
            raise NotRun("the webcam refused a fixed exposure (see the log): two exposures cannot be told apart")
        if self.lasers is not None:
            self.lasers.off()
        configured = self._half_means(self.camera, config.camera.exposure_us)
        self.camera.close()
        other_us = other_exposure_us(config.camera)
        other = self._half_means_opened(config.camera, other_us)
        try:
            return judge(configured[0], configured[1], other[0], other[1], config)
        except TooDark:
            # A dim room: the same two exposures again with more analogue gain, which multiplies the
            # light before the camera's curve as the exposure does.
            gain = brighter_gain(configured[0], config.camera)
            if gain is None:
                raise
        settings = replace(config.camera, analogue_gain=gain)
        configured = self._half_means_opened(settings, config.camera.exposure_us)
        other = self._half_means_opened(settings, other_us)
        return f"{judge(configured[0], configured[1], other[0], other[1], config)} (at gain {gain:.1f})"

    def _half_means_opened(self, settings: CameraSettings, exposure_us: float) -> tuple[list[Any], float]:
        """:meth:`_half_means` of the camera opened with `settings` at `exposure_us`, then closed."""
        from dataclasses import replace

        from edge.parts import open_camera

        config = self._typed()
        try:
            camera = open_camera(replace(config, camera=replace(settings, exposure_us=exposure_us)),
                                 self._pins, self.clock, **self._sim)
            self.stack.callback(camera.close)
            camera.start()
            if getattr(camera, "exposure_fixed", True) is False:
                raise NotRun(f"the webcam refused a fixed exposure of {exposure_us:g} µs: two exposures cannot "
                             "be told apart")
            means = self._half_means(camera, exposure_us)
            camera.close()
            return means
        except EdgeError as exc:
            raise Problem(f"at {exposure_us:g} µs: {exc}", _camera_remedy(self.settings)) from None

    def _half_means(self, camera: Camera, exposure_us: float) -> tuple[list[Any], float]:
        """The means of two halves of TONE_FRAMES frames exposed `exposure_us` (0-1 of full scale:
        one half chooses the values the other's are measured by), and their exposure as they report
        it (µs); Problem if the camera does not take that exposure."""
        import numpy as np

        from edge.vision import SpotFinder

        frames = []
        t_ns = self.clock.now_ns()
        for _ in range(3 * TONE_FRAMES):  # (a new exposure may take a few frames to apply)
            frame = camera.frame_after(t_ns)
            t_ns = frame.t_start_ns + 1
            if abs(frame.exposure_us / exposure_us - 1) <= EXPOSURE_TOLERANCE:
                frames.append(frame)
                if len(frames) == TONE_FRAMES:
                    break
        if len(frames) < TONE_FRAMES:
            raise Problem(f"asked for {exposure_us:g} µs, the frames came at {frame.exposure_us:.0f} µs",
                          "the sensor mode limits the exposure: see camera.exposure_us and camera.frame_rate_hz")
        top = SpotFinder.full_scale(frames[0].image)
        half = TONE_FRAMES // 2
        means = [np.mean([f.image for f in part], axis=0, dtype=np.float64) / top
                 for part in (frames[:half], frames[half:])]
        return means, float(np.mean([f.exposure_us for f in frames]))


def _colours_kept_apart(frames: list[Frame]) -> None:
    """A Problem where the ISP mixed the colours: a colour matrix (libcamera's ColourCorrectionMatrix,
    rows R', G', B') other than none in a frame's metadata. Ranging reads a red spot from red; mixed,
    red carries the other channels' noise and their demosaicing (on the simulator, the IMX219's own
    matrix ranged Bayer frames 1.7 × worse, with 4.5 × the 2σ tails). (A webcam tells nothing of its
    matrix, and takes none from us.)"""
    import numpy as np

    from edge.hw.camera import IDENTITY_CCM  # (what edge asks the ISP for)

    for f in frames:
        if "ColourCorrectionMatrix" not in f.metadata:
            continue
        m = np.asarray(f.metadata["ColourCorrectionMatrix"], dtype=float).ravel()
        if m.size == 9 and float(np.abs(m - np.asarray(IDENTITY_CCM)).max()) > COLOUR_MATRIX_TOLERANCE:
            raise Problem(f"the ISP mixes the colours: its colour matrix takes {m[0]:.2f} R {m[1]:+.2f} G "
                          f"{m[2]:+.2f} B for red", "edge asks for none through the sensor's tuning file: look "
                          "for the camera's warning that it could not read it, and update libcamera's tuning "
                          "files (sudo apt full-upgrade)")


def _lens(frames: list[Frame], dioptres: float) -> str:
    """The camera line's words on a focus motor's lens (empty for a camera without one): held
    where camera.lens_dioptres says, in every frame, or a Problem."""
    at = [float(f.metadata["LensPosition"]) for f in frames if "LensPosition" in f.metadata]
    if not at:
        return ""
    if max(abs(a - dioptres) for a in at) > LENS_TOLERANCE:
        raise Problem(f"the lens moved to {min(at):.2f}–{max(at):.2f} dioptres, not held at {dioptres:g} "
                      "(camera.lens_dioptres): something runs autofocus, and the focal length moves with "
                      "the lens", "the camera must take AfMode = Manual: update picamera2 (sudo apt "
                      "full-upgrade), and stop any other program that uses the camera")
    focus = "infinity" if dioptres == 0 else f"{1.0 / dioptres:.2g} m"
    return f", lens held at {dioptres:g} dioptres (in focus at {focus})"


def _mean(images: list[Any]) -> Any:
    """The mean of frames, in their own type (the doctor's spot tests read any bit depth)."""
    import numpy as np

    return (np.mean(images, axis=0) + 0.5).astype(images[0].dtype)


def unseen_lasers(lines: list[Line], lasers: list[str]) -> list[Line]:
    """`lines` with the `lasers`' "does not light" lines amended where no laser's line found a spot
    at this aim (ok, or a spot off its path): a laser that never goes off leaves nothing in the
    laser-on minus laser-off difference either, and a spot too faint to show is too faint for the
    head's turn to tell (`edge.doctor.spots.stays_put`). Where another laser's spot shows, one that
    never went off mostly shows as well (the stuck-laser set, tuning 128-143: 11 of 32 stuck lasers
    read "does not light", 9 of them where no laser's spot showed); not always, above all the
    sloped laser, whose spot lands apart (tuning 2432-2447: 8 of 32), which every "does not light"
    remedy's card check (_CARD_CHECK) is for."""
    mine = [line for line in lines if line.check in lasers]
    if any(line.status == "ok" or line.detail.startswith("spot at") for line in mine):
        return lines
    return [dataclasses.replace(
        line,
        detail=f"{line.detail}; no laser's spot shows at this aim, so a laser that never goes off would look the same",
        remedy="first aim the unit at a nearer matte wall and run the doctor again: a laser that never goes off "
               f"shows its spot there with every laser switched off (eye safety); then: {line.remedy}",
    ) if line.check in lasers and line.status == "fail" and line.detail.startswith("no spot: it does not light")
        else line for line in lines]


# A laser that never goes off leaves no spot in the difference of laser-on and laser-off frames, as
# a dead one does; where its spot is too faint for the laser-off frames and the head's turn to show
# (tuning 2432-2447 with the sloped laser stuck: 8 of 32 aims, the other lasers' spots showing),
# the doctor cannot tell the two apart. The user can, safely, with every laser switched off.
_CARD_CHECK = ("a spot on a card held in front of it now, with every laser switched off, means instead that it "
               "never goes off (a shorted MOSFET: power the lasers down; eye safety)")


def _not_built_remedy(config: Config) -> str:
    calibrated = config.rig.calibration or "a calibration"
    return ("the rig is not built as configured: calibrate it (`edge calibrate`, or cmd/calibrate), "
            f"or, if it had {calibrated}, a laser moved since: fix it and calibrate again")


# Two lasers' spots this near each other may be one spot (`RigChecks._not_swapped`).
SAME_SPOT_PX = 2.0


def _on_others_path(report: SpotReport, tolerance: float) -> str | None:
    """The laser on whose path `report`'s spot lies, within `tolerance`, where it lies off its own
    by more (as swapped wires put it); None otherwise."""
    nearest = report.nearest
    if report.pixel is None or nearest is None or nearest == report.laser:
        return None
    own = report.from_path_px[report.laser]
    return nearest if report.from_path_px[nearest] <= tolerance < own else None


def _stuck_remedy(pin: int | None) -> str:
    return ("a shorted MOSFET or a pin driven by something else: power the lasers down and "
            f"check its driver on GPIO{pin} before running the service (eye safety)")


def _verdict(report: SpotReport, index: int, config: Config, aim: tuple[float, float],
             not_swapped: tuple[str, float] | None = None) -> str:
    """The laser's line from where its spot was (see :mod:`edge.doctor.spots`). `not_swapped`:
    the laser on whose path the spot lies, and how far its own spot lay (`RigChecks._not_swapped`)."""
    name = report.laser
    wiring = {w.name: w for w in config.rig.wiring()}
    key = f"rig.lasers[{index}]"
    tolerance = config.ranging.path_tolerance_px
    if report.pixel is None:
        if report.inverted:
            raise Problem("lit while its pin is off and dark while it is on: the driver is active-low",
                          f"set {key}.active_high = {str(not wiring[name].active_high).lower()} "
                          "(then `edge lasers off` keeps it dark too)")
        if report.lit_when_off:
            raise Problem("does not go off: its spot shows with every laser switched off",
                          _stuck_remedy(wiring[name].pin))
        lo, hi = config.rig.range_limits_m
        from edge.doctor.spots import ROUNDED_SHARE

        if report.rounded is not None and report.rounded >= ROUNDED_SHARE:
            # (JPEG's rounding leaves most of the difference exactly 0: its noise, and so the
            # strongest change's SNR, says little; the spot may be gone with it.)
            raise Problem(f"no spot: it does not light, or JPEG rounded its spot away ({100 * report.rounded:.0f} % "
                          "of the laser-on and laser-off frames' pixels are equal: a faint or small spot goes "
                          "with the rest of their difference)",
                          f"aim the unit at a nearer or paler matte wall ({lo:g}–{hi:g} m; [rangefinder] pan_deg, "
                          f"tilt_deg; now pan {aim[0]:+g}°, tilt {aim[1]:+g}°), or have the camera deliver frames "
                          'that are not JPEG (a webcam: camera.pixel_format = "YUYV"), and run the doctor again; '
                          f"if it still shows no spot, check its supply, its MOSFET and the wire from "
                          f"GPIO{wiring[name].pin} ({key}.pin); {_CARD_CHECK}")
        once = ", where the frames are that noisy, or once and not again: no spot" if report.fleeting else ""
        raise Problem(f"no spot: it does not light (strongest change {report.snr:.1f}× the noise{once})",
                      f"check its supply, its MOSFET and the wire from GPIO{wiring[name].pin} ({key}.pin); "
                      f"{_CARD_CHECK}; or nothing lies {lo:g}–{hi:g} m in front of it at pan {aim[0]:+g}°, "
                      f"tilt {aim[1]:+g}°: aim the unit at a matte wall ([rangefinder] pan_deg, tilt_deg)")
    u, v = report.pixel
    own = report.from_path_px[name]
    where = f"spot at ({u:.1f}, {v:.1f})"
    if report.lit_when_off:
        raise Problem(f"{where}, but it also shows with every laser switched off: it does not go off",
                      f"check its driver on GPIO{wiring[name].pin} (a shorted MOSFET?) before running the service")
    nearest = _on_others_path(report, tolerance)
    if nearest is not None and not_swapped is None:
        raise Problem(f"{where} lies on laser {nearest}'s path, {own:.1f} px from its own: switching {name} "
                      f"lights {nearest}", f"the wires of GPIO{wiring[name].pin} and GPIO{wiring[nearest].pin} are "
                      f"swapped: swap them, or swap the pins in {key}.pin and the other laser's pin")
    if own > tolerance and report.broad and min(report.from_path_px.values()) > tolerance:
        # (Its own spot out of sight, the laser may as well never go off: its spot then leaves the
        # difference, and a JPEG block of a dark room that flipped in step with the switching took
        # its place, 383 px from its path: evaluation 1153, the parallel laser stuck. Hence the
        # card check here too.)
        lo, hi = config.rig.range_limits_m
        raise Problem(f"no spot on its path, only a broad glow at ({u:.0f}, {v:.0f}), SNR {report.snr:.0f}, "
                      f"{own:.0f} px from it: its light reflected or scattered there (glass, a glossy surface), "
                      "its spot out of sight",
                      f"aim the unit at a matte wall {lo:g}–{hi:g} m away ([rangefinder] pan_deg, tilt_deg; now "
                      f"pan {aim[0]:+g}°, tilt {aim[1]:+g}°) and run the doctor again; {_CARD_CHECK}")
    from edge.doctor.spots import placed_to_px

    unsure = placed_to_px(report.snr)
    if tolerance < own <= tolerance + unsure:
        # (Past ranging's reach by less than the doctor places such a spot to: no word on the build.)
        lo, hi = config.rig.range_limits_m
        then = (f"aim at a nearer or paler wall ({lo:g}–{hi:g} m) and run the doctor again to be sure"
                if report.snr < TIMING_MIN_SNR else "if ranging loses this laser's spots, calibrate (`edge calibrate`)")
        return (f"{where}, {own:.2f} px from its path where ranging keeps {tolerance:g} px: within what a spot of "
                f"SNR {report.snr:.0f} is placed to here (± {unsure:.1f} px), no sign that the rig is built "
                f"otherwise; {then}")
    if own > tolerance:
        beside = ("" if not_swapped is None else f", on laser {not_swapped[0]}'s path, but laser {not_swapped[0]} "
                  f"switched alone lit its own spot {not_swapped[1]:.1f} px from it: not swapped wires")
        raise Problem(f"{where} is {own:.1f} px from where the rig says it can be (ranging keeps spots within "
                      f"{tolerance:g} px, ranging.path_tolerance_px){beside}", _not_built_remedy(config))
    return f"{where}, {own:.2f} px from its path (at about {report.depth_m:.1f} m), SNR {report.snr:.0f}; off: dark"
