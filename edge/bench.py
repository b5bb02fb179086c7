"""Benchmarks: measured, printed, never asserted (the machines that run tests are shared)."""

from __future__ import annotations

import functools
import math
import statistics
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from edge.config import Config
from edge.hw.base import Frame

if TYPE_CHECKING:
    from edge.thesis import ThesisRig


def _interleaved_ms(runs: Sequence[tuple[Callable[[], object], int]], rounds: int
                    ) -> list[tuple[float, float, float]]:
    """Median, 90th percentile and fastest time (ms) of each call of `runs`, (call, n) each, timed
    under the same load: in each of `rounds` rounds every call runs its n times in turn. (Timed one
    after the other, a shared machine's load, which comes and goes within seconds, fell on one side
    of a comparison: the ratio of two such medians swung from 7 to 15.) Runs of a call follow one
    another, so that each but the first finds its data in the caches, as in a loop of its own: a
    small call right after a big one that swept the caches took up to half as long again."""
    times: list[list[float]] = [[] for _ in runs]
    for _ in range(rounds):
        for (fn, n), mine in zip(runs, times):
            for _ in range(n):
                t0 = time.perf_counter()
                fn()
                mine.append((time.perf_counter() - t0) * 1e3)
    return [(statistics.median(t), float(np.percentile(t, 90)), min(t)) for t in times]


