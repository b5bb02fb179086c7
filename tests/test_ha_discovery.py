"""Home Assistant discovery checked against what Home Assistant 2024.3 accepts, not against itself.

The facts below are Home Assistant 2024.3.3's (homeassistant/components/mqtt/*.py, sensor/const.py,
const.py): its MQTT platforms' discovery schemas drop every key they do not know without a word
(``extra=vol.REMOVE_EXTRA``), so a misspelt key would silently do nothing; it refuses a state over
255 characters; a numeric sensor (one with a unit or a state class) must render a number or
``None``; a sensor or binary sensor may not be in the ``config`` category. The templates are
rendered with Jinja's sandbox, as Home Assistant does, strictly (an undefined key, which Home
Assistant would log as a warning, fails here), on payloads that the service's own code makes.

When a Home Assistant is installed (``EDGE_HA_PYTHON``, or ``/tmp/havenv/bin/python`` as the
README's set-up makes it), the payloads are also run through its real schemas
(``test_home_assistants_own_schemas_take_every_key``); ``tools/ha_check.py`` runs the whole device
against a real Home Assistant.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from edge.commands import parse_command
from edge.config import MqttConfig, load_config
from edge.discovery import discovery_payloads
from edge.modes import MODES
from edge.modes.blindaid.logic import Cue
from edge.modes.guard import Track
from edge.modes.rangefinder import Filtered, range_payload
from edge.ranging import OK, ZoneResult
from edge.service.homeassistant import HomeAssistantFeed

jinja2 = pytest.importorskip("jinja2")
from jinja2.sandbox import ImmutableSandboxedEnvironment  # noqa: E402

VERSION = "9.9.9"
DEVICE = "pi.lab"
NODE = "edge_pi_lab"

# ---- Home Assistant 2024.3.3's facts ----

_COMMON = {"availability", "availability_mode", "availability_template", "availability_topic", "device",
           "enabled_by_default", "encoding", "entity_category", "icon", "json_attributes_template",
           "json_attributes_topic", "name", "object_id", "origin", "payload_available", "payload_not_available",
           "qos", "unique_id"}
# Each platform's DISCOVERY_SCHEMA keys (mqtt/<platform>.py).
ACCEPTED = {
    "sensor": _COMMON | {"device_class", "expire_after", "force_update", "last_reset_value_template",
                         "state_class", "state_topic", "suggested_display_precision", "unit_of_measurement",
                         "value_template"},
    "binary_sensor": _COMMON | {"device_class", "expire_after", "force_update", "off_delay", "payload_off",
                                "payload_on", "state_topic", "value_template"},
    "select": _COMMON | {"command_template", "command_topic", "optimistic", "options", "retain", "state_topic",
                         "value_template"},
    "button": _COMMON | {"command_template", "command_topic", "device_class", "payload_press", "retain"},
    "image": _COMMON | {"content_type", "image_encoding", "image_topic", "url_template", "url_topic"},
}
AVAILABILITY_KEYS = {"topic", "payload_available", "payload_not_available", "value_template"}  # mixins.py
DEVICE_KEYS = {"identifiers", "connections", "manufacturer", "model", "name", "hw_version", "serial_number",
               "sw_version", "via_device", "suggested_area", "configuration_url"}
ORIGIN_KEYS = {"name", "sw_version", "support_url"}  # discovery.py MQTT_ORIGIN_INFO_SCHEMA; name required
ENTITY_CATEGORIES = {"config", "diagnostic"}
SENSOR_UNITS = {"distance": {"mm", "cm", "m", "km", "in", "ft", "yd", "mi"},  # sensor/const.py DEVICE_CLASS_UNITS
                "duration": {"d", "h", "min", "s", "ms", "µs"}}
BINARY_SENSOR_CLASSES = {"motion", "problem", "occupancy", "running", "update"}  # a subset of the enum
STATE_CLASSES = {"measurement", "total", "total_increasing"}
MAX_STATE = 255  # const.py MAX_LENGTH_STATE_STATE
# availability_mode's values (mixins.py AVAILABILITY_MODES)
AVAILABILITY_MODES = {"all", "any", "latest"}
# What the README's Home Assistant section lists: (component, object id).
ENTITIES = {
    ("select", "mode"), ("button", "sweep"), ("button", "relearn"), ("button", "lasers_off"),
    ("button", "calibrate"), ("sensor", "range"), ("binary_sensor", "guard"), ("sensor", "tracks"),
    ("binary_sensor", "learning"), ("sensor", "obstacle_distance"), ("sensor", "obstacle_bearing"),
    ("sensor", "camera"), ("sensor", "lasers"), ("sensor", "ptu"), ("sensor", "storage"), ("sensor", "calibration"),
    ("sensor", "calibration_age"), ("binary_sensor", "problem"), ("sensor", "camera_restarts"),
    ("sensor", "backlog"), ("sensor", "last_result"), ("image", "map"),
}

TEMPLATES = ImmutableSandboxedEnvironment(undefined=jinja2.StrictUndefined)


def render(template: str, payload: bytes) -> str:
    """A template as Home Assistant's MQTT entities render it: `value` and `value_json`."""
    text = payload.decode("utf-8")
    return TEMPLATES.from_string(template).render(value=text, value_json=json.loads(text)).strip()


