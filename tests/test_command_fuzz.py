"""The command path fuzzed end to end (issue 13): topic names up to MQTT's 65,535 bytes and payloads
up to the size limit and a little past it, retained or not, sent through a real Mosquitto to a real
`edge run` on the simulated rig in range-finder mode. Whatever comes, the process lives on (its PID
never changes), it still obeys a command afterwards, and ranges keep coming.

Deterministic (``derandomize=True``, no example database) and bounded: a fixed number of examples.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from broker import Mosquitto, Subscriber
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from edge.commands import COMMANDS
from edge.topics import MAX_TOPIC_BYTES

DEVICE = "fz1"
P = f"edge/{DEVICE}"
CMD = f"{P}/cmd/"
LIMIT = 65536  # mqtt.max_payload_bytes (the default)
EXAMPLES = 100


@dataclass
class Device:
    broker: Mosquitto
    proc: subprocess.Popen
    pid: int
    sub: Subscriber
    pub: mqtt.Client
    log: Path


@pytest.fixture(scope="module")
def device(tmp_path_factory) -> Iterator[Device]:
    tmp = tmp_path_factory.mktemp("command-fuzz")
    with Mosquitto() as broker:
        log = tmp / "edge.log"
        sets = [f"device.id={json.dumps(DEVICE)}", f"mqtt.port={broker.port}", 'mqtt.host="127.0.0.1"',
                f"service.state_dir={json.dumps(str(tmp / 'state'))}", 'mode="rangefinder"',
                "rangefinder.pan_deg=-90.0", f"mqtt.max_payload_bytes={LIMIT}",
                "sweep.zones=4", "sweep.pan_step_deg=10.0"]  # a fuzzed cmd/sweep is over quickly
        args = [sys.executable, "-m", "edge", "run", *[a for s in sets for a in ("--set", s)]]
        with log.open("w") as err:  # a file, not a pipe: a chatty run must never block on its stderr
            proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=err)
        sub = Subscriber(broker, (f"{P}/status", f"{P}/range", f"{CMD}mode/result"), persistent=False)
        pub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"fuzz-{uuid.uuid4().hex[:8]}",
                          protocol=mqtt.MQTTv5)
        pub.connect(broker.host, broker.port, keepalive=30)
        pub.loop_start()
        try:
            sub.wait_for(f"{P}/status", lambda m: m.payload == b"online", timeout=60)
            sub.wait_count(f"{P}/range", 5, timeout=60)
            yield Device(broker, proc, proc.pid, sub, pub, log)
        finally:
            pub.disconnect()
            pub.loop_stop()
            sub.close()
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(30)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()


# ---- what is sent ----

# Characters a broker takes in a topic: no wildcards, no NUL or other control characters, no
# surrogates or unassigned code points (Mosquitto refuses those as malformed UTF-8). '/' is in:
# deeper levels under cmd/ must be ignored too.
_CHAR = st.characters(blacklist_categories=("Cc", "Cs", "Cn"), blacklist_characters="+#\0")
_NAMES = st.one_of(
    st.sampled_from([*COMMANDS, "", "result", "sweep/result", "mode/x", "x" * 64]),
    st.text(_CHAR, max_size=40),
    # Long ones: a short pattern repeated up to the whole topic, cut to MQTT's limit below.
    st.builds(lambda pattern, n: pattern * n, st.text(_CHAR, min_size=1, max_size=4),
              st.integers(1, MAX_TOPIC_BYTES)),
)
_JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=12), inner, max_size=4),
    max_leaves=12,
)
_KEYS = st.sampled_from(["mode", "pan_deg", "tilt_deg", "distances_m", "request_id", "x"])
_PAYLOADS = st.one_of(
    st.just(b""),
    st.binary(max_size=64),
    st.dictionaries(_KEYS, _JSON, max_size=4).map(lambda d: json.dumps(d).encode()),
    st.builds(lambda mode, rid: json.dumps({"mode": mode, "request_id": rid}).encode(),
              st.sampled_from(["rangefinder", "guard", "blindaid", "disco"]), st.text(max_size=200)),
    # Large ones, up to the limit and just past it (refused unread).
    st.builds(lambda pattern, n: (pattern * (n // len(pattern) + 1))[:n], st.binary(min_size=1, max_size=8),
              st.integers(0, LIMIT + 64)),
)


def topic_of(name: str) -> str:
    """`cmd/<name>`, cut (at a character boundary) to MQTT's 65,535 bytes."""
    budget = MAX_TOPIC_BYTES - len(CMD.encode())
    return CMD + name.encode("utf-8")[:budget].decode("utf-8", "ignore")


def send(device: Device, topic: str, payload: bytes, retain: bool = False) -> None:
    info = device.pub.publish(topic, payload, qos=1, retain=retain)
    info.wait_for_publish(timeout=30)
    assert info.is_published(), f"the broker did not take a message on {topic[:80]}…"


# ---- the test ----


def test_no_command_kills_or_stops_the_service(device):
    sent = {"n": 0, "longest_topic": 0, "largest_payload": 0}

    @settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                     HealthCheck.function_scoped_fixture])
    @given(name=_NAMES, payload=_PAYLOADS, retain=st.booleans())
    # The edges, always: the longest topic (its result topic cannot exist), one whose result just
    # fits, payloads at the limit and one byte past it, an empty retained one.
    @example(name="x" * MAX_TOPIC_BYTES, payload=b"{}", retain=False)
    @example(name="y" * (MAX_TOPIC_BYTES - len(CMD) - len("/result")), payload=b"{}", retain=False)
    @example(name="mode", payload=b" " * LIMIT, retain=False)
    @example(name="point", payload=b"{" * (LIMIT + 1), retain=True)
    @example(name="sweep", payload=b"", retain=True)
    def one(name: str, payload: bytes, retain: bool) -> None:
        topic = topic_of(name)
        send(device, topic, payload, retain)
        sent["n"] += 1
        sent["longest_topic"] = max(sent["longest_topic"], len(topic.encode()))
        sent["largest_payload"] = max(sent["largest_payload"], len(payload))
        assert device.proc.poll() is None, f"edge run exited ({device.proc.returncode}) after {topic[:80]}…"

    one()
    assert sent["n"] >= EXAMPLES // 2 and sent["longest_topic"] == MAX_TOPIC_BYTES
    assert sent["largest_payload"] > LIMIT
    # Commands are carried out in order: once this one is answered, every fuzzed one was taken. It
    # also ends a pause (a fuzzed cmd/lasers_off) or another mode the fuzzing chose.
    mark = device.sub.mark()
    send(device, f"{CMD}mode", b'{"mode": "rangefinder", "request_id": "after-the-fuzz"}')
    result = json.loads(device.sub.wait_for(f"{CMD}mode/result", lambda m: b"after-the-fuzz" in m.payload,
                                            since=mark, timeout=300).payload)
    assert result["ok"] is True
    mark = device.sub.mark()
    device.sub.wait_count(f"{P}/range", 10, timeout=120, since=mark)
    assert device.proc.poll() is None and device.proc.pid == device.pid
    assert os.path.exists(f"/proc/{device.pid}")
    device.proc.send_signal(signal.SIGTERM)
    assert device.proc.wait(60) == 0
    text = device.log.read_text(errors="replace")
    assert "Traceback" not in text, text[-3000:]
