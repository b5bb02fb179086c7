"""`edge range`: the range finder's output, live, from the broker.

Subscribes to ``<prefix>/<id>/range`` and shows each range on one line that updates in place on a
terminal (one line per message otherwise, for pipes and logs). It reads what the service
publishes, so it works beside a running ``edge run`` and from any machine that reaches the broker.
"""

from __future__ import annotations

import json
import queue
import sys
import time
from typing import Any

from edge.config import Config
from edge.errors import HardwareError


def format_range(payload: dict) -> str:
    status = payload.get("status", "?")
    pan, tilt = payload.get("pan_deg"), payload.get("tilt_deg")
    where = f"pan {pan:+7.2f}° tilt {tilt:+6.2f}°" if isinstance(pan, (int, float)) and isinstance(tilt, (int, float)) else ""
    best = payload.get("filtered_m", payload.get("range_m"))
    sigma = payload.get("filtered_sigma_m", payload.get("sigma_m"))
    if status == "ok" and isinstance(best, (int, float)):
        text = f"{best:7.3f} m ± {1000 * (sigma or 0):5.1f} mm"
    else:
        text = f"{status:>7}" + (f" ({payload['detail']})" if payload.get("detail") else "")
    rate = payload.get("rate_hz")
    tail = f"  {rate:5.1f}/s" if isinstance(rate, (int, float)) else ""
    return f"{text}  {where}{tail}"


def watch(config: Config, device: str | None, count: int | None, timeout_s: float) -> int:
    """Print ranges until `count` arrived or nothing came for `timeout_s`. Returns how many came."""
    import paho.mqtt.client as mqtt

    device = device or config.device.resolved_id()
    topic = f"{config.mqtt.prefix}/{device}/range"
    inbox: queue.Queue[bytes] = queue.Queue()
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5)
    if config.mqtt.username:
        client.username_pw_set(config.mqtt.username, config.mqtt.password or None)
    if config.mqtt.tls.enabled:
        client.tls_set(ca_certs=config.mqtt.tls.ca_file or None,
                       certfile=config.mqtt.tls.cert_file or None, keyfile=config.mqtt.tls.key_file or None)
    client.on_connect = lambda c, *_: c.subscribe(topic, qos=0)
    client.on_message = lambda _c, _u, msg: inbox.put(msg.payload)
    try:
        client.connect(config.mqtt.host, config.mqtt.port, keepalive=config.mqtt.keepalive_s)
    except OSError as exc:
        raise HardwareError(f"broker {config.mqtt.host}:{config.mqtt.port}: {exc}") from None
    client.loop_start()
    tty = sys.stdout.isatty()
    seen = 0
    try:
        while count is None or seen < count:
            try:
                raw = inbox.get(timeout=timeout_s)
            except queue.Empty:
                break
            try:
                payload: Any = json.loads(raw)
            except ValueError:
                continue
            if not isinstance(payload, dict):
                continue
            seen += 1
            line = format_range(payload)
            if tty:
                sys.stdout.write("\r" + line.ljust(78))
            else:
                sys.stdout.write(line + "\n")
            sys.stdout.flush()
    finally:
        if tty and seen:
            sys.stdout.write("\n")
        client.loop_stop()
        client.disconnect()
    if not seen:
        print(f"no range on {topic} within {timeout_s:g} s (is `edge run` running in range-finder mode?)",
              file=sys.stderr)
    return seen
