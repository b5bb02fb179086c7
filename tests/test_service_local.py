"""The service in this process, without MQTT: the lasers are off after every way it can end."""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import pytest

from edge.config import load_config
from edge.errors import HardwareError
from edge.service import Service

PINS = (17, 27, 22)  # the configured lasers, active high: off is low


def _run_and_stop(service: Service, stop) -> dict[int, list[bool]]:
    """Run `service` here; once the lasers have switched a few times call `stop(service)`.
    Returns, per laser pin, the levels it took (the last one is where it was left)."""
    seen: dict[int, list[bool]] = {}

    def watch() -> None:
        deadline = time.monotonic() + 30
        while service.parts is None and time.monotonic() < deadline:
            time.sleep(0.01)
        factory = service.parts.lasers.factory
        pins = {n: factory.pin(n) for n in PINS}
        while time.monotonic() < deadline and not any(sum(v) >= 3 for v in seen.values()):
            for n, pin in pins.items():
                level = bool(pin.state)
                if not seen.get(n) or seen[n][-1] != level:
                    seen.setdefault(n, []).append(level)
            time.sleep(0.002)
        stop(service)
        service.final_pins = pins

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


def _stop_after(service: Service, sweeps: int, bound_s: float) -> None:
    """Ask `service` to stop once it has made `sweeps` sweeps (from a thread, while it runs);
    `bound_s` bounds a failure, not a speed."""
    def watch() -> None:
        deadline = time.monotonic() + bound_s
        while service.sweeps < sweeps and time.monotonic() < deadline:
            time.sleep(0.05)
        service.stop_requested.set()

    threading.Thread(target=watch, daemon=True).start()


@pytest.fixture
def restore_signals():
    saved = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    yield
    for s, h in saved.items():
        signal.signal(s, h)


def _service(*sets: str) -> Service:
    return Service(load_config(None, ["mqtt.enabled=false", 'mode="rangefinder"', "rangefinder.pan_deg=-90.0", *sets]))


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_the_service_cleanly_with_the_lasers_off(restore_signals, sig):
    service = _service()
    watcher = _run_and_stop(service, lambda s: os.kill(os.getpid(), sig))
    assert service.run() == 0
    watcher.join(5)
    assert service.final_pins and all(not pin.state for pin in service.final_pins.values())


def test_an_exception_in_the_loop_leaves_the_lasers_off(restore_signals):
    """The pan-tilt unit falls silent while the range finder ranges: the sweep that comes due
    cannot start, and the driver's error ends the service, which leaves the lasers off."""
    service = _service("service.sweep_interval_s=1.0", "ptu.timeout_s=0.1")

    def silence_the_unit(s: Service) -> None:
        s.parts.emulator.inject("silence", seconds=60.0)

    watcher = _run_and_stop(service, silence_the_unit)
    with pytest.raises(HardwareError):
        service.run()
    watcher.join(5)
    assert service.final_pins and all(not pin.state for pin in service.final_pins.values())
    assert service.state()["health"]["ptu"].startswith("fault: ")


@pytest.mark.parametrize("kind, words", [("dead", "does not light"), ("stuck", "does not go off")])
def test_a_broken_laser_is_reported_and_the_guard_does_not_alarm(restore_signals, caplog, kind, words):
    """The reference laser broken: its zones give no range, `state` says which laser and how, and
    the guard, watching a room that does not change, raises nothing."""
    # Two sweeps to learn, as a guard needs: one alone is too little to know the room by, and a
    # stray range in the third sweep then starts a track (seen with one, in a clean clone).
    service = _service('mode="guard"', "sweep.zones=16", "sweep.pan_step_deg=22.5", "guard.learn_sweeps=2",
                       f'sim.laser_faults=[{{laser="center", kind="{kind}"}}]')

    _stop_after(service, 4, 90)
    with caplog.at_level("INFO"):
        assert service.run() == 0
    assert service.sweeps >= 4  # two to learn the background, two watching
    reported = [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]
    assert any(words in m and "center" in m for m in reported), reported
    assert service.guard.guard is not None and not service.guard.tracks
    assert not [r for r in caplog.records if "guard: intrusion" in r.getMessage()]


def test_working_lasers_raise_no_laser_fault(restore_signals):
    service = _service("sweep.zones=16", "sweep.pan_step_deg=22.5", "service.sweep_interval_s=0.1")

    _stop_after(service, 1, 60)
    assert service.run() == 0 and service.sweeps >= 1
    assert service.health.parts["lasers"] == "ok" and service.health.lasers.verdicts() == {}


CORRIDOR = """
name = "office-corridor"
description = "the office; someone stops in the dark corridor beyond the east doorway at t = 9 s"
extends = "office"

[[movers]]
name = "passer-by"
size_m = [0.45, 0.30, 1.75]
material = "person"
speed_mps = 0.8
start_s = 9.0
path_m = [[5.6, 2.95], [5.6, 3.0]]
pause_s = [120.0, 0.0]
"""


@pytest.mark.slow
@pytest.mark.parametrize("ignore", [None, True])
def test_the_guard_ignores_someone_beyond_a_doorway_only_when_told_to(restore_signals, caplog, tmp_path, repo, ignore):
    """The office's east doorway opens onto a dark corridor; after the guard has learnt the room,
    someone stops in the corridor 1.6 m past the door, in the view of the zone at pan 22.5°. By
    default (``guard.ignore_beyond_doorways`` unset) that is an intrusion, as it always was; with
    it, the map says the room ends about a metre past the door along that zone's ray, and the
    reading beyond is ignored. A sector of 16 zones covers the door and the walls beside it."""
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "office.toml").write_text((repo / "config" / "scenes" / "office.toml").read_text())
    (scenes / "corridor.toml").write_text(CORRIDOR)
    sets = ['mode="guard"', f"sim.scene={json.dumps(str(scenes / 'corridor.toml'))}", "sweep.zones=16",
            "sweep.pan_start_deg=-22.5", "guard.learn_sweeps=2"]
    service = _service(*sets, *([] if ignore is None else [f"guard.ignore_beyond_doorways={str(ignore).lower()}"]))

    _stop_after(service, 6, 300)
    with caplog.at_level("INFO"):
        assert service.run() == 0
    assert service.sweeps >= 6  # two to learn, then the passer-by for three or more
    door = next(r for r in service.steps.last_sweep if abs(r.pan_deg - 22.5) < 0.1)
    assert door.status == "ok" and door.range_m is not None and 3.8 < door.range_m < 4.5  # seen
    state = service.guard.state()
    assert state is not None and door.index in state["open_zones"]  # no range while learning
    intrusions = [r.getMessage() for r in caplog.records if "guard: intrusion" in r.getMessage()]
    if ignore:
        assert door.index in state["doorway_zones"]
        assert intrusions == [] and not service.guard.tracks
    else:
        assert "doorway_zones" not in state  # the state as before
        assert len(intrusions) == 1 and f"in zones [{door.index}]" in intrusions[0], intrusions
