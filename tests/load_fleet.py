#!/usr/bin/env python3
"""Fleet load test: N simulated devices, each a real `edge.mqtt.MqttLink` with its own on-disk
`Outbox`, publishing at a device's rates to one broker, and a group of consumers on MQTT 5 shared
subscriptions measuring what arrives.

    python tests/load_fleet.py --devices 50 --seconds 60            # starts its own Mosquitto
    python tests/load_fleet.py --devices 200 --seconds 120 --port 1883 [--host H]   # an existing broker

Each device (`fleet-000`, `fleet-001`, …) sends, with a random phase per device:
  - a `range` (QoS 0) every 0.1 s, a zone result of ../shared/spec/geometry.md;
  - an `alert` (QoS 1, `publish_event`: on disk first) every 2 s;
  - a `sweep` (QoS 1, retained, 64 zones, about 11 kB) every 10 s.
Alerts and sweeps carry a per-device sequence number (`seq`), the send time (`sent_ns`,
`time.time_ns()` taken just before `publish_event`, so the outbox's fsync is part of the latency)
and a run id (`run`), so that results of another run on a shared broker are ignored.

The consumers (`--consumers`, default 3, clean sessions) share `$share/consumers/edge/+/alert`,
`…/sweep` (QoS 1) and `…/range` (QoS 0). After the publishing time the devices' outboxes drain
for up to `--drain` seconds; then lost QoS 1 messages (sequence numbers sent but never received)
and duplicates are counted. Exit status 0 if nothing was lost and the alerts' p99 end-to-end latency
is under 100 ms, else 1.

One scheduler thread publishes for all devices (each link has paho's network thread and its outbox
sender thread). Not collected by pytest (no test_ prefix); `run()` is for a quick test.
"""

from __future__ import annotations

import argparse
import heapq
import json
import logging
import os
import random
import shutil
import sys
import tempfile
import threading
import time
import uuid
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
for _p in (str(HERE.parent), str(HERE)):  # edge, and broker.py
    if _p not in sys.path:
        sys.path.insert(0, _p)

import paho.mqtt.client as mqtt  # noqa: E402
from paho.mqtt.packettypes import PacketTypes  # noqa: E402
from paho.mqtt.properties import Properties  # noqa: E402

from edge.config import MqttConfig  # noqa: E402
from edge.mqtt import MqttLink  # noqa: E402
from edge.outbox import Outbox  # noqa: E402

log = logging.getLogger("load_fleet")

RANGE_EVERY_S = 0.1
ALERT_EVERY_S = 2.0
SWEEP_EVERY_S = 10.0
PREFIX = "edge"
GROUP = "consumers"
P99_LIMIT_MS = 100.0
LAG_WARN_MS = 100.0  # scheduler lag beyond which the generator, not the broker, sets the pace
KINDS = ("range", "alert", "sweep")


# ---- payloads ----


def _zone(index: int, pan: float, r: float) -> dict[str, Any]:
    return {"index": index, "pan_deg": round(pan, 3), "tilt_deg": 0.0, "status": "ok", "range_m": round(r, 4),
            "sigma_m": 0.0042, "point_m": [0.035, 0.0, round(r, 4)],
            "point_base_m": [round(r * 0.7, 4), round(r * 0.7, 4), 0.1], "normal": [0.01, -0.02, -0.9997]}


SWEEP_ZONES = [_zone(i, i * 5.625 - 180.0 if i * 5.625 > 180 else i * 5.625, 1.0 + (i % 7) * 0.3)
               for i in range(64)]


