"""Sweep recordings in format ``edge-sweep/1`` (``shared/spec/recording.md``): read and write.

A recording is a folder holding ``sweep.json`` (the rig and, per zone, the frames with and without
the lasers) and the frames as PNG files. Other tools write recordings too, so reading is strict:
every broken rule is a :class:`RecordingError` with one line naming the file, the zone, the frame,
the key and the problem. Unknown keys are ignored at every level so that the format can grow.

Writing is atomic: :class:`RecordingWriter` builds the recording in a sibling folder
``<path>.partial-<pid>`` and renames it into place only once ``sweep.json`` is on disk, so that a
crash or a power cut never leaves something that looks like a recording but is not one. What a
killed writer leaves beside the recording (``<path>.partial-<pid>``, ``<path>.old-<pid>``) is
cleaned up by the next writer of the same recording, once process ``<pid>`` is gone. When nothing
is at ``<path>`` (a writer killed in the middle of its swap), the newest whole recording among them
— the finished new one, else the old one moved aside — is first put in place.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import shutil
import struct
import sys
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path, PurePosixPath
from typing import Any, NoReturn

import cv2
import numpy as np

from edge.errors import EdgeError, RecordingError
from edge.fsutil import process_alive
from edge.rig import CameraModel, Laser, Mount, Rig
from edge.schema import FieldError, describe

FORMAT = "edge-sweep/1"
SWEEP_JSON = "sweep.json"
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_MISSING = object()

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------------
# Data model


@dataclass(frozen=True)
class FrameRecord:
    """One camera frame of a zone, as listed in sweep.json."""

    file: str  # relative path inside the recording, exactly as in sweep.json
    lasers_on: tuple[str, ...]  # empty: the background frame
    pan_deg: float | None = None  # set when the unit was nudged off the zone's pose for this frame
    tilt_deg: float | None = None
    t_start_ns: int | None = None  # exposure start, monotonic clock
    exposure_us: float | None = None
    laser_switch_ns: int | None = None  # when the lasers last changed state


@dataclass(frozen=True)
class ZoneRecord:
    """One view direction and its frames."""

    index: int
    pan_deg: float
    tilt_deg: float
    frames: tuple[FrameRecord, ...]
    truth: dict[str, Any] | None = None  # raw JSON object, for scoring only; ranging never reads it

    @property
    def off_frames(self) -> tuple[FrameRecord, ...]:
        """Frames taken with every laser off."""
        return tuple(f for f in self.frames if not f.lasers_on)

    @property
    def on_frames(self) -> tuple[FrameRecord, ...]:
        """Frames taken with at least one laser on."""
        return tuple(f for f in self.frames if f.lasers_on)


@dataclass(frozen=True)
class Recording:
    """A recording read from disk; images are decoded on demand by :meth:`load_image`."""

    path: Path  # the recording folder
    rig: Rig
    zones: tuple[ZoneRecord, ...]
    created: str | None = None
    device: str | None = None

    def load_image(self, zone: ZoneRecord, frame: FrameRecord) -> np.ndarray:
        """Decode one frame: uint8 or uint16, grey (H, W) or colour BGR (H, W, 3).

        Alpha is dropped. Raises RecordingError naming the zone and frame when the file is missing,
        cannot be decoded, is not 8/16-bit or its size differs from the camera's.
        """
        fail = _Checker(str(self.path / SWEEP_JSON)).at(_frame_where(zone.index, frame.file))
        file = _frame_path(self.path, frame.file, fail)
        image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
        if image is None:
            fail("image is unreadable: OpenCV could not decode it")
        if image.dtype not in (np.uint8, np.uint16):
            fail(f"image has pixel type {image.dtype}; frames must be 8- or 16-bit")
        if image.ndim == 3:
            channels = image.shape[2]
            if channels in (1, 2):  # grey, or grey + alpha
                image = image[:, :, 0]
            elif channels == 4:
                image = image[:, :, :3]
            elif channels != 3:
                fail(f"image has {channels} channels; frames must be grey or colour")
        _check_size(image.shape[1], image.shape[0], self.rig.camera, fail)
        return np.ascontiguousarray(image)


# --------------------------------------------------------------------------------------------------
# Strict JSON checking


def _show(text: str) -> str:
    """A user string fit for a one-line message."""
    return text if text.isprintable() else repr(text)


def _frame_where(index: int, file: str) -> str:
    return f"zone {index}, frame {_show(file)}"


class _Checker:
    """Typed access to parsed JSON; every failure names `source` and the key path."""

    def __init__(self, source: str, error: type[EdgeError] = RecordingError):
        self.source = source
        self.error = error

    def fail(self, where: str, message: str) -> NoReturn:
        raise self.error(f"{self.source}: {where}: {message}" if where
                         else f"{self.source}: {message}")

    def at(self, where: str) -> Any:
        """A one-argument fail bound to `where`."""
        return lambda message: self.fail(where, message)

    def get(self, obj: Mapping[str, Any], key: str, where: str, required: bool = True) -> Any:
        """obj[key]; _MISSING when absent (or null) and optional."""
        value = obj.get(key)
        if value is None:
            if required:
                self.fail(where, "missing required key" if key not in obj else "must not be null")
            return _MISSING
        return value

    def table(self, value: Any, where: str) -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            self.fail(where, f"expected an object, got {describe(value, 'an object')}")
        return value

    def array(self, value: Any, where: str) -> list[Any]:
        if not isinstance(value, list):
            self.fail(where, f"expected a list, got {describe(value, 'an object')}")
        return value

    def number(self, value: Any, where: str) -> float:
        # bool is an int in Python but never a number in JSON.
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(where, f"expected a number, got {describe(value, 'an object')}")
        if isinstance(value, int) and abs(value) > sys.float_info.max:
            self.fail(where, "expected a finite number, got a whole number too large for one")
        if not math.isfinite(value):
            self.fail(where, f"expected a finite number, got {value}")
        return float(value)

    def integer(self, value: Any, where: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(where, f"expected a whole number, got {describe(value, 'an object')}")
        return value

    def string(self, value: Any, where: str) -> str:
        if not isinstance(value, str):
            self.fail(where, f"expected a string, got {describe(value, 'an object')}")
        return value

    def boolean(self, value: Any, where: str) -> bool:
        if not isinstance(value, bool):
            self.fail(where, f"expected true or false, got {describe(value, 'an object')}")
        return value

    def numbers(self, value: Any, where: str, n: int) -> tuple[float, ...]:
        items = self.array(value, where)
        if len(items) != n:
            self.fail(where, f"expected {n} numbers, got {len(items)}")
        return tuple(self.number(v, f"{where}[{i}]") for i, v in enumerate(items))

    def optional(self, obj: Mapping[str, Any], key: str, where: str, kind: str) -> Any:
        value = self.get(obj, key, where, required=False)
        return None if value is _MISSING else getattr(self, kind)(value, where)


# --------------------------------------------------------------------------------------------------
# Rig <-> JSON


def rig_to_json(rig: Rig) -> dict[str, Any]:
    """The rig as sweep.json's `camera`, `lasers`, `mount` and `range_limits_m` (GPIO pins, being
    hardware wiring rather than geometry, are not part of the format)."""
    cam = rig.camera
    lasers = []
    for laser in rig.lasers:
        entry: dict[str, Any] = {
            "name": laser.name,
            "origin_m": list(laser.origin_m),
            "direction": list(laser.direction),
        }
        if laser is rig.reference:
            entry["reference"] = True
        lasers.append(entry)
    return {
        "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy,
                   "cx": cam.cx, "cy": cam.cy, "dist": list(cam.dist)},
        "lasers": lasers,
        "mount": {"origin_m": list(rig.mount.origin_m), "rpy_deg": list(rig.mount.rpy_deg)},
        "range_limits_m": list(rig.range_limits_m),
    }


def rig_from_json(
    obj: Mapping[str, Any], source: str, error: type[EdgeError] = RecordingError
) -> Rig:
    """Build a Rig from a JSON object holding `camera`, `lasers` and optionally `mount` and
    `range_limits_m`; raise `error` with a one-line message naming `source` and the key."""
    chk = _Checker(source, error)
    obj = chk.table(obj, "")
    cam = chk.table(chk.get(obj, "camera", "camera"), "camera")
    kw: dict[str, Any] = {k: chk.integer(chk.get(cam, k, f"camera.{k}"), f"camera.{k}")
                          for k in ("width", "height")}
    kw |= {k: chk.number(chk.get(cam, k, f"camera.{k}"), f"camera.{k}")
           for k in ("fx", "fy", "cx", "cy")}
    dist = chk.get(cam, "dist", "camera.dist", required=False)
    if dist is not _MISSING:
        kw["dist"] = chk.numbers(dist, "camera.dist", 5)
    try:
        camera = CameraModel(**kw)
    except FieldError as exc:
        chk.fail(f"camera.{exc.key}", exc.message)

    lasers = []
    for i, raw in enumerate(chk.array(chk.get(obj, "lasers", "lasers"), "lasers")):
        where = f"lasers[{i}]"
        entry = chk.table(raw, where)
        name = chk.string(chk.get(entry, "name", f"{where}.name"), f"{where}.name")
        origin = chk.numbers(
            chk.get(entry, "origin_m", f"{where}.origin_m"), f"{where}.origin_m", 3
        )
        direction = chk.numbers(
            chk.get(entry, "direction", f"{where}.direction"), f"{where}.direction", 3
        )
        reference = chk.optional(entry, "reference", f"{where}.reference", "boolean") or False
        try:
            lasers.append(Laser(name, origin, direction, reference=reference))  # type: ignore
        except FieldError as exc:
            chk.fail(f"{where}.{exc.key}", exc.message)

    mount = Mount()
    raw_mount = chk.get(obj, "mount", "mount", required=False)
    if raw_mount is not _MISSING:
        m = chk.table(raw_mount, "mount")
        parts = {k: chk.numbers(v, f"mount.{k}", 3) for k in ("origin_m", "rpy_deg")
                 if (v := chk.get(m, k, f"mount.{k}", required=False)) is not _MISSING}
        mount = Mount(**parts)  # type: ignore[arg-type]
    extra: dict[str, Any] = {}
    limits = chk.get(obj, "range_limits_m", "range_limits_m", required=False)
    if limits is not _MISSING:
        extra["range_limits_m"] = chk.numbers(limits, "range_limits_m", 2)
    try:
        return Rig(camera, tuple(lasers), mount, **extra)
    except FieldError as exc:
        chk.fail(exc.key, exc.message)


# --------------------------------------------------------------------------------------------------
# Reading


def _relative_problem(file: str) -> str | None:
    """Why `file` may not name a frame inside the recording, or None if it may."""
    if not file:
        return "must not be empty"
    if "\0" in file:
        return "must not contain a NUL character"
    # Windows forms too (\\server, C:): a recording may come from another system.
    if PurePosixPath(file).is_absolute() or file.startswith("\\") or file[1:2] == ":":
        return f"{_show(file)} is absolute; frames must lie inside the recording folder"
    depth = 0
    for part in PurePosixPath(file).parts:
        depth += -1 if part == ".." else 0 if part == "." else 1
        if depth < 0:
            return f"{_show(file)} leaves the recording folder; frames must lie inside it"
    return None


def _frame_path(folder: Path, file: str, fail: Any) -> Path:
    """The frame's file, checked to exist and to stay inside `folder` even through symlinks."""
    path = folder / file
    try:
        exists = path.is_file()
        inside = exists and path.resolve().is_relative_to(folder.resolve())
    except (OSError, RuntimeError) as exc:  # a name too long, a symlink loop
        fail(f"image is unreadable ({_show(str(getattr(exc, 'strerror', None) or exc))})")
    if not exists:
        fail(f"image is missing (no file {_show(str(path))})")
    if not inside:
        fail("file: resolves outside the recording folder (through a symbolic link)")
    return path


