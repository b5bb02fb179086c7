"""edge.mqtt against a real Mosquitto (tests/broker.py): status and Last Will, state, the outbox's
at-least-once, in-order delivery across broker outages and restarts, live messages, commands and
Home Assistant discovery."""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path

import pytest
from broker import Mosquitto, Subscriber, publish

from edge.commands import parse_command, request_id_of
from edge.config import MqttConfig, TlsConfig
from edge.discovery import discovery_payloads
from edge.errors import CommandError, ConfigError
from edge.mqtt import SNAPSHOT_INTERVAL_S, MqttLink
from edge.outbox import Outbox
from edge.topics import Topics, encode, utc_timestamp

log = logging.getLogger(__name__)

DEV = "dev1"
VERSION = "9.9.9"
TS = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$")
T = Topics("edge", DEV)


def config_for(b: Mosquitto | None, **changes) -> MqttConfig:
    # Fast reconnects so that outages in tests last fractions of a second.
    host, port = (b.host, b.port) if b is not None else ("127.0.0.1", 1)
    return MqttConfig(host=host, port=port, keepalive_s=5, reconnect_min_s=0.05, reconnect_max_s=0.3, **changes)


def wait_until(predicate: Callable[[], bool], timeout: float = 5.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


@pytest.fixture
def make_link(broker: Mosquitto, tmp_path: Path) -> Iterator[Callable[..., MqttLink]]:
    """Links on the test's broker, each with its own outbox unless one is given; stopped after."""
    made: list[tuple[MqttLink, Outbox | None]] = []

    def make(device_id: str = DEV, outbox: Outbox | None = None, on_command=None, **changes) -> MqttLink:
        own = None
        if outbox is None:
            outbox = own = Outbox(tmp_path / f"outbox-{len(made)}.sqlite3")
        link = MqttLink(config_for(broker, **changes), device_id, outbox, version=VERSION, on_command=on_command)
        made.append((link, own))
        return link

    yield make
    for link, own in made:
        link.stop(timeout_s=0.5)
        if own is not None:
            own.close()


def started(link: MqttLink) -> MqttLink:
    link.start()
    wait_until(lambda: link.connected, what="the link to connect")
    return link


def sweeps_of(messages) -> list[int]:
    return [json.loads(m.payload)["sweep"] for m in messages]


# ---- pure parts ----


def test_topics_client_id_and_device_id_checks(tmp_path):
    assert (T.status, T.state, T.range, T.sweep, T.alert, T.cue) == tuple(
        f"edge/dev1/{k}" for k in ("status", "state", "range", "sweep", "alert", "cue"))
    assert (T.cmd("mode"), T.result("mode")) == ("edge/dev1/cmd/mode", "edge/dev1/cmd/mode/result")
    with Outbox(tmp_path / "o.sqlite3") as outbox:
        assert MqttLink(config_for(None), DEV, outbox, version=VERSION).client_id == "edge-dev1"
        assert MqttLink(config_for(None, client_id="x"), DEV, outbox, version=VERSION).client_id == "x"
        for bad in ("a/b", "a+", "#", ""):
            with pytest.raises(ConfigError, match=r"^device\.id: "):
                MqttLink(config_for(None), bad, outbox, version=VERSION)


def test_an_unreadable_password_file_is_a_config_error(tmp_path):
    with Outbox(tmp_path / "o.sqlite3") as outbox:
        link = MqttLink(config_for(None, username="u", password_file=str(tmp_path / "nope")), DEV, outbox,
                        version=VERSION)
        with pytest.raises(ConfigError, match=r"^mqtt\.password_file: cannot read .*nope: No such file"):
            link.start()
        assert not link.connected


def test_payloads_are_compact_utf8_json_with_a_millisecond_utc_ts():
    data = encode({"event": "intrusion", "where": "Küche"})
    assert data.startswith(b'{"ts":"') and b" " not in data and "Küche".encode() in data
    body = json.loads(data)
    assert TS.match(body["ts"]) and body["event"] == "intrusion"
    assert json.loads(encode({"ts": "given", "a": 1})) == {"ts": "given", "a": 1}
    assert json.loads(encode({"range_m": float("nan")}))["range_m"] is None
    moment = datetime(2026, 11, 23, 12, 0, 0, 123456, tzinfo=UTC).timestamp()
    assert utc_timestamp(moment) == "2026-11-23T12:00:00.123Z"


# Discovery's payloads are checked against Home Assistant's own rules in tests/test_ha_discovery.py.


# ---- status, Last Will, state ----


def test_online_and_offline_are_retained(broker, subscriber, make_link):
    link = started(make_link())
    assert subscriber.wait_for(T.status).text == "online"
    late = Subscriber(broker)  # a newcomer gets the retained status
    try:
        got = late.wait_for(T.status)
        assert (got.text, got.retain, got.qos) == ("online", True, 1)
    finally:
        late.close()
    link.stop(timeout_s=2)
    assert not link.connected
    subscriber.wait_for(T.status, lambda m: m.text == "offline")
    late = Subscriber(broker)
    try:
        got = late.wait_for(T.status)
        assert (got.text, got.retain) == ("offline", True)
    finally:
        late.close()


CHILD = """
import sys, time
from edge.config import MqttConfig, TlsConfig
from edge.mqtt import MqttLink
from edge.outbox import Outbox
cfg = MqttConfig(host="127.0.0.1", port=int(sys.argv[1]), keepalive_s=5, discovery=False)
MqttLink(cfg, "child", Outbox(sys.argv[2]), version="test").start()
time.sleep(60)
"""


def test_last_will_says_offline_when_the_process_is_killed(broker, subscriber, tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(broker.port), str(tmp_path / "child.sqlite3")],
                            cwd=Path(__file__).resolve().parents[1])
    try:
        subscriber.wait_for("edge/child/status", lambda m: m.text == "online", timeout=15)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=5)
        subscriber.wait_for("edge/child/status", lambda m: m.text == "offline", timeout=5)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    late = Subscriber(broker)
    try:
        got = late.wait_for("edge/child/status")
        assert (got.text, got.retain) == ("offline", True)
    finally:
        late.close()


