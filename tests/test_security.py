"""Security of the MQTT link against a real Mosquitto with passwords, the shipped ACL
(config/mosquitto-acl.conf) and TLS: each device is confined to its own topics, only operators
command devices, bad credentials and unknown CAs are refused, and the device listens on no port.

Devices log in with username = device id (dev1, dev2); `dashboard` is the operators' account and
`homeassistant` Home Assistant's, both as in the ACL file."""

from __future__ import annotations

import ast
import contextlib
import glob
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from broker import Mosquitto
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from edge.config import MqttConfig, TlsConfig
from edge.discovery import discovery_payloads
from edge.mqtt import MqttLink
from edge.outbox import Outbox

REPO = Path(__file__).resolve().parents[1]
ACL = (REPO / "config" / "mosquitto-acl.conf").read_text()
PASSWORDS = {"dev1": "pw-dev1", "dev2": "pw-dev2", "dashboard": "pw-dash", "homeassistant": "pw-ha",
             "consumer": "pw-consumer"}
VERSION = "9.9.9"
NOT_AUTHORIZED = 0x87
BAD_CREDENTIALS = 0x86


# ---- helpers ----


def wait_until(predicate: Callable[[], bool], timeout: float = 5.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


@dataclass(frozen=True)
class Tls:
    ca: str
    cert: str | None = None
    key: str | None = None


class Peer:
    """A raw paho MQTT 5 client logged in as someone: collects what it receives and the reason
    code of each QoS 1 PUBACK."""

    def __init__(self, b: Mosquitto, username: str | None = None, password: str | None = None,
                 tls: Tls | None = None, client_id: str | None = None) -> None:
        self.broker = b
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5,
                                  client_id=client_id or f"sec-{username or 'anon'}-{uuid.uuid4().hex[:8]}")
        if username is not None:
            self.client.username_pw_set(username, password)
        if tls is not None:
            self.client.tls_set(ca_certs=tls.ca, certfile=tls.cert, keyfile=tls.key)
        self.received: list[mqtt.MQTTMessage] = []
        self.acks: dict[int, ReasonCode] = {}
        self.connack: ReasonCode | None = None
        self._cond = threading.Condition()
        self.client.on_connect = self._on_connect
        self.client.on_publish = self._on_publish
        self.client.on_message = self._on_message
        self.client.on_subscribe = self._on_subscribe
        self._subacks: dict[int, list] = {}
        self.session_present: bool | None = None

    def _on_connect(self, client, userdata, flags, reason, properties) -> None:
        with self._cond:
            self.connack = reason
            self.session_present = bool(flags.session_present)
            self._cond.notify_all()

    def _on_publish(self, client, userdata, mid, reason, properties) -> None:
        with self._cond:
            self.acks[mid] = reason
            self._cond.notify_all()

    def _on_message(self, client, userdata, msg) -> None:
        with self._cond:
            self.received.append(msg)
            self._cond.notify_all()

    def _on_subscribe(self, client, userdata, mid, reasons, properties) -> None:
        with self._cond:
            self._subacks[mid] = reasons
            self._cond.notify_all()

    def _wait(self, predicate: Callable[[], bool], timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(predicate, timeout)

    def start(self, timeout: float = 5.0, session_expiry_s: int = 0) -> ReasonCode | Exception | None:
        """Connect (a persistent session if `session_expiry_s`); returns the CONNACK's reason code,
        the exception of a failed TCP/TLS connect, or None when the broker answered nothing (a
        TLS 1.3 server refusing the client's certificate closes the connection after the client's
        handshake has finished)."""
        props = Properties(PacketTypes.CONNECT)
        props.SessionExpiryInterval = session_expiry_s
        try:
            self.client.connect(self.broker.host, self.broker.port, keepalive=10,
                                clean_start=not session_expiry_s, properties=props)
        except (OSError, mqtt.WebsocketConnectionError) as exc:  # ssl.SSLError is an OSError
            return exc
        self.client.loop_start()
        self._wait(lambda: self.connack is not None, timeout)
        if self.connack is None or self.connack.is_failure:
            self.client.loop_stop()  # do not keep retrying in the background
        return self.connack

    def started(self, session_expiry_s: int = 0) -> Peer:
        reason = self.start(session_expiry_s=session_expiry_s)
        assert isinstance(reason, ReasonCode) and not reason.is_failure, f"could not connect: {reason!r}"
        return self

    def subscribe(self, *topics: str) -> Peer:
        result, mid = self.client.subscribe([(t, 1) for t in topics])
        assert result == mqtt.MQTT_ERR_SUCCESS
        assert self._wait(lambda: mid in self._subacks, 5), f"no SUBACK for {topics}"
        return self

    def publish(self, topic: str, payload: bytes | str, qos: int = 1, retain: bool = False) -> ReasonCode | None:
        """Publish and, for QoS 1, wait for the PUBACK: its reason code."""
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        if qos == 0:
            return None
        assert self._wait(lambda: info.mid in self.acks, 5), f"no PUBACK for {topic}"
        return self.acks[info.mid]

    def messages(self, topic: str | None = None) -> list[mqtt.MQTTMessage]:
        with self._cond:
            return [m for m in self.received if topic is None or mqtt.topic_matches_sub(topic, m.topic)]

    def wait_for(self, topic: str, predicate: Callable[[mqtt.MQTTMessage], bool] | None = None,
                 timeout: float = 5.0) -> mqtt.MQTTMessage:
        found: list[mqtt.MQTTMessage] = []

        def match() -> bool:
            found[:] = [m for m in self.received
                        if mqtt.topic_matches_sub(topic, m.topic) and (predicate is None or predicate(m))]
            return bool(found)

        if not self._wait(match, timeout):
            seen = [m.topic for m in self.received][-10:]
            raise AssertionError(f"nothing on {topic} within {timeout} s (last topics: {seen})")
        return found[0]

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def refused(result: ReasonCode | Exception | None) -> bool:
    return result is None or isinstance(result, Exception) or result.is_failure


def link_config(b: Mosquitto, **changes) -> MqttConfig:
    # A client id of its own per link: two links of one device id in a test must not take over
    # each other's connection and persistent session.
    changes.setdefault("client_id", f"edge-test-{uuid.uuid4().hex[:8]}")
    return MqttConfig(host=b.host, port=b.port, keepalive_s=5, reconnect_min_s=0.05, reconnect_max_s=0.3,
                      **changes)


def password_file(folder: Path, user: str, password: str | None = None) -> str:
    path = folder / f"{user}.password"
    path.write_text((password or PASSWORDS[user]) + "\n")
    path.chmod(0o600)
    return str(path)


@pytest.fixture
def secured() -> Iterator[Mosquitto]:
    """A fresh broker (no retained messages or sessions of other tests) with the passwords and the
    shipped ACL."""
    with Mosquitto(passwords=PASSWORDS, acl=ACL) as b:
        yield b


@pytest.fixture
def peers() -> Iterator[Callable[..., Peer]]:
    made: list[Peer] = []

    def make(b: Mosquitto, user: str | None, password: str | None = None, tls: Tls | None = None,
             client_id: str | None = None) -> Peer:
        peer = Peer(b, user, PASSWORDS.get(user or "") if password is None else password, tls, client_id)
        made.append(peer)
        return peer

    yield make
    for p in made:
        p.close()


@pytest.fixture
def links(tmp_path: Path) -> Iterator[Callable[..., MqttLink]]:
    made: list[tuple[MqttLink, Outbox]] = []

    def make(config: MqttConfig, device_id: str) -> MqttLink:
        outbox = Outbox(tmp_path / f"outbox-{device_id}-{len(made)}.sqlite3")
        link = MqttLink(config, device_id, outbox, version=VERSION)
        made.append((link, outbox))
        return link

    yield make
    for link, outbox in made:
        link.stop(timeout_s=0.5)
        outbox.close()


# ---- the ACL with passwords ----


def test_a_device_publishes_all_its_topics_and_home_assistant_sees_its_discovery(secured, peers, links, tmp_path):
    dash = peers(secured, "dashboard").started().subscribe("edge/#")
    ha = peers(secured, "homeassistant").started().subscribe("homeassistant/+/+/+/config")
    config = link_config(secured, username="dev1", password_file=password_file(tmp_path, "dev1"))
    link = links(config, "dev1")
    link.start()
    wait_until(lambda: link.connected, what="dev1 to connect with its password")
    link.publish_state({"mode": "guard"})
    link.publish_live("range", {"index": 3, "range_m": 1.5})
    link.publish_live("cue", {"bearing_deg": 10.0, "range_m": 1.5})
    link.publish_event("sweep", {"sweep": 1, "duration_s": 2.0, "zones": []})
    link.publish_event("alert", {"event": "intrusion", "id": "t1", "sweep": 1})
    link.publish_result("mode", True, request_id="r1")
    for kind in ("status", "state", "range", "cue", "sweep", "alert", "cmd/mode/result"):
        dash.wait_for(f"edge/dev1/{kind}")
    dash.wait_for("edge/dev1/status", lambda m: m.payload == b"online")
    wait_until(lambda: link.stats()["pending"] == 0, what="the outbox to drain")
    # Discovery went through the `homeassistant/+/edge_%u/+/config` pattern.
    expected = set(discovery_payloads(config, "dev1", VERSION))
    wait_until(lambda: {m.topic for m in ha.messages()} >= expected, what="discovery configs")
    # homeassistant/status is readable by devices: Home Assistant's birth message brings discovery again.
    before = len(ha.messages())
    assert not ha.publish("homeassistant/status", "online").is_failure
    wait_until(lambda: len(ha.messages()) >= before + len(expected), what="discovery sent again")
    assert link.stats()["refused"] == 0  # the broker refused none of the device's QoS 1 messages


def test_a_device_cannot_write_another_devices_topics_nor_command_itself(secured, peers):
    dash = peers(secured, "dashboard").started().subscribe("edge/#")
    dev2 = peers(secured, "dev2").started().subscribe("edge/dev2/cmd/+")
    dev1 = peers(secured, "dev1").started()
    forbidden = [
        ("edge/dev2/alert", '{"event": "intrusion", "id": "forged"}', False),
        ("edge/dev2/cmd/mode", '{"mode": "blindaid"}', False),
        ("edge/dev2/status", "offline", True),
        ("edge/dev2/sweep", '{"sweep": 99}', True),
        ("edge/dev1/cmd/mode", '{"mode": "blindaid"}', False),  # its own command topic: read only
        ("edge/dev1/cmd/lasers_off", "{}", False),
        ("edge/dev1", "x", False),
        ("edge/dev1/other", "x", False),
        ("homeassistant/sensor/edge_dev2/range/config", "{}", True),
        ("homeassistant/status", "offline", False),
    ]
    for topic, payload, retain in forbidden:
        reason = dev1.publish(topic, payload, retain=retain)
        # MQTT 5: Mosquitto 2 acknowledges a denied QoS 1 publish with "Not authorized".
        assert reason is not None and reason.value == NOT_AUTHORIZED, (topic, reason)
    # A marker the device may send: once it has arrived, anything let through before it would have too.
    assert dev1.publish("edge/dev1/alert", '{"event": "marker"}').value in (0x00, 0x10)
    dash.wait_for("edge/dev1/alert")
    assert not [m.topic for m in dash.messages() if m.topic.startswith("edge/dev2/")]
    assert not dash.messages("edge/dev1/cmd/+")
    assert not dev2.messages()
    # The dashboard can command dev2, and dev2 reads it.
    assert not dash.publish("edge/dev2/cmd/mode", '{"mode": "guard"}').is_failure
    dev2.wait_for("edge/dev2/cmd/mode")


def test_a_device_reads_neither_other_devices_commands_nor_their_data(secured, peers):
    dev1 = peers(secured, "dev1").started().subscribe("edge/#", "homeassistant/#")  # accepted, filtered on delivery
    dev2 = peers(secured, "dev2").started().subscribe("edge/dev2/cmd/+")
    dash = peers(secured, "dashboard").started()
    assert not dev2.publish("edge/dev2/alert", '{"event": "intrusion", "id": "t9"}').is_failure
    assert not dev2.publish("homeassistant/sensor/edge_dev2/range/config", "{}", retain=True).is_failure
    assert not dash.publish("edge/dev2/cmd/point", '{"pan_deg": 1, "tilt_deg": 0}').is_failure
    dev2.wait_for("edge/dev2/cmd/point")
    assert not dash.publish("edge/dev1/cmd/sweep", "{}").is_failure  # the one thing dev1 may read here
    dev1.wait_for("edge/dev1/cmd/sweep")
    assert [m.topic for m in dev1.messages()] == ["edge/dev1/cmd/sweep"]


def test_operators_command_devices_and_cannot_forge_their_data(secured, peers, links, tmp_path):
    link = links(link_config(secured, username="dev1", password_file=password_file(tmp_path, "dev1")), "dev1")
    link.start()
    wait_until(lambda: link.connected, what="dev1 to connect")
    time.sleep(0.2)  # the link subscribes in its on_connect; let the SUBACK land
    dash = peers(secured, "dashboard").started().subscribe("edge/dev1/#")
    assert not dash.publish("edge/dev1/cmd/mode", '{"mode": "guard", "request_id": "q7"}').is_failure
    got: list[tuple[str, bytes]] = []
    wait_until(lambda: bool(got.extend(link.commands()) or got), what="dev1 to receive the command")
    assert got == [("mode", b'{"mode": "guard", "request_id": "q7"}')]
    link.publish_result("mode", True, request_id="q7")
    assert json.loads(dash.wait_for("edge/dev1/cmd/mode/result").payload)["request_id"] == "q7"
    # Operators command; they do not speak for a device.
    for topic in ("edge/dev1/alert", "edge/dev1/status", "edge/dev1/cmd/mode/result"):
        assert dash.publish(topic, "{}").value == NOT_AUTHORIZED, topic
    # Home Assistant's account may select a mode and press the device's buttons, nothing else.
    ha = peers(secured, "homeassistant").started()
    assert not ha.publish("edge/dev1/cmd/mode", '{"mode": "rangefinder"}').is_failure
    assert ha.publish("edge/dev1/cmd/point", '{"pan_deg": 0, "tilt_deg": 0}').value == NOT_AUTHORIZED
    assert ha.publish("edge/dev1/guard", '{"occupied": false}').value == NOT_AUTHORIZED
    wait_until(lambda: bool(got.extend(link.commands()) or len(got) == 2), what="the mode from Home Assistant")
    assert got[1] == ("mode", b'{"mode": "rangefinder"}')


def test_a_devices_last_will_cannot_speak_for_another_device(secured, peers):
    dash = peers(secured, "dashboard").started().subscribe("edge/+/status")
    liar = peers(secured, "dev1")
    liar.client.will_set("edge/dev2/status", "offline", qos=1, retain=True)
    result = liar.start()
    if isinstance(result, ReasonCode) and not result.is_failure:
        # Accepted: then the will must be dropped when it fires ("disconnect with will message").
        liar.client.disconnect(reasoncode=ReasonCode(PacketTypes.DISCONNECT, "Disconnect with will message"))
        liar.client.loop_stop()
    honest = peers(secured, "dev1")
    honest.client.will_set("edge/dev1/status", "offline", qos=1, retain=False)
    honest.started()
    honest.client.disconnect(reasoncode=ReasonCode(PacketTypes.DISCONNECT, "Disconnect with will message"))
    honest.client.loop_stop()
    # The broker handled the liar's disconnect first: once the honest will is here, the other would be too.
    dash.wait_for("edge/dev1/status", lambda m: m.payload == b"offline")
    assert not dash.messages("edge/dev2/status")


def test_a_device_taking_another_devices_client_id_gets_none_of_its_commands(secured, peers):
    # Mosquitto does not tie a client id to a user: dev1 can connect as `edge-dev2` and take over
    # dev2's persistent session (a denial of service, see docs/deployment.md), but the ACL is
    # checked against dev1's username on every delivery, so dev2's queued commands stay unread.
    dev2 = peers(secured, "dev2", client_id="edge-dev2").started(session_expiry_s=300).subscribe("edge/dev2/cmd/+")
    dev2.close()  # offline; the broker keeps its session and queues what comes for it
    dash = peers(secured, "dashboard").started()
    assert not dash.publish("edge/dev2/cmd/mode", '{"mode": "guard"}').is_failure
    impostor = peers(secured, "dev1", client_id="edge-dev2").started(session_expiry_s=300)
    assert impostor.session_present  # it did get dev2's session…
    assert not dash.publish("edge/dev2/cmd/sweep", "{}").is_failure
    time.sleep(0.5)
    assert not impostor.messages()  # …and none of its commands, queued or new
    assert impostor.publish("edge/dev2/alert", "{}").value == NOT_AUTHORIZED


def test_wrong_password_unknown_user_and_anonymous_are_refused(secured, peers, links, tmp_path):
    for user, password in (("dev1", "wrong"), ("dev1", ""), ("nobody", "pw-dev1"), (None, None)):
        reason = peers(secured, user, password if user else None).start()
        assert isinstance(reason, ReasonCode) and reason.value in (NOT_AUTHORIZED, BAD_CREDENTIALS), (user, reason)
    # Another device's password does not open this device's account.
    reason = peers(secured, "dev1", PASSWORDS["dev2"]).start()
    assert isinstance(reason, ReasonCode) and reason.is_failure
    wrong = password_file(tmp_path, "dev1", "wrong")
    link = links(link_config(secured, username="dev1", password_file=wrong), "dev1")
    link.start()
    time.sleep(0.5)
    assert not link.connected and link.stats()["connects"] == 0


# ---- TLS ----


def _openssl() -> str:
    path = shutil.which("openssl")
    if path is None:
        pytest.skip("openssl is not installed (apt-get install openssl): the TLS tests make their "
                    "certificates with it")
    return path


@dataclass(frozen=True)
class Pki:
    ca: str
    other_ca: str  # a CA nobody here trusts
    server: tuple[str, str]  # cert, key (127.0.0.1 and localhost)
    clients: dict[str, tuple[str, str]]  # CN → (cert, key), signed by `ca`
    strangers: dict[str, tuple[str, str]]  # CN → (cert, key), signed by `other_ca`


def _make_pki(folder: Path) -> Pki:
    openssl = _openssl()
    folder.mkdir(parents=True, exist_ok=True)
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]

    def run(*args: str) -> None:
        subprocess.run([openssl, *args], check=True, capture_output=True, cwd=folder)

    def ca(name: str) -> tuple[str, str]:
        cert, key = str(folder / f"{name}.pem"), str(folder / f"{name}.key")
        run("req", "-x509", *ec, "-keyout", key, "-out", cert, "-days", "2", "-subj", f"/CN=edge test {name}",
            "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign,cRLSign")
        return cert, key

    def leaf(name: str, cn: str, signer: tuple[str, str], ext: str) -> tuple[str, str]:
        cert, key, csr = (str(folder / f"{name}.{s}") for s in ("pem", "key", "csr"))
        ext_file = folder / f"{name}.ext"
        ext_file.write_text("basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\n" + ext)
        run("req", "-new", *ec, "-keyout", key, "-out", csr, "-subj", f"/CN={cn}")
        run("x509", "-req", "-in", csr, "-CA", signer[0], "-CAkey", signer[1], "-CAcreateserial",
            "-out", cert, "-days", "2", "-extfile", str(ext_file))
        return cert, key

    site, other = ca("site-ca"), ca("other-ca")
    server = leaf("server", "localhost", site,
                  "extendedKeyUsage=serverAuth\nsubjectAltName=IP:127.0.0.1,DNS:localhost\n")
    clients = {cn: leaf(f"client-{cn}", cn, site, "extendedKeyUsage=clientAuth\n") for cn in ("dev1", "dashboard")}
    strangers = {"dev1": leaf("stranger-dev1", "dev1", other, "extendedKeyUsage=clientAuth\n")}
    return Pki(site[0], other[0], server, clients, strangers)


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> Pki:
    return _make_pki(tmp_path_factory.mktemp("pki"))


