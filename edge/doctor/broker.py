"""The doctor's broker check: the device's credentials and TLS are accepted, and it may publish to
its own topics.

It logs in as the device does (``[mqtt]``: user, password file, TLS, MQTT 5) under a client id of
its own (``<client id>-doctor``, a clean session), so that the device's persistent session is left
alone — unless the broker ties client ids to user names (``use_username_as_clientid``, as
config/mosquitto-site.conf does), where any login of the device's account stands for the device:
run the doctor with the service stopped. It publishes one QoS 1 message to
``<prefix>/<id>/cmd/doctor/result`` — a topic the device may write (config/mosquitto-acl.conf), not
retained, that no command of ours answers on — and takes the broker's acknowledgement as the verdict
(Mosquitto answers a publish its ACL denies with "Not authorized"). It also subscribes there and
says whether the message came back: a site's ACL lets a device read only its commands, so it may
not.
"""

from __future__ import annotations

import json
import socket
import ssl
import threading
import time
from typing import TYPE_CHECKING, Any

from edge.doctor.checklist import Problem, Skip
from edge.errors import EdgeError

if TYPE_CHECKING:
    from edge.config import Config

TIMEOUT_S = 5.0  # to connect, and for the acknowledgement
ECHO_S = 1.0  # how long to wait for the message to come back


def _where(config: Config) -> str:
    mqtt = config.mqtt
    return f"{mqtt.host}:{mqtt.port}{' (TLS)' if mqtt.tls.enabled else ''}"


def _refused(config: Config, why: str) -> Problem:
    where = _where(config)
    if "user name or password" in why.lower() or "not authori" in why.lower() or "banned" in why.lower():
        return Problem(f"{where} refuses the device's login: {why}",
                       f"check mqtt.username ({config.mqtt.username or 'none'}) and mqtt.password_file against "
                       "the broker's password file (mosquitto_passwd), and that the account is allowed")
    return Problem(f"{where} refuses the connection: {why}", "see the broker's log (journalctl -u mosquitto)")


def check_broker(config: Config) -> str:
    mqtt = config.mqtt
    if not mqtt.enabled:
        raise Skip("mqtt.enabled = false: the device runs without a broker")
    import paho.mqtt.client as paho

    from edge.mqtt import read_password, set_credentials
    from edge.topics import Topics

    where = _where(config)
    try:
        device = config.device.resolved_id()
        topic = Topics(mqtt.prefix, device).result("doctor")
        password = read_password(mqtt)
        client_id = f"{mqtt.client_id or f'{mqtt.prefix}-{device}'}-doctor"
        client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=paho.MQTTv5)
        set_credentials(client, mqtt, password)
    except EdgeError as exc:
        raise Problem(str(exc), "fix [mqtt] (and [mqtt.tls]) in the configuration") from None
    client.connect_timeout = TIMEOUT_S
    events: dict[str, Any] = {}
    done = {name: threading.Event() for name in ("connect", "subscribe", "publish", "echo")}

    def on_connect(_c: Any, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
        events["connect"] = reason
        done["connect"].set()

    def on_disconnect(_c: Any, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
        events["disconnect"] = reason
        done["connect"].set()  # a broker that closes the connection instead of answering the login

    def on_subscribe(_c: Any, _u: Any, _m: Any, reasons: Any, _p: Any) -> None:
        events["subscribe"] = reasons
        done["subscribe"].set()

    def on_publish(_c: Any, _u: Any, _m: Any, reason: Any, _p: Any) -> None:
        events["publish"] = reason
        done["publish"].set()

    def on_message(_c: Any, _u: Any, message: Any) -> None:
        if message.topic == topic:
            done["echo"].set()

    client.on_connect, client.on_disconnect = on_connect, on_disconnect
    client.on_subscribe, client.on_publish, client.on_message = on_subscribe, on_publish, on_message
    try:
        client.connect(mqtt.host, mqtt.port, keepalive=mqtt.keepalive_s, clean_start=True)
    except ssl.SSLCertVerificationError as exc:
        raise Problem(f"{where}: TLS: the broker's certificate is not trusted ({exc.verify_message})",
                      "set mqtt.tls.ca_file to the CA that signed the broker's certificate, and mqtt.host to "
                      "the name in it") from None
    except ssl.SSLError as exc:
        raise Problem(f"{where}: TLS handshake failed ({exc.reason or exc})",
                      "is TLS on at that port? check mqtt.port (8883 for TLS), mqtt.tls and the certificates") from None
    except ConnectionRefusedError:
        raise Problem(f"nothing listens on {where}",
                      "is the broker running (systemctl status mosquitto)? check mqtt.host and mqtt.port") from None
    except socket.gaierror as exc:
        raise Problem(f"{mqtt.host}: cannot resolve the name ({exc.strerror})",
                      "check mqtt.host and the device's network (DNS)") from None
    except TimeoutError:
        raise Problem(f"no answer from {where} within {TIMEOUT_S:g} s",
                      "a firewall, the wrong host, or the wrong port; check mqtt.host and mqtt.port") from None
    except OSError as exc:
        raise Problem(f"cannot reach {where}: {exc.strerror or exc}",
                      "check the network and mqtt.host, mqtt.port") from None
    client.loop_start()
    try:
        return _talk(client, config, topic, events, done)
    finally:
        client.disconnect()
        client.loop_stop()


def _talk(client: Any, config: Config, topic: str, events: dict[str, Any], done: dict[str, threading.Event]) -> str:
    where = _where(config)
    if not done["connect"].wait(TIMEOUT_S):
        raise Problem(f"{where} accepted the TCP connection but did not answer the login within {TIMEOUT_S:g} s",
                      "does the port speak TLS (set mqtt.tls.enabled = true) or is it not an MQTT broker?")
    if "connect" not in events:
        raise Problem(f"{where} closed the connection during the login ({events.get('disconnect')})",
                      "the port may expect TLS (mqtt.tls.enabled), or the broker refuses this client id")
    if events["connect"].is_failure:
        raise _refused(config, str(events["connect"]))
    started = time.monotonic()
    client.subscribe(topic, qos=1)
    done["subscribe"].wait(TIMEOUT_S)
    payload = json.dumps({"ok": True, "doctor": "can the device publish here?",
                          "ts": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
    client.publish(topic, payload, qos=1, retain=False)
    if not done["publish"].wait(TIMEOUT_S):
        raise Problem(f"{where} did not acknowledge a QoS 1 publish to {topic} within {TIMEOUT_S:g} s",
                      "see the broker's log (journalctl -u mosquitto)")
    reason = events["publish"]
    if getattr(reason, "is_failure", False):
        raise Problem(f"{where} refuses the device's publish to its own topic {topic}: {reason}",
                      f"the broker's ACL must let user {config.mqtt.username or '(anonymous)'} write "
                      f"{config.mqtt.prefix}/<its id>/…: see config/mosquitto-acl.conf; [device] id must "
                      "equal the user name")
    echoed = done["echo"].wait(ECHO_S)
    took = time.monotonic() - started
    user = f" as {config.mqtt.username}" if config.mqtt.username else ""
    back = "read back" if echoed else "not read back (the ACL lets a device read only its commands)"
    return f"{where}: logged in{user}, published to {topic} (acknowledged, {back}; {took * 1e3:.0f} ms)"