def test_state_is_retained_and_sent_again_after_a_reconnect(broker, subscriber, make_link):
    n_is = lambda n: lambda m: m.payload and json.loads(m.payload)["n"] == n  # noqa: E731
    link = make_link()
    link.publish_state({"mode": "guard", "n": 1})  # before the first connect: remembered
    started(link)
    got = subscriber.wait_for(T.state, n_is(1))
    assert TS.match(json.loads(got.payload)["ts"]) and got.qos == 1

    broker.stop()
    wait_until(lambda: not link.connected, what="the link to notice the outage")
    link.publish_state({"mode": "blindaid", "n": 2})  # changed while the broker was away
    broker.start()
    subscriber.wait_for(T.state, n_is(2))

    # Sent again at every connect even when unchanged: clear the retained copy, restart the
    # broker, and the state is back.
    publish(broker, T.state, b"", retain=True)
    subscriber.wait_for(T.state, lambda m: m.payload == b"")
    mark = subscriber.mark()
    broker.restart()
    subscriber.wait_for(T.state, n_is(2), since=mark, timeout=10.0)
    # Only now is the retained copy sure to be on the broker: a subscriber that came between the
    # link's connect and its publish would get the state live, with retain False.
    late = Subscriber(broker)
    try:
        got = late.wait_for(T.state)
        body = json.loads(got.payload)
        assert got.retain and body == {"ts": body["ts"], "mode": "blindaid", "n": 2}
    finally:
        late.close()


# ---- snapshots: state and Home Assistant's topics ----


def sends_of(link: MqttLink) -> dict[str, list[float]]:
    """Topic → time.monotonic() of each message the link hands to paho (the device's own pace:
    what the broker delivers to a subscriber comes with its jitter on a loaded machine)."""
    sent: dict[str, list[float]] = {}
    client = link._client
    assert client is not None
    publish_ = client.publish

    def recorded(topic, *args, **kwargs):
        sent.setdefault(topic, []).append(time.monotonic())
        return publish_(topic, *args, **kwargs)

    client.publish = recorded  # type: ignore[method-assign]
    return sent


