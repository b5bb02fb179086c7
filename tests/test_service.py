"""`edge run` end to end: the real process on the simulated rig, a real Mosquitto, a test
NOTIFY_SOCKET. Topics and payloads are checked against ../shared/spec/mqtt.md."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

import pytest
from broker import Mosquitto, Subscriber, publish

DEVICE = "dev1"
P = f"edge/{DEVICE}"
TS = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$")


def start(broker: Mosquitto, tmp_path: Path, *sets: str, run_for: float | None = None,
          env: dict | None = None, config: Path | None = None) -> subprocess.Popen:
    args = [sys.executable, "-m", "edge", "run", *(["--config", str(config)] if config else []),
            "--set", f"device.id={json.dumps(DEVICE)}",
            "--set", f"mqtt.port={broker.port}", "--set", 'mqtt.host="127.0.0.1"',
            "--set", f"service.state_dir={json.dumps(str(tmp_path / 'state'))}",
            "--set", "mqtt.reconnect_min_s=0.2", "--set", "mqtt.reconnect_max_s=1.0"]
    for s in sets:
        args += ["--set", s]
    if run_for is not None:
        args += ["--for", str(run_for)]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, **(env or {})})


def payload(m) -> dict:
    data = json.loads(m.payload)
    assert isinstance(data, dict) and TS.match(data["ts"]), m.payload
    return data


def finish(proc: subprocess.Popen, timeout: float = 300) -> str:
    # A bound for a failure, not a speed: `--for` counts the simulated rig's seconds, which a loaded
    # machine renders slower than real time.
    _, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    return err


def heard_to_the_end(subscriber: Subscriber) -> None:
    """Wait until `subscriber` has the `offline` that a stopped service publishes last, after its
    last state: then it has every message the service published before it (the broker hands one
    client's messages on in order). A process's exit says nothing of what is still on its way to
    the subscriber."""
    started = [i for i, m in enumerate(subscriber.messages()) if m.topic == f"{P}/status" and m.payload == b"online"]
    subscriber.wait_for(f"{P}/status", lambda m: m.payload == b"offline", since=started[-1] if started else 0,
                        timeout=30)


def test_a_range_finder_run_publishes_every_topic_of_the_contract(broker, subscriber, tmp_path):
    proc = start(broker, tmp_path, "mode=\"rangefinder\"", "rangefinder.pan_deg=-90.0", run_for=8)
    online = subscriber.wait_for(f"{P}/status", lambda m: m.payload == b"online", timeout=20)
    assert online.retain or True  # live delivery of a retained message carries retain=0 in MQTT 5
    state = payload(subscriber.wait_for(f"{P}/state", timeout=10))
    assert state["mode"] == "rangefinder" and set(state["health"]) == {"camera", "lasers", "ptu", "calibration",
                                                                                 "storage"}
    assert state["device"] == DEVICE and "version" in state and "uptime_s" in state and "sweeps" in state
    # One range per camera frame: about 30 a second, each a zone result of geometry.md.
    ranges = subscriber.wait_count(f"{P}/range", 60, timeout=20)
    r = payload(ranges[-1])
    assert r["status"] == "ok" and abs(r["range_m"] - 1.30) < 0.02 and r["sigma_m"] > 0
    assert abs(r["filtered_m"] - 1.30) < 0.02 and r["pan_deg"] == pytest.approx(-90.0, abs=0.06)
    # Home Assistant discovery: a distance sensor, a motion binary sensor and a mode select.
    configs = [m for m in subscriber.messages() if m.topic.startswith("homeassistant/")]
    kinds = {m.topic.split("/")[1] for m in configs}
    assert {"sensor", "binary_sensor", "select"} <= kinds
    for m in configs:
        cfg = json.loads(m.payload)
        assert cfg["availability"][0]["topic"] == f"{P}/status" and cfg["device"]["identifiers"]
    finish(proc)
    last = subscriber.wait_for(f"{P}/status", lambda m: m.payload == b"offline", timeout=10)
    assert last.at > ranges[-1].at
    # Retained for late comers: offline and the last state.
    late = Subscriber(broker, (f"{P}/status", f"{P}/state"), persistent=False)
    try:
        assert late.wait_for(f"{P}/status", timeout=5).payload == b"offline"
        assert payload(late.wait_for(f"{P}/state", timeout=5))["mode"] == "rangefinder"
    finally:
        late.close()


def test_commands_are_validated_and_answered_and_the_service_runs_on(broker, subscriber, tmp_path):
    # Stopped by SIGTERM when done; --for only in case the test fails half-way (simulated seconds
    # may pass faster than real ones: no test relies on --for outlasting what it does meanwhile).
    proc = start(broker, tmp_path, "mode=\"rangefinder\"", run_for=600)
    subscriber.wait_for(f"{P}/status", lambda m: m.payload == b"online", timeout=20)
    subscriber.wait_count(f"{P}/range", 5, timeout=20)
    hostile = [
        ("mode", b"{not json", "JSON"),
        ("mode", b'{"mode": "disco"}', "mode"),
        ("mode", b'{"mode": 3}', "mode"),
        ("point", b'{"pan_deg": "left", "tilt_deg": 0}', "pan_deg"),
        ("point", b'{"pan_deg": 1e9, "tilt_deg": 0}', "pan_deg"),
        ("point", b'{"pan_deg": 0, "tilt_deg": 0, "rm -rf": 1}', "rm -rf"),
        ("selfdestruct", b"{}", "selfdestruct"),
        ("sweep", b"\xff\xfe", "UTF-8"),
        ("mode", b'{"mode": "guard", "pad": "' + b"x" * 70000 + b'"}', "max_payload_bytes"),
    ]
    for i, (name, body, word) in enumerate(hostile):
        mark = subscriber.mark()
        request = body
        if body.startswith(b"{") and len(body) < 1000 and b"not json" not in body:
            request = json.dumps({**json.loads(body), "request_id": f"r{i}"}).encode()
        publish(broker, f"{P}/cmd/{name}", request)
        result = payload(subscriber.wait_for(f"{P}/cmd/{name}/result", since=mark, timeout=10))
        assert result["ok"] is False and word.lower() in result["error"].lower(), (name, result)
        assert "\n" not in result["error"]
        if b"request_id" in request:
            assert result.get("request_id") == f"r{i}", (name, request[:80], result)
    # The service runs on, unchanged: still ranging, still in its mode.
    mark = subscriber.mark()
    subscriber.wait_count(f"{P}/range", 5, timeout=10, since=mark)
    # A good command changes the mode, says so in the retained state, and the result echoes the id.
    mark = subscriber.mark()
    publish(broker, f"{P}/cmd/mode", b'{"mode": "guard", "request_id": "go"}')
    result = payload(subscriber.wait_for(f"{P}/cmd/mode/result", since=mark, timeout=10))
    assert result == {**result, "ok": True, "request_id": "go"}
    state = subscriber.wait_for(f"{P}/state", lambda m: json.loads(m.payload)["mode"] == "guard",
                                since=mark, timeout=10)
    assert payload(state)["mode"] == "guard"
    mark = subscriber.mark()
    publish(broker, f"{P}/cmd/lasers_off", b"{}")
    assert payload(subscriber.wait_for(f"{P}/cmd/lasers_off/result", since=mark, timeout=10))["ok"] is True
    proc.send_signal(signal.SIGTERM)
    finish(proc)
    subscriber.wait_for(f"{P}/status", lambda m: m.payload == b"offline", since=mark, timeout=10)


def test_a_killed_service_leaves_its_last_will(broker, subscriber, tmp_path):
    proc = start(broker, tmp_path, "mode=\"rangefinder\"")
    try:
        subscriber.wait_for(f"{P}/status", lambda m: m.payload == b"online", timeout=20)
        mark = subscriber.mark()
        proc.kill()  # SIGKILL: no handler runs, no clean disconnect
        proc.wait(10)
        # The broker publishes the Last Will when it notices (at once, as the socket closes).
        subscriber.wait_for(f"{P}/status", lambda m: m.payload == b"offline", since=mark, timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()


# The device's reconnect back-off in the outage tests: it is back within 0.3 s of the broker (the
# subscriber's is the same), so that an outage's "up" part is the reconnect, not a wait of its own.
QUICK_RECONNECT = ("mqtt.reconnect_min_s=0.05", "mqtt.reconnect_max_s=0.3")


def take_the_broker_away(broker: Mosquitto, subscriber: Subscriber, down_s: Callable[[int], float],
                         times: int = 10) -> list[tuple[float, float]]:
    """Stop and restart the broker `times` times, down for `down_s(k)` seconds each and up until
    the device has connected again (its `online`, which it sends at every connect, has reached
    the subscriber); returns the (stopped, restarted) wall-clock times."""
    outages = []
    for k in range(times):
        broker.stop()
        down = time.time()
        time.sleep(down_s(k))
        outages.append((down, time.time()))
        mark = subscriber.mark()
        broker.restart()
        # A bound for a failure, not a speed (a loaded machine): the device reconnects.
        subscriber.wait_for(f"{P}/status", lambda m: m.payload == b"online", since=mark, timeout=120)
    return outages


def outage_until_queued(broker: Mosquitto, state: Path, count: int, timeout: float = 300.0) -> tuple[float, float]:
    """Stop the broker until the device has queued about `count` messages in its outbox (it makes
    them while the broker is away: its loop never waits for the broker), then start it again;
    returns the (stopped, restarted) wall-clock times. The outages of `take_the_broker_away` last
    a second or two, which a loaded machine may spend without finishing a sweep. The queue is
    watched from outside (its files changing): the device holds it locked, as it should."""
    def files() -> tuple:
        found = []
        for path in sorted(state.glob("outbox.sqlite3*")):
            with contextlib.suppress(OSError):
                st = path.stat()
                found.append((path.name, st.st_mtime_ns, st.st_size))
        return tuple(found)

    broker.stop()
    down = time.time()
    deadline = time.monotonic() + timeout
    try:
        seen, changes = files(), 0
        while changes < count and time.monotonic() < deadline:
            time.sleep(0.05)
            now = files()
            if now != seen:
                seen, changes = now, changes + 1
        time.sleep(0.2)  # made well inside the outage, not at its edge
        return down, time.time()
    finally:
        broker.restart()


def made_while_down(docs: list[dict], outages: list[tuple[float, float]]) -> list[dict]:
    """The published documents whose `ts` falls inside an outage."""
    def made(doc: dict) -> float:  # to the millisecond: outages last a second or two
        return datetime.fromisoformat(doc["ts"].replace("Z", "+00:00")).timestamp()

    return [doc for doc in docs if any(a + 0.1 < made(doc) < b - 0.1 for a, b in outages)]


@pytest.mark.slow
def test_sweeps_published_while_the_broker_is_down_all_arrive_in_order(broker, subscriber, tmp_path):
    # Small sweeps back to back (a map sweep every 0.5 s in range-finder mode), the broker stopped
    # ten times for about a second: every sweep arrives, once or more, in order, and the device
    # kept sweeping while the broker was away (its loop never waits for the broker).
    proc = start(broker, tmp_path, "sweep.zones=3", "sweep.pan_step_deg=10.0", "service.sweep_interval_s=0.5",
                 *QUICK_RECONNECT)
    try:
        first = subscriber.wait_count(f"{P}/sweep", 2, timeout=300)  # bounds for a loaded machine
        outages = take_the_broker_away(broker, subscriber, lambda k: 0.6 + 0.2 * (k % 4))
        outages.append(outage_until_queued(broker, tmp_path / "state", 5))
        mark = subscriber.mark()
        subscriber.wait_count(f"{P}/sweep", 3, timeout=300, since=mark)
        proc.send_signal(signal.SIGTERM)
        err = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    heard_to_the_end(subscriber)
    numbers = [payload(m)["sweep"] for m in subscriber.messages(f"{P}/sweep")]
    assert numbers[:len(first)] == list(range(1, len(first) + 1))
    seen = list(dict.fromkeys(numbers))  # first sightings
    assert seen == list(range(1, max(numbers) + 1)), numbers  # none lost, in order
    for a, b in zip(numbers, numbers[1:]):
        assert b == a + 1 or b <= a, numbers  # a repeat steps back, then goes on in order
    docs = [payload(m) for m in subscriber.messages(f"{P}/sweep")]
    assert all(len(doc["zones"]) == 3 and doc["duration_s"] > 0 for doc in docs)
    assert len(made_while_down(docs, outages)) >= 5  # swept (and queued) while the broker was away
    # What the process knew it had delivered left the queue; nothing is stuck in it. Stopping, it
    # sends what it can for a few seconds and says how many it leaves for the next start: a loaded
    # machine may still be sending the last outage's backlog (137 left once, under CI's load).
    import re
    import sqlite3

    said = re.search(r"MQTT: (\d+) queued message\(s\) stay in the outbox", err)
    rows = sqlite3.connect(tmp_path / "state" / "outbox.sqlite3").execute("select count(*) from outbox").fetchone()
    assert rows[0] <= (int(said.group(1)) if said else 0), err[-2000:]


@pytest.mark.slow
def test_systemd_notifications_and_watchdog(broker, tmp_path):
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(0.5)
    env = {"NOTIFY_SOCKET": str(path), "WATCHDOG_USEC": "1000000"}  # 1 s: fed every 0.5 s
    # Real time: systemd's watchdog is.
    proc = start(broker, tmp_path, "mode=\"rangefinder\"", 'sim.clock="real"', run_for=6, env=env)
    messages: list[str] = []
    heard: list[float] = []
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            messages.append(sock.recv(4096).decode())
            heard.append(time.monotonic())
        except TimeoutError:
            pass
    finish(proc)
    sock.close()
    assert "READY=1" in messages
    ready, stopping = messages.index("READY=1"), messages.index("STOPPING=1")
    assert ready < stopping
    feeds = [t for m, t in zip(messages, heard) if m == "WATCHDOG=1"]
    # About every 0.5 s while running (6 s of it, less the rig's start on a loaded machine): at
    # least one every 2 s, counted over the time it really ran (a loaded machine starves it).
    assert len(feeds) >= max(2, (heard[stopping] - heard[ready]) / 2), messages
    assert any(m.startswith("STATUS=running") for m in messages)


WALKER = """
name = "office-visitor"
description = "the office; a visitor steps in at t = {start} s, stands twice, leaves"
extends = "office"

[[movers]]
name = "visitor"
size_m = [0.45, 0.30, 1.75]
material = "person"
speed_mps = 0.8
start_s = {start}
path_m = [[4.4, 2.25], [3.0, 2.0], [3.0, 0.95], [3.5, 1.5], [4.4, 2.25]]
pause_s = [0.0, {stand}, {stand}, {stand}, 0.0]
"""


def _raised(stderr: str) -> list[tuple[str, str, str]]:
    """(event, track, zones) of every alert the service logged as it raised it."""
    return re.findall(r"guard: (intrusion|moved|cleared) (b\d+-t\d+) in zones (\[[\d, ]*\])", stderr)


@pytest.mark.slow
def test_guard_alerts_survive_ten_broker_outages_exactly_as_raised_and_in_order(broker, subscriber, tmp_path, repo):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "office.toml").write_text((repo / "config" / "scenes" / "office.toml").read_text())
    (scenes / "visitor.toml").write_text(WALKER.format(start=14.0, stand=10.0))
    proc = start(broker, tmp_path, 'mode="guard"', f"sim.scene={json.dumps(str(scenes / 'visitor.toml'))}",
                 "sweep.zones=32", "sweep.pan_step_deg=11.25", "guard.learn_sweeps=2", "ptu.settle_ms=10.0",
                 *QUICK_RECONNECT)
    try:
        # Learning done: the state says so. Then the visitor comes; while the guard follows them,
        # take the broker away and bring it back ten times.
        # (Timeouts bound a failure: the visitor keeps the rig's simulated time, which a loaded
        # machine renders slower than real time.)
        subscriber.wait_for(f"{P}/state", lambda m: json.loads(m.payload).get("guard", {}).get("learning") is False,
                            timeout=300)
        subscriber.wait_for(f"{P}/alert", lambda m: json.loads(m.payload)["event"] == "intrusion", timeout=300)
        outages = take_the_broker_away(broker, subscriber, lambda k: 1.5 + 0.3 * (k % 3))
        outages.append(outage_until_queued(broker, tmp_path / "state", 3))
        subscriber.wait_for(f"{P}/alert", lambda m: json.loads(m.payload)["event"] == "cleared", timeout=300)
        proc.send_signal(signal.SIGTERM)
        err = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    heard_to_the_end(subscriber)
    raised = _raised(err)
    got = [payload(m) for m in subscriber.messages(f"{P}/alert")]
    firsts = list(dict.fromkeys((a["event"], a["id"], str(a["zones"]).replace(" ", ""), a["sweep"]) for a in got))
    assert [(e, i, z) for e, i, z, _ in firsts] == [(e, i, z.replace(" ", "")) for e, i, z in raised], (firsts, raised)
    events = [e for e, _, _ in raised]
    assert events[0] == "intrusion" and events[-1] == "cleared" and "moved" in events
    for a in got:
        assert set(a) >= {"ts", "event", "id", "zones", "bearing_deg", "range_m", "baseline_m", "velocity_mps", "sweep"}
        assert a["range_m"] < a["baseline_m"] or a["event"] == "cleared"
    # The guard's sweeps went through the same outages: none lost, in order; and it went on
    # sweeping and alerting while the broker was away (its loop never waits for the broker).
    numbers = list(dict.fromkeys(payload(m)["sweep"] for m in subscriber.messages(f"{P}/sweep")))
    assert numbers == list(range(1, max(numbers) + 1)), numbers
    sweeps = [payload(m) for m in subscriber.messages(f"{P}/sweep")]
    assert made_while_down([*got, *sweeps], outages), outages  # 4 of 11-12 in runs here (the sweeps test asks more)


def _beeps(path: Path) -> tuple[int, list[tuple[float, float, float]]]:
    """(sample rate, [(onset s, pitch Hz, left/right energy ratio)]) of the sounds in a WAV."""
    import wave

    import numpy as np

    with wave.open(str(path)) as w:
        rate, n = w.getframerate(), w.getnframes()
        assert w.getnchannels() == 2 and w.getsampwidth() == 2
        x = np.frombuffer(w.readframes(n), np.int16).reshape(-1, 2).astype(float)
    k = int(0.004 * rate)
    env = np.sqrt(np.convolve((x ** 2).sum(axis=1), np.ones(k) / k, mode="same"))
    on = env > 0.1 * env.max()
    onsets = np.flatnonzero(np.diff(on.astype(int)) == 1)
    out = []
    for i in onsets:
        seg = x[i + int(0.008 * rate): i + int(0.038 * rate)]
        if len(seg) < int(0.02 * rate):
            continue
        spectrum = np.abs(np.fft.rfft(seg.sum(axis=1) * np.hanning(len(seg)), 8 * len(seg)))
        pitch = np.argmax(spectrum) * rate / (8 * len(seg))
        left, right = (seg ** 2).sum(axis=0)
        out.append((i / rate, pitch, left / max(right, 1e-9)))
    return rate, out


@pytest.mark.slow
def test_blind_aid_cues_on_mqtt_match_the_sound_in_the_wav(broker, subscriber, tmp_path):
    wav = tmp_path / "cues.wav"
    proc = start(broker, tmp_path, 'mode="blindaid"', "sim.scene=office-approach", "blindaid.speak_new=false",
                 f"audio.out={json.dumps(str(wav))}", run_for=18)
    finish(proc)
    heard_to_the_end(subscriber)
    cues = [payload(m) for m in subscriber.messages(f"{P}/cue")]
    assert len(cues) >= 3
    for c in cues:
        assert set(c) >= {"ts", "bearing_deg", "range_m", "zone", "sound", "interval_s", "pitch_hz", "pan"}
    # A loaded machine may make the aid say "cannot see" (its "blind" warble) now and then: aside.
    seen = [c for c in cues if c["sound"] != "blind"]
    # The person walks up to about 0.4 m in front and back: the cues get near, then far again.
    near = min(c["range_m"] for c in seen if c["range_m"] is not None)
    assert near < 0.6
    assert any(c["sound"] == "tone" or (c["sound"] == "beep" and c["interval_s"] < 0.12) for c in seen)
    assert [c for c in seen if c["range_m"] is not None][-1]["range_m"] > 1.5
    _, sounds = _beeps(wav)
    from edge.modes.blindaid.sound import WARBLE_HZ

    def warble(sound: tuple[float, float, float]) -> bool:
        return min(WARBLE_HZ) - 25 < sound[1] < max(WARBLE_HZ) + 25

    # Gaps between beeps with no warble in between (a beep after it starts at once).
    beep_gaps = [b[0] - a[0] for a, b in zip(sounds, sounds[1:]) if not warble(a) and not warble(b)]
    sounds = [s for s in sounds if not warble(s)]
    assert len(sounds) >= 10
    pitches = [c["pitch_hz"] for c in cues if c["sound"] in ("beep", "tone")]
    # Every sound in the file is at the pitch of a cue that was published (within 3 %).
    for t, pitch, _ in sounds:
        assert min(abs(pitch - p) / p for p in pitches) < 0.03, (t, pitch, pitches)
    # And the beeps' rhythm is a cue's: the commonest gap between onsets is one of their intervals.
    import numpy as np

    gaps = np.array(beep_gaps)
    intervals = [c["interval_s"] for c in cues if c["sound"] == "beep"]
    typical = float(np.median(gaps))
    assert min(abs(typical - i) / i for i in intervals) < 0.1, (typical, intervals)


@pytest.mark.slow
def test_a_stalled_or_torn_camera_is_restarted_and_ranging_resumes(broker, subscriber, tmp_path):
    """Frames stop for 3 s, then three frames come torn: zones meanwhile are `fault`, the camera is
    restarted, ranging resumes (on the rig's simulated clock: the same run on any machine)."""
    faults = 'sim.camera_faults=[{kind="stall", at_s=8.0, seconds=3.0}, {kind="corrupt", at_s=13.0, count=3}]'
    proc = start(broker, tmp_path, 'mode="rangefinder"', "rangefinder.pan_deg=-90.0", "camera.timeout_s=0.5", faults,
                 run_for=18.0)
    err = finish(proc)
    heard_to_the_end(subscriber)
    ranges = [json.loads(m.payload) for m in subscriber.messages(f"{P}/range")]
    statuses = [r["status"] for r in ranges]
    first_fault = statuses.index("fault")
    assert "ok" in statuses[:first_fault] and "ok" in statuses[first_fault:], "ranging resumed after the faults"
    faults_seen = [r for r in ranges if r["status"] == "fault"]
    assert any("no frame" in r["detail"] for r in faults_seen) and any("torn" in r["detail"] for r in faults_seen)
    assert err.count("restarting it") >= 2, err[-2000:]
    states = [json.loads(m.payload) for m in subscriber.messages(f"{P}/state")]
    assert any(s["health"]["camera"].startswith("fault") for s in states)
    assert states[-1]["camera_restarts"] >= 2


@pytest.mark.slow
def test_a_hung_camera_stops_the_watchdog_and_the_lasers_go_off(tmp_path):
    """The camera hangs (a driver call that never returns): the loop stops, and so do the watchdog
    notifications. Meanwhile the lasers' own timer has switched off any laser the stuck loop left
    on. Then the watchdog's kill, as systemd sends it (SIGABRT), prints every thread's stack, and
    the unit's ExecStopPost leaves every laser pin at its off level."""
    from test_laser_safety import assert_all_off, exec_stop_post, lit, write_config

    config, wires = write_config(tmp_path)
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(0.2)
    # Real time: a hang and systemd's watchdog are (on the simulated clock the lasers' timer would
    # wait for a clock that the hung loop no longer moves).
    args = [sys.executable, "-m", "edge", "run", "--config", str(config), "--set", "camera.timeout_s=0.5",
            "--set", 'sim.camera_faults=[{kind="hang", at_s=3.0, seconds=60.0}]', "--set", 'sim.clock="real"']
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "NOTIFY_SOCKET": str(path), "WATCHDOG_USEC": "1000000"})
    feeds: list[float] = []
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            try:
                if sock.recv(4096) == b"WATCHDOG=1":
                    feeds.append(time.monotonic())
            except TimeoutError:
                pass
            if feeds and time.monotonic() - feeds[-1] > 5:
                break  # the feeding has stopped for good
        # Whichever frame it hung in: a laser it had on was switched off by the lasers' own timer
        # (max_on_s), so none is lit now.
        assert lit(wires, config) == set(), "a laser stayed on while the loop was stuck"
        proc.send_signal(signal.SIGABRT)  # systemd's WatchdogSignal=
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            _, err = proc.communicate()
        sock.close()
    assert proc.returncode == -signal.SIGABRT
    assert "Fatal Python error: Aborted" in err and "edge/sim/camera.py" in err, err[-3000:]
    result = exec_stop_post(config)
    assert result.returncode == 0, result.stderr
    assert_all_off(wires, config)
    # Fed about every 0.5 s until the hang at ~3 s, then never again.
    assert len(feeds) >= 2
    assert max(b - a for a, b in zip(feeds, feeds[1:])) < 4.0
    assert time.monotonic() - feeds[-1] > 5


