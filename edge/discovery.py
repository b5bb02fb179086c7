"""Home Assistant's MQTT discovery documents for one device (README: "Home Assistant"): every
entity, its topics and templates, published retained by :class:`edge.mqtt.MqttLink` at every
connect. Pure: a configuration in, {config topic: config} out.
"""

from __future__ import annotations

import json
import re
from typing import Any

from edge.config import MqttConfig
from edge.modes import MODES
from edge.topics import Topics

# Jinja for Home Assistant's templates. States stay short (HA refuses one over 255 characters):
# the words go to the attributes. Keys that `state` did not always have are read with .get(): a
# retained state of an older release must not make Home Assistant log template warnings.
_HEALTH_STATE = "{{ 'fault' if '%s' in value_json.get('faults', []) else 'ok' }}"
_HEALTH_ATTRS = "{{ {'detail': value_json.health.get('%s')} | tojson }}"
_ACTIVE = "{{ 'online' if value_json.active else 'offline' }}"


def discovery_payloads(config: MqttConfig, device_id: str, version: str) -> dict[str, dict[str, Any]]:
    """Home Assistant MQTT discovery: {config topic: config}, to be published retained.

    Every entity is on one device, has a unique id, the `origin` block, QoS 1 (commands included)
    and is available while ``status`` is ``online``; the distance and the blind aid's obstacle
    only while their mode runs (their topic's ``active``). The README's "Home Assistant" section
    describes each entity; tests/test_ha_discovery.py checks them against what Home Assistant
    2024.3's MQTT platforms accept."""
    topics = Topics(config.prefix, device_id)
    # Discovery's node and object ids allow [a-zA-Z0-9_-] only.
    node = re.sub(r"[^A-Za-z0-9_-]", "_", f"{config.prefix}_{device_id}")
    online = {"topic": topics.status, "payload_available": "online", "payload_not_available": "offline"}
    common = {
        "availability": [online],
        "qos": 1,
        "device": {
            "identifiers": [node],
            "name": f"edge {device_id}",
            "model": "structured-light range finder",
            "manufacturer": "edge",
            "sw_version": version,
        },
        "origin": {"name": "edge", "sw_version": version},
    }

    def while_active(topic: str) -> dict[str, Any]:
        return {"availability": [online, {"topic": topic, "value_template": _ACTIVE}], "availability_mode": "all"}

    def button(command: str, name: str, payload: dict[str, Any], **more: Any) -> dict[str, Any]:
        return {"name": name, "command_topic": topics.cmd(command),
                "payload_press": json.dumps(payload, separators=(",", ":")), **more}

    def health(part: str, name: str) -> dict[str, Any]:
        return {"name": name, "state_topic": topics.state, "value_template": _HEALTH_STATE % part,
                "json_attributes_topic": topics.state, "json_attributes_template": _HEALTH_ATTRS % part,
                "entity_category": "diagnostic"}

    distance = topics.of("distance")
    guard = topics.of("guard")
    obstacle = topics.of("obstacle")
    distances = [float(d) for d in config.calibrate_distances_m]
    entities: dict[tuple[str, str], dict[str, Any]] = {
        # The range finder's distance, at most once a second unless it changes much ("range" is
        # its object id since the first release: the entity keeps its id and history).
        ("sensor", "range"): {
            "name": "Distance",
            "state_topic": distance,
            "value_template": "{{ value_json.range_m }}",
            "device_class": "distance",
            "unit_of_measurement": "m",
            "state_class": "measurement",
            "suggested_display_precision": 2,
            **while_active(distance),
        },
        ("binary_sensor", "guard"): {
            "name": "Motion",
            "state_topic": guard,
            "value_template": "{{ 'ON' if value_json.occupied else 'OFF' }}",
            "payload_on": "ON",
            "payload_off": "OFF",
            "device_class": "motion",
            "json_attributes_topic": guard,
            "json_attributes_template": ("{{ {'watching': value_json.active, 'learning': value_json.learning, "
                                         "'tracks': value_json.tracks, 'objects': value_json.objects} | tojson }}"),
        },
        ("sensor", "tracks"): {
            "name": "Tracked objects",
            "state_topic": guard,
            "value_template": "{{ value_json.tracks }}",
            "state_class": "measurement",
            "suggested_display_precision": 0,
            "icon": "mdi:account-multiple",
        },
        ("binary_sensor", "learning"): {
            "name": "Guard learning",
            "state_topic": guard,
            "value_template": "{{ 'ON' if value_json.active and value_json.learning else 'OFF' }}",
            "payload_on": "ON",
            "payload_off": "OFF",
            "icon": "mdi:school",
            "entity_category": "diagnostic",
        },
        ("sensor", "obstacle_distance"): {
            "name": "Obstacle distance",
            "state_topic": obstacle,
            "value_template": "{{ value_json.range_m }}",
            "device_class": "distance",
            "unit_of_measurement": "m",
            "state_class": "measurement",
            "suggested_display_precision": 2,
            **while_active(obstacle),
        },
        ("sensor", "obstacle_bearing"): {
            "name": "Obstacle bearing",
            "state_topic": obstacle,
            "value_template": "{{ value_json.bearing_deg }}",
            "unit_of_measurement": "°",
            "state_class": "measurement",
            "suggested_display_precision": 0,
            "icon": "mdi:compass-outline",
            **while_active(obstacle),
        },
        ("select", "mode"): {
            "name": "Mode",
            "command_topic": topics.cmd("mode"),
            "command_template": '{"mode": "{{ value }}"}',
            "state_topic": topics.state,
            "value_template": "{{ value_json.mode }}",
            "options": list(MODES),
        },
        ("button", "sweep"): button("sweep", "Sweep", {}, icon="mdi:radar"),
        ("button", "relearn"): button("relearn", "Relearn background", {}, icon="mdi:school"),
        ("button", "lasers_off"): button("lasers_off", "Lasers off", {}, icon="mdi:laser-pointer"),
        ("button", "calibrate"): button("calibrate", "Calibrate", {"distances_m": distances},
                                        icon="mdi:ruler", entity_category="config"),
        ("image", "map"): {
            "name": "Map",
            "image_topic": topics.of("map"),
            "content_type": "image/png",
        },
        ("sensor", "last_result"): {
            "name": "Last command",
            "state_topic": topics.of("last_result"),
            "value_template": "{{ value_json.command }}: {{ 'ok' if value_json.ok else 'failed' }}",
            "json_attributes_topic": topics.of("last_result"),
            "json_attributes_template": ("{{ {'command': value_json.command, 'ok': value_json.ok, "
                                         "'error': value_json.get('error'), "
                                         "'request_id': value_json.get('request_id'), "
                                         "'at': value_json.ts} | tojson }}"),
            "icon": "mdi:console",
        },
        ("sensor", "camera"): health("camera", "Camera"),
        ("sensor", "lasers"): health("lasers", "Lasers"),
        ("sensor", "ptu"): health("ptu", "Pan-tilt unit"),
        ("sensor", "storage"): health("storage", "Storage"),
        ("sensor", "calibration"): {
            **health("calibration", "Calibration"),
            "value_template": ("{{ 'calibrating' if value_json.get('calibration') else "
                               "('fault' if 'calibration' in value_json.get('faults', []) else "
                               "('calibrated' if value_json.get('calibrated_at') else 'nominal')) }}"),
            "json_attributes_template": ("{{ {'detail': value_json.health.get('calibration'), "
                                         "'calibrated_at': value_json.get('calibrated_at'), "
                                         "'session': value_json.get('calibration')} | tojson }}"),
        },
        ("sensor", "calibration_age"): {
            "name": "Calibration age",
            "state_topic": topics.state,
            "value_template": "{{ value_json.get('calibration_age_d') }}",
            "device_class": "duration",
            "unit_of_measurement": "d",
            "state_class": "measurement",
            "suggested_display_precision": 1,
            "entity_category": "diagnostic",
        },
        ("binary_sensor", "problem"): {
            "name": "Problem",
            "state_topic": topics.state,
            "value_template": "{{ 'ON' if value_json.get('faults', []) else 'OFF' }}",
            "payload_on": "ON",
            "payload_off": "OFF",
            "device_class": "problem",
            "json_attributes_topic": topics.state,
            "json_attributes_template": ("{{ {'faults': value_json.get('faults', []), "
                                         "'health': value_json.health} | tojson }}"),
            "entity_category": "diagnostic",
        },
        ("sensor", "camera_restarts"): {
            "name": "Camera restarts",
            "state_topic": topics.state,
            "value_template": "{{ value_json.get('camera_restarts', 0) }}",
            "state_class": "total_increasing",
            "suggested_display_precision": 0,
            "icon": "mdi:camera-retake",
            "entity_category": "diagnostic",
        },
        ("sensor", "backlog"): {
            "name": "Outbox backlog",
            "state_topic": topics.of("backlog"),
            "value_template": "{{ value_json.messages }}",
            "unit_of_measurement": "messages",
            "state_class": "measurement",
            "suggested_display_precision": 0,
            "icon": "mdi:tray-full",
            "entity_category": "diagnostic",
        },
    }
    return {
        f"{config.discovery_prefix}/{component}/{node}/{obj}/config": {
            **common, **entity, "unique_id": f"{node}_{obj}",
        }
        for (component, obj), entity in entities.items()
    }