def test_tls_with_the_site_ca_and_passwords(pki, peers, links, tmp_path):
    with Mosquitto(passwords=PASSWORDS, acl=ACL, tls=(pki.ca, *pki.server)) as b:
        dash = peers(b, "dashboard", tls=Tls(pki.ca)).started().subscribe("edge/#")
        tls = TlsConfig(enabled=True, ca_file=pki.ca)
        link = links(link_config(b, username="dev1", password_file=password_file(tmp_path, "dev1"), tls=tls), "dev1")
        link.start()
        wait_until(lambda: link.connected, what="dev1 to connect over TLS")
        link.publish_event("alert", {"event": "intrusion", "id": "tls", "sweep": 1})
        assert json.loads(dash.wait_for("edge/dev1/alert").payload)["id"] == "tls"
        # The ACL holds over TLS as well.
        assert peers(b, "dev1", tls=Tls(pki.ca)).started().publish("edge/dev2/alert", "{}").value == NOT_AUTHORIZED
        # A client trusting another CA refuses the broker's certificate (no MITM with a rogue broker).
        result = peers(b, "dev1", tls=Tls(pki.other_ca)).start()
        assert isinstance(result, OSError) and "certificate verify failed" in str(result), result
        wrong = links(link_config(b, username="dev1", password_file=password_file(tmp_path, "dev1"),
                                  tls=TlsConfig(enabled=True, ca_file=pki.other_ca)), "dev1")
        wrong.start()
        time.sleep(0.5)
        assert not wrong.connected and wrong.stats()["connects"] == 0
        # Plain MQTT to the TLS listener gets nowhere.
        assert refused(peers(b, "dev1").start(timeout=1.0))