def _check_size(width: int, height: int, camera: CameraModel, fail: Any) -> None:
    if (width, height) != (camera.width, camera.height):
        fail(f"image is {width}x{height} but the camera is {camera.width}x{camera.height}")


def _check_png_header(path: Path, camera: CameraModel, fail: Any) -> None:
    """Check a PNG's size and bit depth from its IHDR chunk, without decoding the pixels."""
    try:
        with open(path, "rb") as f:
            head = f.read(33)
    except OSError as exc:
        fail(f"image is unreadable ({exc.strerror})")
    if len(head) < 33 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        fail("image is unreadable: not a PNG file")
    if zlib.crc32(head[12:29]) != struct.unpack(">I", head[29:33])[0]:
        fail("image is unreadable: corrupt PNG header")
    width, height, depth = struct.unpack(">IIB", head[16:25])
    if depth not in (8, 16):
        fail(f"image is a {depth}-bit PNG; frames must be 8- or 16-bit")
    _check_size(width, height, camera, fail)


def _parse_frame(chk: _Checker, raw: Any, index: int, k: int, names: Sequence[str]) -> FrameRecord:
    where = f"zone {index}, frames[{k}]"  # until the frame has a name
    entry = chk.table(raw, where)
    file = chk.string(chk.get(entry, "file", f"{where}: file"), f"{where}: file")
    if (problem := _relative_problem(file)) is not None:
        chk.fail(f"{where}: file", problem)
    where = _frame_where(index, file)
    lasers_on = chk.array(chk.get(entry, "lasers_on", f"{where}: lasers_on"), f"{where}: lasers_on")
    for i, name in enumerate(lasers_on):
        chk.string(name, f"{where}: lasers_on[{i}]")
        if name not in names:
            chk.fail(where, f"lasers_on names unknown laser {name!r} (lasers: {', '.join(map(_show, names))})")
        if name in lasers_on[:i]:
            chk.fail(where, f"lasers_on names laser {name!r} twice")
    kinds = {"pan_deg": "number", "tilt_deg": "number", "t_start_ns": "integer",
             "exposure_us": "number", "laser_switch_ns": "integer"}
    extra = {k: chk.optional(entry, k, f"{where}: {k}", kind) for k, kind in kinds.items()}
    return FrameRecord(file, tuple(lasers_on), **extra)