def payloads() -> dict[tuple[str, str], dict[str, Any]]:
    out = {}
    for topic, body in discovery_payloads(MqttConfig(), DEVICE, VERSION).items():
        prefix, component, node, obj, config = topic.split("/")
        assert (prefix, node, config) == ("homeassistant", NODE, "config")
        out[(component, obj)] = body
    return out


# ---- what the device publishes, made by its own code ----


class Snapshots:
    def __init__(self) -> None:
        self.sent: dict[str, list[bytes]] = {}

    def __call__(self, kind: str, payload: dict | bytes, interval: float) -> None:
        data = payload if isinstance(payload, bytes) else json.dumps({"ts": "2026-01-01T00:00:00.000Z", **payload})
        self.sent.setdefault(kind, []).append(data.encode() if isinstance(data, str) else data)


def zone(range_m: float | None, status: str = OK, index: int = -1) -> ZoneResult:
    point = None if range_m is None else np.array([range_m, 0.0, 0.0])
    return ZoneResult(index, 0.0, 0.0, status, range_m=range_m, sigma_m=0.004 if range_m else None,
                      point_base_m=point)


def samples(tmp_path: Path) -> dict[str, list[bytes]]:
    """Topic kind → payloads as the service makes them: states of a real `Service` (healthy, with a
    dead laser and a long fault text, calibrating), and the feed's snapshots in each mode."""
    from edge.service import Service

    config = load_config(None, ["mqtt.enabled=false", f"service.state_dir={json.dumps(str(tmp_path))}",
                                f"device.id={json.dumps(DEVICE)}"])
    service = Service(config)
    states = [service.state()]
    service.health._parts["lasers"] = "fault: " + "laser sloped does not light: its spot is missing " * 10
    service.health._parts["camera"] = "fault: no frame within 1 s"
    service._calibrated_at = "2026-01-02T03:04:05Z"
    states.append({**service.state(), "calibration": {"distances_m": [2.0, 1.3, 0.8], "taken_m": [2.0]}})
    # A retained state of the first release (before faults, storage and the calibration's age):
    # Home Assistant meets one after an upgrade, until the device publishes its own.
    states.append({"device": DEVICE, "mode": "guard", "version": "0.1.0", "uptime_s": 1.0, "sweeps": 0,
                   "health": {"camera": "ok", "lasers": "ok", "ptu": "ok", "calibration": "nominal rig"}})
    out = Snapshots()
    for s in states:
        out("state", s, 0.5)
    feed = HomeAssistantFeed(out, device_id=DEVICE, range_limit_m=5.0)
    for mode in MODES:
        feed.activity(mode, paused=False)
        feed.live("range", range_payload(zone(1.234), Filtered(1.2345, 0.002), {"frame": 7, "rate_hz": 28.0}))
        feed.live("range", range_payload(zone(None, "no_spot"), None, {"frame": 8, "rate_hz": 28.0}))
        feed.live("cue", Cue("beep", 12.5, 1.1, 2, 0.3, 600.0, -0.2).to_json())
        feed.live("cue", Cue().to_json())
    feed.activity("guard", paused=True)
    track = Track("b1-t1", (3, 4), (1.0, 2.0), None, 63.4, 2.236, 3.9, 5, 6)
    feed.guard(True, False, [track, track])
    feed.guard(True, True, [])
    feed.guard(False, False, [track])
    feed.map([zone(1.0, index=i) for i in range(8)], 3, "guard", "2026-01-01 00:00:00 UTC")
    results = [{"command": "sweep", "ok": True}, {"command": "calibrate", "ok": False, "error": "x" * 400,
                                                   "request_id": "r1"}]
    for r in results:
        out("last_result", r, 0.5)
    out("backlog", {"messages": 12}, 1.0)
    return out.sent


def kind_of(topic: str) -> str:
    assert topic.startswith("edge/pi.lab/"), topic
    return topic.removeprefix("edge/pi.lab/")


