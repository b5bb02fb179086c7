"""The broker link (../shared/spec/mqtt.md) on paho-mqtt 2.x, MQTT 5.

Who runs what:

- paho's network thread (``loop_start``) moves bytes and calls our ``_on_*`` callbacks. Those only
  publish small things (status, state, discovery, command results) and hand incoming commands to a
  queue; they never touch the disk.
- our sender thread owns the outbox's sending side: it hands queued events (sweeps, alerts) to paho
  oldest first, at most :data:`WINDOW` unacknowledged at a time, and acknowledges them in the outbox
  (``Outbox.ack``) as PUBACKs come back. It exists so that the caller never waits for the broker and
  paho's thread never waits for SQLite.
- the caller (the service) publishes from its own thread and takes commands with :meth:`commands`.

Snapshots (``state`` and the topics beyond the contract that Home Assistant's entities follow:
``distance``, ``guard``, ``obstacle``, ``map``, ``backlog``, ``last_result``) are retained, QoS 1,
and only their latest value matters: each topic goes out at most once every
:data:`SNAPSHOT_INTERVAL_S` (a newer value waiting meanwhile replaces the one before and goes out
when the interval is up, sent by the sender thread), and every connect sends each one's latest.

Delivery of events is at least once and in order. The outbox is the one record of what is still
owed: at every (re)connect paho's own copies of unacknowledged messages are dropped and sending
starts over from the oldest unacknowledged message in the outbox. (Letting paho re-send its copies
after our reconnect handler had published newer messages would deliver an old retained sweep or
state last, on top of the new one.) Consumers de-duplicate, as the spec says.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt import __version__ as paho_version
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from edge.commands import label, request_id_of
from edge.config import MqttConfig
from edge.discovery import discovery_payloads
from edge.errors import ConfigError
from edge.fsutil import read_small
from edge.outbox import Outbox
from edge.topics import MAX_TOPIC_BYTES, Topics, answerable, check_device_id, encode

log = logging.getLogger(__name__)
_paho_log = logging.getLogger(f"{__name__}.paho")
# paho 2.2's network loop runs once more after a deliberate disconnect(), or a stop while still
# connecting, and logs it as an error. What the user needs of it, we log: a broker that cannot be
# reached (_on_connect_fail) or a connection lost (_on_disconnect).
_paho_log.addFilter(lambda r: not r.getMessage().startswith("Client is not connected"))

WINDOW = 32  # outbox messages handed to paho and not yet acknowledged, at most
# QoS 1 messages paho keeps in flight (beyond it paho queues, in order). paho cannot change it once
# connected, so it cannot follow the broker's Receive Maximum: 20 is Mosquitto's default and paho's.
PAHO_INFLIGHT = 20
EVENT_KINDS = ("sweep", "alert")  # QoS 1 through the outbox; sweep retained
LIVE_KINDS = ("range", "cue")  # QoS 0, dropped while disconnected
# Retained QoS 1 snapshots, latest value only, at most one message every SNAPSHOT_INTERVAL_S per
# topic. `state` is the contract's; the others are ours, beyond it (README: "Home Assistant").
SNAPSHOT_KINDS = ("state", "distance", "guard", "obstacle", "map", "backlog", "last_result")
# So that no Home Assistant entity changes more than twice in any second, with room for jitter.
SNAPSHOT_INTERVAL_S = 0.6
# `last_result`'s entity takes its attributes from the same message as its state, and Home Assistant
# writes them as two changes: this one goes out half as often.
LAST_RESULT_INTERVAL_S = 2 * SNAPSHOT_INTERVAL_S
COMMAND_QUEUE_SIZE = 256  # commands waiting for the service; more are refused
_STOP_RESERVE_S = 1.0  # of stop()'s timeout, kept for `offline` after draining the outbox


def set_credentials(client: paho.Client, config: MqttConfig, password: str | None) -> None:
    """User name, password and TLS from ``[mqtt]``, for the device's link and for the tools that
    talk to the broker as an operator (``edge range``, ``edge calibrate --device``)."""
    if config.username or password:
        client.username_pw_set(config.username or None, password)
    if not config.tls.enabled:
        return
    tls = config.tls
    for key in ("ca_file", "cert_file", "key_file"):
        name = getattr(tls, key)
        if name and not Path(name).expanduser().is_file():
            raise ConfigError(f"mqtt.tls.{key}: no such file: {name}")
    try:
        client.tls_set(ca_certs=tls.ca_file or None, certfile=tls.cert_file or None, keyfile=tls.key_file or None)
    except (OSError, ValueError) as exc:  # ssl.SSLError is an OSError
        raise ConfigError(f"mqtt.tls: cannot use the certificates: {exc}") from None
    client.tls_insecure_set(tls.insecure)


def read_password(config: MqttConfig) -> str | None:
    """The broker password: ``password``, or the first line of ``password_file`` (read now, so
    that the secret never sits in the config file)."""
    if not config.password_file:
        return config.password or None
    path = Path(config.password_file).expanduser()
    try:
        text = read_small(path, 4096).decode("utf-8")  # never a FIFO or /dev/zero: it must not hang
    except (OSError, UnicodeDecodeError) as exc:
        why = getattr(exc, "strerror", None) or str(exc)
        raise ConfigError(f"mqtt.password_file: cannot read {path}: {why}") from None
    password = text.splitlines()[0] if text else ""
    if not password:
        raise ConfigError(f"mqtt.password_file: {path} is empty")
    return password


def _guarded(callback: Callable[..., None]) -> Callable[..., None]:
    """A paho callback that logs its exceptions instead of raising them into paho's thread,
    which would end the network loop and with it every reconnect."""

    def run(*args: Any) -> None:
        try:
            callback(*args)
        except Exception:  # noqa: BLE001
            log.exception("MQTT: %s failed", callback.__name__)

    run.__name__ = callback.__name__
    return run


# ---- the link ----


@dataclass
class _Snapshot:
    """A snapshot topic's latest value and when it last went out."""

    data: bytes
    sent_at: float = -math.inf  # time.monotonic() of the last send
    due: float | None = None  # when the waiting value goes out; None: nothing waits


