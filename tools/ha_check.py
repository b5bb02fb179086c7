#!/usr/bin/env python3
"""edge against a real Home Assistant: its entities, buttons, map, motion sensor and health.

Starts a private Mosquitto, a Home Assistant (2024.3.3, installed in its own virtual environment
outside the repository, see README "Home Assistant") with its MQTT integration configured to that
broker, and `edge run` on the simulator; then checks through Home Assistant's REST and WebSocket
APIs that:

1. every entity of the device appears, all on one device, with no warning or error about them
   in Home Assistant's log;
2. the motion sensor follows the guard: on during an intrusion, still on right after Home
   Assistant restarts, off at once when the mode changes mid-intrusion (and `cleared` goes out);
3. the distance (range finder) and the obstacle (blind aid) are available in their modes only;
4. each button makes the device answer `ok: true` (Sweep, Relearn background, Lasers off, and
   Calibrate on the `bench` scene, where a board is carried to the distances it sends);
5. the map picture changes after a sweep;
6. the `problem` sensor stays off on a healthy rig and turns on with a dead laser;
7. no entity of the device changes more than twice in any second, in every mode.

Run it from the repository (it takes some 10 minutes, longer on a loaded machine):

    python3 -m venv /tmp/havenv && /tmp/havenv/bin/pip install homeassistant==2024.3.3 'josepy<2'
    ./dev edge --help >/dev/null   # makes .venv
    .venv/bin/python tools/ha_check.py [--ha-python /tmp/havenv/bin/python] [--out out/ha_check]

The first start of Home Assistant installs the requirements of its default integrations into its
own environment (the frontend, Pillow, ...), with pip, as Home Assistant always does.

It prints each check as it goes and a summary, writes ``report.json`` and Home Assistant's log to
``--out``, and exits 0 when every check passed.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
import uuid
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt

REPO = Path(__file__).resolve().parents[1]
DEVICE = "hacheck"
P = f"edge/{DEVICE}"
NODE = f"edge_{DEVICE}"
USER, PASSWORD = "edge", "edge-check-pw"
CLIENT_ID = "http://127.0.0.1/"  # IndieAuth client id for the login flow

# Entity ids Home Assistant derives from the device's name ("edge hacheck") and each entity's.
E = {
    "mode": "select.edge_hacheck_mode",
    "sweep": "button.edge_hacheck_sweep",
    "relearn": "button.edge_hacheck_relearn_background",
    "lasers_off": "button.edge_hacheck_lasers_off",
    "calibrate": "button.edge_hacheck_calibrate",
    "distance": "sensor.edge_hacheck_distance",
    "motion": "binary_sensor.edge_hacheck_motion",
    "tracks": "sensor.edge_hacheck_tracked_objects",
    "learning": "binary_sensor.edge_hacheck_guard_learning",
    "obstacle_distance": "sensor.edge_hacheck_obstacle_distance",
    "obstacle_bearing": "sensor.edge_hacheck_obstacle_bearing",
    "camera": "sensor.edge_hacheck_camera",
    "lasers": "sensor.edge_hacheck_lasers",
    "ptu": "sensor.edge_hacheck_pan_tilt_unit",
    "storage": "sensor.edge_hacheck_storage",
    "calibration": "sensor.edge_hacheck_calibration",
    "calibration_age": "sensor.edge_hacheck_calibration_age",
    "problem": "binary_sensor.edge_hacheck_problem",
    "camera_restarts": "sensor.edge_hacheck_camera_restarts",
    "backlog": "sensor.edge_hacheck_outbox_backlog",
    "last_result": "sensor.edge_hacheck_last_command",
    "map": "image.edge_hacheck_map",
}
GONE = ("unavailable", "unknown")

# A visitor who comes in once the guard has learnt the room, and stays (tests/test_service.py's).
VISITOR = """
name = "office-visitor-stays"
description = "the office; a visitor steps in at t = {start} s and stays"
extends = "office"

