"""Smoke tests of the fleet load generator (tests/load_fleet.py), so that a regression in it, or
in the outbox and the link under many clients, shows in CI. A few devices for a few seconds against a
real Mosquitto: they check what arrived, never how fast (the machine is shared)."""

from __future__ import annotations

import json
import math

import load_fleet
import pytest
from broker import Mosquitto

pytestmark = pytest.mark.slow

DEVICES = 5


def test_small_fleet_loses_no_qos1_message_and_reaches_every_device(broker: Mosquitto) -> None:  # noqa: F811
    r = load_fleet.run(DEVICES, 3.0, broker.port, host=broker.host, drain=15.0, consumers=2, seed=1)

    assert r["devices"] == DEVICES and "(external)" in r["broker"]
    assert r["foreign"] == 0
    # Something of every kind was offered (the schedule is fixed by the seed, not by the clock).
    assert r["sent"]["alert"] >= DEVICES and r["sent"]["sweep"] >= 1 and r["sent"]["range"] >= 10 * DEVICES

    # QoS 1: nothing lost, everything delivered once (no reconnect, so no reason to send again).
    assert r["lost"] == {"alert": 0, "sweep": 0}, r["lost_devices"]
    assert r["duplicates"] == {"alert": 0, "sweep": 0}
    assert r["links"]["pending"] == 0 and r["links"]["refused"] == 0 and r["links"]["reconnects"] == 0
    assert r["received"]["alert"] == r["sent"]["alert"] and r["received"]["sweep"] == r["sent"]["sweep"]

    # Per device: every alert and sweep sent arrived, and ranges arrived from every device.
    per_device = r["per_device"]
    assert sorted(per_device) == [f"fleet-{i:03d}" for i in range(DEVICES)]
    for dev, counts in per_device.items():
        sent, received = counts["sent"], counts["received"]
        assert sent["alert"] >= 1, dev
        assert received["alert"] == sent["alert"], dev
        assert received["sweep"] == sent["sweep"], dev
        assert 0 < received["range"] <= sent["range"], dev
    assert sum(c["sent"]["alert"] for c in per_device.values()) == r["sent"]["alert"]
    assert sum(c["received"]["range"] for c in per_device.values()) == r["received"]["range"]
    assert 0 < r["range_delivered"] <= 1

    # The shared subscription spread the messages over the group (each member got something).
    assert len(r["per_consumer"]) == 2 and all(n > 0 for n in r["per_consumer"])
    assert sum(r["per_consumer"]) == sum(r["received"].values())

    # Latencies: present, finite and positive; their size is the machine's business, not the test's.
    for kind in ("alert", "sweep"):
        lat = r["latency"][kind]
        assert lat["n"] == r["sent"][kind]
        for key in ("p50_ms", "p95_ms", "p99_ms", "max_ms"):
            assert math.isfinite(lat[key]) and lat[key] > 0, (kind, key, lat)
        assert lat["p50_ms"] <= lat["p95_ms"] <= lat["p99_ms"] <= lat["max_ms"]
    assert r["seconds"] > 0 and r["total_received_per_s"] > 0


def test_cli_runs_on_its_own_broker_and_prints_the_summary(monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    # The exit status also holds the alerts' p99 to 100 ms: not a thing to assert on a shared machine.
    monkeypatch.setattr(load_fleet, "P99_LIMIT_MS", 1e9)
    code = load_fleet.main(["--devices", "3", "--seconds", "2", "--drain", "15", "--consumers", "2", "--json"])
    out = capsys.readouterr().out

    assert code == 0, out
    summary, _, figures = out.partition("\n{")
    assert "fleet load: 3 devices from fleet-000" in summary
    assert "(own Mosquitto)" in summary
    for kind in ("range", "alert", "sweep"):
        assert any(line.startswith(kind) for line in summary.splitlines()), (kind, summary)
    assert "total received:" in summary and "links: refused 0" in summary
    assert "PASS: lost 0 QoS 1 message(s)" in summary
    result = json.loads("{" + figures)
    assert result["lost"] == {"alert": 0, "sweep": 0} and result["ok"] is True
    assert "per_device" not in result  # the JSON output keeps its shape
