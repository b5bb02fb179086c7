"""Which start of the service this is: the boot id that makes sweep and alert keys unique.

The sweep counter and the guard's track ids start again at 1 and ``t1`` on every start, so without
more a consumer that de-duplicates alerts by (``id``, ``event``, ``sweep``) would drop the second
night's intrusion as a repeat of the first night's. Every start therefore gets a boot id, counted
in ``<state_dir>/boot`` (``b1``, ``b2``, …): it prefixes track ids (``b7-t1``) and is in every
``sweep`` and ``alert`` payload as ``boot``.

The count is written atomically (temporary file, fsync, rename), so a power cut or ``kill -9``
leaves the old count or the new one, never a torn one; a start that was cut short only skips a
number. When the count cannot be read or written (a full or read-only state disk, a garbled file)
the boot id is random instead (``r`` and 8 hex digits, e.g. ``r3f9a02c1``): unique all the same,
only no longer in order, and the service runs on. It is taken on first use (the first sweep or
alert), so a service that never publishes one writes nothing.
"""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

from edge.fsutil import atomic_write_bytes

log = logging.getLogger(__name__)

BOOT_FILE = "boot"
_MAX_BOOT = 10**15  # far beyond any life of an SD card; a larger number is a garbled file


def random_boot_id() -> str:
    return "r" + os.urandom(4).hex()


def next_boot_id(state_dir: str | os.PathLike) -> str:
    """Count this start in `state_dir` and return its boot id (random when it cannot be counted)."""
    path = Path(state_dir) / BOOT_FILE
    try:
        text = path.read_text(encoding="ascii").strip() if path.exists() else "0"
        if not text.isdigit() or not 0 <= int(text) < _MAX_BOOT:
            raise ValueError(f"holds {text[:20]!r}, not a count of starts")
        count = int(text) + 1
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, f"{count}\n".encode("ascii"))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        boot = random_boot_id()
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        log.error("%s: cannot count this start (%s); using the random boot id %s (alerts and sweeps "
                  "stay unique, their boot ids are no longer in order)", path, why, boot)
        return boot
    return f"b{count}"


class BootId:
    """The boot id of this start, counted in `state_dir` on first use (None: random, nothing written)."""

    def __init__(self, state_dir: str | os.PathLike | None) -> None:
        self._state_dir = state_dir
        self._value: str | None = None
        self._lock = threading.Lock()

    @property
    def value(self) -> str:
        with self._lock:
            if self._value is None:
                self._value = random_boot_id() if self._state_dir is None else next_boot_id(self._state_dir)
                log.info("boot id %s", self._value)
            return self._value