class Device:
    """One simulated device: a real MqttLink with its own outbox, and its counters."""

    def __init__(self, index: int, folder: Path, host: str, port: int, run_id: str) -> None:
        self.id = f"fleet-{index:03d}"
        self.run_id = run_id
        self.outbox = Outbox(folder / f"{self.id}.sqlite3")
        config = MqttConfig(host=host, port=port, keepalive_s=30, session_expiry_s=300,
                            reconnect_min_s=0.2, reconnect_max_s=2.0)
        self.link = MqttLink(config, self.id, self.outbox, version="load-test")
        self.sent: Counter[str] = Counter()  # per kind
        self.frame = 0

    def publish(self, kind: str) -> None:
        if kind == "range":
            self.frame += 1
            r = 1.3 + 0.01 * ((self.frame * 7) % 5)
            self.link.publish_live("range", {
                **_zone(-1, -90.0, r), "filtered_m": 1.32, "filtered_sigma_m": 0.003,
                "frame": self.frame, "rate_hz": 10.0, "seq": self.sent["range"] + 1, "run": self.run_id})
        elif kind == "alert":
            seq = self.sent["alert"] + 1
            event = ("intrusion", "moved", "cleared")[(seq - 1) % 3]
            self.link.publish_event("alert", {
                "event": event, "id": f"{self.id}-t{(seq - 1) // 3}", "zones": [12, 13], "bearing_deg": 70.3,
                "range_m": 1.8, "baseline_m": 3.9, "velocity_mps": [0.2, -0.1] if event == "moved" else None,
                "sweep": self.sent["sweep"], "seq": seq, "run": self.run_id, "sent_ns": time.time_ns()})
        else:
            seq = self.sent["sweep"] + 1
            self.link.publish_event("sweep", {"sweep": seq, "duration_s": 9.6, "zones": SWEEP_ZONES,
                                              "seq": seq, "run": self.run_id, "sent_ns": time.time_ns()})
        self.sent[kind] += 1


# ---- consumers ----


class Consumer:
    """One member of the shared-subscription group; records (kind, device, seq, sent_ns, recv_ns).
    Its records are only appended by its own paho thread and read after it has stopped."""

    def __init__(self, index: int, host: str, port: int, run_id: str, group: str = GROUP) -> None:
        self.run_id = run_id
        self.group = group
        self.records: list[tuple[str, str, int, int, int]] = []
        self.foreign = 0  # messages of another run (a shared broker)
        self.subscribed = threading.Event()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5,
                                  client_id=f"fleet-consumer-{index}-{run_id}")
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *a: self.subscribed.set()
        self.client.on_message = self._on_message
        props = Properties(PacketTypes.CONNECT)
        props.SessionExpiryInterval = 0  # a clean session: the group, not the member, holds the stream
        self.client.connect_async(host, port, keepalive=30, clean_start=True, properties=props)
        self.client.loop_start()

    def _on_connect(self, client, userdata, flags, reason, properties) -> None:
        if reason.is_failure:
            log.error("consumer: connection refused: %s", reason)
            return
        share = f"$share/{self.group}/{PREFIX}/+"
        client.subscribe([(f"{share}/alert", 1), (f"{share}/sweep", 1), (f"{share}/range", 0)])

    def _on_message(self, client, userdata, msg) -> None:
        now = time.time_ns()
        parts = msg.topic.split("/")
        if len(parts) != 3:
            return
        try:
            body = json.loads(msg.payload)
        except ValueError:
            return
        if body.get("run") != self.run_id:
            self.foreign += 1
            return
        self.records.append((parts[2], parts[1], int(body.get("seq", 0)), int(body.get("sent_ns", 0)), now))

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


# ---- the run ----


def _percentile(sorted_values: list[float], q: float) -> float:
    if not sorted_values:
        return float("nan")
    k = min(len(sorted_values) - 1, max(0, round(q / 100 * (len(sorted_values) - 1))))
    return sorted_values[k]


def _cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of a process (Linux), None if unknown."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def _broker_pid(conf_path: Path) -> int | None:
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if str(conf_path).encode() in (entry / "cmdline").read_bytes():
                    return int(entry.name)
            except OSError:
                continue
    return None