[[movers]]
name = "visitor"
size_m = [0.45, 0.30, 1.75]
material = "person"
speed_mps = 0.8
start_s = {start}
path_m = [[4.4, 2.25], [3.0, 2.0], [3.0, 0.95]]
pause_s = [0.0, 0.0, 86400.0]
loop = false
"""
GUARD_FAST = ["sweep.zones=32", "sweep.pan_step_deg=11.25", "guard.learn_sweeps=2", "ptu.settle_ms=10.0"]


# ---- the report ----


class Report:
    def __init__(self) -> None:
        self.checks: list[dict[str, Any]] = []
        self.notes: dict[str, Any] = {}
        self.began = time.monotonic()

    def check(self, name: str, ok: bool, detail: str = "") -> bool:
        self.checks.append({"check": name, "ok": bool(ok), "detail": detail,
                            "at_s": round(time.monotonic() - self.began, 1)})
        print(f"[{'PASS' if ok else 'FAIL'}] {name}" + (f": {detail}" if detail else ""), flush=True)
        return ok

    def say(self, text: str) -> None:
        print(f"       {text}", flush=True)

    @property
    def passed(self) -> bool:
        return bool(self.checks) and all(c["ok"] for c in self.checks)


def wait(predicate: Callable[[], Any], timeout: float, step: float = 0.5) -> Any:
    """The first truthy value of predicate() within `timeout` seconds, else None."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            value = predicate()
        except Exception:  # noqa: BLE001 - a service still coming up
            value = None
        if value:
            return value
        if time.monotonic() > deadline:
            return None
        time.sleep(step)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ---- Mosquitto, and a watcher of the device's topics ----


class Broker:
    def __init__(self, folder: Path) -> None:
        self.port = free_port()
        conf = folder / "mosquitto.conf"
        lines = [f"listener {self.port} 127.0.0.1", "allow_anonymous true", f"log_dest file {folder}/mosquitto.log"]
        if os.geteuid() == 0:
            lines.append("user root")
        conf.write_text("\n".join(lines) + "\n")
        exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
        self.proc = subprocess.Popen([exe, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if not wait(lambda: socket.create_connection(("127.0.0.1", self.port), 0.2).close() or True, 10, 0.1):
            raise RuntimeError("mosquitto did not start")

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)


class Watcher:
    """Everything on edge/<id>/# with its arrival time."""

    def __init__(self, port: int) -> None:
        self.messages: list[tuple[float, str, bytes]] = []
        self.lock = threading.Lock()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"ha-check-{uuid.uuid4().hex[:6]}",
                                  protocol=mqtt.MQTTv5)
        self.client.on_connect = lambda c, *a: c.subscribe(f"{P}/#", qos=1)
        self.client.on_message = self._on_message
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()

    def _on_message(self, client, userdata, msg) -> None:
        with self.lock:
            self.messages.append((time.monotonic(), msg.topic, bytes(msg.payload)))

    def mark(self) -> int:
        with self.lock:
            return len(self.messages)

    def find(self, topic: str, since: int = 0, where: Callable[[dict], bool] | None = None) -> dict | None:
        with self.lock:
            found = [p for _, t, p in self.messages[since:] if t == topic]
        for payload in found:
            try:
                body = json.loads(payload)
            except ValueError:
                continue
            if where is None or where(body):
                return body
        return None

    def last_raw(self, topic: str) -> bytes | None:
        with self.lock:
            found = [p for _, t, p in self.messages if t == topic]
        return found[-1] if found else None

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


# ---- the device ----


class Device:
    def __init__(self, broker: Broker, folder: Path, name: str, *sets: str, env: dict | None = None) -> None:
        self.log_path = folder / f"edge-{name}.log"
        args = [sys.executable, "-m", "edge", "run", "--set", f"device.id={json.dumps(DEVICE)}",
                "--set", f"mqtt.port={broker.port}", "--set", 'mqtt.host="127.0.0.1"',
                "--set", f"service.state_dir={json.dumps(str(folder / ('state-' + name)))}",
                "--set", "mqtt.reconnect_min_s=0.2", "--set", "mqtt.reconnect_max_s=1.0"]
        for s in sets:
            args += ["--set", s]
        self.log = open(self.log_path, "w")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(args, cwd=REPO, stdout=self.log, stderr=subprocess.STDOUT,
                                     env={**os.environ, "NOTIFY_SOCKET": "", **(env or {})})

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()
        return self.proc.returncode


