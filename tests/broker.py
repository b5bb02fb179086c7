"""Test helpers for MQTT: a real Mosquitto on a loopback port, and a subscriber that collects.

Tests talk to a real broker because what matters (retained messages, sessions kept across a
broker restart, the Last Will, QoS 1 acknowledgements) is the broker's behaviour, not ours.

The fixtures ``broker`` and ``subscriber`` reach every test module through ``pytest_plugins`` in
tests/conftest.py; the helpers are imported with ``from broker import Mosquitto, publish`` (pytest
puts ``tests/`` on ``sys.path``: the folder is not a package). Without Mosquitto the tests
skip, saying how to install it; with ``CI`` set in the environment they fail instead, so that a CI
machine without a broker cannot pass by skipping.
"""

from __future__ import annotations

import itertools
import os
import random
import shutil
import socket
import subprocess
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

MOSQUITTO_PATHS = ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto")


def find_mosquitto() -> str | None:
    found = shutil.which("mosquitto")
    if found:
        return found
    return next((p for p in MOSQUITTO_PATHS if os.access(p, os.X_OK)), None)


def require_mosquitto() -> str:
    """The broker's path; skip the test without one (fail under CI)."""
    path = find_mosquitto()
    if path is None:
        message = "Mosquitto is not installed (apt-get install mosquitto): the MQTT tests need a real broker"
        if os.environ.get("CI"):
            pytest.fail(message + " and CI is set, so this is a failure, not a skip")
        pytest.skip(message)
    return path


# Ports for the tests' brokers: below Linux's ephemeral range (32768-60999), which the kernel hands
# out for bind(port 0) and for every outgoing connection. A port taken from that range and given to
# Mosquitto a moment later could meanwhile become a client socket's local port (ours, another
# worker's); and the same port again at the broker's restart. Under pytest-xdist each worker
# (PYTEST_XDIST_WORKER=gw0, gw1, ...) has a block of its own, so two workers never pick the same
# port; inside its block a process starts at a random place (another run of the suite on the same
# machine is elsewhere, most likely) and goes round, so a port comes back only after the whole
# block, long after the previous test's clients gave up on it.
PORT_BASE, PORT_BLOCK, PORT_BLOCKS = 20000, 500, 25  # 20000-32499


def _port_block() -> range:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")  # gw<N>; unset without xdist
    index = int(worker[2:]) + 1 if worker.startswith("gw") and worker[2:].isdigit() else 0
    start = PORT_BASE + (index % PORT_BLOCKS) * PORT_BLOCK
    return range(start, start + PORT_BLOCK)


_block = _port_block()
_next_port = itertools.count(random.randrange(PORT_BLOCK))


def free_port() -> int:
    """A loopback port nobody listens on, from this process's block (see PORT_BASE)."""
    for _ in range(PORT_BLOCK):
        port = _block[next(_next_port) % PORT_BLOCK]
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free port in {_block.start}-{_block.stop - 1}")