# ---- the checks ----


def test_every_entity_is_there_once_on_one_device_with_origin_and_a_unique_id():
    found = payloads()
    assert set(found) == ENTITIES
    devices = {json.dumps(p["device"], sort_keys=True) for p in found.values()}
    assert len(devices) == 1
    device = found[("select", "mode")]["device"]
    assert set(device) <= DEVICE_KEYS and device["identifiers"] == [NODE] and device["sw_version"] == VERSION
    unique = [p["unique_id"] for p in found.values()]
    assert len(set(unique)) == len(unique) and all(u.startswith(NODE + "_") for u in unique)
    # The first release's three keep their unique ids, so their history stays with them.
    assert {found[k]["unique_id"] for k in (("sensor", "range"), ("binary_sensor", "guard"), ("select", "mode"))} \
        == {f"{NODE}_range", f"{NODE}_guard", f"{NODE}_mode"}
    for body in found.values():
        assert set(body["origin"]) <= ORIGIN_KEYS and body["origin"]["name"] == "edge"
        # Home Assistant names an entity "<device name> <entity name>": no repeat of the device's.
        assert body["name"] and not body["name"].lower().startswith(device["name"].lower())


def test_every_key_is_one_home_assistant_2024_3_accepts(tmp_path):
    for (component, obj), body in payloads().items():
        unknown = set(body) - ACCEPTED[component]
        assert not unknown, f"{component}/{obj}: Home Assistant would drop {sorted(unknown)}"
        assert body["qos"] == 1, f"{component}/{obj}: QoS 1, commands included (the contract's)"
        for entry in body["availability"]:
            assert set(entry) <= AVAILABILITY_KEYS and "topic" in entry
        assert body.get("availability_mode", "latest") in AVAILABILITY_MODES
        assert body.get("entity_category", "diagnostic") in ENTITY_CATEGORIES
        if component in ("sensor", "binary_sensor"):
            assert body.get("entity_category") != "config", f"{obj}: Home Assistant refuses it"
        if component == "sensor":
            cls, unit = body.get("device_class"), body.get("unit_of_measurement")
            if cls in SENSOR_UNITS:
                assert unit in SENSOR_UNITS[cls], (obj, cls, unit)
            assert cls in (None, *SENSOR_UNITS), obj
            assert body.get("state_class", "measurement") in STATE_CLASSES
            assert isinstance(body.get("suggested_display_precision", 0), int)
        if component == "binary_sensor":
            assert body.get("device_class", "motion") in BINARY_SENSOR_CLASSES
        if component == "image":
            assert body["content_type"].startswith("image/") and "url_topic" not in body


def test_availability_is_the_status_topic_and_the_mode_for_the_mode_bound_sensors():
    found = payloads()
    for key, body in found.items():
        assert body["availability"][0] == {"topic": "edge/pi.lab/status", "payload_available": "online",
                                           "payload_not_available": "offline"}, key
    bound = {k for k, b in found.items() if len(b["availability"]) > 1}
    assert bound == {("sensor", "range"), ("sensor", "obstacle_distance"), ("sensor", "obstacle_bearing")}
    for key in bound:
        assert found[key]["availability_mode"] == "all"
        entry = found[key]["availability"][1]
        assert kind_of(entry["topic"]) in ("distance", "obstacle")
        assert render(entry["value_template"], b'{"active": true}') == "online"
        assert render(entry["value_template"], b'{"active": false}') == "offline"


def test_commands_are_what_the_device_takes():
    found = payloads()
    select = found[("select", "mode")]
    assert select["options"] == list(MODES) and kind_of(select["command_topic"]) == "cmd/mode"
    for mode in MODES:
        sent = TEMPLATES.from_string(select["command_template"]).render(value=mode).encode()
        assert parse_command("mode", sent, max_bytes=256, pan_limits=(-1, 1), tilt_limits=(-1, 1)).args["mode"] == mode
    for obj in ("sweep", "relearn", "lasers_off", "calibrate"):
        button = found[("button", obj)]
        assert kind_of(button["command_topic"]) == f"cmd/{obj}"
        parse_command(obj, button["payload_press"].encode(), max_bytes=256, pan_limits=(-1, 1), tilt_limits=(-1, 1))
    calibrate = json.loads(found[("button", "calibrate")]["payload_press"])
    assert calibrate == {"distances_m": list(MqttConfig().calibrate_distances_m)}
    assert found[("button", "calibrate")]["entity_category"] == "config"
    mine = discovery_payloads(MqttConfig(calibrate_distances_m=(3.0, 1.5, 0.6)), DEVICE, VERSION)
    assert json.loads(mine[f"homeassistant/button/{NODE}/calibrate/config"]["payload_press"]) == \
        {"distances_m": [3.0, 1.5, 0.6]}


