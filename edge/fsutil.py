"""Files: writing them so that a power cut leaves the old file or the new one, never half of one;
reading small documents so that no file can hang, exhaust or crash the reader; refusing to write
over anything that is not a plain file.

Everything we read from disk (configuration, calibration, sweep.json, a password) is a small
document, and anything may sit where it is expected: a FIFO (an open() that waits forever for a
writer), a device node such as /dev/zero (endless bytes), a huge file. :func:`read_small` opens
without blocking, insists on a regular file and reads at most its limit.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import stat
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from edge.errors import ConfigError, EdgeError

if TYPE_CHECKING:
    import numpy as np

log = logging.getLogger(__name__)


# The largest document read_small takes by default: configuration, calibration and sweep.json
# files are a few kB to a few hundred kB (a 4096-zone sweep.json with 32 pairs a zone is ~20 MB).
SMALL_LIMIT = 32 << 20

# Pseudo file systems: nothing of ours is ever written there, and a path there is a device or the
# kernel's, never a document (e.g. audio.out = /dev/sda1). /dev/shm is a plain tmpfs.
_NOT_FOR_OUTPUT = ("/dev", "/proc", "/sys")
_OUTPUT_ALLOWED = ("/dev/shm",)


def read_small(path: str | Path, limit: int = SMALL_LIMIT) -> bytes:
    """The bytes of the regular file `path`, at most `limit` of them.

    Raises FileNotFoundError when there is no such file, and OSError with a readable `strerror`
    for everything else: not a regular file (a FIFO, a device, a folder, a socket), larger than
    `limit`, or unreadable. Never blocks on a FIFO and never reads more than `limit` + 1 bytes."""
    # O_NONBLOCK: opening a FIFO for reading would otherwise wait for a writer, forever.
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise OSError(errno.EINVAL, f"not a regular file (it is {file_kind(info.st_mode)})")
        if info.st_size > limit:
            raise OSError(errno.EFBIG, f"too large ({info.st_size} bytes; at most {limit})")
        os.set_blocking(fd, True)
        chunks, size = [], 0
        while size <= limit:  # the file may grow while we read: stop one byte past the limit
            chunk = os.read(fd, min(1 << 20, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > limit:
            raise OSError(errno.EFBIG, f"too large (over {limit} bytes)")
        return b"".join(chunks)
    finally:
        os.close(fd)


def file_kind(mode: int) -> str:
    """What a file of mode `mode` is, as a message says it: `a folder`, `a FIFO`, …"""
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISLNK, "a symbolic link")):
        if test(mode):
            return name
    return "a regular file" if stat.S_ISREG(mode) else "a special file"


def output_problem(path: str | Path, folder: bool = False) -> str | None:
    """Why `path` may not be written as an output file (or, with `folder`, an output folder), or
    None when it may: it must not be in /dev, /proc or /sys, and what already exists there
    (followed through symbolic links) must be a regular file (a folder)."""
    try:
        real = os.path.realpath(path)
    except (OSError, ValueError) as exc:
        return f"cannot be resolved ({getattr(exc, 'strerror', None) or exc})"
    def under(tops: tuple[str, ...]) -> str | None:
        return next((top for top in tops if real == top or real.startswith(top + "/")), None)

    forbidden = under(_NOT_FOR_OUTPUT)
    if forbidden is not None and under(_OUTPUT_ALLOWED) is None:
        return f"{show(real)} is in {forbidden}, where no output of ours goes"
    try:
        info = os.stat(path)
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        return f"cannot be checked ({getattr(exc, 'strerror', None) or exc})"
    wanted = stat.S_ISDIR if folder else stat.S_ISREG
    if not wanted(info.st_mode):
        return f"exists and is {file_kind(info.st_mode)}, not {'a folder' if folder else 'a regular file'}"
    return None


def show(text: str) -> str:
    """`text` fit for a one-line message (as edge.schema.show, which imports this module)."""
    return text if text.isprintable() else repr(text)


def check_output(path: str | Path, key: str, folder: bool = False,
                 error: type[EdgeError] = ConfigError) -> None:
    """Raise `error` naming `key` (a config key or a command-line option) when `path` may not be
    written as an output (see :func:`output_problem`)."""
    problem = output_problem(path, folder)
    if problem is not None:
        raise error(f"{key}: {show(str(path))}: {problem}")


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write `data` to a temporary file beside `path`, fsync it, rename it over `path`, and fsync
    the folder so that the rename itself survives a power cut.

    Refuses (OSError) to replace anything but a regular file: a rename over a device node, say,
    would replace the device with our file."""
    path = Path(path)
    problem = output_problem(path)
    if problem is not None:
        raise OSError(errno.EEXIST, problem)
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
