"""The guard mode across sweeps: the `Guard` for the sweep's zone count, its events out as alerts.

Alerts carry this start's boot id (`edge.service.identity`), in ``boot`` and in their track ids,
so that (``id``, ``event``, ``sweep``) never repeats across restarts.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from edge.modes.guard import Guard, GuardConfig, Track
from edge.ranging import ZoneResult
from edge.service.identity import BootId

log = logging.getLogger(__name__)


class GuardWatch:
    """Keeps one `Guard` while the sweeps keep their zone count (a new one learns afresh when it
    changes) and hands every event it raises to `publish_alert` (the ``alert`` payload), with this
    start's `boot` id (random when none is given)."""

    def __init__(self, config: GuardConfig, publish_alert: Callable[[dict[str, Any]], object],
                 boot: BootId | None = None) -> None:
        self.config = config
        self.guard: Guard | None = None  # none before the first complete guard sweep
        self._publish_alert = publish_alert
        self._boot = boot if boot is not None else BootId(None)
        self._track_numbers = itertools.count(1)  # across guards: a new zone count keeps counting

    def _new_track_id(self) -> str:
        return f"{self._boot.value}-t{next(self._track_numbers)}"

    def _alert(self, payload: dict[str, Any]) -> None:
        self._publish_alert({**payload, "boot": self._boot.value})

    @property
    def learning(self) -> bool:
        return self.guard is None or self.guard.learning

    @property
    def tracks(self) -> list[Track]:
        return [] if self.guard is None else self.guard.tracks

    def sweep(self, results: Sequence[ZoneResult], sweep: int, t_s: float,
              zone_t_s: Mapping[int, float] | None = None) -> None:
        """Take one complete sweep (see `Guard.update`)."""
        if self.guard is None or self.guard.zone_count != len(results):
            self.guard = Guard(self.config, len(results), self._new_track_id)
        was_learning = self.guard.learning
        events = self.guard.update(results, sweep, t_s, zone_t_s)
        if was_learning and not self.guard.learning:
            log.info("guard: background learnt over %d sweeps; watching", self.config.learn_sweeps)
        for event in events:
            log.warning("guard: %s %s in zones %s at %.2f m, bearing %.1f°", event.event, event.id,
                        list(event.zones), event.range_m, event.bearing_deg)
            self._alert(event.to_json())

    def relearn(self, why: str | None = None) -> None:
        """Learn the background again from the next complete sweep; every followed object is
        cleared (published, so that nobody keeps one no longer followed). Also how the guard
        stands down when it stops watching (another mode, a pause): nobody is left believing in an
        intruder no longer watched, and the room may change unwatched."""
        if self.guard is None:
            return
        if why:
            log.info("guard: learning the background again %s", why)
        for event in self.guard.relearn():
            self._alert(event.to_json())

    def state(self) -> dict[str, Any] | None:
        """The guard's part of `state`, once there is a guard."""
        return None if self.guard is None else self.guard.state()