def test_a_snapshot_goes_out_at_most_twice_a_second_and_its_latest_value_always(broker, subscriber, make_link):
    link = started(make_link())
    sent = sends_of(link)
    mark = subscriber.mark()
    began = time.monotonic()
    for n in range(1, 81):  # 80 states over 2 s or more
        link.publish_state({"n": n})
        time.sleep(0.025)
    ended = time.monotonic()
    got = subscriber.wait_for(T.state, lambda m: json.loads(m.payload)["n"] == 80, since=mark, timeout=5)
    seen = [m for m in subscriber.messages(T.state, since=mark)]
    assert got is seen[-1] and all(m.qos == 1 for m in seen)
    numbers = [json.loads(m.payload)["n"] for m in seen]
    assert numbers == sorted(numbers) and numbers[0] == 1  # the first at once, then the newest waiting
    times = sent[T.state]
    assert len(times) == len(seen) and len(times) <= (ended - began) / SNAPSHOT_INTERVAL_S + 2
    gaps = [b - a for a, b in zip(times, times[1:])]
    # The link keeps SNAPSHOT_INTERVAL_S between the clock readings it decides by; `sends_of` reads
    # the clock a moment later, when paho is called, and that moment varies with the thread's
    # scheduling (a gap of 0.59998 s once, in CI). Values sent as fast as they come would be 0.025 s.
    assert min(gaps) >= SNAPSHOT_INTERVAL_S - 0.05, gaps
    # A longer interval asked for holds a value back longer; a value that changed much, asked with a
    # shorter one, brings the time forward (never below the floor).
    link.publish_snapshot("distance", {"active": True, "range_m": 1.0}, min_interval_s=1.0)  # out at once
    link.publish_snapshot("distance", {"active": True, "range_m": 1.001}, min_interval_s=1.0)
    snap = link._snapshots[T.of("distance")]
    with link._send_lock:
        waits = None if snap.due is None else snap.due - snap.sent_at
    if waits is not None:  # (not yet sent by the sender thread)
        assert waits == pytest.approx(1.0)
    link.publish_snapshot("distance", {"active": True, "range_m": 2.0}, min_interval_s=0.1)
    with link._send_lock:
        waits = None if snap.due is None else snap.due - snap.sent_at
    if waits is not None:
        assert waits == pytest.approx(SNAPSHOT_INTERVAL_S)
    subscriber.wait_for(T.of("distance"), lambda m: json.loads(m.payload)["range_m"] == 2.0, since=mark)
    times = sent[T.of("distance")]
    # 1.001 was replaced before it went out (unless this machine paused us for a second meanwhile).
    assert len(times) in (2, 3) and times[-1] - times[-2] >= SNAPSHOT_INTERVAL_S
    with pytest.raises(ValueError, match="kind must be one of"):
        link.publish_snapshot("range", {})


def test_a_state_whose_health_changed_goes_out_at_once_and_is_not_replaced(broker, subscriber, make_link):
    """A part's fault and its recovery within one snapshot interval (3 s of the simulator's time
    pass in a moment): paced, the fault was replaced by the recovery before it went out, and
    nobody saw it; sent `at_once`, both go out, in order, whatever the pacing holds back."""
    link = started(make_link())
    mark = subscriber.mark()
    link.publish_state({"camera": "ok", "n": 1})
    link.publish_state({"camera": "ok", "n": 2})  # (held back by the pacing)
    link.publish_state({"camera": "fault: no frame", "n": 3}, at_once=True)
    link.publish_state({"camera": "ok", "n": 4}, at_once=True)
    got = subscriber.wait_for(T.state, lambda m: json.loads(m.payload)["n"] == 4, since=mark, timeout=5)
    numbers = [json.loads(m.payload)["n"] for m in subscriber.messages(T.state, since=mark)]
    # (2 is held back by the pacing and replaced by 3, unless this machine stalled for 0.6 s between
    # them: then it went out in its turn. Either way 3 and 4 follow, in order.)
    assert [n for n in numbers if n != 2] == [1, 3, 4] and got.qos == 1