def test_mutual_tls_client_certificate_as_identity(pki, peers, links):
    # require_certificate + use_identity_as_username: the certificate's CN is the username the ACL sees.
    extra = "require_certificate true\nuse_identity_as_username true\nallow_anonymous false"
    with Mosquitto(acl=ACL, tls=(pki.ca, *pki.server), extra=extra) as b:
        dash = peers(b, "dashboard", tls=Tls(pki.ca, *pki.clients["dashboard"])).started().subscribe("edge/#")
        cert, key = pki.clients["dev1"]
        tls = TlsConfig(enabled=True, ca_file=pki.ca, cert_file=cert, key_file=key)
        link = links(link_config(b, tls=tls), "dev1")
        link.start()
        wait_until(lambda: link.connected, what="dev1 to connect with its certificate")
        link.publish_event("alert", {"event": "intrusion", "id": "mtls", "sweep": 1})
        assert json.loads(dash.wait_for("edge/dev1/alert").payload)["id"] == "mtls"
        raw = peers(b, None, tls=Tls(pki.ca, cert, key)).started()
        assert raw.publish("edge/dev2/alert", "{}").value == NOT_AUTHORIZED
        assert raw.publish("edge/dev1/cmd/mode", "{}").value == NOT_AUTHORIZED
        # No certificate, or one from a CA the broker does not trust (even with the right CN): refused.
        assert refused(peers(b, None, tls=Tls(pki.ca)).start(timeout=1.0))
        assert refused(peers(b, None, tls=Tls(pki.ca, *pki.strangers["dev1"])).start(timeout=1.0))
        time.sleep(0.2)
        assert not [m.topic for m in dash.messages() if m.topic.startswith("edge/dev2/")]
        assert not dash.messages("edge/dev1/cmd/+")


