"""The service's side of Home Assistant: what its entities follow, in every mode.

In-process with a recording link: the guard's standing across mode changes, pauses and relearns
(minutes of simulated sweeps end to end; tools/ha_check.py does that against a real Home
Assistant). The pace of the snapshots is the link's (tests/test_mqtt.py).
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

from edge.config import load_config
from edge.ranging import OK, ZoneResult
from edge.service import Service
from edge.service.link import NullLink

HA_TOPICS = ("state", "distance", "guard", "obstacle", "map", "backlog", "last_result")


class Recorder(NullLink):
    def __init__(self) -> None:
        self.snapshots: list[tuple[str, Any]] = []
        self.events: list[tuple[str, dict]] = []
        self.states: list[dict] = []

    def publish_snapshot(self, kind, payload, min_interval_s=0.6):
        self.snapshots.append((kind, payload))

    def publish_event(self, kind, payload):
        self.events.append((kind, payload))

    def publish_state(self, payload, at_once=False):
        self.states.append(payload)

    def last(self, kind: str) -> Any:
        return [p for k, p in self.snapshots if k == kind][-1]


def sweep(ranges: dict[int, float], zones: int = 16) -> list[ZoneResult]:
    """A guard sweep of `zones` zones round the turn: 3 m everywhere but where `ranges` says."""
    out = []
    for k in range(zones):
        pan = 360.0 * k / zones
        r = ranges.get(k, 3.0)
        out.append(ZoneResult(k, pan, 0.0, OK, r, 0.003 * r))
    return out


def guarding_service(tmp_path: Path) -> tuple[Service, Recorder]:
    config = load_config(None, ["mqtt.enabled=false", 'mode="guard"', "guard.learn_sweeps=2",
                                f"service.state_dir={json.dumps(str(tmp_path))}"])
    service = Service(config)
    link = Recorder()
    service.link = link
    return service, link


def intruder(service: Service, link: Recorder) -> None:
    """Learn the empty room, then someone at zone 5 for two sweeps: an intrusion, followed."""
    before = len(link.events)
    for n in range(1, 3):
        service.guard.sweep(sweep({}), n, 10.0 * n)
    for n in range(3, 5):
        service.guard.sweep(sweep({5: 1.5}), n, 10.0 * n)
    service._publish_guard()
    assert [e["event"] for k, e in link.events[before:] if k == "alert"] == ["intrusion"]
    assert link.last("guard") | {"objects": None} == {"active": True, "occupied": True, "tracks": 1,
                                                      "learning": False, "objects": None}


def test_leaving_guard_mode_mid_intrusion_clears_it_and_the_motion_sensor(tmp_path):
    service, link = guarding_service(tmp_path)
    intruder(service, link)
    service.handle_command("mode", b'{"mode": "rangefinder"}')
    # Everyone who followed the intruder hears `cleared`; the guard state says nobody is there.
    assert [e["event"] for k, e in link.events if k == "alert"] == ["intrusion", "cleared"]
    assert link.last("guard")["active"] is False and link.last("guard")["occupied"] is False
    assert link.last("distance")["active"] is True and link.last("obstacle")["active"] is False
    # Back to guarding: it learns the room afresh (it may have changed unwatched), nobody is there.
    service.handle_command("mode", b'{"mode": "guard"}')
    assert link.last("guard") | {"objects": None} == {"active": True, "occupied": False, "tracks": 0,
                                                      "learning": True, "objects": None}
    assert link.last("distance")["active"] is False
    assert service.state()["guard"]["learning"] is True


def test_a_pause_in_guard_mode_stands_the_guard_down_and_a_relearn_says_so(tmp_path):
    service, link = guarding_service(tmp_path)
    intruder(service, link)
    service.handle_command("lasers_off", b"{}")
    assert [e["event"] for k, e in link.events if k == "alert"] == ["intrusion", "cleared"]
    assert link.last("guard")["active"] is False and link.last("guard")["occupied"] is False
    service.handle_command("mode", b'{"mode": "guard"}')  # resumes
    assert link.last("guard")["active"] is True and link.last("guard")["learning"] is True
    intruder(service, link)
    service.handle_command("relearn", b"{}")
    assert [e["event"] for k, e in link.events if k == "alert"][-1] == "cleared"
    assert link.last("guard")["occupied"] is False and link.last("guard")["learning"] is True


def test_several_tracks_keep_the_motion_sensor_on_until_the_last_one_is_cleared(tmp_path):
    service, link = guarding_service(tmp_path)
    for n in range(1, 3):
        service.guard.sweep(sweep({}), n, 10.0 * n)
    for n in range(3, 5):
        service.guard.sweep(sweep({2: 1.5, 10: 1.2}), n, 10.0 * n)
    service._publish_guard()
    assert link.last("guard")["tracks"] == 2
    for n in range(5, 7):  # the first leaves: cleared after two sweeps without it
        service.guard.sweep(sweep({10: 1.2}), n, 10.0 * n)
        service._publish_guard()
    assert Counter(e["event"] for k, e in link.events if k == "alert")["cleared"] == 1
    assert link.last("guard")["occupied"] is True and link.last("guard")["tracks"] == 1
    for n in range(7, 9):
        service.guard.sweep(sweep({}), n, 10.0 * n)
        service._publish_guard()
    assert link.last("guard")["occupied"] is False


def test_state_carries_the_faults_and_the_calibrations_age(tmp_path):
    service, _ = guarding_service(tmp_path)
    state = service.state()
    assert state["faults"] == [] and state["calibrated_at"] is None and state["calibration_age_d"] is None
    service.health._parts["ptu"] = "fault: no reply"
    service._calibrated_at = "2020-01-01T00:00:00Z"
    state = service.state()
    assert state["faults"] == ["ptu"] and state["calibration_age_d"] > 365