def test_a_command_whose_result_topic_cannot_exist_is_dropped_and_the_service_runs_on(broker, subscriber, tmp_path):
    # Issue 13, item 1: a command name of ~65,520 bytes makes `cmd/<name>/result` longer than MQTT's
    # 65,535-byte topic limit; paho raised, and the process died. Now it is dropped with a log line,
    # a long name whose result fits is answered, and the service goes on ranging.
    proc = start(broker, tmp_path, 'mode="rangefinder"')
    try:
        subscriber.wait_for(f"{P}/status", lambda m: m.payload == b"online", timeout=20)
        subscriber.wait_count(f"{P}/range", 5, timeout=20)
        prefix = f"{P}/cmd/"
        unanswerable = "x" * (65535 - len(prefix))  # the longest topic there is
        answerable = "y" * (65535 - len(prefix) - len("/result"))  # its result topic just fits
        publish(broker, prefix + unanswerable, b"{}")
        mark = subscriber.mark()
        publish(broker, prefix + answerable, b'{"request_id": "long"}')
        result = payload(subscriber.wait_for(f"{prefix}{answerable}/result", since=mark, timeout=20))
        assert result["ok"] is False and result["request_id"] == "long" and len(result["error"]) < 200
        mark = subscriber.mark()
        subscriber.wait_count(f"{P}/range", 5, timeout=30, since=mark)
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        err = finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert "cannot be answered" in err
    assert max(len(line) for line in err.splitlines()) < 1000  # no 65 kB log lines
