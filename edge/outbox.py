"""The on-disk queue of outgoing QoS 1 MQTT messages (alerts, sweeps).

``../spec/mqtt.md`` promises that every alert reaches the broker at least once, even if the broker
was down when it happened and the device lost power meanwhile. So such a message is first written
here, committed to disk, and only deleted (:meth:`Outbox.ack`) once the broker has acknowledged it.

One SQLite file (stdlib ``sqlite3``), one table, WAL mode with ``synchronous=FULL``: each commit
fsyncs the write-ahead log, so a :meth:`Outbox.put` that has returned survives a power cut, and a
commit cut short by one is simply not there after the restart (never half a message).

Choices made here, and why:

- ``seq`` is an ``INTEGER PRIMARY KEY AUTOINCREMENT``: it never goes back, not even when the queue
  was emptied and the device restarted, so a sender's ``after=`` cursor stays meaningful.
- ``locking_mode=EXCLUSIVE``: one process owns the queue. A second ``edge run`` on the same state
  folder gets a :class:`StorageError` instead of sending the same messages twice, and the number of
  pending messages can be counted in memory instead of by a table scan on every ``put``.
- A corrupt or unreadable file (a failing SD card) is moved aside as ``<name>.corrupt-<UTC time>``
  and the queue starts empty, with an error in the log: the range finder must keep running, and the
  bad file stays for whoever wants to look into it. A folder that cannot be written is a
  :class:`StorageError`: then there is nowhere to start again.
- The bound (``max_messages``): sweeps are retained snapshots of which only the newest matters, so
  the oldest sweeps are dropped first, then other non-alert messages (state, command results);
  alerts are never dropped, even if that means going beyond the bound.
- A full disk (SQLite's "database or disk is full") must not stop the device. The outbox keeps a
  reserve file beside it (``<name>.reserve``, :data:`RESERVE_BYTES`, made when there is room): on a
  full disk it gives the reserve back, checkpoints the WAL and drops the oldest messages, sweeps
  first and alerts last, until the new one fits. When nothing more can go (or SQLite cannot even
  delete) the message is kept in memory only: it is still sent while the process lives, but not
  after a restart, and :attr:`Outbox.condition` says ``full: …`` until a message fits on disk again
  (messages held in memory then go to disk too). The WAL is checkpointed every
  :data:`_WAL_PAGES` pages, so that it never needs more than the reserve to be emptied. Deleted
  rows are not overwritten (``secure_delete`` off): dropping a message must cost almost no space.
"""

from __future__ import annotations

import logging
import os
import sqlite3
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from edge.errors import StorageError
from edge.fsutil import fsync_dir

log = logging.getLogger(__name__)

# The rank of a message when the queue is over its bound: the lowest rank is dropped first.
_RANK_SWEEP = 0
_RANK_OTHER = 1
_RANK_ALERT = 2  # never dropped

_SCHEMA = """
CREATE TABLE IF NOT EXISTS outbox (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    topic TEXT NOT NULL,
    payload BLOB NOT NULL,
    qos INTEGER NOT NULL,
    retain INTEGER NOT NULL,
    created REAL NOT NULL,
    rank INTEGER NOT NULL
)"""
# What the bound rule reads: the oldest droppable messages, by rank.
_INDEX = "CREATE INDEX IF NOT EXISTS outbox_by_rank ON outbox (rank, seq)"
_COLUMNS = ("seq", "topic", "payload", "qos", "retain", "created", "rank")

# sqlite3 primary result codes (the low byte of an extended code) that mean the file is bad.
_SQLITE_CANTOPEN = 14
_SQLITE_CORRUPT = 11
_SQLITE_NOTADB = 26
_SQLITE_BUSY = 5
_SQLITE_LOCKED = 6

_SQLITE_FULL = 13

RESERVE_BYTES = 256 * 1024  # given back on a full disk, so that SQLite can checkpoint and delete
_RESERVE_MIN = 64 * 1024  # on a small disk a quarter of what is free, but not less than this
_WAL_PAGES = 16  # checkpoint the WAL this often (pages of 4 kB): within the reserve
_MEMORY_MAX = 1000  # messages held in memory when the disk is full: beyond, the bound's rule drops
_DROPPING = "full: {}: dropping the oldest queued sweeps to make room (alerts are kept)"
_BUSY_TIMEOUT_S = 5.0  # waiting for a previous owner that is still shutting down
_OVERFLOW_WARN_EVERY_S = 60.0  # alerts beyond the bound: a reminder this often, not on every put


