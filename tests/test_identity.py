"""Alert and sweep keys stay unique across restarts: each start's boot id, counted in the state folder."""

from __future__ import annotations

import json
import logging
import threading
import time
from pathlib import Path

from edge.config import load_config
from edge.modes.guard import GuardConfig
from edge.ranging import OK, ZoneResult
from edge.service import Service
from edge.service.guarding import GuardWatch
from edge.service.identity import BOOT_FILE, BootId, next_boot_id
from tests.test_service_parts import Recorder


def _sweep(ranges: dict[int, float], n: int = 16) -> list[ZoneResult]:
    return [ZoneResult(i, 360.0 / n * i, 0.0, OK, range_m=ranges.get(i, 3.0), sigma_m=0.005) for i in range(n)]


def _night(state_dir: Path) -> list[dict]:
    """One start of the guard: learn an empty room, then someone stands in zones 4-5."""
    alerts: list[dict] = []
    watch = GuardWatch(GuardConfig(learn_sweeps=3, confirm_sweeps=2), alerts.append, BootId(state_dir))
    for sweep in range(1, 4):
        watch.sweep(_sweep({}), sweep, float(sweep))
    for sweep in range(4, 7):
        watch.sweep(_sweep({4: 1.5, 5: 1.5}), sweep, float(sweep))
    return alerts


def test_the_same_intrusion_after_a_restart_has_another_key(tmp_path: Path) -> None:
    first, second = _night(tmp_path), _night(tmp_path)
    assert [a["event"] for a in first] == [a["event"] for a in second] == ["intrusion"]
    key = lambda a: (a["id"], a["event"], a["sweep"])  # noqa: E731 - mqtt.md's de-duplication key
    assert key(first[0]) != key(second[0])
    assert (first[0]["id"], first[0]["boot"]) == ("b1-t1", "b1")
    assert (second[0]["id"], second[0]["boot"]) == ("b2-t1", "b2")
    assert (tmp_path / BOOT_FILE).read_text() == "2\n"


def test_track_ids_keep_counting_when_the_zone_count_changes(tmp_path: Path) -> None:
    alerts: list[dict] = []
    watch = GuardWatch(GuardConfig(learn_sweeps=2, confirm_sweeps=1), alerts.append, BootId(tmp_path))
    for n in (16, 8):  # a new guard for another zone count learns afresh, but ids go on
        for sweep in (1, 2):
            watch.sweep(_sweep({}, n), sweep, float(sweep))
        watch.sweep(_sweep({4: 1.5, 5: 1.5}, n), 3, 3.0)
    assert [a["id"] for a in alerts if a["event"] == "intrusion"] == ["b1-t1", "b1-t2"]


def test_a_count_that_cannot_be_kept_gives_a_random_boot_id(tmp_path: Path, caplog) -> None:
    (tmp_path / BOOT_FILE).write_text("not a number\n")
    with caplog.at_level(logging.ERROR):
        a, b = next_boot_id(tmp_path), next_boot_id(tmp_path)
    assert a != b and all(x.startswith("r") and len(x) == 9 for x in (a, b))
    assert "cannot count this start" in caplog.text and "not a count of starts" in caplog.text
    blocked = tmp_path / "file"
    blocked.write_text("")  # a state folder that is a file: nothing can be written under it
    assert next_boot_id(blocked / "state").startswith("r")


def _run_until_a_sweep(state_dir: Path) -> Recorder:
    """One real start of the service in guard mode, stopped after its first complete sweep."""
    config = load_config(None, ["mqtt.enabled=false", f"service.state_dir={json.dumps(str(state_dir))}",
                                'mode="guard"', "sweep.zones=4", "service.guard_pairs_per_zone=1"])
    link = Recorder()
    service = Service(config, link=link)

    def stop_after_a_sweep() -> None:
        deadline = time.monotonic() + 120
        while service.sweeps < 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        service.stop_requested.set()

    watcher = threading.Thread(target=stop_after_a_sweep, daemon=True)
    watcher.start()
    assert service.run() == 0
    watcher.join(5)
    return link


def test_sweeps_of_two_starts_on_one_state_folder_have_different_keys(tmp_path: Path) -> None:
    sweeps = []
    for _ in range(2):
        sweeps += [p for kind, p in _run_until_a_sweep(tmp_path).events if kind == "sweep"][:1]
    assert [(p["boot"], p["sweep"]) for p in sweeps] == [("b1", 1), ("b2", 1)]