def test_snapshots_are_retained_sent_again_at_every_connect_and_the_last_before_offline(broker, subscriber,
                                                                                        make_link):
    link = started(make_link())
    png = b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 40
    link.publish_snapshot("map", png)
    link.publish_snapshot("guard", {"active": True, "occupied": True, "tracks": 1})
    assert subscriber.wait_for(T.of("map")).payload == png  # bytes as they are, no JSON
    subscriber.wait_for(T.of("guard"))
    broker.stop()
    wait_until(lambda: not link.connected, what="the link to notice the outage")
    link.publish_snapshot("guard", {"active": False, "occupied": False, "tracks": 0})
    # Marked while the broker is down, so nothing can arrive first: the link and the subscriber
    # reconnect the moment the listener opens, which may be before start() sees the broker's log
    # say it runs; a mark taken after start() could then miss all of it.
    mark = subscriber.mark()
    broker.start()
    wait_until(lambda: link.connected, what="the reconnect")
    # (The subscriber may first get the broker's retained copy again, as it re-subscribes.)
    subscriber.wait_for(T.of("guard"), lambda m: json.loads(m.payload)["occupied"] is False, since=mark,
                        timeout=10.0)
    assert subscriber.wait_for(T.of("map"), since=mark, timeout=10.0).payload == png
    late = Subscriber(broker)
    try:
        assert json.loads(late.wait_for(T.of("guard")).payload)["active"] is False
        assert late.wait_for(T.of("map")).retain
    finally:
        late.close()
    # One still waiting for its interval goes out at stop, handed over before `offline`.
    order: list[str] = []
    client = link._client
    publish_ = client.publish
    client.publish = lambda topic, *a, **k: order.append(topic) or publish_(topic, *a, **k)
    link.publish_state({"n": 1})
    link.publish_state({"n": 2})
    link.stop(timeout_s=2)
    subscriber.wait_for(T.state, lambda m: json.loads(m.payload)["n"] == 2)
    subscriber.wait_for(T.status, lambda m: m.text == "offline")
    assert order[-2:] == [T.state, T.status], order


def test_the_last_result_and_the_backlog_are_snapshots_too(broker, subscriber, make_link):
    link = started(make_link())
    assert json.loads(subscriber.wait_for(T.of("backlog")).payload)["messages"] == 0
    link.publish_result("sweep", True, request_id="r1")
    got = subscriber.wait_for(T.of("last_result"))
    assert json.loads(got.payload) | {"ts": None} == {"ts": None, "command": "sweep", "ok": True, "request_id": "r1"}
    link.publish_result("x" * 5000, False, "unknown command")  # a name from outside: cut short
    got = subscriber.wait_for(T.of("last_result"), lambda m: json.loads(m.payload)["ok"] is False)
    assert len(json.loads(got.payload)["command"]) < 100
    # The backlog follows the outbox: events put while the broker is away are counted, and once
    # they are delivered after the reconnect it says 0 again.
    broker.stop()
    wait_until(lambda: not link.connected, what="the link to notice the outage")
    for i in range(5):
        link.publish_event("alert", alert(i))
    mark = subscriber.mark()
    broker.start()
    subscriber.wait_count(T.alert, 5, timeout=10, since=mark)
    wait_until(lambda: link.stats()["pending"] == 0, what="the outbox to drain")
    time.sleep(0.7)  # the backlog's last word, after its interval
    assert json.loads(subscriber.messages(T.of("backlog"), since=mark)[-1].payload)["messages"] == 0


# ---- events: the outbox ----


def alert(i: int) -> dict:
    return {"event": "intrusion", "id": f"t{i % 7}", "zones": [i % 64], "range_m": 1.5, "sweep": i}


def test_events_arrive_in_order_exactly_as_put(broker, subscriber, make_link):
    link = started(make_link())
    n = 200
    for i in range(n):
        link.publish_event("alert", alert(i))
    link.publish_event("sweep", {"sweep": 1, "duration_s": 36.9, "zones": []})
    got = subscriber.wait_count(T.alert, n)
    assert [json.loads(m.payload) | {"ts": None} for m in got] == [alert(i) | {"ts": None} for i in range(n)]
    assert all(m.qos == 1 and not m.retain for m in got)
    wait_until(lambda: link.stats()["pending"] == 0, what="every event to be acknowledged")
    stats = link.stats()
    assert stats["acked"] == n + 1 and stats["sent"] == n + 1
    late = Subscriber(broker)  # the last sweep is retained; alerts are not
    try:
        assert late.wait_for(T.sweep).retain
        time.sleep(0.2)
        assert late.messages(T.alert) == []
    finally:
        late.close()