def _median_ms(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median and 90th percentile time (ms) of `repeats` runs of `fn`."""
    median, p90, _ = _interleaved_ms([(fn, repeats)], 1)[0]
    return median, p90


def bench_render(config: Config, repeats: int = 20) -> list[str]:
    """Time the virtual camera: a new view (ray cast and shading) and a frame of a cached view."""
    from edge.sim.record import scene_for, true_rig
    from edge.sim.render import Renderer

    renderer = Renderer(scene_for(config), true_rig(config), config.sim)
    names = {n: 1.0 for n in renderer.rig.laser_names}
    rng = np.random.default_rng(0)
    pans = iter(np.arange(repeats * 4) * 5.625)
    cam = renderer.rig.camera
    view_ms = _median_ms(lambda: renderer.render(next(pans), 0.0, {}, 0.0, rng), repeats)
    renderer.render(0.0, 0.0, {}, 0.0, rng)
    off_ms = _median_ms(lambda: renderer.render(0.0, 0.0, {}, 0.0, rng), repeats)
    on_ms = _median_ms(lambda: renderer.render(0.0, 0.0, names, 0.0, rng), repeats)
    through = " (its sensor's 1640x1232, scaled by the ISP: sim.sensor.isp)" if config.sim.sensor.isp else ""
    return [
        f"render {cam.width}x{cam.height}{through}, scene {renderer.scene.name} (median / p90 of {repeats}):",
        f"  new view (ray cast + shading + frame): {view_ms[0]:7.1f} / {view_ms[1]:.1f} ms",
        f"  frame of a cached view, lasers off:    {off_ms[0]:7.1f} / {off_ms[1]:.1f} ms",
        f"  frame of a cached view, lasers on:     {on_ms[0]:7.1f} / {on_ms[1]:.1f} ms",
    ]


def bench_ranging(config: Config, repeats: int = 200) -> list[str]:
    """Time ranging one laser-off/laser-on pair, decoded frames in memory, at 640 × 480 (rendered at
    that size, and as the Pi camera's ISP hands them over) and at 1640 × 1232, beside the thesis'
    straightforward full-frame numpy pipeline on the same frames."""
    from edge import thesis
    from edge.config import CameraConfig
    from edge.ranging import FrameGroup, Ranger
    from edge.sim.record import scene_for, true_rig
    from edge.sim.render import Renderer

    sensor = config.sim.sensor
    # The product's own camera: a Bayer sensor, demosaiced at 1640 × 1232 and scaled (sim.sensor.isp).
    bayer = sensor.bayer if sensor.bayer != "none" else "ea"
    pi = replace(sensor, isp=True, colour=True, bayer=bayer, jpeg_quality=0, yuyv=False)
    kinds = (("picam-v2", replace(sensor, isp=False), ""),
             ("picam-v2", pi, f" from the sensor's 1640x1232 through the ISP (demosaiced {bayer})"),
             ("picam-v2-1640", replace(sensor, isp=False), ""))
    lines = [f"ranging one on/off pair (median / p90 of {repeats} runs, one core, the thesis' interleaved):"]
    for model, frames, through in kinds:
        cfg = replace(config, rig=replace(config.rig, camera=CameraConfig(model=model)),
                      sim=replace(config.sim, sensor=frames))
        rig = cfg.rig.build()
        renderer = Renderer(scene_for(cfg), true_rig(cfg), cfg.sim)
        rng = np.random.default_rng(0)
        pan = -90.0  # a wall in the office, about 1.3 m away
        names = {n: 1.0 for n in rig.laser_names}
        on = renderer.render(pan, 0.0, names, 0.0, rng)
        off = renderer.render(pan, 0.0, {}, 0.0, rng)
        ranger = Ranger(rig)
        group = [FrameGroup([on], [off], rig.laser_names, (pan, 0.0))]
        result = ranger.range_zone(0, pan, 0.0, group)
        baseline = functools.partial(_thesis_range, thesis.thesis_rig(rig), on, off, thesis.masks(rig))
        r_thesis = baseline()
        # Both under the same load: in 8 rounds, a fifth as many of theirs (the slower) as of ours.
        rounds = 8
        ours, theirs = _interleaved_ms(
            [(functools.partial(ranger.range_zone, 0, pan, 0.0, group), max(1, repeats // rounds)),
             (baseline, max(3, repeats // (5 * rounds)))], rounds)
        cam = rig.camera
        lines += [
            f"  {cam.width}x{cam.height}{through}: triangulate {ours[0]:.3f} / {ours[1]:.3f} ms "
            f"(range {result.range_m:.3f} m, {result.status}); thesis full-frame "
            f"{theirs[0]:.2f} / {theirs[1]:.2f} ms (range {r_thesis:.3f} m); "
            f"{theirs[0] / ours[0]:.1f}x faster (fastest runs: {theirs[2] / ours[2]:.1f}x)",
        ]
    return lines


def _thesis_range(t: ThesisRig, on: np.ndarray, off: np.ndarray, boxes: dict[str, np.ndarray]) -> float:
    """The thesis' pipeline on one 8-bit pair: full-frame spots, then its formula (nan: a spot is missing)."""
    from edge import thesis

    p = thesis.spot_positions(on, off, boxes, 0.08 * 255)
    pc, pp, ps = p.get(t.center.name), p.get(t.parallel.name), p.get(t.sloped.name)
    if pc is None or pp is None or ps is None:
        return math.nan
    return thesis.thesis_range(t, pc, pp, ps)


# --- latency on the rig: the device's own work apart from the simulator's -----------------------
#
# On the simulated rig the device's work (ranging, the modes' logic) and the simulator's (rendering
# each frame) run on the same computer. A frame is handed to the code only once it is rendered (the
# capture's `on_frame` hook), so the wall time from that moment to the result is the device's work
# alone. On a simulated clock the rig's time stands still meanwhile, so rig-clock latencies hold no
# computing at all; on the real clock they hold the rendering too. Latency figures are therefore
# modelled: the frame's end on the rig's clock plus the work measured here, what a device as fast as
# this computer would take.


@dataclass(frozen=True)
class Spread:
    """Median, 95th percentile and maximum of some times (ms); nan when there are none."""

    median: float
    p95: float
    max: float

    @classmethod
    def of(cls, values_ms: Sequence[float]) -> Spread:
        if not len(values_ms):
            return cls(math.nan, math.nan, math.nan)
        v = np.asarray(values_ms, dtype=float)
        return cls(float(np.median(v)), float(np.percentile(v, 95)), float(v.max()))

    def __str__(self) -> str:
        return f"median {self.median:.1f} ms, p95 {self.p95:.1f} ms, max {self.max:.1f} ms"


class _Stopwatch:
    """Wall and thread CPU time of the newest frame's delivery, taken in the capture's `on_frame`
    hook (the frame is rendered by then) before passing the frame on to `then`."""

    def __init__(self, then: Callable[[Frame], None] | None = None) -> None:
        self.then = then
        self.wall_ns = self.cpu_ns = 0
        self.frame: Frame | None = None

    def __call__(self, frame: Frame) -> None:
        self.wall_ns, self.cpu_ns = time.perf_counter_ns(), time.thread_time_ns()
        self.frame = frame
        if self.then is not None:
            self.then(frame)

    def since(self) -> tuple[float, float]:
        """Wall and CPU time (ms) from the newest delivery to now, on the delivering thread."""
        return (time.perf_counter_ns() - self.wall_ns) / 1e6, (time.thread_time_ns() - self.cpu_ns) / 1e6


def _clock_words(simulated: bool) -> str:
    return "simulated time" if simulated else "real time (sim.clock = \"real\")"


@dataclass
class BlindAidLatency:
    """Per zone of the blind aid's fan: the device's work and the latency of its cue's sound."""

    simulated: bool  # the rig ran on simulated time
    passes: int
    chunk_ms: float
    frame_ms: float
    lead_ms: float  # a live sound card is fed this far ahead of the clock …
    buffer_ms: float  # … through a buffer this long: both add to the latency
    work_ms: list[float] = field(default_factory=list)  # last frame delivered → cue decided (wall)
    cpu_ms: list[float] = field(default_factory=list)  # the same, the loop thread's CPU time
    stream_ms: list[float] = field(default_factory=list)  # frame end → cue sound, modelled
    as_ran_ms: list[float] = field(default_factory=list)  # frame end → cue sound on the rig's clock
    changed: list[bool] = field(default_factory=list)  # the zone changed the cue
    faults: int = 0  # zones whose parts failed (not measured)

    @property
    def card_latency_ms(self) -> list[float]:
        return [s + self.lead_ms + self.buffer_ms for s in self.stream_ms]

    def lines(self) -> list[str]:
        changed = [s for s, c in zip(self.stream_ms, self.changed) if c]
        lines = [
            f"blind aid on {_clock_words(self.simulated)}: {len(self.work_ms)} zones over {self.passes} fan "
            f"passes, frames every {self.frame_ms:.1f} ms, sound in chunks of {self.chunk_ms:g} ms",
            f"  device's work, last frame delivered → cue decided (ranging + blind-aid logic, wall time, "
            f"rendering excluded): {Spread.of(self.work_ms)}",
            f"    the same in the loop thread's CPU time (waiting for a core left out): "
            f"{Spread.of(self.cpu_ms)}",
            f"  in the stream, frame end → cue sound for a device this fast (frame end + work, up to the next "
            f"chunk): {Spread.of(self.stream_ms)}",
            f"  with a sound card (+ {self.lead_ms:g} ms lead + {self.buffer_ms:g} ms buffer): "
            f"{Spread.of(self.card_latency_ms)}",
            f"  cues that changed ({len(changed)}), in the stream: " + ", ".join(f"{x:.1f}" for x in changed) + " ms",
        ]
        if not self.simulated:
            lines.append(f"  as it ran on the rig's real clock, frame end → cue sound in the stream (includes "
                         f"rendering the frame on the same cores): {Spread.of(self.as_ran_ms)}")
        if self.faults:
            lines.append(f"  {self.faults} zones failed (not counted)")
        return lines


def _chunk_start_s(t_s: float, chunk_n: int, rate: int) -> float:
    """The first chunk boundary at or after `t_s` (stream seconds): where a cue decided at `t_s`
    starts sounding (:class:`edge.modes.blindaid.sound.CuePlayer`'s grid)."""
    sample = max(0, math.ceil(t_s * rate - 1e-6))
    return -(-sample // chunk_n) * chunk_n / rate


def measure_blindaid(config: Config, passes: int = 3) -> BlindAidLatency:
    """Run the blind aid on the configured (simulated) rig for `passes` passes of its fan, timing
    every zone (see the notes above)."""
    from edge.modes.blindaid.logic import BlindAid, Cue
    from edge.modes.blindaid.runner import BlindAidRunner
    from edge.parts import open_parts
    from edge.ranging import FAULT, ZoneResult

    config = replace(config, audio=replace(config.audio, out=""))
    lead = config.audio.lead_ms
    buffer = int(lead * 2) or 40  # the aplay buffer open_audio asks for
    with open_parts(config) as parts:
        runner = BlindAidRunner(config, parts, on_cue=lambda cue: None)
        runner.sweeper.truth = None  # the simulator's truth of each zone is its work, not the device's
        watch = _Stopwatch(runner.sweeper.capture.on_frame)
        runner.sweeper.capture.on_frame = watch
        out = BlindAidLatency(parts.clock.simulated, passes, config.audio.chunk_ms,
                              config.camera.frame_ns / 1e6, lead, buffer)
        grid = (runner.player.chunk_n, runner.player.sample_rate)

        class TimedAid(BlindAid):
            def update(self, result: ZoneResult, t_s: float, seen_s: float | None = None) -> Cue | None:
                cue = super().update(result, t_s, seen_s)
                work, cpu = watch.since()
                if result.status == FAULT:
                    out.faults += 1
                    return cue
                frame_t = (runner.sweeper.last_frame_end_ns - runner.t0_ns) / 1e9
                out.work_ms.append(work)
                out.cpu_ms.append(cpu)
                out.stream_ms.append((_chunk_start_s(frame_t + work / 1e3, *grid) - frame_t) * 1e3)
                out.as_ran_ms.append((_chunk_start_s(t_s, *grid) - frame_t) * 1e3)
                out.changed.append(cue is not None)
                return cue

        runner.aid = TimedAid(config.blindaid)  # as fresh as the runner's own: nothing has run yet
        try:
            for _ in range(passes):
                runner.scan(lambda: False)
        finally:
            runner.close()
    return out


def bench_blindaid(config: Config, repeats: int = 3) -> list[str]:
    """The blind aid's latency, frame end → cue sound: the device's work apart from rendering."""
    return measure_blindaid(config, repeats).lines()


@dataclass
class RangefinderLatency:
    """Per frame of the range finder: the device's work, and the ranges' rate on the rig's clock."""

    simulated: bool
    frame_rate_hz: float
    work_ms: list[float] = field(default_factory=list)  # frame delivered → range ready (wall)
    cpu_ms: list[float] = field(default_factory=list)
    as_ran_ms: list[float] = field(default_factory=list)  # frame end → range ready on the rig's clock
    range_times_ns: list[int] = field(default_factory=list)  # on the rig's clock
    range_frames: list[int] = field(default_factory=list)  # the camera's number of each range's frame
    statuses: Counter[str] = field(default_factory=Counter)
    frames_used: int = 0
    straddled: int = 0  # frames not used as they were exposed across a laser switch
    wall_s: float = 0.0

    @property
    def ranges(self) -> int:
        return len(self.range_times_ns)

    @property
    def rig_s(self) -> float:
        """Rig time from the first range to the last."""
        return (self.range_times_ns[-1] - self.range_times_ns[0]) / 1e9 if self.range_times_ns else 0.0

    @property
    def rate_hz(self) -> float:
        return (self.ranges - 1) / self.rig_s if self.rig_s > 0 else math.nan

    @property
    def dropped(self) -> int:
        """Frames the camera made between the first range's and the last's that gave no range
        (before the first, the simulator renders its first view: no device has that wait)."""
        if not self.range_frames:
            return 0
        return self.range_frames[-1] - self.range_frames[0] + 1 - self.ranges

    def lines(self) -> list[str]:
        statuses = ", ".join(f"{n} {s}" for s, n in self.statuses.most_common())
        lines = [
            f"range finder on {_clock_words(self.simulated)}: {self.ranges} ranges ({statuses}) from "
            f"{self.frames_used} frames in {self.rig_s:.2f} s of rig time ({self.wall_s:.2f} s wall)",
            f"  device's work, frame delivered → range ready (ranging + filter, wall time, rendering "
            f"excluded): {Spread.of(self.work_ms)}",
            f"    the same in the loop thread's CPU time (waiting for a core left out): "
            f"{Spread.of(self.cpu_ms)}",
            f"  ranges per second of rig time: {self.rate_hz:.2f} (camera {self.frame_rate_hz:g} fps: one range "
            f"a frame); frames dropped: {self.dropped} ({self.straddled} across a laser switch)",
        ]
        if not self.simulated:
            lines.append(f"  as it ran on the rig's real clock, frame end → range ready (includes rendering the "
                         f"frame on the same cores): {Spread.of(self.as_ran_ms)}")
        return lines


def measure_rangefinder(config: Config, frames: int = 90) -> RangefinderLatency:
    """Run the range finder (``[rangefinder]``'s aim) on the configured rig for `frames` ranges."""
    from edge.calibration.in_use import believed_rig
    from edge.modes.rangefinder import Filtered, Rangefinder
    from edge.parts import open_parts
    from edge.ranging import Ranger, ZoneResult

    pan, tilt = config.rangefinder.pan_deg, config.rangefinder.tilt_deg
    ranger = Ranger(believed_rig(config).rig, config.ranging)
    with open_parts(config) as parts:
        parts.ptu.move(pan, tilt)
        out = RangefinderLatency(parts.clock.simulated, config.camera.frame_rate_hz)
        capture, clock = parts.capture, parts.clock
        watch = _Stopwatch(capture.on_frame)
        capture.on_frame = watch

        def on_range(result: ZoneResult, filtered: Filtered | None, extra: dict) -> None:
            work, cpu = watch.since()
            now = clock.now_ns()
            out.work_ms.append(work)
            out.cpu_ms.append(cpu)
            out.range_times_ns.append(now)
            out.statuses[result.status] += 1
            out.range_frames.append(int(extra.get("frame", -1)))
            if watch.frame is not None:
                out.as_ran_ms.append((now - watch.frame.t_end_ns) / 1e6)

        finder = Rangefinder(capture, ranger, parts.lasers.names)
        straddled, began = capture.dropped, time.monotonic()
        # One frame more than ranges: the first frame has nothing before it to be ranged with.
        out.frames_used = finder.run(pan, tilt, on_range, lambda: False, max_frames=frames + 1)
        out.wall_s = time.monotonic() - began
        out.straddled = capture.dropped - straddled
    return out


def bench_rangefinder(config: Config, repeats: int = 90) -> list[str]:
    """The range finder's frame → range: the device's work per frame, and one range per frame."""
    return measure_rangefinder(config, repeats).lines()