def _site_config(pki: Pki, folder: Path, port: int) -> Path:
    """config/mosquitto-site.conf with its paths and port replaced for this machine."""
    folder.mkdir(parents=True, exist_ok=True)
    passwd = folder / "passwd"
    passwd.write_text("")
    for user, password in PASSWORDS.items():
        subprocess.run(["mosquitto_passwd", "-b", str(passwd), user, password], check=True, capture_output=True)
    replace = {
        "pid_file": f"pid_file {folder / 'mosquitto.pid'}",
        "listener 8883": f"listener {port} 127.0.0.1",
        "password_file": f"password_file {passwd}",
        "acl_file": f"acl_file {REPO / 'config' / 'mosquitto-acl.conf'}",
        "persistence_location": f"persistence_location {folder}/",
        "log_dest": f"log_dest file {folder / 'mosquitto.log'}",
        "cafile": f"cafile {pki.ca}",
        "certfile": f"certfile {pki.server[0]}",
        "keyfile": f"keyfile {pki.server[1]}",
    }
    lines, used = [], set()
    for line in (REPO / "config" / "mosquitto-site.conf").read_text().splitlines():
        key = next((k for k in replace if line == k or line.startswith(k + " ")), None)
        lines.append(replace[key] if key else line)
        used.add(key)
    assert set(replace) <= used, f"config/mosquitto-site.conf has no {sorted(set(replace) - used)} line"
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        lines.append("user root")  # Mosquitto 2 run as root drops to `mosquitto`, who cannot write here
    conf = folder / "mosquitto.conf"
    conf.write_text("\n".join(lines) + "\n")
    return conf