def run(devices: int, seconds: float, port: int | None = None, *, host: str = "127.0.0.1",
        drain: float = 5.0, consumers: int = 3, first: int = 0, group: str = GROUP,
        nodelay: bool = False, seed: int = 1) -> dict[str, Any]:
    """Run the load and return the figures (see :func:`report`). Without `port`, on a Mosquitto of
    its own (with `set_tcp_nodelay true` if `nodelay`)."""
    broker = None
    if port is None:
        from broker import Mosquitto  # tests/broker.py

        broker = Mosquitto(extra="set_tcp_nodelay true" if nodelay else "").start()
        host, port = broker.host, broker.port
    folder = Path(tempfile.mkdtemp(prefix="edge-fleet-"))
    run_id = uuid.uuid4().hex[:10]
    fleet: list[Device] = []
    members: list[Consumer] = []
    broker_pid = _broker_pid(broker.conf_path) if broker is not None else None
    try:
        members = [Consumer(i, host, port, run_id, group) for i in range(consumers)]
        for c in members:
            if not c.subscribed.wait(10):
                raise RuntimeError(f"a consumer could not subscribe at {host}:{port}")
        fleet = [Device(first + i, folder, host, port, run_id) for i in range(devices)]
        for d in fleet:
            d.link.start()
        deadline = time.monotonic() + 30
        while not all(d.link.connected for d in fleet):
            if time.monotonic() > deadline:
                missing = [d.id for d in fleet if not d.link.connected]
                raise RuntimeError(f"{len(missing)} device(s) not connected within 30 s: {missing[:5]}")
            time.sleep(0.05)
        time.sleep(0.5)  # discovery and status bursts of the connects settle

        # One scheduler for all devices: a heap of (due, kind, device), each on a fixed period
        # from its own random phase (devices are not in step).
        rng = random.Random(seed)
        periods = {"range": RANGE_EVERY_S, "alert": ALERT_EVERY_S, "sweep": SWEEP_EVERY_S}
        t0 = time.monotonic()
        heap = [(t0 + rng.uniform(0, periods[k]), k, i) for i in range(devices) for k in KINDS]
        heapq.heapify(heap)
        end = t0 + seconds
        lags: list[float] = []
        cpu0, wall0 = time.process_time(), time.time_ns()
        broker_cpu0 = _cpu_s(broker_pid) if broker_pid else None
        while heap:
            due, kind, i = heap[0]
            if due >= end:
                break
            now = time.monotonic()
            if due > now:
                time.sleep(due - now)
                continue
            heapq.heapreplace(heap, (due + periods[kind], kind, i))
            lags.append(now - due)
            fleet[i].publish(kind)
        t_end = time.monotonic()
        wall_end = time.time_ns()
        cpu_gen = time.process_time() - cpu0
        broker_cpu = (_cpu_s(broker_pid) - broker_cpu0) if broker_pid and broker_cpu0 is not None else None

        # Drain: until every QoS 1 message sent has arrived, or `drain` seconds.
        sent_q1 = sum(d.sent["alert"] + d.sent["sweep"] for d in fleet)
        drain_deadline = time.monotonic() + drain
        while time.monotonic() < drain_deadline:
            got = {(k, dev, s) for c in members for (k, dev, s, _, _) in list(c.records) if k != "range"}
            if len(got) >= sent_q1 and all(len(d.outbox) == 0 for d in fleet):
                break
            time.sleep(0.2)
        time.sleep(0.3)  # late duplicates, if any
        stats = [d.link.stats() for d in fleet]
        with ThreadPoolExecutor(max_workers=16) as pool:
            list(pool.map(lambda d: d.link.stop(timeout_s=2.0), fleet))
        for c in members:
            c.close()
        return report(fleet, members, stats, seconds=t_end - t0, window_ns=(wall0, wall_end), lags=lags,
                      cpu_gen=cpu_gen, broker_cpu=broker_cpu, devices=devices, consumers=consumers, group=group,
                      external=broker is None, host=host, port=port, nodelay=nodelay)
    finally:
        for d in fleet:
            try:
                d.link.stop(timeout_s=0.1)
            finally:
                d.outbox.close()
        for c in members:
            c.close()
        if broker is not None:
            broker.close()
        shutil.rmtree(folder, ignore_errors=True)


