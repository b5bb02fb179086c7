"""Writing files so that a power cut leaves the old file or the new one, never half of one."""

from __future__ import annotations

import errno
import logging
import os
import re
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from edge.errors import EdgeError

if TYPE_CHECKING:
    import numpy as np

log = logging.getLogger(__name__)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write `data` to a temporary file beside `path`, fsync it, rename it over `path`, and fsync
    the folder so that the rename itself survives a power cut."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    remove_dead_temporaries(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=folder)
    try:
        os.fchmod(fd, 0o666 & ~current_umask())  # mkstemp's 0600 would hide the file from its group
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(folder)


# What fsync of a folder fails with on file systems that cannot sync one (some network and FUSE
# file systems): not a lost write, only a promise they do not make.
_CANNOT_SYNC_A_FOLDER = frozenset({errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EBADF})


def fsync_dir(path: str | Path) -> None:
    """Make the creations, renames and removals of entries in folder `path` survive a power cut.

    On a file system that cannot sync a folder (fsync fails with EINVAL, ENOTSUP or EBADF) this
    does nothing and says so at debug level: the files themselves are synced by their writers, and
    that is as durable as such a file system gets. Any other failure raises OSError — the folder
    cannot be opened (gone, not readable) or the disk reported an error (EIO) — because the
    caller can then not promise that what it wrote will still be there after a power cut."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in _CANNOT_SYNC_A_FOLDER:
            raise
        log.debug("%s: this file system cannot sync a folder (%s)", path, exc.strerror)
    finally:
        os.close(fd)


def remove_dead_temporaries(path: Path) -> None:
    """Remove the temporaries that writers of `path` killed before their rename left beside it
    (``.<name>.<pid>.<random>.tmp``, `pid` gone): on a device left alone for months they would
    pile up. Never fails: at worst a temporary stays."""
    pattern = re.compile(re.escape(f".{path.name}.") + r"([1-9][0-9]*)\.[^/]+\.tmp")
    folder = path.parent if str(path.parent) else Path(".")
    try:
        names = os.listdir(folder)
    except OSError:
        return
    for name in names:
        match = pattern.fullmatch(name)
        # Not our own pid: another thread of ours may be writing the same file right now.
        if match is None or int(match.group(1)) == os.getpid() or process_alive(int(match.group(1))):
            continue
        leftover = folder / name
        if leftover.is_symlink() or not leftover.is_file():
            continue
        try:
            leftover.unlink()
        except OSError as exc:
            log.warning("%s: cannot remove the leftover of a killed writer: %s", leftover, exc)
        else:
            log.info("%s: removed the leftover of a killed writer", leftover)


def process_alive(pid: int) -> bool:
    """Whether process `pid` may still be writing; when in doubt, True. Our own pid counts as
    gone: what it left was left by a crashed process that had our number."""
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # PermissionError: alive, another user's process
        return True
    return True


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Encode `image` (uint8/uint16, grey or BGR) as PNG and write it atomically."""
    import cv2  # here, not at the top: the atomic writes serve light modules (the outbox) too

    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise EdgeError(f"{path}: could not encode the image as PNG")
    atomic_write_bytes(path, buf.tobytes())


def current_umask() -> int:
    """The process's umask (reading it means setting it: set it straight back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
