"""A full state disk (a small tmpfs, filled): the outbox drops the oldest sweeps, never an alert,
holds what does not fit in memory, and never raises; a restart on the full disk runs on too."""

from __future__ import annotations

import contextlib
import os
import subprocess
import uuid
from pathlib import Path

import pytest

from edge.outbox import Outbox

ALERT = "edge/dev1/alert"
SWEEP = "edge/dev1/sweep"
SIZE_KB = 1024


@pytest.fixture
def small_disk(tmp_path: Path):
    """A 1 MB tmpfs of its own, unmounted after."""
    folder = tmp_path / "disk"
    folder.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={SIZE_KB}k", "tmpfs", str(folder)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root): {done.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def _fill(folder: Path, leave_bytes: int = 0) -> Path:
    """Fill the disk with another program's file, up to `leave_bytes` free."""
    hog = folder / f"hog-{uuid.uuid4().hex}"
    with open(hog, "wb") as fh, contextlib.suppress(OSError):
        while True:
            stat = os.statvfs(folder)
            free = stat.f_bavail * stat.f_frsize - leave_bytes
            if free <= 0:
                break
            fh.write(b"\0" * min(free, 65536))
            fh.flush()
    return hog


def _sweep(n: int) -> bytes:
    return b'{"sweep": %d, "zones": "%s"}' % (n, b"z" * 20_000)


def test_a_full_disk_drops_the_oldest_sweeps_keeps_every_alert_and_never_raises(small_disk: Path) -> None:
    conditions: list[str] = []
    box = Outbox(small_disk / "outbox.sqlite3", on_condition=conditions.append)
    _fill(small_disk, leave_bytes=300 * 1024)  # others filled the disk; the reserve is ours
    alerts = [box.put(ALERT, b'{"event": "intrusion", "n": %d}' % i) for i in range(3)]
    sweeps = [box.put(SWEEP, _sweep(n), retain=True) for n in range(60)]  # ~1.2 MB: far more than fits
    assert box.condition.startswith("full: ")
    assert conditions and conditions[0].startswith("full: ")
    pending = box.pending(limit=10_000)
    topics = [m.topic for m in pending]
    assert [m.seq for m in pending if m.topic == ALERT] == alerts  # every alert still there
    kept = [m.seq for m in pending if m.topic == SWEEP]
    assert kept[-1] == sweeps[-1]  # the newest sweep is never the one dropped
    assert len(kept) < len(sweeps) and kept == sweeps[-len(kept):]  # the oldest went first
    assert topics.count(ALERT) == 3 and len(box) == len(pending)
    more_alerts = [box.put(ALERT, b'{"event": "moved"}') for _ in range(5)]  # an alert still gets a seq
    assert set(more_alerts) <= {m.seq for m in box.pending(limit=10_000)}
    for m in box.pending(limit=10_000):  # the broker takes them all: acks never raise either
        box.ack(m.seq)
    assert len(box) == 0
    box.close()


def test_when_nothing_can_go_messages_are_held_in_memory_and_go_to_disk_when_room_returns(small_disk: Path) -> None:
    conditions: list[str] = []
    box = Outbox(small_disk / "outbox.sqlite3", on_condition=conditions.append)
    hog = _fill(small_disk)
    seqs = []
    for _ in range(500):  # only alerts, which are never dropped: the disk runs out for good
        seqs.append(box.put(ALERT, b'{"event": "moved", "pad": "%s"}' % (b"x" * 4000)))
        if "in memory" in box.condition:
            break
    assert "in memory" in box.condition and conditions[-1] == box.condition
    seqs += [box.put(ALERT, b'{"event": "cleared"}') for _ in range(3)]
    assert [m.seq for m in box.pending(limit=1000)] == seqs  # all of them, in order, for the sender
    hog.unlink()  # room again
    box.put(SWEEP, _sweep(1), retain=True)
    assert box.condition == "ok" and conditions[-1] == "ok"
    box.close()
    with Outbox(small_disk / "outbox.sqlite3") as again:  # after a restart: nothing was lost
        assert [m.topic for m in again.pending(limit=1000)] == [ALERT] * len(seqs) + [SWEEP]


def test_a_restart_on_a_full_disk_opens_and_runs_on(small_disk: Path) -> None:
    path = small_disk / "outbox.sqlite3"
    with Outbox(path) as box:
        for n in range(10):
            box.put(SWEEP, _sweep(n), retain=True)
    _fill(small_disk)
    with Outbox(path) as box:  # opens although not a byte is free
        for n in range(10, 30):
            box.put(SWEEP, _sweep(n), retain=True)
        box.put(ALERT, b'{"event": "intrusion"}')
        assert box.condition.startswith("full: ")
        pending = box.pending(limit=1000)
        assert pending[-1].topic == ALERT and pending[-2].payload == _sweep(29)


def test_the_service_runs_on_with_a_full_state_disk_and_says_so_in_state(small_disk: Path) -> None:
    """The issue's restart: the broker is away, sweeps of a previous run fill the state disk."""
    import json
    import threading
    import time

    from edge.config import load_config
    from edge.service import Service
    from tests.broker import free_port

    with Outbox(small_disk / "outbox.sqlite3") as box:
        for n in range(10):
            box.put(SWEEP, _sweep(n), retain=True)
    hog = _fill(small_disk)
    config = load_config(None, [f"service.state_dir={json.dumps(str(small_disk))}", 'mqtt.host="127.0.0.1"',
                                f"mqtt.port={free_port()}", 'mode="guard"', "sweep.zones=4",
                                "service.guard_pairs_per_zone=1", "service.watchdog=false"])
    service = Service(config)
    seen: list[str] = []

    def watch() -> None:
        deadline = time.monotonic() + 180

        def sweeps(n: int) -> None:
            target = service.sweeps + n
            while time.monotonic() < deadline and service.sweeps < target:
                time.sleep(0.02)

        sweeps(1)
        # The outbox's first meeting with the full disk drops the queued sweeps and gives back its
        # own files' room (its WAL): wait for it, then take that room too.
        while time.monotonic() < deadline and not service.state()["health"]["storage"].startswith("full"):
            time.sleep(0.02)
        hogs = [hog, _fill(small_disk)]  # now not a byte is left
        sweeps(3)
        seen.append(service.state()["health"]["storage"])
        for h in hogs:
            h.unlink()  # room again
        sweeps(2)
        seen.append(service.state()["health"]["storage"])
        service.stop_requested.set()

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    assert service.run() == 0
    watcher.join(5)
    assert service.sweeps >= 6
    assert seen[0].startswith("full: ") and seen[1] == "ok"
