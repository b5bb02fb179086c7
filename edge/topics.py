"""The device's MQTT topics and payloads (../shared/spec/mqtt.md): topic names under
``<prefix>/<id>/``, which command names can be answered, and the JSON every payload is. Pure:
:mod:`edge.mqtt` (the link), :mod:`edge.discovery` and the doctor's broker check use them.
"""

from __future__ import annotations

import json
import logging
import math
import time
from datetime import UTC, datetime
from typing import Any

from edge.errors import ConfigError

log = logging.getLogger(__name__)

MAX_TOPIC_BYTES = 65535  # MQTT's limit on a topic name (a 2-byte length), UTF-8


def check_device_id(device_id: str) -> str:
    """The device id as a topic level: not empty, no wildcard, no level separator."""
    if not device_id or any(c in device_id for c in "+#/\0"):
        raise ConfigError(f"device.id: {device_id!r} cannot be an MQTT topic level (no '+', '#', '/' or NUL; "
                          "not empty): set [device] id")
    return device_id


class Topics:
    """The device's topics, ``<prefix>/<id>/…``."""

    def __init__(self, prefix: str, device_id: str) -> None:
        self.base = f"{prefix}/{check_device_id(device_id)}"
        self.status = f"{self.base}/status"
        self.state = f"{self.base}/state"
        self.range = f"{self.base}/range"
        self.sweep = f"{self.base}/sweep"
        self.alert = f"{self.base}/alert"
        self.cue = f"{self.base}/cue"
        self.cmd_prefix = f"{self.base}/cmd/"
        self.cmd_filter = f"{self.base}/cmd/+"

    def of(self, kind: str) -> str:
        return f"{self.base}/{kind}"

    def cmd(self, name: str) -> str:
        return f"{self.cmd_prefix}{name}"

    def result(self, name: str) -> str:
        return f"{self.cmd_prefix}{name}/result"


def answerable(topics: Topics, name: str) -> bool:
    """Whether a command called `name` can be answered on its ``cmd/<name>/result`` topic: one topic
    level (no wildcard, separator or NUL) whose result topic fits MQTT's 65,535 bytes."""
    if not name or any(c in name for c in "+#/\0"):
        return False
    try:
        return len(topics.result(name).encode("utf-8")) <= MAX_TOPIC_BYTES
    except UnicodeEncodeError:  # a lone surrogate
        return False


def utc_timestamp(t: float | None = None) -> str:
    """ISO 8601 UTC with milliseconds, e.g. ``2026-11-23T12:00:00.123Z``."""
    moment = datetime.fromtimestamp(time.time() if t is None else t, tz=UTC)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{moment.microsecond // 1000:03d}Z"


def encode(payload: dict[str, Any]) -> bytes:
    """Compact UTF-8 JSON with a ``ts`` added if absent. Non-finite numbers become null (JSON has
    none; a NaN somewhere in a zone result must not stop the device), with a warning."""
    if not isinstance(payload, dict):
        raise TypeError(f"MQTT payloads are JSON objects, got {type(payload).__name__}")
    body = payload if "ts" in payload else {"ts": utc_timestamp(), **payload}
    try:
        text = json.dumps(body, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    except ValueError:
        log.warning("payload with a non-finite number: sent as null")
        text = json.dumps(_finite(body), separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    return text.encode("utf-8")


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value