def report(fleet: list[Device], members: list[Consumer], stats: list[dict[str, int]], *, seconds: float,
           window_ns: tuple[int, int], lags: list[float], cpu_gen: float, broker_cpu: float | None,
           devices: int, consumers: int, group: str, external: bool, host: str, port: int,
           nodelay: bool = False) -> dict[str, Any]:
    records = [r for c in members for r in c.records]
    sent = {k: sum(d.sent[k] for d in fleet) for k in KINDS}
    received = Counter(r[0] for r in records)
    in_window = Counter(r[0] for r in records if window_ns[0] <= r[4] <= window_ns[1])
    per_consumer = [len(c.records) for c in members]

    seen: Counter[tuple[str, str, int]] = Counter()
    latency: dict[str, list[float]] = defaultdict(list)
    for kind, dev, seq, sent_ns, recv_ns in records:
        if kind == "range":
            continue
        key = (kind, dev, seq)
        seen[key] += 1
        if seen[key] == 1:
            latency[kind].append((recv_ns - sent_ns) / 1e6)
    lost: dict[str, int] = {}
    lost_devices: dict[str, list[str]] = {}
    for kind in ("alert", "sweep"):
        missing = 0
        who = []
        for d in fleet:
            gaps = sum(1 for s in range(1, d.sent[kind] + 1) if (kind, d.id, s) not in seen)
            missing += gaps
            if gaps:
                who.append(f"{d.id}:{gaps}")
        lost[kind] = missing
        lost_devices[kind] = who
    duplicates = {kind: sum(n - 1 for (k, _, _), n in seen.items() if k == kind and n > 1)
                  for kind in ("alert", "sweep")}
    # Per device: sent, and received (distinct sequence numbers for the QoS 1 kinds, messages for range).
    got: dict[str, Counter[str]] = defaultdict(Counter)
    for kind, dev, _seq in seen:
        got[dev][kind] += 1
    for kind, dev, *_ in records:
        if kind == "range":
            got[dev]["range"] += 1
    per_device = {d.id: {"sent": {k: d.sent[k] for k in KINDS}, "received": {k: got[d.id][k] for k in KINDS}}
                  for d in fleet}
    lat = {}
    for kind in ("alert", "sweep"):
        values = sorted(latency[kind])
        lat[kind] = {"n": len(values), "p50_ms": _percentile(values, 50), "p95_ms": _percentile(values, 95),
                     "p99_ms": _percentile(values, 99), "max_ms": values[-1] if values else float("nan")}
    lags_sorted = sorted(lags)
    ok = lost["alert"] == 0 and lost["sweep"] == 0 and lat["alert"]["p99_ms"] < P99_LIMIT_MS
    return {
        "devices": devices, "consumers": consumers, "group": group, "seconds": round(seconds, 2),
        "first_device": fleet[0].id if fleet else None,
        "broker": f"{host}:{port}" + (" (external)" if external else
                                      " (own Mosquitto" + (", set_tcp_nodelay" if nodelay else "") + ")"),
        "sent": sent, "received": dict(received),
        "sent_per_s": {k: sent[k] / seconds for k in KINDS},
        "received_per_s": {k: in_window[k] / seconds for k in KINDS},
        "total_received_per_s": sum(in_window.values()) / seconds,
        "range_delivered": received["range"] / sent["range"] if sent["range"] else float("nan"),
        "latency": lat, "lost": lost, "lost_devices": lost_devices, "duplicates": duplicates,
        "per_consumer": per_consumer, "per_device": per_device,
        "foreign": sum(c.foreign for c in members),
        "links": {"refused": sum(s["refused"] for s in stats), "dropped_live": sum(s["dropped_live"] for s in stats),
                  "reconnects": sum(s["connects"] - 1 for s in stats), "pending": sum(s["pending"] for s in stats)},
        "scheduler_lag_ms": {"p99": _percentile(lags_sorted, 99) * 1e3,
                             "max": (lags_sorted[-1] * 1e3) if lags_sorted else float("nan")},
        "cpu": {"generator_cores": cpu_gen / seconds,
                "broker_cores": (broker_cpu / seconds) if broker_cpu is not None else None},
        "ok": ok,
    }


