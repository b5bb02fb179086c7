"""The on-disk outbox: order, acknowledgement, persistence, threads, the bound, a corrupt file, and
a process killed (SIGKILL) in the middle of writing, again and again."""

from __future__ import annotations

import hashlib
import logging
import os
import random
import signal
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

import edge.outbox
from edge.errors import StorageError
from edge.outbox import Outbox, OutboxMessage

REPO = Path(__file__).resolve().parents[1]
ALERT = "edge/dev1/alert"
SWEEP = "edge/dev1/sweep"
STATE = "edge/dev1/state"


@pytest.fixture
def box(tmp_path: Path):
    outbox = Outbox(tmp_path / "state" / "outbox.sqlite3")
    yield outbox
    outbox.close()


def _topics(outbox: Outbox) -> list[str]:
    return [m.topic for m in outbox.pending(limit=10_000)]


# --- order and acknowledgement -------------------------------------------------------------------


def test_put_creates_the_folder_and_pending_returns_messages_oldest_first(tmp_path: Path) -> None:
    path = tmp_path / "deep" / "er" / "outbox.sqlite3"
    with Outbox(path) as outbox:
        assert path.is_file()
        before = time.time()
        seqs = [
            outbox.put(ALERT, b'{"event": "intrusion"}'),
            outbox.put(SWEEP, b"\x00\xffbinary", qos=1, retain=True),
            outbox.put(STATE, b"", qos=0),
        ]
        after = time.time()
        assert seqs == sorted(seqs) and len(set(seqs)) == 3
        messages = outbox.pending()
        assert [m.seq for m in messages] == seqs
        assert messages[0] == OutboxMessage(seqs[0], ALERT, b'{"event": "intrusion"}', 1, False,
                                            messages[0].created)
        assert messages[1].payload == b"\x00\xffbinary" and messages[1].retain is True
        assert messages[2].qos == 0 and messages[2].payload == b""
        assert all(before <= m.created <= after for m in messages)
        assert len(outbox) == 3


def test_pending_pages_with_limit_and_after(box: Outbox) -> None:
    seqs = [box.put(ALERT, str(i).encode()) for i in range(10)]
    assert [m.seq for m in box.pending(limit=4)] == seqs[:4]
    assert [m.seq for m in box.pending(limit=4, after=seqs[3])] == seqs[4:8]
    assert [m.seq for m in box.pending(limit=100, after=seqs[-1])] == []


def test_ack_deletes_and_an_unknown_seq_is_a_no_op(box: Outbox) -> None:
    a, b, c = (box.put(ALERT, bytes([i])) for i in range(3))
    box.ack(b)
    assert [m.seq for m in box.pending()] == [a, c]
    assert len(box) == 2
    box.ack(b)  # again
    box.ack(c + 1000)  # never existed
    assert [m.seq for m in box.pending()] == [a, c]
    assert len(box) == 2


def test_bad_arguments_are_refused_and_nothing_is_queued(box: Outbox) -> None:
    with pytest.raises(TypeError):
        box.put(ALERT, "text, not bytes")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        box.put("", b"x")
    with pytest.raises(ValueError):
        box.put(ALERT, b"x", qos=3)
    assert len(box) == 0
    assert box.put(ALERT, bytearray(b"ok")) > 0 and box.pending()[0].payload == b"ok"


def test_a_closed_outbox_says_so(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path / "o.sqlite3")
    outbox.close()
    outbox.close()  # idempotent
    with pytest.raises(StorageError, match="o.sqlite3: the outbox is closed"):
        outbox.put(ALERT, b"x")


# --- persistence ---------------------------------------------------------------------------------


def test_messages_and_seq_survive_reopening(tmp_path: Path) -> None:
    path = tmp_path / "outbox.sqlite3"
    with Outbox(path) as outbox:
        seqs = [outbox.put(ALERT, f"alert {i}".encode()) for i in range(5)]
        outbox.ack(seqs[0])
    with Outbox(path) as outbox:
        assert [(m.seq, m.payload) for m in outbox.pending()] == [(s, f"alert {i}".encode())
                                                                 for i, s in enumerate(seqs) if i]
        assert len(outbox) == 4
        for m in outbox.pending():
            outbox.ack(m.seq)
        assert len(outbox) == 0
    # Emptied and reopened: seq still goes on from where it was, never back.
    with Outbox(path) as outbox:
        assert outbox.put(ALERT, b"later") > seqs[-1]