def _parse_zone(chk: _Checker, raw: Any, position: int, names: Sequence[str]) -> ZoneRecord:
    where = f"zones[{position}]"
    entry = chk.table(raw, where)
    index = chk.integer(chk.get(entry, "index", f"{where}: index"), f"{where}: index")
    if index < 0:
        chk.fail(f"{where}: index", f"must not be negative, got {index}")
    where = f"zone {index}"
    pan = chk.number(chk.get(entry, "pan_deg", f"{where}: pan_deg"), f"{where}: pan_deg")
    tilt = chk.number(chk.get(entry, "tilt_deg", f"{where}: tilt_deg"), f"{where}: tilt_deg")
    raw_frames = chk.array(chk.get(entry, "frames", f"{where}: frames"), f"{where}: frames")
    frames = tuple(_parse_frame(chk, f, index, k, names) for k, f in enumerate(raw_frames))
    has_off = any(not f.lasers_on for f in frames)
    has_on = any(f.lasers_on for f in frames)
    if not (has_off and has_on):
        lacking = "with no laser on" if has_on else "with lasers on" if has_off else "at all"
        chk.fail(f"{where}: frames", f"needs a frame with no laser on and one with lasers on "
                 f"(has no frame {lacking})")
    truth = chk.optional(entry, "truth", f"{where}: truth", "table")
    return ZoneRecord(index, pan, tilt, frames, dict(truth) if truth is not None else None)


