"""systemd notifications over a real AF_UNIX datagram socket, and a watchdog that a stuck loop
cannot feed."""

from __future__ import annotations

import logging
import os
import socket
import uuid
from pathlib import Path

import pytest

from edge.notify import Notifier, WatchdogFeeder


class Listener:
    """What systemd does with NOTIFY_SOCKET: a bound datagram socket."""

    def __init__(self, address: str) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(address)

    def next(self) -> bytes:
        self.sock.settimeout(2.0)
        return self.sock.recv(4096)

    def nothing(self) -> bool:
        """No datagram waiting. sendto() on a local datagram socket has queued it by the time it
        returns, so an empty queue now means nothing was sent."""
        self.sock.setblocking(False)
        try:
            self.sock.recv(4096)
        except BlockingIOError:
            return True
        return False

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def systemd(tmp_path: Path, monkeypatch):
    path = tmp_path / "n.sock"
    assert len(str(path)) < 100, "AF_UNIX paths are limited to 107 bytes"
    listener = Listener(str(path))
    monkeypatch.setenv("NOTIFY_SOCKET", str(path))
    monkeypatch.delenv("WATCHDOG_USEC", raising=False)
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    yield listener
    listener.close()


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_each_method_sends_its_datagram(systemd: Listener) -> None:
    notifier = Notifier()
    assert notifier.enabled
    assert notifier.ready() is True
    assert systemd.next() == b"READY=1"
    notifier.status("sweeping zone 12 of 64")
    assert systemd.next() == b"STATUS=sweeping zone 12 of 64"
    notifier.watchdog()
    assert systemd.next() == b"WATCHDOG=1"
    notifier.stopping()
    assert systemd.next() == b"STOPPING=1"
    assert systemd.nothing()
    notifier.close()


def test_a_status_stays_on_one_line(systemd: Listener) -> None:
    # A newline would start a new assignment: "STATUS=a\nREADY=1" would tell systemd we are ready.
    Notifier().status("camera failed:\nREADY=1")
    assert systemd.next() == b"STATUS=camera failed: READY=1"


def test_the_abstract_socket_form(monkeypatch) -> None:
    name = f"edge-test-{uuid.uuid4().hex}"
    listener = Listener("\0" + name)
    try:
        monkeypatch.setenv("NOTIFY_SOCKET", "@" + name)
        notifier = Notifier()
        assert notifier.ready()
        assert listener.next() == b"READY=1"
    finally:
        listener.close()


def test_without_notify_socket_everything_is_a_no_op(monkeypatch) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    monkeypatch.setenv("WATCHDOG_USEC", "30000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    notifier = Notifier()
    assert not notifier.enabled
    assert notifier.watchdog_interval_s is None  # nobody to feed
    assert [notifier.ready(), notifier.status("x"), notifier.watchdog(), notifier.stopping()] == [False] * 4
    feeder = WatchdogFeeder(notifier)
    feeder.progressed()
    assert not feeder.active and feeder.feed_if_due() is False


def test_an_unusable_notify_socket_value_disables_notifying(monkeypatch, caplog) -> None:
    monkeypatch.setenv("NOTIFY_SOCKET", "vsock:2:1234")
    with caplog.at_level(logging.WARNING, logger="edge.notify"):
        notifier = Notifier()
    assert not notifier.enabled and notifier.ready() is False
    assert "vsock:2:1234" in caplog.text


@pytest.mark.parametrize(
    ("usec", "pid", "interval"),
    [
        ("30000000", "self", 15.0),  # WatchdogSec=30: feed every 15 s
        ("30000000", None, 15.0),  # no WATCHDOG_PID: for whoever reads it
        ("30000000", "other", None),  # meant for another process (our parent)
        (None, "self", None),  # no watchdog asked for
        ("0", "self", None),
        ("soon", "self", None),  # garbage: ignored, not a crash
    ],
)
def test_watchdog_interval(systemd: Listener, monkeypatch, usec, pid, interval) -> None:
    if usec is not None:
        monkeypatch.setenv("WATCHDOG_USEC", usec)
    if pid is not None:
        monkeypatch.setenv("WATCHDOG_PID", str(os.getpid() if pid == "self" else os.getpid() + 1))
    assert Notifier().watchdog_interval_s == interval


def test_send_errors_are_logged_once_and_never_raised(tmp_path: Path, monkeypatch, caplog) -> None:
    path = tmp_path / "n.sock"
    monkeypatch.setenv("NOTIFY_SOCKET", str(path))  # nobody listening (yet)
    notifier = Notifier()
    with caplog.at_level(logging.DEBUG, logger="edge.notify"):
        assert notifier.ready() is False
        assert notifier.watchdog() is False
        assert notifier.status("still here") is False
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and str(path) in warnings[0].getMessage()

    # The socket comes (back): sending works again, and says so.
    listener = Listener(str(path))
    try:
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="edge.notify"):
            assert notifier.watchdog() is True
        assert listener.next() == b"WATCHDOG=1"
        assert "works again" in caplog.text
    finally:
        listener.close()
    # ... and goes away again: warned once more, still no exception.
    path.unlink()
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="edge.notify"):
        assert notifier.watchdog() is False
        assert notifier.watchdog() is False
    assert len(caplog.records) == 1


def test_the_feeder_feeds_a_loop_that_progresses(systemd: Listener, monkeypatch) -> None:
    monkeypatch.setenv("WATCHDOG_USEC", "2000000")  # interval 1 s
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    clock = FakeClock()
    feeder = WatchdogFeeder(Notifier(), clock=clock)
    assert feeder.active

    feeder.progressed()
    assert feeder.feed_if_due() is True  # the first progress feeds at once
    assert systemd.next() == b"WATCHDOG=1"

    clock.now += 0.5
    feeder.progressed()
    assert feeder.feed_if_due() is False  # progress, but not due yet
    assert systemd.nothing()

    clock.now += 0.75  # (binary fractions: the sums below are exact)
    assert feeder.feed_if_due() is True  # due now, and progress was reported since the last feed
    assert systemd.next() == b"WATCHDOG=1"

    fed = 0
    for _ in range(20):  # a healthy loop ticking every 0.25 s
        clock.now += 0.25
        feeder.progressed()
        fed += feeder.feed_if_due()
    assert fed == 5
    assert [systemd.next() for _ in range(fed)] == [b"WATCHDOG=1"] * fed
    assert systemd.nothing()


def test_a_stuck_loop_stops_feeding(systemd: Listener, monkeypatch) -> None:
    monkeypatch.setenv("WATCHDOG_USEC", "2000000")
    clock = FakeClock()
    feeder = WatchdogFeeder(Notifier(), clock=clock)
    feeder.progressed()
    assert feeder.feed_if_due()
    assert systemd.next() == b"WATCHDOG=1"

    # The loop still comes round (a timer, another thread) but a sweep is hung: no progressed().
    for _ in range(100):
        clock.now += 0.5
        assert feeder.feed_if_due() is False
    assert systemd.nothing()  # systemd's WatchdogSec runs out and it restarts the service

    feeder.progressed()  # it recovers (before systemd acted): feeding resumes at once
    assert feeder.feed_if_due() is True
    assert systemd.next() == b"WATCHDOG=1"