def test_a_second_owner_is_refused_while_the_first_has_it(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(edge.outbox, "_BUSY_TIMEOUT_S", 0.2)  # the real wait is for a slow stop
    path = tmp_path / "outbox.sqlite3"
    with Outbox(path) as first:
        first.put(ALERT, b"x")
        with pytest.raises(StorageError, match="in use by another process"):
            Outbox(path)
        assert len(first) == 1
    assert not list(tmp_path.glob("*.corrupt-*"))  # a busy file is not a bad one


# --- threads -------------------------------------------------------------------------------------


def test_put_from_one_thread_and_ack_from_another(box: Outbox) -> None:
    n = 400
    put: list[int] = []
    acked: list[int] = []
    errors: list[BaseException] = []

    def producer() -> None:
        try:
            for i in range(n):
                put.append(box.put(ALERT, i.to_bytes(4, "big")))
        except BaseException as exc:  # surfaced below: a thread's exception is otherwise lost
            errors.append(exc)

    def consumer() -> None:  # like paho's network thread: ack what was sent
        try:
            after = 0
            deadline = time.monotonic() + 60
            while len(acked) < n and time.monotonic() < deadline:
                for m in box.pending(limit=50, after=after):
                    assert int.from_bytes(m.payload, "big") == len(acked)  # in order, intact
                    box.ack(m.seq)
                    acked.append(m.seq)
                    after = m.seq
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=producer), threading.Thread(target=consumer)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not errors
    assert acked == put and len(set(put)) == n
    assert len(box) == 0 and box.pending() == []


# --- the bound -----------------------------------------------------------------------------------


def test_over_the_bound_the_oldest_sweeps_go_first_never_alerts(tmp_path: Path, caplog) -> None:
    with Outbox(tmp_path / "o.sqlite3", max_messages=5) as outbox:
        a1 = outbox.put(ALERT, b"a1")
        outbox.put(SWEEP, b"s1", retain=True)
        s2 = outbox.put(SWEEP, b"s2", retain=True)
        a2 = outbox.put(ALERT, b"a2")
        x1 = outbox.put(STATE, b"x1", retain=True)
        assert len(outbox) == 5
        with caplog.at_level(logging.WARNING, logger="edge.outbox"):
            s3 = outbox.put(SWEEP, b"s3", retain=True)
        assert [m.seq for m in outbox.pending()] == [a1, s2, a2, x1, s3]  # s1, the oldest sweep
        assert "dropped the 1 oldest" in caplog.text
        a3 = outbox.put(ALERT, b"a3")
        assert [m.seq for m in outbox.pending()] == [a1, a2, x1, s3, a3]  # s2
        a4 = outbox.put(ALERT, b"a4")
        assert [m.seq for m in outbox.pending()] == [a1, a2, x1, a3, a4]  # s3 goes before x1


def test_sweeps_then_other_messages_are_dropped_and_alerts_kept_beyond_the_bound(
    tmp_path: Path, caplog
) -> None:
    with Outbox(tmp_path / "o.sqlite3", max_messages=4) as outbox:
        outbox.put(SWEEP, b"s1")
        x1 = outbox.put(STATE, b"x1")
        a1 = outbox.put(ALERT, b"a1")
        a2 = outbox.put(ALERT, b"a2")
        with caplog.at_level(logging.WARNING, logger="edge.outbox"):
            a3 = outbox.put(ALERT, b"a3")  # drops s1 (sweeps first)
            assert [m.seq for m in outbox.pending()] == [x1, a1, a2, a3]
            a4 = outbox.put(ALERT, b"a4")  # drops x1 (then other non-alerts)
            assert [m.seq for m in outbox.pending()] == [a1, a2, a3, a4]
        assert caplog.text.count("dropped the 1 oldest") == 2
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="edge.outbox"):
            extra = [outbox.put(ALERT, f"a{i}".encode()) for i in range(5, 9)]
        # Only alerts: all kept beyond the bound, and said so (once, not on every put).
        assert [m.seq for m in outbox.pending()] == [a1, a2, a3, a4, *extra]
        assert len(outbox) == 8
        assert caplog.text.count("beyond its bound of 4") == 1
        assert "dropped the" not in caplog.text


