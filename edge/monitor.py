"""Tools that talk to a running device through the broker, as an operator would.

- `edge range`: the range finder's output, live. Subscribes to ``<prefix>/<id>/range`` and shows
  each range on one line that updates in place on a terminal (one line per message otherwise, for
  pipes and logs).
- `edge calibrate --device ID --distances …`: sends ``cmd/calibrate`` and follows the session —
  which distance the device waits for, what it ranges, what it took — until its result.

Both read what the service publishes, so they work beside a running ``edge run`` and from any
machine that reaches the broker, with the credentials of ``[mqtt]``.
"""

from __future__ import annotations

import json
import queue
import sys
import threading
import time
import uuid
from collections.abc import Sequence
from typing import Any

from edge.config import Config
from edge.errors import HardwareError


def format_range(payload: dict) -> str:
    status = payload.get("status", "?")
    pan, tilt = payload.get("pan_deg"), payload.get("tilt_deg")
    known = isinstance(pan, (int, float)) and isinstance(tilt, (int, float))
    where = f"pan {pan:+7.2f}° tilt {tilt:+6.2f}°" if known else ""
    best = payload.get("filtered_m", payload.get("range_m"))
    sigma = payload.get("filtered_sigma_m", payload.get("sigma_m"))
    if status == "ok" and isinstance(best, (int, float)):
        text = f"{best:7.3f} m ± {1000 * (sigma or 0):5.1f} mm"
    else:
        text = f"{status:>7}" + (f" ({payload['detail']})" if payload.get("detail") else "")
    rate = payload.get("rate_hz")
    tail = f"  {rate:5.1f}/s" if isinstance(rate, (int, float)) else ""
    return f"{text}  {where}{tail}"


def _connect(config: Config, topics: list[tuple[str, int]], inbox: queue.Queue) -> Any:
    """An MQTT 5 client of the configured broker, subscribed to `topics`, messages (topic,
    payload) into `inbox`; started. The caller stops it."""
    import paho.mqtt.client as mqtt

    from edge.mqtt import read_password, set_credentials

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5)
    set_credentials(client, config.mqtt, read_password(config.mqtt))
    subscribed = threading.Event()
    refused: list[str] = []

    def on_connect(c: Any, _userdata: Any, _flags: Any, reason: Any, _props: Any) -> None:
        if reason.is_failure:
            refused.append(str(reason))
            subscribed.set()
        else:
            c.subscribe(topics)

    client.on_connect = on_connect
    client.on_subscribe = lambda *_: subscribed.set()
    client.on_message = lambda _c, _u, msg: inbox.put((msg.topic, msg.payload))
    try:
        client.connect(config.mqtt.host, config.mqtt.port, keepalive=config.mqtt.keepalive_s)
    except OSError as exc:
        raise HardwareError(f"broker {config.mqtt.host}:{config.mqtt.port}: {exc}") from None
    client.loop_start()
    if not subscribed.wait(10.0) or refused:
        _stop(client)
        why = f"refused the connection: {refused[0]}" if refused else "no answer within 10 s"
        who = config.mqtt.username or "anonymous"
        raise HardwareError(f"broker {config.mqtt.host}:{config.mqtt.port}: {why} (as {who})")
    return client


def _stop(client: Any) -> None:
    client.loop_stop()
    client.disconnect()


def watch(config: Config, device: str | None, count: int | None, timeout_s: float) -> int:
    """Print ranges until `count` arrived or nothing came for `timeout_s`. Returns how many came."""
    device = device or config.device.resolved_id()
    topic = f"{config.mqtt.prefix}/{device}/range"
    inbox: queue.Queue[tuple[str, bytes]] = queue.Queue()
    client = _connect(config, [(topic, 0)], inbox)
    tty = sys.stdout.isatty()
    seen = 0
    try:
        while count is None or seen < count:
            try:
                _, raw = inbox.get(timeout=timeout_s)
            except queue.Empty:
                break
            payload = _json_object(raw)
            if payload is None:
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
        _stop(client)
    if not seen:
        print(f"no range on {topic} within {timeout_s:g} s (is `edge run` running in range-finder mode?)",
              file=sys.stderr)
    return seen


def calibrate_device(config: Config, device: str | None, distances: Sequence[float], answer_s: float = 10.0) -> int:
    """Ask the device to calibrate itself at `distances` (``cmd/calibrate``) and follow the session
    until its result: 0 when it calibrated, 1 when not (the device's reason on stderr)."""
    device = device or config.device.resolved_id()
    base = f"{config.mqtt.prefix}/{device}"
    inbox: queue.Queue[tuple[str, bytes]] = queue.Queue()
    client = _connect(config, [(f"{base}/state", 1), (f"{base}/range", 0), (f"{base}/cmd/calibrate/result", 1)],
                      inbox)
    request = f"cli-{uuid.uuid4().hex[:12]}"
    tty = sys.stdout.isatty()
    try:
        client.publish(f"{base}/cmd/calibrate", json.dumps({"distances_m": list(distances), "request_id": request}),
                       qos=1).wait_for_publish(answer_s)
        print(f"{device}: calibrating at {', '.join(f'{d:g}' for d in distances)} m. Bring a flat, matte "
              "target squarely in front of the unit to each distance in turn (starting from elsewhere) and hold "
              "it still a couple of seconds at each.")
        answered, waiting, last_heard = False, None, time.monotonic()
        # The session ends by itself (the device's service.calibrate_timeout_s); we only give up on
        # a device that says nothing at all.
        while True:
            try:
                topic, raw = inbox.get(timeout=1.0)
            except queue.Empty:
                if time.monotonic() - last_heard > (answer_s if not answered else 120.0):
                    print(file=sys.stderr)
                    print(f"edge: {device} said nothing for {time.monotonic() - last_heard:.0f} s: is `edge run` "
                          "running there and connected?", file=sys.stderr)
                    return 1
                continue
            last_heard = time.monotonic()
            payload = _json_object(raw)
            if payload is None:
                continue
            if topic.endswith("/result") and payload.get("request_id") == request:
                if tty:
                    sys.stdout.write("\n")
                return _report_result(payload)
            session = payload.get("calibration") if topic.endswith("/state") else None
            if isinstance(session, dict):
                answered = True
                if session.get("waiting_for_m") not in (waiting, None):
                    waiting = session["waiting_for_m"]
                    taken = session.get("taken_m") or []
                    done = f"took {', '.join(f'{d:g}' for d in taken)} m; " if taken else ""
                    print(("\n" if tty else "") + f"{done}waiting for the target at {waiting:g} m")
            elif topic.endswith("/range") and tty and answered:
                sys.stdout.write("\r  " + format_range(payload).ljust(76))
                sys.stdout.flush()
    finally:
        _stop(client)


def _json_object(raw: bytes) -> dict | None:
    """A payload that is a JSON object, else None (anything else on a topic is ignored)."""
    try:
        payload = json.loads(raw)
    except ValueError:
        return None
    return payload if isinstance(payload, dict) else None


def _report_result(result: dict) -> int:
    if not result.get("ok"):
        print(f"edge: cmd/calibrate: {result.get('error', 'failed')}", file=sys.stderr)
        return 1
    cal = result.get("calibration") or {}
    for name, laser in (cal.get("lasers") or {}).items():
        print(f"  laser {name}: {laser.get('angle_from_nominal_deg', float('nan')):.3f}° from nominal, "
              f"residuals rms {laser.get('rms_px', float('nan')):.3f} px, "
              f"max {laser.get('max_px', float('nan')):.3f} px")
    print(f"calibrated; the device keeps it in {cal.get('file', '?')} and ranges with it from now on")
    return 0