def test_a_broker_outage_loses_no_event_and_keeps_their_order(broker, subscriber, make_link, record_property):
    link = started(make_link())
    n = 90
    for i in range(30):  # some of these are in flight when the broker goes
        link.publish_event("alert", alert(i))
    broker.stop()
    for i in range(30, 60):  # put while the broker is away
        link.publish_event("alert", alert(i))
    assert not link.connected and link.stats()["pending"] >= 30
    broker.start()
    for i in range(60, n):
        link.publish_event("alert", alert(i))

    wait_until(lambda: set(sweeps_of(subscriber.messages(T.alert))) >= set(range(n)), timeout=15,
               what="every event after the outage")
    received = sweeps_of(subscriber.messages(T.alert))
    first_seen = list(dict.fromkeys(received))
    assert first_seen == list(range(n)), "events out of order"
    # After a reconnect sending starts over from the oldest unacknowledged event: each step is the
    # next event, or a step back to where a re-send (by the link or by the broker) started over.
    assert all(b == a + 1 or b <= a for a, b in zip(received, received[1:])), received
    assert link.stats()["connects"] == 2
    duplicates = len(received) - n
    record_property("duplicates", duplicates)
    log.info("broker outage: %d events, %d duplicate deliveries", n, duplicates)
    wait_until(lambda: link.stats()["pending"] == 0, what="the outbox to empty")


def test_the_outbox_survives_a_restart_of_the_link(broker, tmp_path, make_link):
    path = tmp_path / "kept.sqlite3"
    broker.stop()
    outbox = Outbox(path)
    first = make_link(outbox=outbox)
    first.start()
    for i in range(10):
        first.publish_event("alert", alert(i))
    first.stop(timeout_s=0.3)  # the broker is away: nothing can be delivered
    outbox.close()

    broker.start()
    sub = Subscriber(broker)
    try:
        with Outbox(path) as again:
            assert len(again) == 10
            second = started(make_link(outbox=again))
            got = sub.wait_count(T.alert, 10)
            assert sweeps_of(got) == list(range(10))
            wait_until(lambda: len(again) == 0, what="the outbox to empty")
            second.stop(timeout_s=1)
    finally:
        sub.close()


def test_live_messages_are_dropped_while_disconnected(broker, make_link):
    broker.stop()
    link = make_link()
    link.start()
    assert link.publish_live("range", {"range_m": 1.0}) is False
    assert link.publish_live("cue", {"bearing_deg": 3}) is False
    assert link.stats()["dropped_live"] == 2
    broker.start()
    sub = Subscriber(broker)
    try:
        wait_until(lambda: link.connected, what="the link to connect")
        assert link.publish_live("range", {"range_m": 2.5}) is True
        got = sub.wait_for(T.range)
        assert json.loads(got.payload)["range_m"] == 2.5 and got.qos == 0 and not got.retain
        time.sleep(0.1)
        assert [json.loads(m.payload)["range_m"] for m in sub.messages(T.range)] == [2.5]
        assert link.stats()["live_sent"] == 1
    finally:
        sub.close()


# ---- commands ----


def result_of(sub: Subscriber, name: str, since: int = 0) -> dict:
    body = json.loads(sub.wait_for(T.result(name), since=since).payload)
    assert TS.match(body["ts"])
    return body


def test_a_command_reaches_commands(broker, subscriber, make_link):
    link = started(make_link())
    publish(broker, T.cmd("point"), b'{"pan_deg": 10, "tilt_deg": 0}')
    got: list = []
    wait_until(lambda: got.extend(link.commands()) or got, what="the command")
    assert got == [("point", b'{"pan_deg": 10, "tilt_deg": 0}')]
    assert link.commands() == []