@contextlib.contextmanager
def _site_broker(pki, tmp_path) -> Iterator[Mosquitto]:
    """Mosquitto started with the shipped site config (its paths and port replaced)."""
    if not shutil.which("mosquitto_passwd"):
        pytest.skip("mosquitto_passwd is not installed (it comes with mosquitto)")
    b = Mosquitto()  # for its executable, port and life cycle; started with the site's config instead
    try:
        b.conf_path = _site_config(pki, tmp_path / "site", b.port)
        b.log_path = tmp_path / "site" / "mosquitto.log"
        yield b.start()
    finally:
        b.close()


def test_the_example_site_config_runs_with_the_acl(pki, peers, links, tmp_path):
    with _site_broker(pki, tmp_path) as b:
        tls = Tls(pki.ca)
        dash = peers(b, "dashboard", tls=tls).started().subscribe("edge/#")
        config = link_config(b, username="dev1", password_file=password_file(tmp_path, "dev1"),
                             tls=TlsConfig(enabled=True, ca_file=pki.ca))
        link = links(config, "dev1")
        link.start()
        wait_until(lambda: link.connected, what="dev1 to connect to the site config's listener")
        link.publish_event("alert", {"event": "intrusion", "id": "site", "sweep": 1})
        assert json.loads(dash.wait_for("edge/dev1/alert").payload)["id"] == "site"
        assert peers(b, "dev2", tls=tls).started().publish("edge/dev1/alert", "{}").value == NOT_AUTHORIZED
        assert refused(peers(b, None, tls=tls).start(timeout=1.0))  # allow_anonymous false
        assert refused(peers(b, "dev1").start(timeout=1.0))  # no plain MQTT