# ---- Home Assistant ----


class HomeAssistant:
    def __init__(self, python: Path, folder: Path, broker_port: int) -> None:
        self.python = python
        self.hass = python.parent / "hass"
        self.config = folder / "ha-config"
        self.log_path = folder / "home-assistant.log"
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None
        self.access: str | None = None
        self.refresh: str | None = None
        self._write_config(broker_port)

    def _write_config(self, broker_port: int) -> None:
        storage = self.config / ".storage"
        storage.mkdir(parents=True, exist_ok=True)
        (self.config / "configuration.yaml").write_text(f"""
homeassistant:
  name: edge check
  latitude: 59.35
  longitude: 18.07
  elevation: 0
  unit_system: metric
  time_zone: UTC
  country: SE
  currency: SEK
http:
  server_host: 127.0.0.1
  server_port: {self.port}
api:
auth:
websocket_api:
logger:
  default: warning
""")
        # The MQTT integration's config entry, as its config flow would make it.
        entry = {"entry_id": uuid.uuid4().hex, "version": 1, "minor_version": 1, "domain": "mqtt",
                 "title": "127.0.0.1", "data": {"broker": "127.0.0.1", "port": broker_port}, "options": {},
                 "pref_disable_new_entities": False, "pref_disable_polling": False, "source": "user",
                 "unique_id": None, "disabled_by": None}
        (storage / "core.config_entries").write_text(json.dumps(
            {"version": 1, "minor_version": 1, "key": "core.config_entries", "data": {"entries": [entry]}}))
        # A user of Home Assistant's own auth provider (admin once it first logs in).
        subprocess.run([str(self.hass), "--script", "auth", "-c", str(self.config), "add", USER, PASSWORD],
                       check=True, capture_output=True, timeout=300)

    def start(self, timeout: float = 900) -> float:
        """Start and log in; the seconds it took."""
        began = time.monotonic()
        self.proc = subprocess.Popen([str(self.hass), "-c", str(self.config), "--log-file", str(self.log_path)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if not wait(lambda: self._status() == 200, timeout, 1.0):
            raise RuntimeError(f"Home Assistant did not answer within {timeout} s (see {self.log_path})")
        if self.access is None:
            self._login()
        return time.monotonic() - began

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(120)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None

    def _status(self) -> int:
        # The frontend's manifest needs no token: /api/ without one would be logged as a failed login.
        try:
            with urllib.request.urlopen(f"{self.url}/manifest.json", timeout=5) as r:
                return r.status
        except urllib.error.HTTPError as exc:
            return exc.code

    def _form(self, path: str, data: dict) -> dict:
        body = urllib.parse.urlencode(data).encode()
        with urllib.request.urlopen(urllib.request.Request(f"{self.url}{path}", data=body), timeout=30) as r:
            return json.loads(r.read())

    def _login(self) -> None:
        flow = self._json("POST", "/auth/login_flow", {"client_id": CLIENT_ID, "handler": ["homeassistant", None],
                                                       "redirect_uri": CLIENT_ID}, auth=False)
        done = self._json("POST", f"/auth/login_flow/{flow['flow_id']}",
                          {"client_id": CLIENT_ID, "username": USER, "password": PASSWORD}, auth=False)
        tokens = self._form("/auth/token", {"grant_type": "authorization_code", "code": done["result"],
                                            "client_id": CLIENT_ID})
        self.access, self.refresh = tokens["access_token"], tokens["refresh_token"]

    def _renew(self) -> None:
        tokens = self._form("/auth/token", {"grant_type": "refresh_token", "refresh_token": self.refresh,
                                            "client_id": CLIENT_ID})
        self.access = tokens["access_token"]

    def _json(self, method: str, path: str, body: Any = None, auth: bool = True, raw: bool = False) -> Any:
        for attempt in (1, 2):
            headers = {"Content-Type": "application/json"}
            if auth:
                headers["Authorization"] = f"Bearer {self.access}"
            data = None if body is None else json.dumps(body).encode()
            request = urllib.request.Request(f"{self.url}{path}", data=data, headers=headers, method=method)
            try:
                with urllib.request.urlopen(request, timeout=30) as r:
                    content = r.read()
                    return content if raw else json.loads(content or b"null")
            except urllib.error.HTTPError as exc:
                if exc.code == 401 and auth and attempt == 1:
                    self._renew()
                    continue
                raise
        raise AssertionError("unreachable")

    # ---- what the checks use ----

    def states(self) -> dict[str, dict]:
        return {s["entity_id"]: s for s in self._json("GET", "/api/states")}

    def state(self, entity_id: str) -> str | None:
        try:
            return self._json("GET", f"/api/states/{entity_id}")["state"]
        except urllib.error.HTTPError as exc:
            if exc.code == 404:
                return None
            raise

    def attributes(self, entity_id: str) -> dict:
        return self._json("GET", f"/api/states/{entity_id}")["attributes"]

    def call(self, domain: str, service: str, **data: Any) -> None:
        self._json("POST", f"/api/services/{domain}/{service}", data)

    def template(self, text: str) -> str:
        return self._json("POST", "/api/template", {"template": text}, raw=True).decode()

    def image(self, entity_id: str) -> bytes:
        return self._json("GET", f"/api/image_proxy/{entity_id}", raw=True)

    def log_problems(self) -> list[str]:
        """WARNING and ERROR lines of Home Assistant's log (the first line of each)."""
        try:
            lines = self.log_path.read_text(errors="replace").splitlines()
        except OSError:
            return []
        return [line for line in lines if " WARNING (" in line or " ERROR (" in line or " CRITICAL (" in line]


# The WebSocket listener runs in Home Assistant's environment (aiohttp is there): it prints each
# state change of the device's entities as a JSON line.
_LISTEN = r"""
import asyncio, json, sys, time
import aiohttp
async def main(url, token, prefix):
    async with aiohttp.ClientSession() as session:
        async with session.ws_connect(url) as ws:
            await ws.receive_json()
            await ws.send_json({"type": "auth", "access_token": token})
            if (await ws.receive_json()).get("type") != "auth_ok":
                sys.exit("websocket: auth failed")
            await ws.send_json({"id": 1, "type": "subscribe_events", "event_type": "state_changed"})
            print(json.dumps({"ready": True}), flush=True)
            async for msg in ws:
                data = json.loads(msg.data)
                if data.get("type") != "event":
                    continue
                event = data["event"]["data"]
                if prefix not in event["entity_id"]:
                    continue
                new, old = event.get("new_state") or {}, event.get("old_state") or {}
                print(json.dumps({"t": time.time(), "entity_id": event["entity_id"], "old": old.get("state"),
                                  "new": new.get("state"), "attrs": new.get("attributes") != old.get("attributes")}),
                      flush=True)
asyncio.run(main(*sys.argv[1:]))
"""


class Changes:
    """State changes of the device's entities, from Home Assistant's WebSocket API."""

    def __init__(self, ha: HomeAssistant) -> None:
        self.events: list[dict] = []
        self.lock = threading.Lock()
        self.ready = threading.Event()
        url = f"ws://127.0.0.1:{ha.port}/api/websocket"
        self.proc = subprocess.Popen([str(ha.python), "-c", _LISTEN, url, ha.access or "", NODE],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()
        self.ready.wait(30)

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            data = json.loads(line)
            if data.get("ready"):
                self.ready.set()
                continue
            with self.lock:
                self.events.append(data)

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)

    def of(self, entity_id: str, since: float = 0.0) -> list[dict]:
        with self.lock:
            return [e for e in self.events if e["entity_id"] == entity_id and e["t"] >= since]

    def worst(self, since: float, until: float) -> dict[str, tuple[int, int]]:
        """Entity → (most changes in any one second, most MQTT messages: changes under 50 ms
        apart come from one message, its state and its attributes written one after the other)."""
        by: dict[str, list[float]] = defaultdict(list)
        with self.lock:
            for e in self.events:
                if since <= e["t"] <= until:
                    by[e["entity_id"]].append(e["t"])
        out = {}
        for entity, times in by.items():
            times.sort()
            merged = [t for i, t in enumerate(times) if i == 0 or t - times[i - 1] > 0.05]
            out[entity] = (_most_in_a_second(times), _most_in_a_second(merged))
        return out


def _most_in_a_second(times: list[float]) -> int:
    best, j = 0, 0
    for i, t in enumerate(times):
        while times[j] <= t - 1.0:
            j += 1
        best = max(best, i - j + 1)
    return best


# ---- the checks ----


def expect_state(ha: HomeAssistant, entity: str, wanted: Callable[[str | None], bool], timeout: float) -> str | None:
    """The entity's state once `wanted` takes it (None after `timeout`)."""
    seen: list[str | None] = []

    def look() -> bool:
        seen.append(ha.state(entity))
        return wanted(seen[-1])

    return seen[-1] if wait(look, timeout, 0.25) else None


def press(ha: HomeAssistant, watcher: Watcher, report: Report, name: str, command: str,
          timeout: float = 60) -> dict | None:
    mark = watcher.mark()
    ha.call("button", "press", entity_id=E[name])
    result = wait(lambda: watcher.find(f"{P}/cmd/{command}/result", mark), timeout)
    report.check(f"button {E[name]} → cmd/{command} answered ok: true",
                 bool(result and result.get("ok") is True), json.dumps(result))
    return result


def select_mode(ha: HomeAssistant, watcher: Watcher, mode: str) -> dict | None:
    mark = watcher.mark()
    ha.call("select", "select_option", entity_id=E["mode"], option=mode)
    return wait(lambda: watcher.find(f"{P}/cmd/mode/result", mark), 30)


def rates(report: Report, changes: Changes, label: str, since: float, until: float) -> None:
    worst = changes.worst(since, until)
    raw = max((r for r, _ in worst.values()), default=0)
    msgs = max((m for _, m in worst.values()), default=0)
    busiest = sorted(worst.items(), key=lambda kv: -kv[1][1])[:3]
    report.notes.setdefault("rates", {})[label] = {e: {"changes": r, "messages": m} for e, (r, m) in worst.items()}
    report.check(f"{label}: every entity updates at most twice in any second", msgs <= 2,
                 f"{until - since:.0f} s watched; most updates in one second {msgs} "
                 f"(state changes {raw}, a state and its attributes from one message count once); "
                 f"busiest {[(e.split('.')[1], m) for e, (_, m) in busiest]}")


def run(args: argparse.Namespace) -> Report:
    report = Report()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="edge-ha-check-"))
    scenes = work / "scenes"
    scenes.mkdir()
    shutil.copy(REPO / "config" / "scenes" / "office.toml", scenes / "office.toml")
    (scenes / "visitor.toml").write_text(VISITOR.format(start=args.visitor_at))
    bench = (REPO / "config" / "scenes" / "bench.toml").read_text()
    (scenes / "bench-late.toml").write_text(bench.replace("\nstart_s = 3.0\n", "\nstart_s = 40.0\n"))

    with contextlib.ExitStack() as stack:
        broker = Broker(work)
        stack.callback(broker.stop)
        watcher = Watcher(broker.port)
        stack.callback(watcher.close)
        ha = HomeAssistant(Path(args.ha_python), work, broker.port)
        stack.callback(lambda: shutil.copy(ha.log_path, out / "home-assistant.log") if ha.log_path.exists() else None)
        stack.callback(ha.stop)
        took = ha.start()
        report.say(f"Home Assistant {ha._json('GET', '/api/config')['version']} up in {took:.0f} s on port {ha.port}")
        changes = Changes(ha)
        stack.callback(lambda: changes.stop())
        earlier: list[Changes] = []  # the listeners before a restart of Home Assistant

        # ---- A: a healthy rig guarding an office that a visitor comes into ----
        device = Device(broker, work, "guard", 'mode="guard"', f"sim.scene={json.dumps(str(scenes / 'visitor.toml'))}",
                        *GUARD_FAST)
        stack.callback(device.stop)
        present = wait(lambda: all(ha.state(e) is not None for e in E.values()), 300, 1.0)
        states = ha.states()
        missing = [e for e in E.values() if e not in states]
        report.check(f"all {len(E)} entities appear", not missing, f"missing: {missing}" if missing else "")
        ours = sorted(e for e in states if NODE in e)
        mode_entity = E["mode"]
        on_device = json.loads(ha.template(f"{{{{ device_entities(device_id('{mode_entity}')) | tojson }}}}"))
        mqtt_entities = json.loads(ha.template("{{ integration_entities('mqtt') | tojson }}"))
        device_name = ha.template(f"{{{{ device_attr(device_id('{mode_entity}'), 'name') }}}}")
        report.check("every entity is on one device", bool(present) and sorted(on_device) == sorted(E.values())
                     and sorted(mqtt_entities) == sorted(E.values()),
                     f"device '{device_name}' has {len(on_device)} entities; MQTT has {len(mqtt_entities)}; "
                     f"named for it: {len(ours)}")
        report.notes["entities"] = {e: {"state": states.get(e, {}).get("state"),
                                        "name": states.get(e, {}).get("attributes", {}).get("friendly_name")}
                                    for e in E.values()}
        guard_began = time.time()
        healthy = expect_state(ha, E["problem"], lambda s: s == "off", 60)
        report.check("the problem sensor is off on the healthy rig", healthy == "off",
                     f"{E['problem']}: {ha.state(E['problem'])}")
        on = expect_state(ha, E["motion"], lambda s: s == "on", args.intrusion_timeout)
        report.check("the motion sensor turns on during the intrusion", on == "on",
                     f"tracked objects {ha.state(E['tracks'])}; alert: {watcher.find(P + '/alert')}")
        guard_until = time.time()
        rates(report, changes, "guard mode", guard_began, guard_until)

        # Home Assistant restarts mid-intrusion: the motion sensor is right as soon as it is back.
        earlier.append(changes)
        changes.stop()
        ha.stop()
        ha.start()
        after: list[str | None] = []
        wait(lambda: after.append(ha.state(E["motion"])) or after[-1] not in (None, *GONE), 120, 0.1)
        first = next((s for s in after if s not in (None, *GONE)), None)
        report.check("right after Home Assistant restarts, the motion sensor is still on", first == "on",
                     f"states seen while it came up: {_runs(after)}")
        changes = Changes(ha)

        # The mode changes mid-intrusion: the motion sensor goes off, `cleared` goes out.
        mark = watcher.mark()
        began = time.monotonic()
        result = select_mode(ha, watcher, "rangefinder")
        off = expect_state(ha, E["motion"], lambda s: s == "off", 30)
        cleared = wait(lambda: watcher.find(f"{P}/alert", mark, lambda a: a.get("event") == "cleared"), 30)
        report.check("after a mode change mid-intrusion the motion sensor is off", off == "off" and bool(cleared)
                     and bool(result and result.get("ok")),
                     f"off after {time.monotonic() - began:.1f} s; cmd/mode {result}; alert {cleared}")

        # The range finder: the distance is there, the obstacle is not.
        t0 = time.time()
        distance = expect_state(ha, E["distance"], lambda s: s not in (None, *GONE), 60)
        report.check("range finder: the distance sensor follows it, the obstacle is unavailable",
                     distance is not None and _number(distance) is not None
                     and ha.state(E["obstacle_distance"]) == "unavailable",
                     f"distance {distance} {ha.attributes(E['distance']).get('unit_of_measurement')}, "
                     f"obstacle {ha.state(E['obstacle_distance'])}")
        time.sleep(args.mode_seconds)
        ranges = sum(1 for _, t, _ in watcher.messages if t == f"{P}/range")
        rates(report, changes, "range finder mode", t0, time.time())
        report.say(f"{ranges} range messages so far; distance changed {len(changes.of(E['distance'], t0))} times "
                   f"in Home Assistant meanwhile")

        # The blind aid.
        select_mode(ha, watcher, "blindaid")
        t0 = time.time()
        obstacle = expect_state(ha, E["obstacle_bearing"], lambda s: s not in (None, "unavailable"), 60)
        time.sleep(args.mode_seconds)
        report.check("blind aid: the obstacle's distance and bearing are there, the distance is unavailable",
                     obstacle is not None and ha.state(E["distance"]) == "unavailable",
                     f"obstacle {ha.state(E['obstacle_distance'])} m at {ha.state(E['obstacle_bearing'])}°, "
                     f"distance {ha.state(E['distance'])}")
        rates(report, changes, "blind aid mode", t0, time.time())

        # The buttons, and the map after a sweep.
        before = _digest(ha.image(E["map"]))
        last_map = watcher.last_raw(f"{P}/map")
        sweeps_before = json.loads(watcher.last_raw(f"{P}/sweep") or b'{"sweep": 0}')["sweep"]
        press(ha, watcher, report, "sweep", "sweep")
        new_map = wait(lambda: watcher.last_raw(f"{P}/map") not in (None, last_map), 600, 1.0)
        after_digest = wait(lambda: (d := _digest(ha.image(E["map"]))) != before and d, 60, 1.0)
        sweep_now = json.loads(watcher.last_raw(f"{P}/sweep") or b'{"sweep": 0}')["sweep"]
        report.check("the map picture changes after a sweep", bool(new_map) and bool(after_digest),
                     f"sweep {sweeps_before} → {sweep_now}; image {before[:12]} → {str(after_digest)[:12]}; "
                     f"{len(watcher.last_raw(f'{P}/map') or b'')} bytes")
        (out / "map.png").write_bytes(ha.image(E["map"]))
        press(ha, watcher, report, "relearn", "relearn")
        press(ha, watcher, report, "lasers_off", "lasers_off")
        last = expect_state(ha, E["last_result"], lambda s: s == "lasers_off: ok", 30)
        report.check("the last command's result shows in Home Assistant", last == "lasers_off: ok",
                     f"{E['last_result']}: {last}")
        resumed = select_mode(ha, watcher, "guard")
        report.check("the mode select resumes after lasers off", bool(resumed and resumed.get("ok")),
                     json.dumps(resumed))
        problems = [e for c in (*earlier, changes) for e in c.of(E["problem"]) if e["new"] == "on"]
        report.check("the problem sensor stayed off on the healthy rig, in every mode",
                     not problems and ha.state(E["problem"]) == "off",
                     f"turned on {len(problems)} times; lasers: {ha.state(E['lasers'])}")
        code = device.stop()
        report.check("the device stopped cleanly", code == 0, f"exit status {code}")
        time.sleep(2)
        report.check("entities go unavailable when the device stops",
                     ha.state(E["mode"]) == "unavailable" and ha.state(E["motion"]) == "unavailable",
                     f"mode {ha.state(E['mode'])}, motion {ha.state(E['motion'])}")

        # ---- B: Calibrate, with a board carried to the distances the button sends ----
        device = Device(broker, work, "bench", f"sim.scene={json.dumps(str(scenes / 'bench-late.toml'))}",
                        'mode="rangefinder"', "service.sweep_interval_s=0", 'sim.clock="paced"',
                        "sim.rig_error.laser_angle_deg=0.5", "sim.rig_error.laser_offset_m=0.002",
                        "sim.rig_error.seed=4")
        stack.callback(device.stop)
        wait(lambda: ha.state(E["mode"]) == "rangefinder", 120, 0.5)
        report.say(f"calibration before: {ha.state(E['calibration'])}, age {ha.state(E['calibration_age'])}")
        press(ha, watcher, report, "calibrate", "calibrate", timeout=args.calibrate_timeout)
        calibrated = expect_state(ha, E["calibration"], lambda s: s == "calibrated", 30)
        age = ha.state(E["calibration_age"])
        report.check("the calibration and its age show after it",
                     calibrated == "calibrated" and _number(age) is not None,
                     f"{E['calibration']}: {calibrated}; {E['calibration_age']}: {age} d")
        device.stop()

        # ---- C: a dead laser ----
        t0 = time.time()
        device = Device(broker, work, "dead", 'mode="guard"', *GUARD_FAST,
                        'sim.laser_faults=[{laser="parallel", kind="dead"}]')
        stack.callback(device.stop)
        problem = expect_state(ha, E["problem"], lambda s: s == "on", args.fault_timeout)
        lasers = ha.state(E["lasers"])
        detail = ha.attributes(E["lasers"]).get("detail", "")
        report.check("the problem sensor turns on with a dead laser", problem == "on" and lasers == "fault",
                     f"after {time.time() - t0:.0f} s; {E['lasers']}: {lasers}; detail: {detail[:160]}")
        rates(report, changes, "guard mode with a dead laser", t0, time.time())
        device.stop()

        # ---- Home Assistant's log ----
        problems_in_log = ha.log_problems()
        ours_in_log = [line for line in problems_in_log if _about_us(line)]
        report.notes["ha_log_warnings"] = problems_in_log
        report.check("Home Assistant's log has no warning or error about the device", not ours_in_log,
                     f"{len(ours_in_log)} about us: {ours_in_log[:5]}; "
                     f"{len(problems_in_log) - len(ours_in_log)} others (listed in report.json)")
    shutil.rmtree(work, ignore_errors=True)
    return report