class MqttLink:
    """The device's connection to its broker; see the module notes for threads and delivery."""

    def __init__(self, config: MqttConfig, device_id: str, outbox: Outbox, *, version: str,
                 on_command: Callable[[str, bytes], None] | None = None) -> None:
        self.config = config
        self.device_id = check_device_id(device_id)
        self.topics = Topics(config.prefix, device_id)
        self.version = version
        self.client_id = config.client_id or f"{config.prefix}-{device_id}"
        self._outbox = outbox
        self._on_command = on_command
        self._commands: queue.Queue[tuple[str, bytes]] = queue.Queue(COMMAND_QUEUE_SIZE)
        self._client: paho.Client | None = None
        self._sender: threading.Thread | None = None
        # _send_lock: held around every hand-over to paho that must not interleave with a
        # reconnect (events, state) and by _on_connect. Lock order: _send_lock, then paho's locks.
        self._send_lock = threading.Lock()
        # _cond guards what the sender thread waits on; never held while calling paho.
        self._cond = threading.Condition()
        self._connected = False
        self._generation = 0  # +1 per successful connect; outbox bookkeeping is per connection
        self._acks: list[tuple[int, int]] = []  # (generation, mid) of PUBACKs not yet processed
        self._wake = False
        self._closing = False  # stop() has begun: nothing new goes out
        self._unreachable = False  # a failed connect was logged: quiet until connected again
        self._finished = False  # stop() is done with paho: the sender thread may end
        self._snapshots: dict[str, _Snapshot] = {}  # topic → snapshot; under _send_lock
        self._snapshot_due = math.inf  # the earliest `due` of a waiting snapshot; under _cond
        self._backlog: int | None = None  # the outbox's size as last published; sender thread only
        self._inflight: dict[int, int] = {}  # mid → outbox seq; sender thread only
        self._stats = {"sent": 0, "acked": 0, "refused": 0, "dropped_live": 0, "live_sent": 0,
                       "connects": 0, "commands_refused": 0, "commands_dropped": 0}

    # ---- life cycle ----

    def start(self) -> None:
        """Connect in the background; a broker that is down is retried with back-off."""
        if self._client is not None:
            raise RuntimeError("MqttLink.start() called twice")
        cfg = self.config
        password = read_password(cfg)
        client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=self.client_id, protocol=paho.MQTTv5)
        client.enable_logger(_paho_log)
        if not hasattr(client, "drop_out_messages"):
            log.warning("MQTT: paho-mqtt %s has no drop_out_messages() (2.2 and later have): after a "
                        "reconnect an old retained sweep or state may be delivered last", paho_version)
        client.will_set(self.topics.status, "offline", qos=1, retain=True)
        set_credentials(client, cfg, password)
        client.reconnect_delay_set(cfg.reconnect_min_s, cfg.reconnect_max_s)  # type: ignore[arg-type]
        client.max_inflight_messages_set(PAHO_INFLIGHT)
        client.on_connect = _guarded(self._on_connect)
        client.on_disconnect = _guarded(self._on_disconnect)
        client.on_connect_fail = _guarded(self._on_connect_fail)
        client.on_publish = _guarded(self._on_publish)
        client.on_message = _guarded(self._on_message)
        props = Properties(PacketTypes.CONNECT)
        props.SessionExpiryInterval = cfg.session_expiry_s
        # The broker must not send us more than a few times the largest command we take: bigger
        # ones are dropped by the broker (unseen), smaller oversized ones get an error result.
        props.MaximumPacketSize = cfg.max_payload_bytes * 4 + 4096
        client.connect_async(cfg.host, cfg.port, keepalive=cfg.keepalive_s, clean_start=False, properties=props)
        self._client = client
        self._sender = threading.Thread(target=self._send_loop, name="mqtt-outbox", daemon=True)
        self._sender.start()
        client.loop_start()
        log.info("MQTT: connecting to %s:%d as %s", cfg.host, cfg.port, self.client_id)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Send what can be sent of the outbox within `timeout_s` (the rest stays on disk for the
        next start), publish ``offline`` and wait for it, then disconnect."""
        client = self._client
        if client is None or self._closing:
            return
        deadline = time.monotonic() + timeout_s
        drain_until = deadline - min(_STOP_RESERVE_S, timeout_s / 2)
        while self._connected and len(self._outbox) > 0 and time.monotonic() < drain_until:
            time.sleep(0.01)
        left = len(self._outbox)
        if left:
            log.info("MQTT: %d queued message(s) stay in the outbox for the next start", left)
        self._flush_snapshots(force=True)  # the last state, before `offline`
        with self._send_lock:
            self._closing = True  # no more events from the sender, nothing from callbacks
            info = client.publish(self.topics.status, "offline", qos=1, retain=True) if self._connected else None
        if info is not None and info.rc == paho.MQTT_ERR_SUCCESS:
            try:
                info.wait_for_publish(max(deadline - time.monotonic(), 0.1))
            except (RuntimeError, ValueError) as exc:  # the connection went away meanwhile
                log.info("MQTT: offline not confirmed: %s", exc)
        client.disconnect()
        client.loop_stop()
        with self._cond:
            self._connected = False
            self._finished = True
            self._cond.notify_all()
        if self._sender is not None:
            self._sender.join(timeout=2)
        log.info("MQTT: disconnected (%s)", self._stats_text())

    @property
    def connected(self) -> bool:
        return self._connected

    def stats(self) -> dict[str, int]:
        """Counters: sent (event hand-overs, re-sends included), acked, refused (PUBACK with an
        error), dropped_live, live_sent, connects, commands_refused, commands_dropped (no result
        topic possible), and pending (in the outbox)."""
        with self._cond:
            out = dict(self._stats)
        try:
            out["pending"] = len(self._outbox)
        except Exception:  # noqa: BLE001 - a closed outbox: stats must still answer
            out["pending"] = -1
        return out

    def _stats_text(self) -> str:
        return ", ".join(f"{k} {v}" for k, v in self.stats().items())

    # ---- publishing ----

    def publish_event(self, kind: str, payload: dict[str, Any]) -> int:
        """A sweep (retained) or an alert: on disk first, then sent when the broker can take it.
        Returns the outbox seq; never waits for the broker."""
        if kind not in EVENT_KINDS:
            raise ValueError(f"publish_event: kind must be one of {', '.join(EVENT_KINDS)}, got {kind!r}")
        seq = self._outbox.put(self.topics.of(kind), encode(payload), qos=1, retain=kind == "sweep")
        self._poke()
        return seq

    def publish_live(self, kind: str, payload: dict[str, Any]) -> bool:
        """A range or a cue, QoS 0: sent now if connected, else dropped (and counted)."""
        if kind not in LIVE_KINDS:
            raise ValueError(f"publish_live: kind must be one of {', '.join(LIVE_KINDS)}, got {kind!r}")
        client = self._client
        ok = False
        if client is not None and self._connected and not self._closing:
            ok = client.publish(self.topics.of(kind), encode(payload), qos=0).rc == paho.MQTT_ERR_SUCCESS
        with self._cond:
            self._stats["live_sent" if ok else "dropped_live"] += 1
        return ok

    def publish_state(self, payload: dict[str, Any], at_once: bool = False) -> None:
        """The state snapshot: retained, QoS 1, remembered and sent again at every connect; at
        most one every :data:`SNAPSHOT_INTERVAL_S` (the latest wins, none is left behind), but
        `at_once` (a part's health changed) now: paced, a fault that ended within the interval
        was replaced by the recovery before it went out, and nobody saw it (a camera that
        stalled for 3 s of the simulator's time, which passes in a fraction of a second)."""
        self.publish_snapshot("state", payload, at_once=at_once)

    def publish_snapshot(self, kind: str, payload: dict[str, Any] | bytes,
                         min_interval_s: float = SNAPSHOT_INTERVAL_S, at_once: bool = False) -> None:
        """A snapshot (see the module notes): a JSON object, or bytes sent as they are (the map's
        PNG). Sent now if the topic's last message is at least `min_interval_s` old (never less
        than :data:`SNAPSHOT_INTERVAL_S`) or `at_once`, else when that time is up, unless a newer
        value replaces it meanwhile (a later call with a shorter interval brings the time
        forward). Never waits for the broker."""
        if kind not in SNAPSHOT_KINDS:
            raise ValueError(f"publish_snapshot: kind must be one of {', '.join(SNAPSHOT_KINDS)}, got {kind!r}")
        data = bytes(payload) if isinstance(payload, (bytes, bytearray)) else encode(payload)
        topic = self.topics.of(kind)
        interval = max(float(min_interval_s), SNAPSHOT_INTERVAL_S)
        with self._send_lock:  # so that a reconnect sends this one, not the one before
            snap = self._snapshots.get(topic)
            if snap is None:
                snap = self._snapshots[topic] = _Snapshot(data)
            snap.data = data
            now = time.monotonic()
            due = snap.sent_at + interval
            if snap.due is not None:
                due = min(due, snap.due)
            if at_once or now >= due:
                self._send_snapshot(topic, snap, now)
                return
            snap.due = due
            with self._cond:
                if due < self._snapshot_due:
                    self._snapshot_due = due
                    self._cond.notify_all()

    def _send_snapshot(self, topic: str, snap: _Snapshot, now: float) -> None:
        """Hand one snapshot to paho (with _send_lock held). Disconnected, it waits for the
        connect, which sends every snapshot."""
        snap.due = None
        if self._client is not None and self._connected and not self._closing:
            self._client.publish(topic, snap.data, qos=1, retain=True)
            snap.sent_at = now

    def _flush_snapshots(self, force: bool = False) -> None:
        """Send the snapshots whose time has come (every waiting one if `force`)."""
        with self._send_lock:
            now = time.monotonic()
            later = math.inf
            for topic, snap in self._snapshots.items():
                if snap.due is None:
                    continue
                if force or now >= snap.due:
                    self._send_snapshot(topic, snap, now)
                else:
                    later = min(later, snap.due)
            with self._cond:
                self._snapshot_due = later

    def publish_result(self, name: str, ok: bool, error: str | None = None, request_id: str | None = None,
                       extra: dict[str, Any] | None = None) -> None:
        """A command's result on ``cmd/<name>/result``, QoS 1 (`extra`: more keys, e.g. what a
        calibration found). Not queued on disk: one given while disconnected is kept by paho and
        sent after the reconnect.

        Never raises: a result that cannot be sent (a name that is no topic level, a result topic
        over MQTT's length limit) is dropped with a log line, since the name came from outside."""
        if not answerable(self.topics, name):
            log.warning("MQTT: no result for cmd/%s: it cannot be answered on MQTT (its result topic "
                        "would be longer than %d bytes, or the name is no topic level); dropped",
                        label(name), MAX_TOPIC_BYTES)
            return
        body: dict[str, Any] = {"ok": bool(ok), **(extra or {})}
        if error is not None:
            body["error"] = error
        if request_id is not None:
            body["request_id"] = request_id
        client = self._client
        if client is not None and not self._closing:
            try:
                client.publish(self.topics.result(name), encode(body), qos=1)
            except (ValueError, TypeError) as exc:  # paho's checks of a topic or payload
                log.warning("MQTT: no result for cmd/%s: %s", label(name), exc)
                return
            # The last command's result, for Home Assistant: the name as logs show it (a name
            # can be 65 kB long), no `extra` (a calibration's summary is the result's business).
            last = {"command": label(name), "ok": bool(ok),
                    **({"error": error} if error is not None else {}),
                    **({"request_id": request_id} if request_id is not None else {})}
            self.publish_snapshot("last_result", last, LAST_RESULT_INTERVAL_S)

    def commands(self) -> list[tuple[str, bytes]]:
        """The commands received since the last call, oldest first: (name, raw payload)."""
        out = []
        while True:
            try:
                out.append(self._commands.get_nowait())
            except queue.Empty:
                return out

    def publish_discovery(self) -> None:
        if not self.config.discovery or self._client is None:
            return
        for topic, body in discovery_payloads(self.config, self.device_id, self.version).items():
            data = json.dumps(body, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
            self._client.publish(topic, data, qos=1, retain=True)

    # ---- paho callbacks (network thread) ----

    def _on_connect(self, client: paho.Client, userdata: Any, flags: Any, reason: Any, properties: Any) -> None:
        if reason.is_failure:
            log.warning("MQTT: %s:%d refused the connection: %s", self.config.host, self.config.port, reason)
            return
        with self._send_lock:
            if self._closing:
                return
            # What paho kept from the last connection: events are re-sent from the outbox and
            # snapshots (status, state, discovery) afresh below; command results are re-published.
            leftovers = client.drop_out_messages() if hasattr(client, "drop_out_messages") else []
            receive_max = getattr(properties, "ReceiveMaximum", None)
            if receive_max is not None and receive_max < PAHO_INFLIGHT:
                log.warning("MQTT: the broker takes %d unacknowledged messages, we may send %d: it may "
                            "disconnect us under load", receive_max, PAHO_INFLIGHT)
            # Subscribed before "online" goes out: the broker takes a client's packets in order, so
            # whoever sees "online" and sends a command at once finds us listening.
            # retainAsPublished: without it the broker clears the retain flag of a retained command
            # delivered live, or kept for us while we were offline, and it would be carried out.
            # Retained commands only when the subscription is new: they are refused anyway, once
            # is enough (the session keeps the subscription across reconnects).
            subscriptions = [(self.topics.cmd_filter,
                              SubscribeOptions(qos=1, retainAsPublished=True,
                                               retainHandling=SubscribeOptions.RETAIN_SEND_IF_NEW_SUB))]
            if self.config.discovery:
                subscriptions.append((f"{self.config.discovery_prefix}/status", SubscribeOptions(qos=1)))
            client.subscribe(subscriptions)
            client.publish(self.topics.status, "online", qos=1, retain=True)
            now = time.monotonic()
            for topic, snap in self._snapshots.items():  # each one's latest, waiting or not
                client.publish(topic, snap.data, qos=1, retain=True)
                snap.sent_at, snap.due = now, None
            for m in leftovers:
                if m.topic.endswith("/result"):
                    client.publish(m.topic, m.payload, qos=m.qos, retain=m.retain)
            self.publish_discovery()
            with self._cond:
                self._connected = True
                self._generation += 1
                self._stats["connects"] += 1
                self._snapshot_due = math.inf
                self._cond.notify_all()
        self._unreachable = False
        log.info("MQTT: connected to %s:%d (session %s)", self.config.host, self.config.port,
                 "resumed" if flags.session_present else "new")

    def _on_connect_fail(self, client: paho.Client, userdata: Any) -> None:
        # Once an outage, not at every retry: the journal of a device without its broker for a
        # week must stay readable.
        if self._closing or self._unreachable:
            return
        self._unreachable = True
        log.warning("MQTT: cannot reach %s:%d; retrying (back-off %g–%g s); events wait in the outbox",
                    self.config.host, self.config.port, self.config.reconnect_min_s, self.config.reconnect_max_s)

    def _on_disconnect(self, client: paho.Client, userdata: Any, flags: Any, reason: Any, properties: Any) -> None:
        with self._cond:
            was = self._connected
            self._connected = False
        if was and not self._closing:
            log.warning("MQTT: connection to %s:%d lost (%s); retrying", self.config.host, self.config.port, reason)

    def _on_publish(self, client: paho.Client, userdata: Any, mid: int, reason: Any, properties: Any) -> None:
        # Called with paho's message lock held: only note it, the sender thread does the rest.
        with self._cond:
            self._acks.append((self._generation, mid))
            if reason is not None and getattr(reason, "is_failure", False):
                self._stats["refused"] += 1
                log.error("MQTT: the broker refused message %d: %s", mid, reason)
            self._cond.notify_all()

    def _on_message(self, client: paho.Client, userdata: Any, msg: paho.MQTTMessage) -> None:
        try:
            topic = msg.topic
        except UnicodeDecodeError:
            return
        if topic == f"{self.config.discovery_prefix}/status":
            # Home Assistant (re)started: it forgets entities unless discovery is sent again. A
            # retained `online` only comes with our own subscription, after we sent discovery.
            if msg.payload == b"online" and not msg.retain:
                log.info("MQTT: Home Assistant is online: discovery sent again")
                self.publish_discovery()
            return
        if not topic.startswith(self.topics.cmd_prefix):
            return
        name = topic[len(self.topics.cmd_prefix):]
        if not name or "/" in name:
            return
        if not answerable(self.topics, name):
            # Nothing can be carried out that nobody can be told about: a name this long is no
            # command anyway, and its result topic would be beyond MQTT's limit.
            log.warning("MQTT: a command on %s%s cannot be answered (its result topic would be longer "
                        "than %d bytes): dropped", self.topics.cmd_prefix, label(name), MAX_TOPIC_BYTES)
            with self._cond:
                self._stats["commands_dropped"] += 1
            return
        self._command(name, msg)

    def _command(self, name: str, msg: paho.MQTTMessage) -> None:
        size, limit = len(msg.payload), self.config.max_payload_bytes
        if size > limit:
            self._refuse(name, f"payload of {size} bytes exceeds mqtt.max_payload_bytes = {limit}")
            return
        payload = bytes(msg.payload)
        if not payload:
            # An empty message is how a retained command is cleared (MQTT deletes a retained
            # message so); it is no command, and gets no answer.
            log.info("MQTT: cmd/%s: empty message ignored (it clears a retained command; a command's "
                     "payload is at least {})", label(name))
            return
        if msg.retain:
            self._refuse(name, "retained command ignored: commands must not be retained (a stale one would "
                         "fire at every start); clear it by publishing an empty retained message to its topic",
                         request_id_of(payload))
            return
        if self._on_command is not None:
            try:
                self._on_command(name, payload)
            except Exception:  # noqa: BLE001 - a failing handler must not take the link down
                log.exception("MQTT: command handler failed for cmd/%s", label(name))
            return
        try:
            self._commands.put_nowait((name, payload))
        except queue.Full:
            self._refuse(name, f"{COMMAND_QUEUE_SIZE} commands are waiting: the device is busy, try again later",
                         request_id_of(payload))

    def _refuse(self, name: str, error: str, request_id: str | None = None) -> None:
        log.warning("MQTT: cmd/%s refused: %s", label(name), error)
        with self._cond:
            self._stats["commands_refused"] += 1
        self.publish_result(name, False, error, request_id)

    # ---- the sender thread ----

    def _poke(self) -> None:
        with self._cond:
            self._wake = True
            self._cond.notify_all()

    def _send_loop(self) -> None:
        generation = 0  # the connection our _inflight and cursor belong to
        cursor = 0  # the last seq handed to paho on this connection
        while True:
            with self._cond:
                while not (self._finished or self._acks or self._wake or self._generation != generation
                           or time.monotonic() >= self._snapshot_due):
                    wait = self._snapshot_due - time.monotonic()
                    self._cond.wait(wait if math.isfinite(wait) else None)
                acks, self._acks, self._wake = self._acks, [], False
                current, finished = self._generation, self._finished
                snapshots_due = time.monotonic() >= self._snapshot_due
            try:
                if snapshots_due and not finished:
                    self._flush_snapshots()
                for ack_generation, mid in acks:
                    seq = self._inflight.pop(mid, None) if ack_generation == generation else None
                    if seq is not None:
                        self._outbox.ack(seq)
                        with self._cond:
                            self._stats["acked"] += 1
                if finished:  # acks that came in while stopping are in the outbox now
                    return
                if current != generation:  # a new connection: start over from the oldest unacked
                    generation, cursor = current, 0
                    self._inflight.clear()
                cursor = self._drain(generation, cursor)
                self._publish_backlog()
            except Exception:  # noqa: BLE001 - e.g. a StorageError: keep trying, loudly
                log.exception("MQTT: sending queued messages failed; retrying in 1 s")
                time.sleep(1.0)
                self._poke()

    def _publish_backlog(self) -> None:
        """The outbox's size on ``backlog`` when it changed (sender thread)."""
        if not self._connected:
            return
        pending = len(self._outbox)
        if pending != self._backlog:
            self._backlog = pending
            self.publish_snapshot("backlog", {"messages": pending})

    def _drain(self, generation: int, cursor: int) -> int:
        """Hand the next queued messages to paho, oldest first, up to the window. Returns the new
        cursor."""
        client = self._client
        assert client is not None
        while len(self._inflight) < WINDOW:
            batch = self._outbox.pending(limit=WINDOW - len(self._inflight), after=cursor)
            if not batch:
                break
            for m in batch:
                with self._send_lock:
                    # Sent on the connection whose bookkeeping this is, or not at all.
                    if self._closing or not self._connected or self._generation != generation:
                        return cursor
                    info = client.publish(m.topic, m.payload, qos=m.qos, retain=m.retain)
                if info.rc not in (paho.MQTT_ERR_SUCCESS, paho.MQTT_ERR_NO_CONN):
                    log.error("MQTT: paho refused queued message %d: %s", m.seq, paho.error_string(info.rc))
                    return cursor
                self._inflight[info.mid] = m.seq
                cursor = m.seq
                with self._cond:
                    self._stats["sent"] += 1
        return cursor