def test_the_site_config_ties_client_ids_to_usernames(pki, peers, links, tmp_path):
    # use_username_as_clientid: whatever client id a client sends, the broker uses its username.
    # The read-only consumer connecting as `edge-dev1` (the device's own default client id) once
    # knocked the device off and could take its session; now it is simply `consumer`.
    with _site_broker(pki, tmp_path) as b:
        tls = Tls(pki.ca)
        dash = peers(b, "dashboard", tls=tls).started().subscribe("edge/dev1/alert")
        config = link_config(b, username="dev1", password_file=password_file(tmp_path, "dev1"),
                             tls=TlsConfig(enabled=True, ca_file=pki.ca), client_id="edge-dev1",
                             session_expiry_s=300)
        link = links(config, "dev1")
        link.start()
        wait_until(lambda: link.connected, what="dev1 to connect to the site config's listener")
        impostor = peers(b, "consumer", tls=tls, client_id="edge-dev1").started(session_expiry_s=300)
        assert not impostor.session_present  # not the device's session: its own, as `consumer`
        time.sleep(1.0)  # a take-over would have disconnected the device by now
        assert link.connected and link.stats()["connects"] == 1, link.stats()
        link.publish_event("alert", {"event": "intrusion", "id": "still-here", "sweep": 1})
        assert json.loads(dash.wait_for("edge/dev1/alert").payload)["id"] == "still-here"
        assert impostor.client.is_connected()  # and the consumer keeps its own connection
        assert link.stats()["connects"] == 1