def test_every_state_and_attribute_template_renders_on_what_the_device_publishes(tmp_path):
    """Short states (at most 255 characters), numbers where Home Assistant expects one, JSON
    objects for attributes, on every payload the service's code makes in every mode."""
    sent = samples(tmp_path)
    checked = set()
    for (component, obj), body in payloads().items():
        if component == "image":
            continue
        if "state_topic" not in body:
            assert component in ("button",)
            continue
        kind = kind_of(body["state_topic"])
        assert sent.get(kind), f"{obj}: nothing on {kind} to try it on"
        numeric = component == "sensor" and ("unit_of_measurement" in body or "state_class" in body)
        for data in sent[kind]:
            state = render(body["value_template"], data)
            assert 0 < len(state) <= MAX_STATE, (obj, state)
            if numeric:
                assert state == "None" or re.fullmatch(r"-?\d+(\.\d+)?", state), (obj, state)
            if component == "binary_sensor":
                assert state in (body["payload_on"], body["payload_off"]), (obj, state)
            if component == "select":
                assert state in body["options"]
            if "json_attributes_template" in body:
                assert kind_of(body["json_attributes_topic"]) == kind
                attrs = json.loads(render(body["json_attributes_template"], data))
                assert isinstance(attrs, dict), obj
            checked.add(obj)
    assert checked == {o for c, o in ENTITIES if c not in ("button", "image")}


def test_what_the_states_say(tmp_path):
    sent = samples(tmp_path)
    found = payloads()

    def states(key: tuple[str, str], kind: str) -> list[str]:
        return [render(found[key]["value_template"], d) for d in sent[kind]]

    assert states(("sensor", "lasers"), "state") == ["ok", "fault", "ok"]
    assert states(("sensor", "camera"), "state") == ["ok", "fault", "ok"]
    assert states(("binary_sensor", "problem"), "state") == ["OFF", "ON", "OFF"]
    assert states(("sensor", "calibration"), "state") == ["nominal", "calibrating", "nominal"]
    age = states(("sensor", "calibration_age"), "state")
    assert age[0] == age[2] == "None" and float(age[1]) > 0
    long = json.loads(sent["state"][1])["health"]["lasers"]
    assert len(long) > MAX_STATE  # the explanation, too long for a state, is an attribute
    attrs = json.loads(render(found[("sensor", "lasers")]["json_attributes_template"], sent["state"][1]))
    assert attrs == {"detail": long}
    motion = states(("binary_sensor", "guard"), "guard")
    tracks = states(("sensor", "tracks"), "guard")
    # Two tracks, none while learning, and none counted while the guard does not watch.
    assert motion == ["ON", "OFF", "OFF"] and tracks == ["2", "0", "0"]
    distance = states(("sensor", "range"), "distance")
    assert "1.234" in distance and "None" in distance  # the filter's output, to the millimetre
    assert states(("sensor", "last_result"), "last_result") == ["sweep: ok", "calibrate: failed"]


def test_the_map_is_a_small_png(tmp_path):
    png = samples(tmp_path)["map"][0]
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) < 60_000


def _ha_python() -> str | None:
    path = os.environ.get("EDGE_HA_PYTHON") or "/tmp/havenv/bin/python"
    return path if os.access(path, os.X_OK) else None


_VALIDATE = """
import importlib, json, sys
import voluptuous as vol
payloads = json.load(sys.stdin)
bad = []
for key, body in payloads.items():
    component = key.split("/")[0]
    schema = importlib.import_module("homeassistant.components.mqtt." + component).DISCOVERY_SCHEMA
    try:
        kept = schema(dict(body))
    except vol.Invalid as exc:
        bad.append(f"{key}: {exc}")
        continue
    dropped = set(body) - set(kept)
    if dropped:
        bad.append(f"{key}: dropped {sorted(dropped)}")
print(json.dumps(bad))
"""


@pytest.mark.ha
def test_home_assistants_own_schemas_take_every_key():
    python = _ha_python()
    if python is None:
        pytest.skip("no Home Assistant installed (EDGE_HA_PYTHON; the README's Home Assistant section says how)")
    body = {f"{c}/{o}": p for (c, o), p in payloads().items()}
    run = subprocess.run([python, "-c", _VALIDATE], input=json.dumps(body), capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout.strip().splitlines()[-1]) == []