class Mosquitto:
    """A private Mosquitto: loopback only, on a free port, persistence in a temporary folder so
    that :meth:`restart` keeps retained messages and persistent sessions, as a real one does.

    ``passwords`` ({user: password}) turns anonymous access off; ``acl`` is the text of an ACL file;
    ``tls`` is (ca_file, cert_file, key_file) for a TLS listener on the same port."""

    def __init__(self, *, passwords: dict[str, str] | None = None, acl: str | None = None,
                 tls: tuple[str, str, str] | None = None, extra: str = "") -> None:
        self.executable = require_mosquitto()
        self.host = "127.0.0.1"
        self.port = free_port()
        self.dir = Path(tempfile.mkdtemp(prefix="edge-mosquitto-"))
        self.log_path = self.dir / "mosquitto.log"
        self.conf_path = self.dir / "mosquitto.conf"
        self._proc: subprocess.Popen | None = None
        self._started = False  # once it ran, its port is the broker's address: restart() keeps it
        self._settings = (passwords, acl, tls, extra)
        self._write_conf(*self._settings)
        self._own_conf = self.conf_path

    def _write_conf(self, passwords: dict[str, str] | None, acl: str | None,
                    tls: tuple[str, str, str] | None, extra: str) -> None:
        lines = [
            f"listener {self.port} {self.host}",
            f"allow_anonymous {'false' if passwords else 'true'}",
            "persistence true",
            f"persistence_location {self.dir}/",
            f"log_dest file {self.log_path}",
            "log_type error",
            "log_type warning",
            "log_type notice",
            "log_type information",
            "connection_messages true",
        ]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            # Run as root, Mosquitto 2 drops to the user `mosquitto`, who cannot write our folder.
            lines.append("user root")
        if passwords:
            pw_file = self.dir / "passwords"
            pw_file.write_text("")
            for user, password in passwords.items():
                subprocess.run(["mosquitto_passwd", "-b", str(pw_file), user, password], check=True,
                               capture_output=True)
            lines.append(f"password_file {pw_file}")
        if acl is not None:
            acl_file = self.dir / "acl"
            acl_file.write_text(acl)
            lines.append(f"acl_file {acl_file}")
        if tls is not None:
            ca, cert, key = tls
            lines += [f"cafile {ca}", f"certfile {cert}", f"keyfile {key}"]
        if extra:
            lines.append(extra)
        self.conf_path.write_text("\n".join(lines) + "\n")

    # ---- life cycle ----

    def start(self, timeout_s: float = 5.0) -> Mosquitto:
        """Start and wait until it accepts connections. If its port was taken between
        :func:`free_port` and Mosquitto's bind (another process's socket), the first start moves to
        another free port; a restart, or a start with a config file of the test's own, whose port
        clients already know, tries the same port again until `timeout_s`."""
        if self.running:
            return self
        deadline = time.monotonic() + timeout_s
        attempts = 0
        while not self._start_once(deadline, timeout_s):
            attempts += 1
            if time.monotonic() > deadline or attempts >= 20:
                raise RuntimeError(f"mosquitto could not listen on port {self.port}: address already in use "
                                   f"({attempts} attempt(s))")
            if not self._started and self.conf_path == self._own_conf:
                self.port = free_port()
                self._write_conf(*self._settings)
            else:
                time.sleep(0.1)
        self._started = True
        return self

    def _start_once(self, deadline: float, timeout_s: float) -> bool:
        """One Mosquitto process: True once it accepts connections, False if its port was in use."""
        log_from = self._log_size()
        proc = self._proc = subprocess.Popen([self.executable, "-c", str(self.conf_path)],
                                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        while True:
            if proc.poll() is not None:
                self._proc = None
                err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
                if proc.stderr:
                    proc.stderr.close()
                if "Address already in use" in err + self._log_since(log_from):
                    return False
                raise RuntimeError(f"mosquitto exited with status {proc.returncode}: "
                                   f"{err.strip() or self.log_tail()}")
            try:
                with socket.create_connection((self.host, self.port), timeout=0.2):
                    pass
                # Something accepts: ours once its log says it runs (its listener is open), not
                # another process's listener on the same port while ours is still starting. (A
                # config of the test's own may log elsewhere: then the connection has to do.)
                if " running" in self._log_since(log_from) or (
                        self.conf_path != self._own_conf and not self.log_path.exists()):
                    return True
            except OSError:
                pass
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"mosquitto did not accept connections on port {self.port} "
                                   f"within {timeout_s} s: {self.log_tail()}")
            time.sleep(0.02)

    def _log_size(self) -> int:
        try:
            return self.log_path.stat().st_size
        except OSError:
            return 0

    def _log_since(self, offset: int) -> str:
        try:
            with open(self.log_path, "rb") as fh:
                fh.seek(offset)
                return fh.read().decode(errors="replace")
        except OSError:
            return ""

    def stop(self) -> None:
        """SIGTERM, as systemd does: Mosquitto saves its database on the way out."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc.stderr:
            proc.stderr.close()

    def restart(self) -> Mosquitto:
        """Stop and start again on the same port with the same persistence."""
        self.stop()
        return self.start()

    def close(self) -> None:
        self.stop()
        shutil.rmtree(self.dir, ignore_errors=True)

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def log_tail(self, lines: int = 10) -> str:
        try:
            return " | ".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"

    def __enter__(self) -> Mosquitto:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class Received:
    topic: str
    payload: bytes
    retain: bool
    qos: int
    at: float  # time.monotonic() on arrival

    @property
    def text(self) -> str:
        return self.payload.decode("utf-8")


_ids = itertools.count()


class Subscriber:
    """A paho MQTT 5 client that subscribes (QoS 1) and collects everything it receives.

    Its session is persistent (clean_start False, 5 min expiry), so that across a broker restart
    the broker keeps what was published for it while it was reconnecting."""

    def __init__(self, broker: Mosquitto, topics: tuple[str, ...] = ("#",), persistent: bool = True) -> None:
        self.topics = topics
        self.received: list[Received] = []
        self._cond = threading.Condition()
        self._subscribed = threading.Event()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2,
                                  client_id=f"test-sub-{next(_ids)}-{uuid.uuid4().hex[:8]}",
                                  protocol=mqtt.MQTTv5)
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *a: self._subscribed.set()
        self.client.on_message = self._on_message
        self.client.reconnect_delay_set(0.05, 0.3)
        props = Properties(PacketTypes.CONNECT)
        props.SessionExpiryInterval = 300 if persistent else 0
        self.client.connect_async(broker.host, broker.port, keepalive=10, clean_start=not persistent,
                                  properties=props)
        self.client.loop_start()
        if not self._subscribed.wait(5):
            raise RuntimeError(f"test subscriber could not subscribe on port {broker.port}")

    def _on_connect(self, client, userdata, flags, reason, properties) -> None:
        # A resumed session still has its subscriptions; subscribing again would make the broker
        # send the retained messages again, which tests of "sent again after a reconnect" must
        # not mistake for the device's doing.
        if not reason.is_failure and not flags.session_present:
            client.subscribe([(t, 1) for t in self.topics])

    def _on_message(self, client, userdata, msg) -> None:
        item = Received(msg.topic, bytes(msg.payload), bool(msg.retain), msg.qos, time.monotonic())
        with self._cond:
            self.received.append(item)
            self._cond.notify_all()

    def mark(self) -> int:
        """An index into what was received: pass it as ``since`` to look only at what follows."""
        with self._cond:
            return len(self.received)

    def messages(self, topic: str | None = None, since: int = 0) -> list[Received]:
        with self._cond:
            return [m for m in self.received[since:] if topic is None or m.topic == topic]

    def wait_for(self, topic: str, predicate: Callable[[Received], bool] | None = None,
                 timeout: float = 5.0, since: int = 0) -> Received:
        """The first message on `topic` (received at index >= `since`) that satisfies `predicate`;
        AssertionError after `timeout` seconds."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for m in self.received[since:]:
                    if m.topic == topic and (predicate is None or predicate(m)):
                        return m
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    seen = [m.topic for m in self.received[since:]][-10:]
                    raise AssertionError(f"no matching message on {topic} within {timeout} s "
                                         f"(last topics seen: {seen})")
                self._cond.wait(remaining)

    def wait_count(self, topic: str, count: int, timeout: float = 10.0, since: int = 0) -> list[Received]:
        """Wait until at least `count` messages arrived on `topic`; return them."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                found = [m for m in self.received[since:] if m.topic == topic]
                if len(found) >= count:
                    return found
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise AssertionError(f"{len(found)} of {count} messages on {topic} within {timeout} s")
                self._cond.wait(remaining)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def publish(broker: Mosquitto, topic: str, payload: bytes | str, *, qos: int = 1, retain: bool = False) -> None:
    """Publish one message from a throw-away client and wait for the broker's acknowledgement."""
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"test-pub-{uuid.uuid4().hex[:8]}",
                         protocol=mqtt.MQTTv5)
    client.connect(broker.host, broker.port, keepalive=10)
    client.loop_start()
    try:
        info = client.publish(topic, payload, qos=qos, retain=retain)
        info.wait_for_publish(timeout=5)
        if not info.is_published():
            raise AssertionError(f"publishing to {topic} was not acknowledged within 5 s")
    finally:
        client.disconnect()
        client.loop_stop()


@pytest.fixture
def broker() -> Iterator[Mosquitto]:
    """A fresh, running Mosquitto for one test."""
    with Mosquitto() as b:
        yield b


@pytest.fixture
def subscriber(broker: Mosquitto) -> Iterator[Subscriber]:
    """A subscriber to everything on the test's broker."""
    sub = Subscriber(broker)
    yield sub
    sub.close()