def read_recording(path: str | Path, check_images: bool = True) -> Recording:
    """Read and check the recording in folder `path` (a path to its sweep.json works too).

    With `check_images`, every frame's PNG header is read to check that it exists and matches the
    camera; pixels are decoded only by :meth:`Recording.load_image`.
    """
    folder = Path(path)
    if folder.name == SWEEP_JSON and folder.is_file():
        folder = folder.parent
    if not folder.is_dir():
        raise RecordingError(
            f"{folder}: no such folder" if not folder.exists()
            else f"{folder}: not a folder (a recording is a folder holding {SWEEP_JSON})"
        )
    sweep = folder / SWEEP_JSON
    if not sweep.is_file():
        raise RecordingError(f"{folder}: no {SWEEP_JSON} in this folder")
    chk = _Checker(str(sweep))
    try:
        doc = json.loads(sweep.read_bytes())
    except OSError as exc:
        chk.fail("", f"cannot be read ({exc.strerror})")
    except json.JSONDecodeError as exc:
        chk.fail("", f"not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})")
    except UnicodeDecodeError:
        chk.fail("", "not valid JSON (not UTF-8 text)")
    except RecursionError:
        chk.fail("", "not usable JSON (nested too deeply)")
    except ValueError as exc:  # a whole number of more digits than Python converts
        chk.fail("", f"not usable JSON ({str(exc).splitlines()[0]})")
    if not isinstance(doc, dict):
        chk.fail("", f"expected a JSON object, got {describe(doc, 'an object')}")
    fmt = chk.string(chk.get(doc, "format", "format"), "format")
    if fmt != FORMAT:
        chk.fail("format", f"expected {FORMAT!r}, got {fmt!r}")
    created = chk.optional(doc, "created", "created", "string")
    device = chk.optional(doc, "device", "device", "string")
    rig = rig_from_json(doc, str(sweep))

    zones: list[ZoneRecord] = []
    seen: dict[int, int] = {}
    for position, raw in enumerate(chk.array(chk.get(doc, "zones", "zones"), "zones")):
        zone = _parse_zone(chk, raw, position, rig.laser_names)
        if zone.index in seen:
            chk.fail(f"zone {zone.index}: index",
                     f"duplicate zone index (zones[{seen[zone.index]}] and zones[{position}])")
        seen[zone.index] = position
        zones.append(zone)
        for frame in zone.frames:
            # Even without check_images a frame may not point outside the folder or be missing.
            fail = chk.at(_frame_where(zone.index, frame.file))
            file = _frame_path(folder, frame.file, fail)
            if check_images:
                _check_png_header(file, rig.camera, fail)
    return Recording(folder, rig, tuple(zones), created, device)


