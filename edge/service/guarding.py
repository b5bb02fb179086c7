"""The guard mode across sweeps: the `Guard` for the sweep's zone count, its events out as alerts.

Alerts carry this start's boot id (`edge.service.identity`), in ``boot`` and in their track ids,
so that (``id``, ``event``, ``sweep``) never repeats across restarts.

With ``guard.ignore_beyond_doorways`` the zones that look through a doorway onto a dark corridor,
and where the room ends along them, are taken from the map (``GridKeeper.outside_m``) when the
background has been learnt, and kept until it is learnt again: the map goes on taking every sweep,
and a person standing in the corridor would soon be a wall in it, closing the doorway.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from edge.modes.guard import Guard, GuardConfig, Track
from edge.ranging import ZoneResult
from edge.rig import Laser
from edge.service.identity import BootId

log = logging.getLogger(__name__)

Doorways = Callable[[Sequence[ZoneResult]], Mapping[int, float]]


class GuardWatch:
    """Keeps one `Guard` while the sweeps keep their zone count (a new one learns afresh when it
    changes) and hands every event it raises to `publish_alert` (the ``alert`` payload), with this
    start's `boot` id (random when none is given)."""

    def __init__(self, config: GuardConfig, publish_alert: Callable[[dict[str, Any]], object],
                 boot: BootId | None = None, doorways: Doorways | None = None,
                 reference: Callable[[], Laser] | None = None) -> None:
        """`doorways(results)`: for the zones of a sweep, those whose rays leave the room through a
        doorway and where it ends along them (the map's); used with ``ignore_beyond_doorways``.
        `reference()`: the rig's reference laser when a guard starts learning (`Guard`'s)."""
        self.config = config
        self._reference = reference
        self.guard: Guard | None = None  # none before the first complete guard sweep
        self._publish_alert = publish_alert
        self._boot = boot if boot is not None else BootId(None)
        self._track_numbers = itertools.count(1)  # across guards: a new zone count keeps counting
        self._doorways = doorways if config.ignore_beyond_doorways else None
        self._outside_m: dict[int, float] = {}  # zone → where the room ends along it (m)

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
            self.guard = Guard(self.config, len(results), self._new_track_id,
                               None if self._reference is None else self._reference())
            self._outside_m = {}
        was_learning = self.guard.learning
        events = self.guard.update(results, sweep, t_s, zone_t_s, outside_m=self._outside_m)
        if was_learning and not self.guard.learning:
            log.info("guard: background learnt over %d sweeps; watching", self.config.learn_sweeps)
            self._learn_doorways(results)
        for event in events:
            log.warning("guard: %s %s in zones %s at %.2f m, bearing %.1f°", event.event, event.id,
                        list(event.zones), event.range_m, event.bearing_deg)
            self._alert(event.to_json())

    def _learn_doorways(self, results: Sequence[ZoneResult]) -> None:
        if self._doorways is None:
            return
        self._outside_m = dict(self._doorways(results))
        if self._outside_m:
            log.info("guard: ignoring what zones %s see beyond a doorway (%s m away)", sorted(self._outside_m),
                     ", ".join(f"{self._outside_m[k]:.1f}" for k in sorted(self._outside_m)))

    def relearn(self, why: str | None = None) -> None:
        """Learn the background again from the next complete sweep; every followed object is
        cleared (published, so that nobody keeps one no longer followed). Also how the guard
        stands down when it stops watching (another mode, a pause): nobody is left believing in an
        intruder no longer watched, and the room may change unwatched."""
        if self.guard is None:
            return
        if why:
            log.info("guard: learning the background again %s", why)
        self._outside_m = {}  # learnt again with the background
        for event in self.guard.relearn():
            self._alert(event.to_json())

    def state(self) -> dict[str, Any] | None:
        """The guard's part of `state`, once there is a guard; with ``ignore_beyond_doorways``, the
        zones that ignore what they see beyond a doorway (``doorway_zones``)."""
        if self.guard is None:
            return None
        state = self.guard.state()
        if self._doorways is not None:
            state["doorway_zones"] = sorted(self._outside_m)
        return state
