"""The service's smaller parts through their public interfaces: the link to nobody, the command
dispatcher, the guard across sweeps; and the service answering commands through any `Link`."""

from __future__ import annotations

import json

from edge.commands import Command
from edge.config import load_config
from edge.errors import CommandError
from edge.modes.guard import GuardConfig
from edge.ranging import OK, ZoneResult
from edge.service import Service
from edge.service.commanding import LATER, Dispatcher
from edge.service.guarding import GuardWatch
from edge.service.link import Link, NullLink, open_link

LIMITS = ((-150.0, 150.0), (-45.0, 30.0))


class Recorder:
    """A `Link` that keeps what went out and hands out the commands it is given."""

    def __init__(self, commands=()) -> None:
        self.queued = list(commands)
        self.results: list[tuple] = []
        self.states: list[dict] = []
        self.events: list[tuple] = []
        self.stopped = False

    def start(self) -> None:
        pass

    def stop(self) -> None:
        self.stopped = True

    def commands(self):
        out, self.queued = self.queued, []
        return out

    def publish_state(self, payload):
        self.states.append(payload)

    def publish_event(self, kind, payload):
        self.events.append((kind, payload))

    def publish_live(self, kind, payload):
        self.events.append((kind, payload))

    def publish_result(self, name, ok, error=None, request_id=None, extra=None):
        self.results.append((name, ok, error, request_id))


def test_the_null_link_takes_everything_and_gives_nothing(tmp_path):
    link: Link = NullLink()
    link.start()
    link.publish_state({"a": 1})
    link.publish_event("sweep", {})
    link.publish_live("range", {})
    link.publish_result("sweep", True)
    assert link.commands() == []
    link.stop()
    config = load_config(None, ["mqtt.enabled=false", f"service.state_dir={json.dumps(str(tmp_path))}"])
    with open_link(config, "dev") as opened:
        assert isinstance(opened, NullLink)
    assert list(tmp_path.iterdir()) == []  # no outbox without MQTT


def test_the_dispatcher_answers_every_command_once():
    results: list[tuple] = []
    done: list[Command] = []

    def sweep(command: Command) -> None:
        done.append(command)

    def relearn(command: Command) -> str:
        raise CommandError("no guard to relearn")

    handlers = {"sweep": sweep, "relearn": relearn, "calibrate": lambda c: LATER, "point": lambda c: "out of reach"}
    dispatch = Dispatcher(handlers, lambda *r: results.append(r), lambda: LIMITS, 1024)
    dispatch.handle("sweep", b'{"request_id": "a"}')
    dispatch.handle("relearn", b"{}")
    dispatch.handle("calibrate", b'{"distances_m": [0.5, 1.0, 2.0], "request_id": "c"}')
    dispatch.handle("point", b'{"pan_deg": 10, "tilt_deg": 0}')
    dispatch.handle("point", b'{"pan_deg": 170, "tilt_deg": 0, "request_id": "far"}')  # beyond the unit's reach
    dispatch.handle("sweep", b"{not json")
    assert [c.name for c in done] == ["sweep"]
    assert results[0] == ("sweep", True, None, "a")
    assert results[1] == ("relearn", False, "no guard to relearn", None)
    assert results[2] == ("point", False, "out of reach", None)  # calibrate: its result comes later
    assert results[3][:2] == ("point", False) and results[3][3] == "far" and "pan_deg" in results[3][2]
    assert results[4][:2] == ("sweep", False) and len(results) == 5


def test_the_guard_watch_learns_watches_and_relearns():
    alerts: list[dict] = []
    watch = GuardWatch(GuardConfig(learn_sweeps=2), alerts.append)
    assert watch.learning and watch.tracks == [] and watch.state() is None
    watch.relearn("before any guard")  # nothing to relearn
    for sweep in (1, 2):
        watch.sweep([ZoneResult(i, 45.0 * i, 0.0, OK, range_m=3.0, sigma_m=0.005) for i in range(8)], sweep, sweep)
    assert not watch.learning and watch.state()["zones"] == 8
    watch.sweep([ZoneResult(i, 30.0 * i, 0.0, OK, range_m=3.0, sigma_m=0.005) for i in range(12)], 3, 3)
    assert watch.learning and watch.state()["zones"] == 12  # another zone count: learnt afresh
    assert alerts == []


def test_the_service_answers_commands_through_its_link(tmp_path):
    config = load_config(None, ["mqtt.enabled=false", f"service.state_dir={json.dumps(str(tmp_path))}"])
    link = Recorder()
    service = Service(config, link=link)
    service.handle_command("calibrate", b'{"distances_m": [0.5, 1.0, 2.0], "request_id": "r"}')
    service.handle_command("point", b'{"pan_deg": 0, "tilt_deg": 0}')
    service.handle_command("sweep", b"{}")
    service.handle_command("mode", b'{"mode": "guard"}')
    assert link.results == [("calibrate", False, "the rig is not running", "r"),
                            ("point", False, "the rig is not running", None),
                            ("sweep", True, None, None), ("mode", True, None, None)]
    assert service.mode == "guard" and link.states[-1]["mode"] == "guard"
    assert set(link.states[-1]) == {"device", "mode", "health", "version", "uptime_s", "sweeps", "camera_restarts"}