# ---- no listening port ----


def _socket_inodes(pid: int) -> set[int]:
    """The socket inodes held by a process and its descendants."""
    inodes: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        for fd in glob.glob(f"/proc/{p}/fd/*"):
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith("socket:["):
                inodes.add(int(target[8:-1]))
        for children in glob.glob(f"/proc/{p}/task/*/children"):
            try:
                todo += [int(c) for c in Path(children).read_text().split()]
            except OSError:
                pass
    return inodes


@dataclass(frozen=True)
class InetSocket:
    table: str  # tcp, tcp6, udp, udp6, …
    local_port: int
    remote_port: int
    state: str  # hex, e.g. 0A = TCP LISTEN, 01 = ESTABLISHED, 07 = UDP unconnected
    inode: int


def _inet_sockets() -> list[InetSocket]:
    found = []
    for path in glob.glob("/proc/net/tcp") + glob.glob("/proc/net/tcp6") + glob.glob("/proc/net/udp*"):
        lines = Path(path).read_text().splitlines()[1:]
        for line in lines:
            f = line.split()
            found.append(InetSocket(Path(path).name, int(f[1].rsplit(":", 1)[1], 16),
                                    int(f[2].rsplit(":", 1)[1], 16), f[3], int(f[9])))
    return found


def _listening(sockets: list[InetSocket]) -> list[InetSocket]:
    """TCP in LISTEN, and UDP bound to a port but connected to nobody (it takes datagrams from anyone)."""
    return [s for s in sockets if (s.table.startswith("tcp") and s.state == "0A")
            or (s.table.startswith("udp") and s.local_port != 0 and s.remote_port == 0)]


@pytest.mark.skipif(not os.path.isdir("/proc/net"), reason="needs Linux /proc")
def test_the_listener_detector_sees_a_listener():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as tcp, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        tcp.bind(("127.0.0.1", 0))
        tcp.listen()
        udp.bind(("127.0.0.1", 0))
        mine = [s for s in _inet_sockets() if s.inode in _socket_inodes(os.getpid())]
        found = {(s.table, s.local_port) for s in _listening(mine)}
        assert {("tcp", tcp.getsockname()[1]), ("udp", udp.getsockname()[1])} <= found


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir("/proc/net"), reason="needs Linux /proc")
def test_the_device_opens_no_listening_port(tmp_path, peers):
    with Mosquitto(passwords=PASSWORDS, acl=ACL) as b:
        dash = peers(b, "dashboard").started().subscribe("edge/#")
        args = [sys.executable, "-m", "edge", "run", "--set", f"mqtt.port={b.port}",
                "--set", 'mqtt.host="127.0.0.1"', "--set", 'device.id="dev1"', "--set", 'mqtt.username="dev1"',
                "--set", f"mqtt.password_file={json.dumps(password_file(tmp_path, 'dev1'))}",
                "--set", f"service.state_dir={json.dumps(str(tmp_path / 'state'))}",
                "--set", 'mode="rangefinder"', "--for", "600"]  # stopped below; --for only if the test fails
        proc = subprocess.Popen(args, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "NOTIFY_SOCKET": ""})
        try:
            dash.wait_for("edge/dev1/status", lambda m: m.payload == b"online", timeout=20)
            dash.wait_for("edge/dev1/range", timeout=10)
            listening, to_broker = [], []
            for _ in range(10):  # a few looks while it runs: a listener opened late counts too
                inodes = _socket_inodes(proc.pid)
                mine = [s for s in _inet_sockets() if s.inode in inodes]
                listening += _listening(mine)
                to_broker += [s for s in mine if s.table.startswith("tcp") and s.state == "01"
                              and s.remote_port == b.port]
                time.sleep(0.2)
            assert proc.poll() is None, "the service ended before it could be looked at"
            assert to_broker, "the service's own MQTT connection was not found: the /proc mapping is broken"
            assert not listening, f"the device listens: {listening}"
            # An operator watches with `edge range`, logging in with a password file as the device does.
            watcher = subprocess.run(
                [sys.executable, "-m", "edge", "range", "--device", "dev1", "--count", "3",
                 "--set", f"mqtt.port={b.port}", "--set", 'mqtt.host="127.0.0.1"', "--set", 'mqtt.username="dashboard"',
                 "--set", f"mqtt.password_file={json.dumps(password_file(tmp_path, 'dashboard'))}"],
                cwd=REPO, capture_output=True, text=True, timeout=30)
            assert watcher.returncode == 0, watcher.stderr[-2000:]
            assert len([ln for ln in watcher.stdout.splitlines() if "pan" in ln]) == 3, watcher.stdout
            stranger = subprocess.run(
                [sys.executable, "-m", "edge", "range", "--device", "dev1", "--count", "3",
                 "--set", f"mqtt.port={b.port}", "--set", 'mqtt.host="127.0.0.1"', "--set", 'mqtt.username="dashboard"',
                 "--set", 'mqtt.password="wrong"'], cwd=REPO, capture_output=True, text=True, timeout=30)
            assert stranger.returncode == 1 and stranger.stderr.strip() == (
                f"edge: broker 127.0.0.1:{b.port}: refused the connection: Not authorized (as dashboard)")
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert proc.returncode == 0, err[-3000:]
        # The ACL let through everything the real service sends (a refused PUBACK is logged).
        assert "the broker refused" not in err and "refused 0," in err and "Traceback" not in err, err[-3000:]
        assert dash.messages("edge/dev1/state")