def test_a_command_handler_is_called_instead_when_given(broker, make_link):
    seen: list = []
    link = started(make_link(on_command=lambda name, payload: seen.append((name, payload))))
    publish(broker, T.cmd("sweep"), b"{}")
    wait_until(lambda: seen, what="the handler")
    assert seen == [("sweep", b"{}")] and link.commands() == []


def test_an_oversized_command_is_refused_unread(broker, subscriber, make_link):
    link = started(make_link(max_payload_bytes=256))
    publish(broker, T.cmd("mode"), b"\xff" * 300)  # not even UTF-8: it is never looked at
    body = result_of(subscriber, "mode")
    assert body["ok"] is False and body["error"] == "payload of 300 bytes exceeds mqtt.max_payload_bytes = 256"
    # Far larger ones the broker does not even send us (MQTT 5 Maximum Packet Size): no result,
    # but no harm either.
    publish(broker, T.cmd("mode"), b"x" * 100_000)
    publish(broker, T.cmd("sweep"), b"{}")
    got: list = []
    wait_until(lambda: got.extend(link.commands()) or got, what="the next command")
    assert got == [("sweep", b"{}")]
    assert link.stats()["commands_refused"] == 1 and link.stats()["connects"] == 1 and link.connected
    assert len(subscriber.messages(T.result("mode"))) == 1


def next_commands(link: MqttLink, marker: str) -> list[tuple[str, bytes]]:
    """The commands the link took up to a live `cmd/<marker> {}` sent now (commands arrive in order)."""
    got: list = []
    wait_until(lambda: got.extend(link.commands()) or (marker, b"{}") in got, what=f"cmd/{marker}")
    return got[:got.index((marker, b"{}"))]


def test_a_retained_command_is_ignored(broker, subscriber, make_link):
    publish(broker, T.cmd("lasers_off"), b'{"request_id": "stale"}', retain=True)
    link = started(make_link())
    body = result_of(subscriber, "lasers_off")
    assert body["ok"] is False and body["error"].startswith("retained command ignored")
    assert body["request_id"] == "stale"
    publish(broker, T.cmd("sweep"), b"{}")
    got: list = []
    wait_until(lambda: got.extend(link.commands()) or got, what="a live command")
    assert got == [("sweep", b"{}")]


def test_a_retained_command_is_ignored_when_it_comes_live_or_was_kept_for_an_offline_device(
        broker, subscriber, make_link):
    # Issue 13, item 9: with MQTT 5's default subscription (retain_as_published off) the broker
    # clears the retain flag on live delivery, and on messages kept for an offline session: both
    # were carried out. The device now subscribes with retain_as_published.
    link = started(make_link())
    publish(broker, T.cmd("sweep"), b'{"request_id": "live"}', retain=True)
    body = result_of(subscriber, "sweep")
    assert body["ok"] is False and body["error"].startswith("retained command ignored")
    publish(broker, T.cmd("relearn"), b"{}")
    assert next_commands(link, "relearn") == []
    link.stop(timeout_s=1.0)  # the session stays with the broker
    mark = subscriber.mark()
    publish(broker, T.cmd("mode"), b'{"mode": "guard", "request_id": "offline"}', retain=True)
    again = started(make_link())  # the same device id, so the same client id and session
    body = result_of(subscriber, "mode", since=mark)
    assert body["ok"] is False and body["request_id"] == "offline" and "retained" in body["error"]
    publish(broker, T.cmd("relearn"), b"{}")
    assert next_commands(again, "relearn") == []


def test_an_empty_message_clears_a_retained_command_and_does_nothing(broker, subscriber, make_link):
    # Issue 13, item 9: the README's way to clear a retained command (an empty retained message)
    # started a sweep, since an empty payload stood for {}. An empty message is no command now,
    # retained or not: nothing is carried out and nothing is answered.
    link = started(make_link())
    publish(broker, T.cmd("sweep"), b"{}", retain=True)
    result_of(subscriber, "sweep")
    mark = subscriber.mark()
    publish(broker, T.cmd("sweep"), b"", retain=True)  # clears it at the broker
    publish(broker, T.cmd("lasers_off"), b"")  # and a plain empty message
    publish(broker, T.cmd("relearn"), b"{}")
    assert next_commands(link, "relearn") == []
    assert subscriber.messages(T.result("sweep"), since=mark) == []
    assert subscriber.messages(T.result("lasers_off"), since=mark) == []
    late = Subscriber(broker, (T.cmd("sweep"),), persistent=False)  # nothing is retained any more
    try:
        time.sleep(0.5)
        assert late.messages() == []
    finally:
        late.close()


