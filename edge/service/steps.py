"""One step of each mode on opened parts: a sweep, a burst of ranges, a pass of the blind aid's fan.

The service's loop chooses the step; a step runs until it is done or `should_stop()` says so
(checked between zones or frames, where the loop also takes commands). Every zone and frame of
every mode goes out as a live ``range`` and into the rig's health (which restarts a stalled
camera); the blind aid hears besides when the health says its reference laser cannot range.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Set
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from edge.config import Config
from edge.errors import HardwareError
from edge.ranging import FAULT, Ranger, ZoneResult
from edge.service.guarding import GuardWatch
from edge.service.health import RigHealth
from edge.service.identity import BootId

if TYPE_CHECKING:
    from edge.maps import GridKeeper
    from edge.modes.blindaid.runner import BlindAidRunner
    from edge.parts import Parts

log = logging.getLogger(__name__)

ShouldStop = Callable[[], bool]
Publish = Callable[[str, dict[str, Any]], object]


class ModeSteps:
    """`publish_live` and `publish_event` are the link's; `pause(s)` waits, ending early on a
    stop; `now()` is the rig's time in seconds (the guard's clock)."""

    def __init__(self, health: RigHealth, guard: GuardWatch, boot: BootId, *, publish_live: Publish,
                 publish_event: Publish, pause: Callable[[float], object], now: Callable[[], float],
                 grid: GridKeeper | None = None) -> None:
        self.health = health
        self.grid = grid  # the map kept across sweeps and restarts: every complete sweep goes in
        self.guard = guard
        self._boot = boot
        self.sweeps = 0  # complete sweeps so far
        self.last_sweep: list[ZoneResult] = []  # the zones of the last complete sweep
        self._publish_live = publish_live
        self._publish_event = publish_event
        self._pause = pause
        self._now = now
        self._started = now()
        self._blindaid: BlindAidRunner | None = None
        self._blinded: str | None = None  # why the service says the blind aid cannot see

    @property
    def blindaid(self) -> BlindAidRunner | None:
        """The blind aid's runner while its fan is open (its clock, its sound)."""
        return self._blindaid

    def zone(self, result: ZoneResult, lit_when_off: Set[str] = frozenset()) -> None:
        """A zone's outcome, out and into the health."""
        self._publish_live("range", result.to_json())
        self.health.zone(result, frozenset(lit_when_off))

    def sweep(self, parts: Parts, config: Config, ranger: Ranger, should_stop: ShouldStop) -> bool:
        """One sweep (a guard's, in guard mode), published when complete; False when it ended early."""
        from edge.sweep import sweeper_for

        guarding = config.mode == "guard"
        if guarding:
            config = replace(config, sweep=replace(config.sweep, pairs_per_zone=config.service.guard_pairs_per_zone))
        zone_t: dict[int, float] = {}

        def on_zone(result: ZoneResult) -> None:
            zone_t[result.index] = self._now() - self._started
            self.zone(result, sweeper.lit_when_off)

        sweeper = sweeper_for(parts, on_zone=on_zone, config=config, ranger=ranger)
        report = sweeper.run(should_stop=should_stop)
        if len(report.results) < len(config.sweep.poses()):
            log.info("sweep ended early after %d zones", len(report.results))
            return False
        self.sweeps += 1
        if self.grid is not None:
            self.grid.add_sweep(ranger.rig, report.results)
        self.last_sweep = list(report.results)
        self._publish_event("sweep", {
            "sweep": self.sweeps,
            "boot": self._boot.value,  # (boot, sweep) is unique across restarts
            "duration_s": round(report.duration_s, 3),
            "zones": [r.to_json() for r in report.results],
        })
        ok = sum(r.status == "ok" for r in report.results)
        log.info("sweep %d: %d of %d zones ok in %.1f s (limit %.1f s), %d faults",
                 self.sweeps, ok, len(report.results), report.duration_s, report.limit_s, report.faults)
        if guarding:
            self.guard.sweep(report.results, self.sweeps, self._now() - self._started, zone_t)
        return True

    def point(self, parts: Parts, ranger: Ranger, pan: float, tilt: float) -> ZoneResult:
        """Aim and range one zone there (cmd/point)."""
        from edge.sweep import sweeper_for

        result = sweeper_for(parts, ranger=ranger).zone(-1, pan, tilt)
        self.zone(result)
        return result

    def range(self, parts: Parts, ranger: Ranger, aim: tuple[float, float], should_stop: ShouldStop) -> None:
        """Aim, then range frame after frame (the range finder)."""
        from edge.modes.rangefinder import Filtered, Rangefinder, range_payload

        pan, tilt = aim
        try:
            parts.ptu.move(pan, tilt)
        except HardwareError as exc:
            self.zone(ZoneResult(-1, pan, tilt, FAULT, detail=str(exc), part=exc.part))
            self._pause(1.0)  # a unit that failed gets a moment before the next try
            return
        finder = Rangefinder(parts.capture, ranger, parts.lasers.names)

        def on_range(result: ZoneResult, filtered: Filtered | None, extra: dict[str, Any]) -> None:
            self._publish_live("range", range_payload(result, filtered, extra))
            self.health.zone(result)

        finder.run(pan, tilt, on_range, should_stop)

    def fan(self, parts: Parts, config: Config, ranger: Ranger, should_stop: ShouldStop) -> None:
        """One pass of the blind aid; its runner (and sound) stays open for the next."""
        if self._blindaid is None:
            from edge.modes.blindaid.logic import Cue
            from edge.modes.blindaid.runner import BlindAidRunner

            def on_cue(cue: Cue) -> None:
                self._publish_live("cue", cue.to_json())

            self._blindaid = BlindAidRunner(config, parts, on_cue, ranger=ranger)
            self._blindaid.set_blinded(self._blinded)
        reference = ranger.rig.reference.name
        runner = self._blindaid

        def on_zone(result: ZoneResult, lit_when_off: Set[str]) -> None:
            self.zone(result, lit_when_off)
            runner.set_blinded(self._blinded or self.health.cannot_see(reference))

        runner.on_zone = on_zone
        runner.scan(should_stop)

    def blinded(self, reason: str | None) -> None:
        """The rig cannot see although it runs (`reason`, e.g. "lasers switched off by
        cmd/lasers_off"), or, with None, can again: the blind aid says "cannot see" meanwhile.
        Keep the fan open (no `close_fan`) while ranging is paused so: its sound goes on."""
        self._blinded = reason
        if self._blindaid is not None:
            self._blindaid.set_blinded(reason)

    def close_fan(self) -> None:
        """Close the blind aid's runner (its sound, its button), if open."""
        if self._blindaid is not None:
            self._blindaid.close()
            self._blindaid = None