def print_summary(r: dict[str, Any]) -> None:
    print(f"fleet load: {r['devices']} devices from {r['first_device']}, {r['seconds']} s, {r['consumers']} "
          f"consumers ($share/{r['group']}/...), broker {r['broker']}")
    print(f"{'kind':<7}{'QoS':>4}{'sent':>9}{'received':>10}{'sent/s':>9}{'recv/s':>9}"
          f"{'p50 ms':>9}{'p95 ms':>9}{'p99 ms':>9}{'max ms':>9}{'lost':>6}{'dup':>5}")
    for kind, qos in (("range", 0), ("alert", 1), ("sweep", 1)):
        lat = r["latency"].get(kind)
        cells = (f"{lat['p50_ms']:>9.1f}{lat['p95_ms']:>9.1f}{lat['p99_ms']:>9.1f}{lat['max_ms']:>9.1f}"
                 if lat else f"{'-':>9}" * 4)
        lost = f"{r['lost'][kind]:>6}{r['duplicates'][kind]:>5}" if kind in r["lost"] else f"{'-':>6}{'-':>5}"
        print(f"{kind:<7}{qos:>4}{r['sent'][kind]:>9}{r['received'].get(kind, 0):>10}"
              f"{r['sent_per_s'][kind]:>9.1f}{r['received_per_s'][kind]:>9.1f}{cells}{lost}")
    print(f"total received: {r['total_received_per_s']:.0f} msg/s; ranges delivered "
          f"{100 * r['range_delivered']:.2f} %; per consumer {r['per_consumer']}")
    links = r["links"]
    cpu = r["cpu"]
    broker_cpu = f"{cpu['broker_cores']:.2f}" if cpu["broker_cores"] is not None else "n/a"
    print(f"links: refused {links['refused']}, reconnects {links['reconnects']}, dropped live "
          f"{links['dropped_live']}, still queued {links['pending']}; scheduler lag p99 "
          f"{r['scheduler_lag_ms']['p99']:.1f} ms, max {r['scheduler_lag_ms']['max']:.1f} ms; "
          f"CPU cores: generator {cpu['generator_cores']:.2f}, broker {broker_cpu}")
    for kind, who in r["lost_devices"].items():
        if who:
            print(f"lost {kind}s: {', '.join(who[:20])}")
    if r["scheduler_lag_ms"]["p99"] > LAG_WARN_MS:
        print(f"WARNING: the generator fell behind (scheduler lag p99 {r['scheduler_lag_ms']['p99']:.0f} ms): "
              "it offered less than the nominal rates (see sent/s). Use fewer devices per process: run "
              "several processes against one broker (--port) with distinct --first and --group.")
    verdict = "PASS" if r["ok"] else "FAIL"
    print(f"{verdict}: lost {r['lost']['alert'] + r['lost']['sweep']} QoS 1 message(s), alert p99 "
          f"{r['latency']['alert']['p99_ms']:.1f} ms (limit {P99_LIMIT_MS:.0f} ms)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--devices", type=int, default=50)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--drain", type=float, default=5.0, help="seconds to wait for QoS 1 messages after the run")
    parser.add_argument("--consumers", type=int, default=3)
    parser.add_argument("--port", type=int, default=None, help="an existing broker's port (default: start Mosquitto)")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--first", type=int, default=0, help="number of the first device (fleet-NNN)")
    parser.add_argument("--group", default=GROUP, help="shared-subscription group of the consumers")
    parser.add_argument("--nodelay", action="store_true",
                        help="own Mosquitto with set_tcp_nodelay true (no Nagle delay towards the consumers)")
    parser.add_argument("--json", action="store_true", help="also print the figures as JSON")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    if args.devices < 1 or args.devices > 1000 or args.seconds <= 0 or args.consumers < 1:
        parser.error("--devices 1-1000, --seconds > 0, --consumers >= 1")
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    result = run(args.devices, args.seconds, args.port, host=args.host, drain=args.drain, consumers=args.consumers,
                 first=args.first, group=args.group, nodelay=args.nodelay)
    print_summary(result)
    if args.json:
        print(json.dumps({k: v for k, v in result.items() if k != "per_device"}, indent=2, default=str))
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
