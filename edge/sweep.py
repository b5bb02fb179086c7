"""The sweep: for each zone move, settle, capture the laser-off/laser-on frames, range, hand on.

Written against the driver interfaces (``edge.hw.base``), so the same code runs the Pi's parts and
the simulated ones. A part that fails for a zone makes that zone a ``fault`` and the sweep goes on;
a part that keeps failing (the unit hung, the camera gone) ends the sweep with a clear error. The
lasers are off between zones and whenever anything goes wrong (``edge.capture``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from edge.capture import Capture
from edge.config import Config
from edge.errors import HardwareError
from edge.hw.base import PanTilt
from edge.ranging import FAULT, FrameGroup, Ranger, ZoneResult
from edge.recording import RecordingWriter

log = logging.getLogger(__name__)

# This many zones failing in a row means the part is gone, not hiccuping: end the sweep.
MAX_FAULTS_IN_A_ROW = 3


@dataclass
class SweepReport:
    results: list[ZoneResult] = field(default_factory=list)
    duration_s: float = 0.0  # on the rig's clock: what the rig took (simulated time on a simulated rig)
    wall_s: float = 0.0  # what the computer took (on a simulated clock: mostly rendering)
    simulated_time: bool = False  # duration_s is simulated time
    limit_s: float = 0.0  # what the camera's frame rate and the unit's motion allow at best
    dropped_frames: int = 0  # frames exposed across a laser switch, never used

    @property
    def faults(self) -> int:
        return sum(r.status == FAULT for r in self.results)


def sweep_limit_s(
    config: Config, ptu: PanTilt, views: Sequence[Sequence[tuple[float, float]]], start: tuple[float, float]
) -> float:
    """The fastest a sweep can be: per zone, its `views` (the zone's pose and its speckle nudges)
    each reached as fast as the configured speed and acceleration allow, let settle for
    ``ptu.settle_ms``, and filmed for one laser-off and one laser-on frame period."""
    frame_s = config.camera.frame_ns / 1e9
    settle_s = config.ptu.settle_ms / 1000.0
    total, here = 0.0, start
    for zone in views:
        for target in zone:
            total += ptu.move_time_s(here[0], here[1], *target) + settle_s + 2 * frame_s
            here = target
    return total


def zone_views(config: Config, pan: float, tilt: float,
               pan_limits: tuple[float, float] | None = None) -> list[tuple[float, float]]:
    """Where the unit points for each of a zone's laser-off/laser-on pairs: the zone's pose, then
    the speckle nudges; a nudge that would pass a pan limit goes the other way instead."""
    views = []
    for nudge in config.sweep.nudges_deg():
        p = pan + nudge
        if pan_limits is not None and not pan_limits[0] <= p <= pan_limits[1]:
            p = pan - nudge
        views.append((p, tilt))
    return views


def visiting_order(poses: Sequence[tuple[float, float]], start: tuple[float, float],
                   move_s: Callable[[tuple[float, float], tuple[float, float]], float] | None = None) -> list[int]:
    """Zone indices in the order to visit them, keeping the unit's moves short: a serpentine over
    the tilt levels — one pass in pan at a tilt, back at the next — or over the pans (every tilt at
    a pan, then the next pan), whichever takes less time by `move_s(from, to)` (default: the
    longer axis's angle), started from the corner nearer to where the unit is. A single tilt
    level is one pass in pan from the nearer end (a full turn read in index order would swing the
    head round by 354° at the wrap)."""
    if not poses:
        return []
    cost = move_s or (lambda a, b: max(abs(a[0] - b[0]), abs(a[1] - b[1])))

    def serpentine(major: int) -> list[int]:
        levels = sorted({p[major] for p in poses})
        rows = [sorted((i for i in range(len(poses)) if poses[i][major] == level),
                       key=lambda i: (poses[i][1 - major], poses[i][major])) for level in levels]
        return [i for k, row in enumerate(rows) for i in (row if k % 2 == 0 else row[::-1])]

    def total(order: list[int]) -> float:
        here, t = start, 0.0
        for i in order:
            t += cost(here, poses[i])
            here = poses[i]
        return t

    candidates = []
    for major in (1, 0):  # rows of one tilt (the usual), then columns of one pan
        order = serpentine(major)
        candidates += [order, order[::-1]]
        # Mirrored within each row: starting the first row from its other end.
        mirrored = serpentine_mirrored(poses, order, major)
        candidates += [mirrored, mirrored[::-1]]
    return min(candidates, key=total)


def serpentine_mirrored(poses: Sequence[tuple[float, float]], order: list[int], major: int) -> list[int]:
    """`order` (a serpentine) with every row run the other way."""
    rows: list[list[int]] = []
    for i in order:
        if rows and poses[rows[-1][0]][major] == poses[i][major]:
            rows[-1].append(i)
        else:
            rows.append([i])
    return [i for row in rows for i in row[::-1]]


class Sweeper:
    """Runs sweeps with one set of parts."""

    def __init__(
        self,
        config: Config,
        ptu: PanTilt,
        capture: Capture,
        ranger: Ranger,
        on_zone: Callable[[ZoneResult], None] | None = None,
        truth: Callable[[int, float, float], dict | None] | None = None,
        foresee: Callable[[list[tuple[float, float]]], None] | None = None,
    ):
        self.config = config
        self.ptu = ptu
        self.capture = capture
        self.ranger = ranger
        self.on_zone = on_zone
        self.truth = truth  # the simulator's truth for a zone, for recordings and scoring
        self._foresee = foresee  # a simulated camera renders the next zone's views meanwhile
        self.last_frame_end_ns = 0  # when the newest frame's exposure ended (latency measurements)
        self.lit_when_off: set[str] = set()  # of the last zone: lasers whose spots showed unlit

    def run(
        self,
        poses: Sequence[tuple[float, float]] | None = None,
        recorder: RecordingWriter | None = None,
        progress: Callable[[int, int], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
    ) -> SweepReport:
        poses = list(poses if poses is not None else self.config.sweep.poses())
        report = SweepReport()
        try:
            start = self.ptu.position()
        except HardwareError as exc:
            raise type(exc)(f"cannot start the sweep: {exc}", part=exc.part) from None
        order = visiting_order(poses, start, lambda a, b: self.ptu.move_time_s(*a, *b))
        views = [self.views(*poses[i]) for i in order]
        report.limit_s = sweep_limit_s(self.config, self.ptu, views, start)
        dropped_before = self.capture.dropped
        clock = self.capture.clock  # the rig's: a simulated rig's sweep takes its simulated time
        started, wall_started = clock.now_ns(), time.monotonic()
        in_a_row = 0
        for done, index in enumerate(order):
            pan, tilt = poses[index]
            if should_stop is not None and should_stop():
                break
            if done + 1 < len(order):
                self.foresee(*poses[order[done + 1]])
            result = self.zone(index, pan, tilt, recorder)
            in_a_row = in_a_row + 1 if result.status == FAULT else 0
            report.results.append(result)
            if self.on_zone is not None:
                self.on_zone(result)
            if progress is not None:
                progress(done + 1, len(poses))
            if in_a_row >= MAX_FAULTS_IN_A_ROW:
                raise HardwareError(
                    f"sweep stopped after {in_a_row} failed zones in a row (last: {result.detail})",
                    part=result.part,
                )
        report.results.sort(key=lambda r: r.index)
        report.duration_s = (clock.now_ns() - started) / 1e9
        report.wall_s = time.monotonic() - wall_started
        report.simulated_time = clock.simulated
        report.dropped_frames = self.capture.dropped - dropped_before
        return report

    def foresee(self, pan: float, tilt: float) -> None:
        """The zone at (pan, tilt) comes next (a hint: a simulated camera renders it ahead)."""
        if self._foresee is not None:
            self._foresee(self.views(pan, tilt))

    def views(self, pan: float, tilt: float) -> list[tuple[float, float]]:
        return zone_views(self.config, pan, tilt, self.ptu.limits_deg[0])

    def zone(self, index: int, pan: float, tilt: float, recorder: RecordingWriter | None = None) -> ZoneResult:
        """Move, capture and range one zone. A part failing makes it a `fault`, not an exception."""
        taken = []
        reached = (pan, tilt)
        try:
            for k, view in enumerate(self.views(pan, tilt)):
                at = self.ptu.move(*view)
                if k == 0:
                    reached = at
                for frame, lasers_on, switch_ns in self.capture.zone(pairs=1):
                    taken.append((frame, tuple(lasers_on), switch_ns, at))
                    self.last_frame_end_ns = frame.t_end_ns
        except HardwareError as exc:
            log.warning("zone %d (pan %.2f°, tilt %.2f°): %s", index, pan, tilt, exc)
            return ZoneResult(index, pan, tilt, FAULT, detail=str(exc), part=exc.part)
        groups = _groups(taken)
        result = self.ranger.range_zone(index, reached[0], reached[1], groups)
        self.lit_when_off = lit_when_off(self.ranger, result, groups)
        truth = self.truth(index, *reached) if self.truth else None
        if recorder is not None:
            recorder.add_zone(index, reached[0], reached[1], _recorded(taken, reached), truth)
        return result


def lit_when_off(ranger: Ranger, result: ZoneResult, groups: Sequence[FrameGroup]) -> set[str]:
    """The lasers whose spots show in the zone's laser-off frames (stuck on). A stuck spot can
    even leak into the difference (room-light flicker scales the off frame), so every laser is
    looked at, not only the missing ones."""
    if not groups or not groups[0].off:
        return set()
    off = groups[0].off[0]
    return {n for n in ranger.rig.laser_names if ranger.finder.lit_in_off(off, n)}


def _groups(taken) -> list[FrameGroup]:
    """Frames of each view as one group: its laser-on frames against its laser-off frames."""
    views: dict[tuple[float, float], dict[str, list]] = {}
    lasers: dict[tuple[float, float], tuple[str, ...]] = {}
    for frame, lasers_on, _, view in taken:
        kind = "on" if lasers_on else "off"
        views.setdefault(view, {"on": [], "off": []})[kind].append(frame.image)
        if lasers_on:
            lasers[view] = lasers_on
    return [
        FrameGroup(v["on"], v["off"], lasers[view], view)
        for view, v in views.items()
        if v["on"] and v["off"]
    ]


def _recorded(taken, reached: tuple[float, float]) -> list:
    frames = []
    for frame, lasers_on, switch_ns, view in taken:
        extra: dict = {
            "t_start_ns": frame.t_start_ns,
            "exposure_us": frame.exposure_us,
            "laser_switch_ns": switch_ns,
        }
        if not math.isclose(view[0], reached[0], abs_tol=1e-9) or not math.isclose(view[1], reached[1], abs_tol=1e-9):
            extra["pan_deg"], extra["tilt_deg"] = view
        frames.append((frame.image, list(lasers_on), extra))
    return frames


@dataclass
class ConfiguredSweep:
    """A sweep on the configured parts, with the truth when the parts are simulated."""

    report: SweepReport
    truths: dict[int, dict] = field(default_factory=dict)  # zone index → truth object (simulator)
    room: list = field(default_factory=list)  # the true room's floor plan in the base frame

    def truth_ranges(self) -> list[float | None]:
        return [(self.truths.get(r.index) or {}).get("range_m") for r in self.report.results]


def sweeper_for(parts, on_zone: Callable[[ZoneResult], None] | None = None, config: Config | None = None,
                ranger: Ranger | None = None, capture: Capture | None = None) -> Sweeper:
    """A sweeper on opened parts (``edge.parts``), ranging with the configured rig and its
    calibration (``edge.calibration.in_use``; `config`, when
    given, changes how it sweeps: a mode's own pattern; `ranger`, when given, is reused rather
    than built again: building one lays out every laser's search band; `capture`, when given,
    replaces the parts' own: one that heeds every frame)."""
    config = config or parts.config
    truth = parts.truth if parts.simulated else None
    if ranger is None:
        from edge.calibration.in_use import believed_rig

        ranger = Ranger(believed_rig(config).rig, config.ranging)
    return Sweeper(config, parts.ptu, capture or parts.capture, ranger, on_zone=on_zone, truth=truth,
                   foresee=parts.foresee if parts.simulated else None)


def run_configured_sweep(
    config: Config,
    progress: Callable[[int, int], None] | None = None,
    recorder: RecordingWriter | None = None,
    on_zone: Callable[[ZoneResult], None] | None = None,
) -> ConfiguredSweep:
    """One sweep on the configured parts (real or simulated), lasers off and parts closed after.
    With `recorder`, every zone's frames are saved as it goes (``edge record``), ranged with the
    recording's rig, so that a replay ranges alike."""
    from edge.parts import open_parts

    ranger = Ranger(recorder.rig, config.ranging) if recorder is not None else None
    with open_parts(config) as parts:
        report = sweeper_for(parts, on_zone, ranger=ranger).run(recorder=recorder, progress=progress)
        return ConfiguredSweep(report, dict(parts.truths), parts.room())