def test_the_request_id_is_echoed(broker, subscriber, make_link):
    link = started(make_link())
    publish(broker, T.cmd("point"), b'{"pan_deg": 500, "tilt_deg": 0, "request_id": "r-17"}')
    publish(broker, T.cmd("sweep"), b'{"request_id": "r-18"}')
    got: list = []
    wait_until(lambda: got.extend(link.commands()) or len(got) == 2, what="two commands")
    for name, payload in got:  # what the service does with them
        try:
            command = parse_command(name, payload, max_bytes=4096, pan_limits=(-159, 159), tilt_limits=(-47, 31))
        except CommandError as exc:
            link.publish_result(name, False, str(exc), request_id_of(payload))
        else:
            link.publish_result(name, True, request_id=command.request_id)
    bad, good = result_of(subscriber, "point"), result_of(subscriber, "sweep")
    assert bad == {"ts": bad["ts"], "ok": False, "request_id": "r-17",
                   "error": "cmd/point: pan_deg = 500 is outside the pan limits -159..159°"}
    assert good == {"ts": good["ts"], "ok": True, "request_id": "r-18"}
    assert not subscriber.wait_for(T.result("point")).retain


# ---- Home Assistant ----


def test_discovery_is_retained_and_sent_again_when_home_assistant_comes_online(broker, subscriber, make_link):
    link = started(make_link())
    expected = discovery_payloads(link.config, DEV, VERSION)
    for topic, body in expected.items():
        assert json.loads(subscriber.wait_for(topic).payload) == body
    late = Subscriber(broker)
    try:
        for topic in expected:
            assert late.wait_for(topic).retain
    finally:
        late.close()
    mark = subscriber.mark()
    publish(broker, "homeassistant/status", b"online")
    for topic in expected:
        subscriber.wait_for(topic, since=mark)


def test_no_discovery_when_disabled(broker, subscriber, make_link):
    started(make_link(discovery=False))
    subscriber.wait_for(T.status)
    time.sleep(0.2)
    assert not [m for m in subscriber.messages() if m.topic.startswith("homeassistant/")]


# ---- authentication and TLS ----


def test_username_and_password_file(tmp_path):
    with Mosquitto(passwords={"edge": "s3cret"}) as b:
        secret = tmp_path / "secret"
        secret.write_text("s3cret\n")
        wrong = tmp_path / "wrong"
        wrong.write_text("nope\n")
        with Outbox(tmp_path / "a.sqlite3") as ob_a, Outbox(tmp_path / "b.sqlite3") as ob_b:
            good = MqttLink(config_for(b, username="edge", password_file=str(secret)), "a", ob_a, version=VERSION)
            bad = MqttLink(config_for(b, username="edge", password_file=str(wrong)), "b", ob_b, version=VERSION)
            try:
                started(good)
                bad.start()
                time.sleep(0.5)
                assert not bad.connected
            finally:
                good.stop(timeout_s=1)
                bad.stop(timeout_s=0.2)


def test_tls(tmp_path):
    openssl = shutil.which("openssl")
    if openssl is None:
        pytest.skip("openssl is needed to make a test certificate (apt-get install openssl)")
    cert, key = str(tmp_path / "cert.pem"), str(tmp_path / "key.pem")
    subprocess.run([openssl, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", key, "-out", cert,
                    "-days", "1", "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1"],
                   check=True, capture_output=True)
    with Mosquitto(tls=(cert, cert, key)) as b, Outbox(tmp_path / "o.sqlite3") as outbox:
        with pytest.raises(ConfigError, match=r"^mqtt\.tls\.ca_file: no such file: "):
            MqttLink(config_for(b, tls=TlsConfig(enabled=True, ca_file=str(tmp_path / "nope.pem"))), DEV,
                     outbox, version=VERSION).start()
        link = MqttLink(config_for(b, tls=TlsConfig(enabled=True, ca_file=cert)), DEV, outbox, version=VERSION)
        try:
            started(link)
        finally:
            link.stop(timeout_s=1)


