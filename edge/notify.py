"""systemd's notification protocol (``sd_notify``) in pure Python, and a watchdog that only a loop
making progress can feed.

Under ``Type=notify`` systemd sets ``NOTIFY_SOCKET`` (a datagram socket: a path, or an abstract
name written with a leading ``@``) and waits for ``READY=1``; with ``WatchdogSec=`` it also sets
``WATCHDOG_USEC`` and ``WATCHDOG_PID`` and kills the service when ``WATCHDOG=1`` stops coming.
Each message is a datagram of ``KEY=value`` lines (``man sd_notify``).

Outside systemd (a terminal, the tests) there is no ``NOTIFY_SOCKET`` and every method is a cheap
no-op. Sending never raises: the service must not die because the notify socket went away (a
``systemctl daemon-reexec``, say); the first failure is logged at warning, later ones at debug.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time
from collections.abc import Callable, Mapping
from types import FrameType

log = logging.getLogger(__name__)

_SEND_TIMEOUT_S = 1.0  # a full socket buffer must not stall the loop for long


def _address(value: str) -> str | None:
    """NOTIFY_SOCKET → a socket address for ``sendto``; None for forms we do not speak."""
    if value.startswith("@"):
        return "\0" + value[1:]  # abstract namespace
    if value.startswith("/"):
        return value
    return None  # e.g. "vsock:..." (virtual machines): not for a Pi


def _watchdog_usec(env: Mapping[str, str]) -> int | None:
    """WATCHDOG_USEC when the watchdog is meant for this process, else None (sd_watchdog_enabled)."""
    raw = env.get("WATCHDOG_USEC", "")
    if not raw:
        return None
    pid = env.get("WATCHDOG_PID", "")
    if pid:
        try:
            if int(pid) != os.getpid():
                return None  # set for our parent (we are a child it started): not ours to feed
        except ValueError:
            log.warning("systemd notify: ignoring WATCHDOG_PID=%r: not a number", pid)
            return None
    try:
        usec = int(raw)
    except ValueError:
        log.warning("systemd notify: ignoring WATCHDOG_USEC=%r: not a number", raw)
        return None
    return usec if usec > 0 else None


class Notifier:
    """Sends state changes to systemd. Thread-safe; every method returns whether it was sent."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        raw = env.get("NOTIFY_SOCKET", "")
        self._address = _address(raw) if raw else None
        if raw and self._address is None:
            log.warning("systemd notify: NOTIFY_SOCKET=%r is not a path or @abstract name; "
                        "not notifying", raw)
        usec = _watchdog_usec(env) if self._address is not None else None
        # Half the timeout, as systemd recommends: one late feed must not get us killed.
        self._interval_s = usec / 2e6 if usec is not None else None
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._failing = False

    @property
    def enabled(self) -> bool:
        """Whether systemd is listening (NOTIFY_SOCKET is set to a usable address)."""
        return self._address is not None

    @property
    def watchdog_interval_s(self) -> float | None:
        """How often to send WATCHDOG=1 (half of WATCHDOG_USEC), or None when no watchdog is asked
        for this process."""
        return self._interval_s

    def ready(self) -> bool:
        """Start-up is complete (``Type=notify`` units count as started only now)."""
        return self.send("READY=1")

    def status(self, text: str) -> bool:
        """A one-line status for ``systemctl status``."""
        # Newlines would start new KEY=value assignments: keep the status on its line.
        return self.send("STATUS=" + " ".join(text.splitlines()))

    def watchdog(self) -> bool:
        """Feed the watchdog (``WATCHDOG=1``). Prefer :class:`WatchdogFeeder` in loops."""
        return self.send("WATCHDOG=1")

    def stopping(self) -> bool:
        """Shutdown has begun."""
        return self.send("STOPPING=1")

    def send(self, message: str) -> bool:
        """Send one raw notification (``KEY=value`` lines). Never raises."""
        if self._address is None:
            return False
        data = message.encode("utf-8", "replace")
        with self._lock:
            try:
                if self._sock is None:
                    self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                    self._sock.settimeout(_SEND_TIMEOUT_S)
                self._sock.sendto(data, self._address)
            except OSError as exc:
                self._drop_socket()  # a fresh socket next time, in case this one is broken
                if not self._failing:
                    log.warning("systemd notify: cannot send %s to %s: %s (further failures are "
                                "logged at debug level)", message.split("=")[0], self._shown(), exc)
                    self._failing = True
                else:
                    log.debug("systemd notify: cannot send %s: %s", message.split("=")[0], exc)
                return False
            if self._failing:
                log.info("systemd notify: sending to %s works again", self._shown())
                self._failing = False
            return True

    def close(self) -> None:
        with self._lock:
            self._drop_socket()

    def _drop_socket(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _shown(self) -> str:
        address = self._address or ""
        return "@" + address[1:] if address.startswith("\0") else address


class WatchdogFeeder:
    """Feeds systemd's watchdog only while the loop really makes progress.

    A thread that fed the watchdog on a timer would keep a hung sweep alive for ever. Instead the
    loop calls :meth:`progressed` whenever it gets something done (a zone measured, a command
    answered, an idle tick that completed) and :meth:`feed_if_due` often; ``WATCHDOG=1`` goes out
    only if there was progress since the last one and the interval is due. A stuck loop stops
    feeding, and systemd kills and restarts the service (``Restart=on-failure``).
    """

    def __init__(self, notifier: Notifier, clock: Callable[[], float] = time.monotonic) -> None:
        self.notifier = notifier
        self._clock = clock
        self._progress = False
        self._last_feed: float | None = None

    @property
    def active(self) -> bool:
        """Whether systemd asked for a watchdog at all (else both methods do nothing)."""
        return self.notifier.watchdog_interval_s is not None

    def progressed(self) -> None:
        """The loop got something done (safe from any thread: it only sets a flag)."""
        self._progress = True

    def feed_if_due(self) -> bool:
        """Send WATCHDOG=1 if progress was reported since the last feed and the interval is due.
        Returns whether it fed."""
        interval = self.notifier.watchdog_interval_s
        if interval is None or not self._progress:
            return False
        now = self._clock()
        if self._last_feed is not None and now - self._last_feed < interval:
            return False
        self._progress = False
        self._last_feed = now
        return self.notifier.watchdog()

    def tick(self) -> None:
        """What the loop calls when it got something done: progress, and a feed when due."""
        self.progressed()
        self.feed_if_due()


def stop_on_signals(stop: threading.Event) -> None:
    """SIGTERM (systemd's stop) and SIGINT set `stop`, which the service's loop checks between
    zones. Only the main thread may take signals: tests that run a service in a thread stop it by
    setting the event themselves."""
    if threading.current_thread() is not threading.main_thread():
        return

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("%s: stopping", signal.Signals(signum).name)
        stop.set()

    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, on_signal)