# --------------------------------------------------------------------------------------------------
# Writing


def _is_recording(path: Path) -> bool:
    try:
        return json.loads((path / SWEEP_JSON).read_bytes()).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems cannot sync a directory; the data files are synced regardless
    finally:
        os.close(fd)


def _jsonable(value: Any) -> Any:
    """json.dumps hook: numpy scalars and arrays as plain JSON."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def _no_recording_at(path: Path) -> bool:
    """True when nothing, or only an empty folder, is at `path`."""
    if not os.path.lexists(path):
        return True
    try:
        return path.is_dir() and not path.is_symlink() and not any(path.iterdir())
    except OSError:
        return False


def _written_ns(path: Path) -> int:
    """When the recording in `path` was written (its sweep.json's mtime); 0 when unknown."""
    try:
        return (path / SWEEP_JSON).stat().st_mtime_ns
    except OSError:
        return 0


def _is_whole_recording(path: Path) -> bool:
    """Strictly checked, frames included: a half-deleted old recording must not come back."""
    try:
        read_recording(path)
    except (EdgeError, OSError, ValueError):
        return False
    return True


class RecordingWriter:
    """Write a recording atomically; use as a context manager::

        with RecordingWriter("rec", rig) as w:
            w.add_zone(0, 0.0, 0.0, [(off, [], {}), (on, ["center"], {"t_start_ns": 5})])

    sweep.json is written, and the folder renamed into place, only when the block ends without an
    exception; otherwise everything written is removed.
    """

    def __init__(self, path: str | Path, rig: Rig, device: str | None = None,
                 created: str | None = None):
        self.path = Path(path)
        self.rig = rig
        self.device = device
        self.created = created or datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
        absolute = Path(os.path.abspath(self.path))
        self._partial = absolute.with_name(f"{absolute.name}.partial-{os.getpid()}")
        self._old = absolute.with_name(f"{absolute.name}.old-{os.getpid()}")
        self._chk = _Checker(str(self.path / SWEEP_JSON))
        self._zones: list[dict[str, Any]] = []
        self._indices: set[int] = set()
        self._open = False
        self._check_target()  # refuse before anything is captured, not after

    def _check_target(self) -> None:
        p = self.path
        if not os.path.lexists(p) or (p.is_dir() and not p.is_symlink() and
                                      (not any(p.iterdir()) or _is_recording(p))):
            return
        what = ("a symbolic link" if p.is_symlink() else
                "a folder with other files in it" if p.is_dir() else "not a folder")
        raise RecordingError(f"{p}: refusing to replace it: it exists and is {what}, "
                             f"not an {FORMAT} recording")

    def __enter__(self) -> RecordingWriter:
        self._clean_leftovers()
        if self._partial.exists():  # left by a crashed process that had our pid
            shutil.rmtree(self._partial)
        (self._partial / "frames").mkdir(parents=True)
        self._open = True
        return self

    def _clean_leftovers(self) -> None:
        """Remove what killed writers of this recording left beside it; restore an orphaned old one.

        Why: a writer killed mid-write (SIGKILL, power cut) leaves ``<name>.partial-<pid>`` and
        ``<name>.old-<pid>`` behind. Readers never look at them, but on a device left alone for
        months they would fill the SD card. Only real folders of exactly those names whose process
        is gone (or is us, starting afresh) are touched; a live process may still be writing.
        Failing to clean up only logs a warning: it must never cost a recording.
        """
        target = Path(os.path.abspath(self.path))
        if not target.name:
            return  # the root folder: never a recording
        pattern = re.compile(re.escape(target.name) + r"\.(partial|old)-([1-9][0-9]*)")
        partials: list[Path] = []
        olds: list[Path] = []
        try:
            names = sorted(os.listdir(target.parent))
        except OSError as exc:
            log.warning("%s: cannot look for leftovers of killed writers: %s", target.parent, exc)
            return
        for name in names:
            match = pattern.fullmatch(name)
            if match is None:
                continue
            leftover = target.parent / name
            # A writer only ever leaves folders; a symbolic link or a file is someone else's.
            if os.path.islink(leftover) or not os.path.isdir(leftover):
                continue
            if process_alive(int(match.group(2))):
                continue
            (partials if match.group(1) == "partial" else olds).append(leftover)
        if (olds or partials) and _no_recording_at(target):
            # Killed between moving the old recording aside and renaming the new one in, or
            # between finishing a first recording and renaming it: the newest whole one goes in
            # place (a finished partial is newer than the old one it was to replace).
            whole = [p for p in olds + partials if p != self._partial and _is_whole_recording(p)]
            if whole:
                newest = max(whole, key=_written_ns)
                try:
                    os.rename(newest, target)
                except OSError as exc:
                    log.warning("%s: cannot restore the recording left by a killed writer "
                                "to %s: %s", newest, target, exc)
                else:
                    log.info("%s: restored the recording left by a killed writer to %s",
                             newest, target)
                    (olds if newest in olds else partials).remove(newest)
                    _fsync_dir(target.parent)
            if _no_recording_at(target):  # never delete the only copies
                olds = [p for p in olds if p not in whole]
                partials = [p for p in partials if p not in whole]
        for leftover in partials + olds:
            if leftover == self._partial:
                continue  # ours, removed by __enter__ as before
            try:
                shutil.rmtree(leftover)
            except OSError as exc:
                log.warning("%s: cannot remove the leftover of a killed writer: %s", leftover, exc)
            else:
                log.info("%s: removed the leftover of a killed writer", leftover)

    def add_zone(
        self,
        index: int,
        pan_deg: float,
        tilt_deg: float,
        frames: Sequence[tuple[np.ndarray, Sequence[str], Mapping[str, object]]],
        truth: Mapping[str, Any] | None = None,
    ) -> ZoneRecord:
        """Add one zone. Each frame is (image, lasers_on, extra keys) where image is uint8 or
        uint16, grey (H, W) or BGR (H, W, 3), of the camera's size, and the extra keys are
        sweep.json's optional frame keys (pan_deg, tilt_deg, t_start_ns, exposure_us,
        laser_switch_ns). Raises RecordingError when the zone would break the format."""
        if not self._open:
            raise RecordingError(f"{self.path}: add_zone outside the writer's with block")
        if isinstance(index, np.integer):
            index = int(index)
        index = self._chk.integer(index, f"zones[{len(self._zones)}]: index")
        entries, images = [], []
        for k, (image, lasers_on, *rest) in enumerate(frames):
            extras = dict(rest[0]) if rest else {}
            fail = self._chk.at(f"zone {index}, frames[{k}]")
            if {"file", "lasers_on"} & extras.keys():
                fail("extra keys may not set 'file' or 'lasers_on'")
            image = np.asarray(image)
            if image.dtype not in (np.uint8, np.uint16) or not (
                image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)
            ):
                fail(f"image must be uint8/uint16 (H, W) or (H, W, 3), got {image.dtype} "
                     f"{image.shape}")
            _check_size(image.shape[1], image.shape[0], self.rig.camera, fail)
            lasers_on = [str(name) for name in lasers_on]
            name = f"frames/z{index:03d}-{k}-{'on' if lasers_on else 'off'}.png"
            entries.append({"file": name, "lasers_on": lasers_on,
                            **{key: v for key, v in extras.items() if v is not None}})
            images.append(image)
        raw: dict[str, Any] = {"index": index, "pan_deg": pan_deg, "tilt_deg": tilt_deg,
                               "frames": entries}
        if truth is not None:
            raw["truth"] = truth
        try:  # through JSON and back, so that what we return is exactly what a reader will see
            raw = json.loads(json.dumps(raw, default=_jsonable, allow_nan=False))
        except (TypeError, ValueError) as exc:
            self._chk.fail(f"zone {index}", f"cannot be written as JSON ({exc})")
        zone = _parse_zone(self._chk, raw, len(self._zones), self.rig.laser_names)
        if index in self._indices:
            self._chk.fail(f"zone {index}: index", "duplicate zone index")
        for frame, image in zip(zone.frames, images):
            self._write_png(self._partial / frame.file, image, self._chk.at(
                _frame_where(index, frame.file)))
        self._indices.add(index)
        self._zones.append(raw)
        return zone

    @staticmethod
    def _write_png(path: Path, image: np.ndarray, fail: Any) -> None:
        try:
            ok = cv2.imwrite(str(path), image)
        except cv2.error as exc:
            fail(f"cannot write image ({str(exc).strip().splitlines()[-1]})")
        if not ok:
            fail("cannot write image")
        with open(path, "rb") as f:  # the frame must be on disk before sweep.json points at it
            os.fsync(f.fileno())

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> bool:
        self._open = False
        if exc_type is not None:
            shutil.rmtree(self._partial, ignore_errors=True)
            return False
        try:
            self._finish()
        except BaseException:
            shutil.rmtree(self._partial, ignore_errors=True)
            raise
        return False

    def _finish(self) -> None:
        doc: dict[str, Any] = {"format": FORMAT, "created": self.created}
        if self.device is not None:
            doc["device"] = self.device
        doc |= rig_to_json(self.rig)
        doc["zones"] = self._zones
        with open(self._partial / SWEEP_JSON, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1, allow_nan=False)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        _fsync_dir(self._partial / "frames")
        _fsync_dir(self._partial)
        self._check_target()  # the target may have changed while we were recording
        if os.path.lexists(self.path) and any(self.path.iterdir()):
            # An earlier recording: move it aside, so that at every instant `path` is either the
            # old recording or the new one, then delete it.
            if self._old.exists():
                shutil.rmtree(self._old)
            os.rename(self.path, self._old)
            try:
                os.rename(self._partial, self.path)
            except BaseException:
                os.rename(self._old, self.path)
                raise
            shutil.rmtree(self._old)
        else:
            if os.path.lexists(self.path):
                os.rmdir(self.path)
            os.rename(self._partial, self.path)
        _fsync_dir(self._partial.parent)