def test_the_newest_sweep_is_kept_even_among_alerts_only(tmp_path: Path) -> None:
    with Outbox(tmp_path / "o.sqlite3", max_messages=2) as outbox:
        a1 = outbox.put(ALERT, b"a1")
        a2 = outbox.put(ALERT, b"a2")
        s1 = outbox.put(SWEEP, b"s1")  # over the bound, but the newest snapshot matters
        assert [m.seq for m in outbox.pending()] == [a1, a2, s1]
        s2 = outbox.put(SWEEP, b"s2")  # now s1 is the oldest sweep
        assert [m.seq for m in outbox.pending()] == [a1, a2, s2]
        outbox.ack(a1)
        outbox.ack(a2)
        assert len(outbox) == 1
    with Outbox(tmp_path / "o.sqlite3", max_messages=2) as outbox:  # the count is right on reopen
        assert len(outbox) == 1 and outbox.pending()[0].payload == b"s2"


# --- bad files and folders -----------------------------------------------------------------------


def _assert_moved_aside(path: Path, original: bytes, caplog) -> None:
    aside = sorted(path.parent.glob(path.name + ".corrupt-*"))
    assert [p.name for p in aside if not p.name.endswith(("-wal", "-shm"))] == [aside[0].name]
    assert aside[0].read_bytes() == original  # kept for whoever wants to look into it
    errors = [r for r in caplog.records if r.levelno == logging.ERROR and r.name == "edge.outbox"]
    assert len(errors) == 1 and str(path) in errors[0].getMessage()
    assert "moved it aside as " + aside[0].name in errors[0].getMessage()


def test_a_file_that_is_not_a_database_is_moved_aside(tmp_path: Path, caplog) -> None:
    path = tmp_path / "outbox.sqlite3"
    garbage = b"this is not an SQLite file, it is what a failing SD card left\n" * 100
    path.write_bytes(garbage)
    with caplog.at_level(logging.ERROR, logger="edge.outbox"), Outbox(path) as outbox:
        assert len(outbox) == 0
        seq = outbox.put(ALERT, b"after")
        assert outbox.pending()[0].seq == seq
    _assert_moved_aside(path, garbage, caplog)


def test_a_database_with_damaged_pages_is_moved_aside(tmp_path: Path, caplog) -> None:
    path = tmp_path / "outbox.sqlite3"
    with Outbox(path) as outbox:
        for i in range(300):
            outbox.put(ALERT, os.urandom(200) + i.to_bytes(4, "big"))
    data = bytearray(path.read_bytes())
    page = int.from_bytes(data[16:18], "big")
    assert len(data) > 6 * page
    # Scribble over the tree's interior: the header still says "SQLite format 3".
    data[page: 4 * page] = os.urandom(3 * page)
    damaged = bytes(data)
    path.write_bytes(damaged)
    with caplog.at_level(logging.ERROR, logger="edge.outbox"), Outbox(path) as outbox:
        assert len(outbox) == 0
        outbox.put(ALERT, b"after")
    _assert_moved_aside(path, damaged, caplog)


def test_a_database_of_something_else_is_moved_aside(tmp_path: Path, caplog) -> None:
    path = tmp_path / "outbox.sqlite3"
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE outbox (id INTEGER PRIMARY KEY, text TEXT)")
    conn.commit()
    conn.close()
    original = path.read_bytes()
    with caplog.at_level(logging.ERROR, logger="edge.outbox"), Outbox(path) as outbox:
        outbox.put(ALERT, b"x")
    _assert_moved_aside(path, original, caplog)


def test_a_folder_that_cannot_be_written_is_a_storage_error(tmp_path: Path) -> None:
    blocker = tmp_path / "state"
    blocker.write_text("a file where the state folder should be")
    with pytest.raises(StorageError, match=r"state/outbox.sqlite3: the folder .*state cannot be written"):
        Outbox(blocker / "outbox.sqlite3")