# --- nothing reaches a shell -------------------------------------------------------------------


def _calls(tree: ast.AST) -> Iterator[tuple[str, ast.Call]]:
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            yield ast.unparse(node.func), node


def test_no_shell_and_no_code_from_data_anywhere_in_the_package():
    """Commands and files carry data only: no shell, no eval, no pickle anywhere in `edge/`, and
    every program started gets an argument list (so a config value or a spoken text can only ever
    be one argument, never a command line)."""
    started = []
    for path in sorted((REPO / "edge").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        where = path.relative_to(REPO)
        for name, call in _calls(tree):
            assert name not in {"eval", "exec", "compile", "os.system", "os.popen", "pickle.loads", "pickle.load",
                                "marshal.loads", "__import__", "yaml.load"}, f"{where}:{call.lineno}: {name}"
            assert not any(k.arg == "shell" for k in call.keywords), f"{where}:{call.lineno}: shell= given"
            if name.startswith("subprocess.") or name.startswith("os.exec") or name.startswith("os.spawn"):
                assert name in {"subprocess.Popen", "subprocess.run"}, f"{where}:{call.lineno}: {name}"
                first = call.args[0] if call.args else None
                assert isinstance(first, ast.Name | ast.List), f"{where}:{call.lineno}: {name} without an argument list"
                started.append(f"{where}:{call.lineno}")
    # The detector sees the three places that do start programs (aplay and espeak-ng, and the
    # doctor's `timedatectl show`, a fixed argument list): it is not blind.
    assert sorted(s.split(":")[0] for s in started) == [
        "edge/doctor/system.py", "edge/modes/blindaid/sound.py", "edge/modes/blindaid/sound.py"], started


def test_a_hostile_text_for_the_speech_engine_is_one_argument(tmp_path, monkeypatch):
    """The blind aid speaks texts built from ranges; even a hostile text (or voice from a config
    file) reaches espeak-ng as one argv entry: no shell parses it, a leading dash is no option."""
    from edge.modes.blindaid import sound as audio

    fake = tmp_path / "espeak-ng"
    record = tmp_path / "argv.json"
    fake.write_text(f"#!{sys.executable}\nimport json, sys\n"
                    f"json.dump(sys.argv[1:], open({str(record)!r}, 'w'))\n")
    fake.chmod(0o755)
    pwned = tmp_path / "pwned"
    text = f"--help; touch {pwned} $(touch {pwned}) `touch {pwned}`"
    audio._speak_cached.cache_clear()
    audio._speak_cached(str(fake), text, 22050, 1.0, f"en; touch {pwned}", 160)
    argv = json.loads(record.read_text())
    assert argv[-1] == " " + text and argv[argv.index("-v") + 1] == f"en; touch {pwned}"
    assert not pwned.exists()