@dataclass(frozen=True)
class OutboxMessage:
    """One queued message."""

    seq: int  # increasing, assigned by put(); order of sending
    topic: str
    payload: bytes
    qos: int
    retain: bool
    created: float  # time.time() when put


def _rank(topic: str) -> int:
    if topic.endswith("/alert"):
        return _RANK_ALERT
    if topic.endswith("/sweep"):
        return _RANK_SWEEP
    return _RANK_OTHER


def _code(exc: sqlite3.Error) -> int:
    """The primary SQLite result code of an error (Python 3.11+), -1 if unknown."""
    code = getattr(exc, "sqlite_errorcode", None)
    return code & 0xFF if isinstance(code, int) else -1


class _BadFile(Exception):
    """Internal: the database file is corrupt, unreadable or not ours (it is moved aside)."""


class Outbox:
    """A durable FIFO of outgoing MQTT messages. Thread-safe; one ``Outbox`` per file."""

    def __init__(self, path: str | os.PathLike, max_messages: int = 100_000,
                 on_condition: Callable[[str], object] | None = None) -> None:
        """`on_condition` is told each new :attr:`condition` (from the thread that puts)."""
        if max_messages < 1:
            raise ValueError(f"max_messages must be >= 1, got {max_messages}")
        self.path = Path(path)
        self.max_messages = max_messages
        self.condition = "ok"  # or "full: …", as `state` reports the storage
        self._on_condition = on_condition
        self._reserve = self.path.with_name(self.path.name + ".reserve")
        self._lock = threading.Lock()
        self._overflow_warned_at: float | None = None
        self._conn: sqlite3.Connection | None = None  # None once closed
        self._count = 0  # messages in the file: counted once at open, then kept (we own the file)
        self._last_seq = 0  # the last seq given, on disk or in memory
        self._memory: dict[int, tuple[OutboxMessage, int]] = {}  # seq → (message, rank): no room on disk
        self._acked_unsaved: set[int] = set()  # acknowledged, but the disk was too full to delete them
        self._prepare_folder()
        try:
            self._conn, self._count = self._open()
        except _BadFile as bad:
            moved = self._move_aside()
            log.error("%s: %s; moved it aside as %s and started an empty outbox (its messages are "
                      "not sent)", self.path, bad, moved.name)
            try:
                self._conn, self._count = self._open()
            except _BadFile as again:
                raise StorageError(f"{self.path}: cannot start an empty outbox: {again}") from None
        self._last_seq = self._conn.execute(
            "SELECT COALESCE((SELECT seq FROM sqlite_sequence WHERE name = 'outbox'), 0)").fetchone()[0]
        self._make_reserve()

    # --- the queue -------------------------------------------------------------------------------

    def put(self, topic: str, payload: bytes, qos: int = 1, retain: bool = False) -> int:
        """Queue a message; it is committed to disk before this returns. Returns its seq."""
        if not isinstance(topic, str) or not topic:
            raise ValueError(f"outbox: topic must be a non-empty string, got {topic!r}")
        if not isinstance(payload, (bytes, bytearray, memoryview)):
            raise TypeError(f"outbox: payload must be bytes, got {type(payload).__name__}")
        if qos not in (0, 1, 2):
            raise ValueError(f"outbox: qos must be 0, 1 or 2, got {qos!r}")
        with self._lock:
            self._live()
            seq = self._last_seq = self._last_seq + 1
            message = OutboxMessage(seq, topic, bytes(payload), qos, bool(retain), time.time())
            try:
                # Short of room (the reserve given back): drop before the file grows into the last of it.
                short = self._short_of_room()
                if short:
                    self._drop_for_room(len(message.payload))
                dropped = self._insert([(message, _rank(topic))])
                condition = _DROPPING.format(self.path.parent) if short else "ok"
            except sqlite3.Error as exc:
                self._rollback()
                if _code(exc) != _SQLITE_FULL:
                    raise self._storage_error("cannot queue a message", exc) from None
                condition = self._put_on_full_disk(message, _rank(topic))
                dropped = 0
            else:
                self._warn_over_bound(dropped)
                self._to_disk_from_memory()
                self._make_reserve()
            changed, self.condition = condition != self.condition, condition
        if changed:
            (log.info if condition == "ok" else log.error)("%s: storage %s", self.path, condition)
            if self._on_condition is not None:
                self._on_condition(condition)
        return seq

    def _insert(self, messages: list[tuple[OutboxMessage, int]]) -> int:
        """Write messages (and drop what the bound wants for them) in one transaction: a power cut
        leaves all or none. Returns how many the bound dropped. sqlite3.Error: nothing written."""
        conn = self._live()
        conn.execute("BEGIN IMMEDIATE")
        conn.executemany(
            "INSERT INTO outbox (seq, topic, payload, qos, retain, created, rank) VALUES (?, ?, ?, ?, ?, ?, ?)",
            [(m.seq, m.topic, m.payload, m.qos, int(m.retain), m.created, rank) for m, rank in messages])
        dropped = self._drop_over_bound(messages[-1][0].seq, len(messages))
        conn.execute("COMMIT")
        self._count += len(messages) - dropped
        return dropped

    def _put_on_full_disk(self, message: OutboxMessage, rank: int) -> str:
        """The disk is full: give back the reserve, then drop the oldest messages (sweeps first,
        never alerts) until `message` fits; else hold it in memory. Returns the condition."""
        self._release_reserve()
        if not self._memory:  # else the disk had no room before this message either: do not churn
            while True:
                self._checkpoint()
                freed = self._drop_for_room(len(message.payload))
                try:
                    self._insert([(message, rank)])
                    return _DROPPING.format(self.path.parent)
                except sqlite3.Error as exc:
                    self._rollback()
                    if _code(exc) != _SQLITE_FULL:
                        raise self._storage_error("cannot queue a message", exc) from None
                if not freed:
                    break
        self._hold_in_memory(message, rank)
        return (f"full: {self.path.parent}: no room left for queued messages; new ones are held "
                "in memory only (sent while the service runs, lost on a restart)")

    def _short_of_room(self) -> bool:
        """The reserve was given back and the disk has not got its room back since."""
        if self._reserve.exists():
            return False
        try:
            stat = os.statvfs(self._reserve.parent)
        except OSError:
            return False
        return stat.f_bavail * stat.f_frsize < 2 * _RESERVE_MIN

    def _drop_for_room(self, need_bytes: int) -> int:
        """Delete the oldest non-alert messages holding at least `need_bytes` (and what was acked
        but not yet deleted). Returns how many rows went; 0 when none can go."""
        conn = self._live()
        try:
            rows = conn.execute("SELECT seq, length(payload) FROM outbox WHERE rank < ? ORDER BY rank, seq LIMIT 256",
                                (_RANK_ALERT,)).fetchall()
            victims, size = [], 0
            for seq, length in rows:
                if size > need_bytes:
                    break
                victims.append(seq)
                size += length + 64
            gone = sorted(self._acked_unsaved | set(victims))
            if not gone:
                return 0
            conn.execute("BEGIN IMMEDIATE")
            deleted = sum(max(conn.execute("DELETE FROM outbox WHERE seq = ?", (seq,)).rowcount, 0) for seq in gone)
            conn.execute("COMMIT")
        except sqlite3.Error as exc:
            self._rollback()
            log.debug("%s: cannot drop messages to make room: %s", self.path, exc)
            return 0
        self._count -= deleted
        self._acked_unsaved.clear()
        if victims:
            log.info("%s: the disk is full: dropped the %d oldest queued non-alert message(s), "
                        "sweeps first, to make room", self.path, len(victims))
        return deleted

    def _hold_in_memory(self, message: OutboxMessage, rank: int) -> None:
        self._memory[message.seq] = (message, rank)
        if len(self._memory) > _MEMORY_MAX:  # the bound's rule, in memory: oldest sweeps first
            droppable = sorted((r, seq) for seq, (_, r) in self._memory.items() if r < _RANK_ALERT)
            if droppable:
                del self._memory[droppable[0][1]]

    def _to_disk_from_memory(self) -> None:
        """There is room again: messages held in memory go to disk (they keep their seq)."""
        if not self._memory:
            return
        try:
            self._insert(sorted(self._memory.values(), key=lambda held: held[0].seq))
        except sqlite3.Error as exc:
            self._rollback()
            log.debug("%s: messages held in memory stay there: %s", self.path, exc)
            return
        log.info("%s: %d message(s) held in memory are on disk again", self.path, len(self._memory))
        self._memory.clear()

    def pending(self, limit: int = 100, after: int = 0) -> list[OutboxMessage]:
        """Up to `limit` messages not yet acknowledged with seq > `after`, oldest first."""
        with self._lock:
            conn = self._live()
            try:
                rows = conn.execute(
                    "SELECT seq, topic, payload, qos, retain, created FROM outbox WHERE seq > ? "
                    "ORDER BY seq LIMIT ?",
                    (after, limit + len(self._acked_unsaved)),
                ).fetchall()
            except sqlite3.Error as exc:
                raise self._storage_error("cannot read queued messages", exc) from None
            out = [OutboxMessage(seq, topic, bytes(payload), qos, bool(retain), created)
                   for seq, topic, payload, qos, retain, created in rows if seq not in self._acked_unsaved]
            out += [m for m, _ in self._memory.values() if m.seq > after]
        return sorted(out, key=lambda m: m.seq)[:limit]

    def ack(self, seq: int) -> None:
        """The broker has the message: delete it. An unknown (or already acked) seq is a no-op."""
        with self._lock:
            conn = self._live()
            if self._memory.pop(seq, None) is not None:
                return
            try:
                deleted = conn.execute("DELETE FROM outbox WHERE seq = ?", (seq,)).rowcount
            except sqlite3.Error as exc:
                if _code(exc) != _SQLITE_FULL:
                    raise self._storage_error(f"cannot delete message {seq}", exc) from None
                # Too full even to delete: not sent again by this process, deleted when there is room.
                if conn.execute("SELECT 1 FROM outbox WHERE seq = ?", (seq,)).fetchone():
                    self._acked_unsaved.add(seq)
                return
            self._count -= max(deleted, 0)
            if self._count <= self.max_messages:
                self._overflow_warned_at = None

    def __len__(self) -> int:
        """The number of messages not yet acknowledged."""
        with self._lock:
            self._live()
            return self._count - len(self._acked_unsaved) + len(self._memory)

    def close(self) -> None:
        """Close the file (idempotent). Committed messages stay for the next start."""
        with self._lock:
            conn, self._conn = self._conn, None
            if conn is not None:
                conn.close()  # checkpoints the WAL into the main file

    def __enter__(self) -> Outbox:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- opening ---------------------------------------------------------------------------------

    def _prepare_folder(self) -> None:
        """Create the folder and prove that it can be written: a probe file, because permission
        bits say nothing about a read-only file system or, for root, anything at all."""
        folder = self.path.parent
        try:
            folder.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=folder, prefix=".outbox-probe-"):
                pass
        except OSError as exc:
            raise StorageError(f"{self.path}: the folder {folder} cannot be written: "
                               f"{exc.strerror or exc}") from None
        if self.path.is_dir():
            raise StorageError(f"{self.path}: is a folder, not an outbox file")

    def _open(self) -> tuple[sqlite3.Connection, int]:
        """Open (or create) the database and check it. Bad files raise :class:`_BadFile`."""
        existed = self.path.exists()
        try:
            conn = sqlite3.connect(self.path, timeout=_BUSY_TIMEOUT_S, isolation_level=None,
                                   check_same_thread=False)  # our lock serialises the threads
        except sqlite3.Error as exc:
            raise self._classify(exc, existed) from None
        try:
            # EXCLUSIVE before WAL: the WAL index then lives in our memory (no -shm file) and the
            # lock, taken on the first read below, keeps other processes out until close().
            conn.execute("PRAGMA locking_mode = EXCLUSIVE")
            # Check before changing anything, so that a bad file is moved aside as it was found.
            problems = [row[0] for row in conn.execute("PRAGMA quick_check(5)")]
            if problems != ["ok"]:
                raise _BadFile(f"corrupt database ({'; '.join(map(str, problems))})")
            columns = tuple(row[1] for row in conn.execute("PRAGMA table_info(outbox)"))
            if columns and columns != _COLUMNS:
                raise _BadFile(f"not an outbox: its table has columns {', '.join(columns)}")
            mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise StorageError(f"{self.path}: cannot switch the outbox to WAL mode (got {mode!r})")
            conn.execute("PRAGMA synchronous = FULL")  # fsync the WAL at every commit
            conn.execute("PRAGMA journal_size_limit = 8388608")  # give the SD card its space back
            conn.execute(f"PRAGMA wal_autocheckpoint = {_WAL_PAGES}")  # a WAL the reserve can empty
            conn.execute("PRAGMA secure_delete = 0")  # dropping a message must not write it over
            conn.execute(_SCHEMA)
            conn.execute(_INDEX)
            count = conn.execute("SELECT COUNT(*) FROM outbox").fetchone()[0]
        except BaseException as exc:
            conn.close()
            if isinstance(exc, sqlite3.Error):
                raise self._classify(exc, existed) from None
            raise
        if not existed:
            fsync_dir(self.path.parent)  # the new file's name must survive a power cut too
        log.debug("%s: outbox open, %d message(s) pending", self.path, count)
        return conn, count

    def _classify(self, exc: sqlite3.Error, existed: bool) -> Exception:
        """A bad file (moved aside) or a StorageError (the file is fine, the situation is not)."""
        code = _code(exc)
        if code in (_SQLITE_CORRUPT, _SQLITE_NOTADB):
            return _BadFile(f"corrupt database ({exc})")
        if code == _SQLITE_CANTOPEN and existed and self.path.is_file():
            return _BadFile(f"unreadable ({exc})")
        if code in (_SQLITE_BUSY, _SQLITE_LOCKED):
            return StorageError(f"{self.path}: the outbox is in use by another process "
                                "(is another edge running with the same state folder?)")
        return self._storage_error("cannot open the outbox", exc)

    def _move_aside(self) -> Path:
        """Rename the bad file (and its WAL, which belongs to it) to ``<name>.corrupt-<time>``."""
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        target = self.path.with_name(f"{self.path.name}.corrupt-{stamp}")
        n = 1
        while target.exists():  # twice in one second: do not overwrite the first
            n += 1
            target = self.path.with_name(f"{self.path.name}.corrupt-{stamp}-{n}")
        try:
            for suffix in ("-wal", "-shm"):
                side = self.path.with_name(self.path.name + suffix)
                if side.exists():
                    os.replace(side, target.with_name(target.name + suffix))
            os.replace(self.path, target)
            fsync_dir(self.path.parent)
        except OSError as exc:
            raise StorageError(f"{self.path}: corrupt, and cannot be moved aside: "
                               f"{exc.strerror or exc}") from None
        return target

    # --- helpers ---------------------------------------------------------------------------------

    def _live(self) -> sqlite3.Connection:
        if self._conn is None:
            raise StorageError(f"{self.path}: the outbox is closed")
        return self._conn

    def _rollback(self) -> None:
        try:
            if self._conn is not None and self._conn.in_transaction:
                self._conn.execute("ROLLBACK")
        except sqlite3.Error as exc:
            log.error("%s: rollback failed: %s", self.path, exc)

    def _checkpoint(self) -> None:
        """Copy the WAL into the database and truncate it (its room back); best effort."""
        try:
            self._live().execute("PRAGMA wal_checkpoint(TRUNCATE)")
        except sqlite3.Error as exc:
            log.debug("%s: checkpoint failed: %s", self.path, exc)

    def _make_reserve(self) -> None:
        """Set room aside for a full disk, when there is plenty (never the last of it)."""
        if self._reserve.exists():
            return
        try:
            stat = os.statvfs(self._reserve.parent)
            size = min(RESERVE_BYTES, stat.f_bavail * stat.f_frsize // 4)
            if size < _RESERVE_MIN:
                return
            fd = os.open(self._reserve, os.O_WRONLY | os.O_CREAT, 0o600)
            try:
                os.posix_fallocate(fd, 0, size)
            finally:
                os.close(fd)
        except OSError as exc:
            self._reserve.unlink(missing_ok=True)
            log.debug("%s: no reserve: %s", self._reserve, exc)

    def _release_reserve(self) -> None:
        try:
            self._reserve.unlink(missing_ok=True)
        except OSError as exc:
            log.error("%s: cannot give the reserve back: %s", self._reserve, exc.strerror or exc)

    def _storage_error(self, what: str, exc: sqlite3.Error) -> StorageError:
        return StorageError(f"{self.path}: {what}: {exc}")

    def _drop_over_bound(self, new_seq: int, added: int = 1) -> int:
        """Within put's transaction: drop the oldest droppable messages beyond the bound, sweeps
        first, never alerts and never the message just put (the newest snapshot is the one that
        matters). Returns how many were dropped."""
        excess = self._count + added - self.max_messages
        if excess <= 0:
            return 0
        conn = self._live()
        victims = conn.execute(
            "SELECT seq FROM outbox WHERE rank < ? AND seq != ? ORDER BY rank, seq LIMIT ?",
            (_RANK_ALERT, new_seq, excess),
        ).fetchall()
        conn.executemany("DELETE FROM outbox WHERE seq = ?", victims)
        return len(victims)

    def _warn_over_bound(self, dropped: int) -> None:
        if dropped:
            log.warning("%s: outbox over its bound of %d messages: dropped the %d oldest "
                        "non-alert message(s), sweeps first", self.path, self.max_messages, dropped)
        if self._count <= self.max_messages:
            self._overflow_warned_at = None
            return
        now = time.monotonic()
        if self._overflow_warned_at is None or now - self._overflow_warned_at >= _OVERFLOW_WARN_EVERY_S:
            self._overflow_warned_at = now
            log.warning("%s: outbox holds %d messages, beyond its bound of %d: alerts are never "
                        "dropped (is the broker reachable?)", self.path, self._count, self.max_messages)