def test_a_command_that_cannot_be_answered_is_dropped_and_publish_result_never_raises(broker, subscriber, make_link):
    # Issue 13, item 1: `cmd/<name>/result` for a name of ~65,520 bytes is beyond MQTT's 65,535-byte
    # topic limit; paho raised ValueError in the service's thread and the process died.
    link = started(make_link())
    publish(broker, T.cmd("x" * (65535 - len(T.cmd_prefix))), b"{}")
    publish(broker, T.cmd("sweep"), b"{}")
    assert next_commands(link, "sweep") == []
    assert link.stats()["commands_dropped"] == 1 and link.connected
    for name in ("y" * 65535, "a/b", "", "\ud800"):
        link.publish_result(name, False, "no")  # logged and dropped: the name came from outside
    link.publish_result("mode", True, request_id="still-fine")
    assert result_of(subscriber, "mode")["request_id"] == "still-fine"


def test_the_device_listens_before_it_says_online(tmp_path: Path) -> None:
    """Whoever sees `online` and sends a command at once must find the device subscribed: the
    broker takes one client's packets in order, so SUBSCRIBE has to go out before PUBLISH online
    (seen lost in a clean clone, when the other way round)."""
    with Mosquitto(extra="log_type debug") as debug_broker:
        outbox = Outbox(tmp_path / "outbox.sqlite3")
        link = MqttLink(config_for(debug_broker), DEV, outbox, version=VERSION)
        try:
            started(link)
            wait_until(lambda: "Received SUBSCRIBE" in debug_broker.log_path.read_text()
                       and "status" in debug_broker.log_path.read_text(), what="the broker's log")
        finally:
            link.stop(timeout_s=0.5)
            outbox.close()
        lines = debug_broker.log_path.read_text().splitlines()
    mine = [i for i, line in enumerate(lines) if f"from edge-{DEV}" in line]
    subscribe = next(i for i in mine if "Received SUBSCRIBE" in lines[i])
    online = next(i for i in mine if "Received PUBLISH" in lines[i] and f"'edge/{DEV}/status'" in lines[i])
    assert subscribe < online, lines[subscribe - 1:online + 2]


def unreachable_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.levelno == logging.WARNING and "cannot reach" in r.getMessage()]


def test_an_unreachable_broker_is_one_warning_an_outage(broker, make_link, caplog):
    """A user without a broker reads one line that names it, not one per retry, and again at the
    next outage."""
    caplog.set_level(logging.DEBUG, logger="edge.mqtt")
    broker.stop()
    link = make_link()
    link.start()
    wait_until(lambda: len(unreachable_warnings(caplog)) == 1, what="the warning")
    time.sleep(1.0)  # several retries at 0.05–0.3 s
    assert unreachable_warnings(caplog) == [
        f"MQTT: cannot reach {broker.host}:{broker.port}; retrying (back-off 0.05–0.3 s); events wait in the outbox"]
    broker.start()
    wait_until(lambda: link.connected, what="the link to connect")
    broker.stop()
    wait_until(lambda: len(unreachable_warnings(caplog)) == 2, what="the warning of the second outage")


def test_stopping_while_the_broker_is_unreachable_logs_no_error(broker, tmp_path, caplog):
    """paho logs "Client is not connected" as an error when stopped while still connecting: a
    device without its broker must not end every run with an error that means nothing."""
    caplog.set_level(logging.DEBUG, logger="edge.mqtt")
    broker.stop()
    outbox = Outbox(tmp_path / "outbox.sqlite3")
    # The default back-off's first wait (1 s) is when `edge run` without a broker is stopped.
    config = MqttConfig(host=broker.host, port=broker.port, reconnect_min_s=1.0, reconnect_max_s=60.0)
    link = MqttLink(config, DEV, outbox, version=VERSION)
    link.start()
    wait_until(lambda: len(unreachable_warnings(caplog)) == 1, what="the warning")
    link.stop(timeout_s=0.5)
    outbox.close()
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR] == []