def test_a_folder_in_place_of_the_file_is_a_storage_error(tmp_path: Path) -> None:
    (tmp_path / "outbox.sqlite3").mkdir()
    with pytest.raises(StorageError, match="outbox.sqlite3: is a folder"):
        Outbox(tmp_path / "outbox.sqlite3")


# --- power cut -----------------------------------------------------------------------------------

# The child puts checksummed messages as fast as it can and acks the oldest now and then; it
# prints "p <seq>" once put() has returned and "a <seq>" once ack() has, and is SIGKILLed at a
# random moment. What it printed is what it was promised.
CHILD = textwrap.dedent(
    """
    import hashlib, os, random, sys
    from edge.outbox import Outbox
    box = Outbox(sys.argv[1])
    rng = random.Random(int(sys.argv[2]))
    out = sys.stdout
    n = 0
    while True:
        body = os.urandom(rng.randrange(0, 5000))
        seq = box.put("edge/dev1/alert", hashlib.sha256(body).digest() + body)
        out.write(f"p {seq}\\n"); out.flush()
        n += 1
        if n % 3 == 0:
            oldest = box.pending(limit=1)
            if oldest:
                box.ack(oldest[0].seq)
                out.write(f"a {oldest[0].seq}\\n"); out.flush()
    """
)


def test_sigkill_mid_write_loses_nothing_promised_and_corrupts_nothing(tmp_path: Path) -> None:
    path = tmp_path / "outbox.sqlite3"
    rng = random.Random(20240607)
    promised: set[int] = set()  # put() returned
    acked: set[int] = set()  # ack() returned
    seen_max = 0
    rounds_with_puts = 0
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    rounds = 8
    for round_no in range(rounds):
        child = subprocess.Popen([sys.executable, "-c", CHILD, str(path), str(round_no)],
                                 stdout=subprocess.PIPE, cwd=REPO, env=env)
        first = b""
        try:
            if round_no % 4 == 0:  # at any moment, perhaps while it is still opening the file
                time.sleep(rng.uniform(0.0, 0.3))
            else:  # mid-stream: once it is putting, however slow the machine is to start it
                first = child.stdout.readline()
                time.sleep(rng.uniform(0.0, 0.3))
        finally:
            child.send_signal(signal.SIGKILL)
            # Through the same buffered reader as readline() (communicate() would bypass what it
            # has buffered); the pipe ends when the child has died.
            out = child.stdout.read()
            child.stdout.close()
            child.wait(timeout=30)
        assert child.returncode == -signal.SIGKILL
        round_puts = []
        for line in (first + out).decode().splitlines(keepends=True):
            if not line.endswith("\n"):
                continue  # cut short by the kill: not a promise
            kind, seq = line.split()
            if kind == "p":
                round_puts.append(int(seq))
            else:
                acked.add(int(seq))
        promised.update(round_puts)
        rounds_with_puts += bool(round_puts)
        # seq never goes back, not even across a crash.
        assert all(s > seen_max for s in round_puts)

        with Outbox(path) as outbox:
            messages = outbox.pending(limit=1_000_000)
            assert len(outbox) == len(messages)
        seqs = [m.seq for m in messages]
        assert all(a < b for a, b in zip(seqs, seqs[1:])), "seqs not strictly increasing"
        for m in messages:
            digest, body = m.payload[:32], m.payload[32:]
            assert hashlib.sha256(body).digest() == digest, f"message {m.seq} is damaged"
            assert (m.topic, m.qos, m.retain) == ("edge/dev1/alert", 1, False)
        present = set(seqs)
        assert not (acked & present), "an acknowledged message came back"
        # A promised message may be missing only if the kill fell between an ack and its print:
        # at most one per round, and the oldest pending one (the child acks the oldest).
        missing = promised - acked - present
        assert len(missing) <= 1 and all(s < min(present, default=s + 1) for s in missing), (
            f"lost after round {round_no}: {sorted(missing)}")
        acked |= missing
        # At most one put per round can have committed without its print: nothing else appears.
        assert len(present - promised) <= round_no + 1
        seen_max = max([seen_max, *seqs, *promised, *acked])
    assert rounds_with_puts >= rounds * 3 // 4, "the child hardly ever got to put: the test proved little"
    assert not list(tmp_path.glob("*.corrupt-*")), "a kill left a file the outbox took for corrupt"