def _about_us(line: str) -> bool:
    """A log line about the device or its entities: it names them or their topics, or comes from
    a part of Home Assistant that handles them (templates, MQTT discovery and entities, the entity
    platforms). Not: the broker connection of Home Assistant itself, Home Assistant's own Python."""
    text = line.lower()
    sources = ("helpers.template", "mqtt.models", "mqtt.discovery", "mqtt.mixins", "mqtt.sensor",
               "mqtt.binary_sensor", "mqtt.select", "mqtt.button", "mqtt.image", "components.sensor",
               "components.binary_sensor", "components.image", "helpers.entity")
    return DEVICE in text or "edge/" in text or NODE in text or any(s in text for s in sources)


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _number(text: str | None) -> float | None:
    try:
        return float(text) if text is not None else None
    except ValueError:
        return None


def _runs(states: list[str | None]) -> list[str]:
    """States seen, with repeats collapsed: ['unavailable ×12', 'on ×3']."""
    out: list[list[Any]] = []
    for s in states:
        if out and out[-1][0] == s:
            out[-1][1] += 1
        else:
            out.append([s, 1])
    return [f"{s} ×{n}" for s, n in out]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ha-python", default=os.environ.get("EDGE_HA_PYTHON", "/tmp/havenv/bin/python"),
                        help="the Python of Home Assistant's virtual environment (default: %(default)s)")
    parser.add_argument("--out", default=str(REPO / "out" / "ha_check"), help="where the report goes")
    parser.add_argument("--visitor-at", type=float, default=45.0,
                        help="when the visitor comes in, in the scene's seconds (after the guard learnt the room)")
    parser.add_argument("--mode-seconds", type=float, default=20.0, help="how long each mode is watched")
    parser.add_argument("--intrusion-timeout", type=float, default=900.0)
    parser.add_argument("--calibrate-timeout", type=float, default=400.0)
    parser.add_argument("--fault-timeout", type=float, default=600.0)
    args = parser.parse_args()
    if not os.access(args.ha_python, os.X_OK):
        print(f"ha_check: no Home Assistant at {args.ha_python} (see the module's notes to install one)",
              file=sys.stderr)
        return 2
    report = run(args)
    out = Path(args.out)
    (out / "report.json").write_text(json.dumps({"passed": report.passed, "checks": report.checks,
                                                 **report.notes}, indent=2) + "\n")
    failed = [c for c in report.checks if not c["ok"]]
    print(f"\n{len(report.checks) - len(failed)} passed, {len(failed)} failed")
    return 0 if report.passed else 1


if __name__ == "__main__":
    sys.exit(main())
