"""Sweep recordings in format ``edge-sweep/1`` (``shared/spec/recording.md``): read and write.

A recording is a folder holding ``sweep.json`` (the rig and, per zone, the frames with and without
the lasers) and the frames as PNG files. Other tools write recordings too, so reading is strict:
sweep.json is described by dataclasses (:class:`SweepFile`, :class:`ZoneRecord`, ...) read by the
loader of :mod:`edge.schema`, and every broken rule is a :class:`RecordingError` with one line
naming the file, the zone, the frame, the key and the problem. Unknown keys are ignored at every
level so that the format can grow.

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
import os
import re
import shutil
import stat
import struct
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path, PurePosixPath
from typing import Annotated, Any, ClassVar, NoReturn

import cv2
import numpy as np

from edge.errors import EdgeError, RecordingError
from edge.fsutil import fsync_dir, output_problem, process_alive, read_small
from edge.hw.camera import lens_dioptres_problem
from edge.rig import CameraModel, Laser, Mount, Rig, Vec3
from edge.schema import Check, FieldError, Label, build, describe, fail, read_json, require, show
from edge.tone import require_gamma

FORMAT = "edge-sweep/1"
SWEEP_JSON = "sweep.json"
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

log = logging.getLogger(__name__)

Fail = Callable[[str], NoReturn]  # raises a RecordingError about one place in a recording


# --------------------------------------------------------------------------------------------------
# Checks of single values (run by the loader as it reads them, see edge.schema)


def format_is(expected: str) -> Check:
    """A check that a document's `format` is `expected`."""
    return lambda got: None if got == expected else f"expected {expected!r}, got {got!r}"


def _not_negative(index: int) -> str | None:
    return f"must not be negative, got {index}" if index < 0 else None


def _relative_problem(file: str) -> str | None:
    """Why `file` may not name a frame inside the recording, or None if it may."""
    if not file:
        return "must not be empty"
    # Windows forms too (\\server, C:): a recording may come from another system.
    if PurePosixPath(file).is_absolute() or file.startswith("\\") or file[1:2] == ":":
        return f"{show(file)} is absolute; frames must lie inside the recording folder"
    depth = 0
    for part in PurePosixPath(file).parts:
        depth += -1 if part == ".." else 0 if part == "." else 1
        if depth < 0:
            return f"{show(file)} leaves the recording folder; frames must lie inside it"
    return None


# --------------------------------------------------------------------------------------------------
# Data model: the values of sweep.json, read by edge.schema


@dataclass(frozen=True)
class FrameRecord:
    """One camera frame of a zone, as listed in sweep.json."""

    LABEL: ClassVar[Label] = Label("file", "frame {}")

    file: Annotated[str, _relative_problem]  # relative path inside the recording, as in sweep.json
    lasers_on: tuple[str, ...]  # empty: the background frame
    pan_deg: float | None = None  # set when the unit was nudged off the zone's pose for this frame
    tilt_deg: float | None = None
    t_start_ns: int | None = None  # exposure start, monotonic clock
    exposure_us: float | None = None
    laser_switch_ns: int | None = None  # when the lasers last changed state

    def __post_init__(self) -> None:
        for i, name in enumerate(self.lasers_on):
            require(name not in self.lasers_on[:i], "lasers_on", f"names laser {name!r} twice")


@dataclass(frozen=True)
class ZoneRecord:
    """One view direction and its frames."""

    LABEL: ClassVar[Label] = Label("index", "zone {}")

    index: Annotated[int, _not_negative]
    pan_deg: float
    tilt_deg: float
    frames: tuple[FrameRecord, ...]
    truth: dict[str, Any] | None = None  # raw JSON object, for scoring only; ranging never reads it

    def __post_init__(self) -> None:
        has_off, has_on = bool(self.off_frames), bool(self.on_frames)
        lacking = "with no laser on" if has_on else "with lasers on" if has_off else "at all"
        require(has_off and has_on, "frames", "needs a frame with no laser on and one with lasers "
                f"on (has no frame {lacking})")

    @property
    def off_frames(self) -> tuple[FrameRecord, ...]:
        """Frames taken with every laser off."""
        return tuple(f for f in self.frames if not f.lasers_on)

    @property
    def on_frames(self) -> tuple[FrameRecord, ...]:
        """Frames taken with at least one laser on."""
        return tuple(f for f in self.frames if f.lasers_on)

    def check_lasers(self, names: Sequence[str]) -> None:
        """Raise FieldError unless every laser a frame switches on is one of `names`."""
        for frame in self.frames:
            for name in frame.lasers_on:
                require(name in names, _frame_where(self.index, frame.file),
                        f"lasers_on names unknown laser {name!r} (lasers: {', '.join(map(show, names))})")


@dataclass(frozen=True)
class LaserKeys:
    """A laser as sweep.json and calibration files write it: its ray, no wiring."""

    name: str
    origin_m: Vec3
    direction: Vec3
    reference: bool = False

    def __post_init__(self) -> None:
        self.laser()  # Laser checks the name and the direction

    def laser(self) -> Laser:
        return Laser(name=self.name, origin_m=self.origin_m, direction=self.direction,
                     reference=self.reference)


def rig_of(camera: CameraModel, lasers: Sequence[LaserKeys], mount: Mount | None = None,
           range_limits_m: tuple[float, float] | None = None) -> Rig:
    """The Rig of a document's keys (raises FieldError: the laser names, the reference, the limits)."""
    extra: dict[str, Any] = {} if range_limits_m is None else {"range_limits_m": range_limits_m}
    return Rig(camera, tuple(k.laser() for k in lasers), mount or Mount(), **extra)


@dataclass(frozen=True, kw_only=True)
class SweepFile:
    """sweep.json as it is on disk (``shared/spec/recording.md``)."""

    format: Annotated[str, format_is(FORMAT)]
    created: str | None = None
    device: str | None = None
    camera: CameraModel
    lasers: tuple[LaserKeys, ...]
    mount: Mount | None = None
    range_limits_m: tuple[float, float] | None = None
    # edge's own key, beyond recording.md (which lets the format grow): the tone curve the frames
    # came through, value = light^(1/frame_gamma) (edge.tone); absent: not said (linear, or as the
    # replaying configuration's ranging.frame_gamma says).
    frame_gamma: float | None = None
    # Also edge's own: where a focus motor held the lens (dioptres; absent: no motor, or not said).
    # A calibration fitted from these frames holds for that position alone.
    lens_dioptres: Annotated[float, lens_dioptres_problem] | None = None
    zones: tuple[ZoneRecord, ...]

    def __post_init__(self) -> None:
        if self.frame_gamma is not None:
            require_gamma(self.frame_gamma, "frame_gamma")
        names = self.rig().laser_names
        seen: dict[int, int] = {}
        for position, zone in enumerate(self.zones):
            zone.check_lasers(names)
            require(zone.index not in seen, f"{_zone_where(zone.index)}: index",
                    f"duplicate zone index (zones[{seen.get(zone.index)}] and zones[{position}])")
            seen[zone.index] = position

    def rig(self) -> Rig:
        return rig_of(self.camera, self.lasers, self.mount, self.range_limits_m)


def timestamp() -> str:
    """Now, as the `created` key of edge's files says it (UTC, to the second)."""
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def load(cls: type[Any], data: Any, source: str, path: str = "",
         error: type[EdgeError] = RecordingError) -> Any:
    """`data`, a JSON object of an edge file format, as the dataclass `cls` (see edge.schema):
    unknown keys are ignored so that the formats can grow."""
    return build(cls, data, source, path, error, unknown_keys="ignore", table="an object")


@dataclass(frozen=True)
class Recording:
    """A recording read from disk; images are decoded on demand by :meth:`load_image`."""

    path: Path  # the recording folder
    rig: Rig
    zones: tuple[ZoneRecord, ...]
    created: str | None = None
    device: str | None = None
    frame_gamma: float | None = None  # the frames' tone curve, where the recording says it
    lens_dioptres: float | None = None  # where a focus motor held the lens, where the recording says it

    def load_image(self, zone: ZoneRecord, frame: FrameRecord) -> np.ndarray:
        """Decode one frame: uint8 or uint16, grey (H, W) or colour BGR (H, W, 3).

        Alpha is dropped. Raises RecordingError naming the zone and frame when the file is missing,
        cannot be decoded, is not 8/16-bit or its size differs from the camera's.
        """
        fail = _at(str(self.path / SWEEP_JSON), _frame_where(zone.index, frame.file))
        file = _frame_path(self.path, frame.file, fail)
        # The header first, always: a small PNG can claim 30000 x 30000 pixels (2.7 GB decoded),
        # and the file may have changed since read_recording looked.
        _check_png_header(file, self.rig.camera, fail)
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


def _zone_where(index: int) -> str:
    return ZoneRecord.LABEL.name(index)


def _frame_where(index: int, file: str) -> str:
    return f"{_zone_where(index)}, {FrameRecord.LABEL.name(file)}"


def _at(source: str, where: str) -> Fail:
    """A one-argument fail about `where` in `source`."""
    def fail_here(message: str) -> NoReturn:
        fail(RecordingError, source, where, message)
    return fail_here


# --------------------------------------------------------------------------------------------------
# Rig -> JSON


def camera_to_json(cam: CameraModel) -> dict[str, Any]:
    """A camera model as sweep.json's `camera`."""
    return {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
            "dist": list(cam.dist)}


def rig_to_json(rig: Rig) -> dict[str, Any]:
    """The rig as sweep.json's `camera`, `lasers`, `mount` and `range_limits_m` (GPIO pins, being
    hardware wiring rather than geometry, are not part of the format)."""
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
        "camera": camera_to_json(rig.camera),
        "lasers": lasers,
        "mount": {"origin_m": list(rig.mount.origin_m), "rpy_deg": list(rig.mount.rpy_deg)},
        "range_limits_m": list(rig.range_limits_m),
    }


# --------------------------------------------------------------------------------------------------
# Reading


def _frame_path(folder: Path, file: str, fail: Fail) -> Path:
    """The frame's file, checked to exist and to stay inside `folder` even through symlinks."""
    path = folder / file
    try:
        exists = path.is_file()
        inside = exists and path.resolve().is_relative_to(folder.resolve())
    except (OSError, RuntimeError) as exc:  # a name too long, a symlink loop
        fail(f"image is unreadable ({show(str(getattr(exc, 'strerror', None) or exc))})")
    if not exists:
        fail(f"image is missing (no file {show(str(path))})")
    if not inside:
        fail("file: resolves outside the recording folder (through a symbolic link)")
    return path


def _check_size(width: int, height: int, camera: CameraModel, fail: Fail) -> None:
    if (width, height) != (camera.width, camera.height):
        fail(f"image is {width}x{height} but the camera is {camera.width}x{camera.height}")


def _check_png_header(path: Path, camera: CameraModel, fail: Fail) -> None:
    """Check a PNG's size and bit depth from its IHDR chunk, without decoding the pixels."""
    try:
        # Not blocking: a FIFO put there after _frame_path looked must not hang us.
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                fail("image is unreadable: not a regular file")
            head = os.read(fd, 33)
        finally:
            os.close(fd)
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


def read_recording(path: str | Path, check_images: bool = True) -> Recording:
    """Read and check the recording in folder `path` (a path to its sweep.json works too).

    With `check_images`, every frame's PNG header is read to check that it exists and matches the
    camera; pixels are decoded only by :meth:`Recording.load_image`.
    """
    folder = Path(path)
    if folder.name == SWEEP_JSON and folder.is_file():
        folder = folder.parent
    if not folder.is_dir():
        fail(RecordingError, str(folder), "", "no such folder" if not folder.exists()
             else f"not a folder (a recording is a folder holding {SWEEP_JSON})")
    sweep = folder / SWEEP_JSON
    if not sweep.is_file():
        fail(RecordingError, str(folder), "", f"no {SWEEP_JSON} in this folder")
    raw = read_json(sweep, RecordingError)
    if not isinstance(raw, dict):
        fail(RecordingError, str(sweep), "", f"expected a JSON object, got {describe(raw, 'an object')}")
    doc: SweepFile = load(SweepFile, raw, str(sweep))
    rig = doc.rig()
    for zone in doc.zones:
        for frame in zone.frames:
            # Even without check_images a frame may not point outside the folder or be missing.
            fail_here = _at(str(sweep), _frame_where(zone.index, frame.file))
            file = _frame_path(folder, frame.file, fail_here)
            if check_images:
                _check_png_header(file, rig.camera, fail_here)
    return Recording(folder, rig, doc.zones, doc.created, doc.device, doc.frame_gamma, doc.lens_dioptres)


# --------------------------------------------------------------------------------------------------
# Writing


def _is_recording(path: Path) -> bool:
    try:
        return json.loads(read_small(path / SWEEP_JSON)).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


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
                 created: str | None = None, frame_gamma: float = 1.0, lens_dioptres: float | None = None):
        self.path = Path(path)
        self.rig = rig
        self.device = device
        self.frame_gamma = frame_gamma  # the frames' tone curve: written where it is not linear
        self.lens_dioptres = lens_dioptres  # where a focus motor held the lens: written where there is one
        self.created = created or timestamp()
        absolute = Path(os.path.abspath(self.path))
        self._partial = absolute.with_name(f"{absolute.name}.partial-{os.getpid()}")
        self._old = absolute.with_name(f"{absolute.name}.old-{os.getpid()}")
        self._source = str(self.path / SWEEP_JSON)
        self._zones: list[dict[str, Any]] = []
        self._indices: set[int] = set()
        self._open = False
        self._check_target()  # refuse before anything is captured, not after

    def _check_target(self) -> None:
        p = self.path
        problem = output_problem(p, folder=True)
        if problem is not None and "not a folder" not in problem:  # a file: said below
            raise RecordingError(f"{show(str(p))}: refusing to write a recording there: {problem}")
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
                    try:
                        fsync_dir(target.parent)
                    except OSError as exc:
                        log.warning("%s: cannot sync the folder: %s", target.parent, exc)
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
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
            fail(RecordingError, self._source, f"zones[{len(self._zones)}]: index",
                 f"expected a whole number, got {describe(index, 'an object')}")
        index = int(index)
        entries, images = [], []
        for k, (image, lasers_on, *rest) in enumerate(frames):
            extras = dict(rest[0]) if rest else {}
            fail_here = _at(self._source, f"{_zone_where(index)}, frames[{k}]")
            if {"file", "lasers_on"} & extras.keys():
                fail_here("extra keys may not set 'file' or 'lasers_on'")
            image = np.asarray(image)
            if image.dtype not in (np.uint8, np.uint16) or not (
                image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)
            ):
                fail_here(f"image must be uint8/uint16 (H, W) or (H, W, 3), got {image.dtype} "
                          f"{image.shape}")
            _check_size(image.shape[1], image.shape[0], self.rig.camera, fail_here)
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
            fail(RecordingError, self._source, _zone_where(index), f"cannot be written as JSON ({exc})")
        zone: ZoneRecord = load(ZoneRecord, raw, self._source, f"zones[{len(self._zones)}]")
        try:
            zone.check_lasers(self.rig.laser_names)
        except FieldError as exc:
            fail(RecordingError, self._source, exc.key, exc.message)
        if index in self._indices:
            fail(RecordingError, self._source, f"{_zone_where(index)}: index", "duplicate zone index")
        for frame, image in zip(zone.frames, images):
            self._write_png(self._partial / frame.file, image,
                            _at(self._source, _frame_where(index, frame.file)))
        self._indices.add(index)
        self._zones.append(raw)
        return zone

    @staticmethod
    def _write_png(path: Path, image: np.ndarray, fail_here: Fail) -> None:
        try:
            ok = cv2.imwrite(str(path), image)
        except cv2.error as exc:
            fail_here(f"cannot write image ({str(exc).strip().splitlines()[-1]})")
        if not ok:
            fail_here("cannot write image")
        with open(path, "rb") as f:  # the frame must be on disk before sweep.json points at it
            os.fsync(f.fileno())

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self._open = False
        if exc_type is not None:
            shutil.rmtree(self._partial, ignore_errors=True)
            return
        try:
            self._finish()
        except BaseException:
            shutil.rmtree(self._partial, ignore_errors=True)
            raise

    def _finish(self) -> None:
        doc: dict[str, Any] = {"format": FORMAT, "created": self.created}
        if self.device is not None:
            doc["device"] = self.device
        doc |= rig_to_json(self.rig)
        if self.frame_gamma != 1.0:
            doc["frame_gamma"] = self.frame_gamma
        if self.lens_dioptres is not None:
            doc["lens_dioptres"] = self.lens_dioptres
        doc["zones"] = self._zones
        with open(self._partial / SWEEP_JSON, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1, allow_nan=False)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        fsync_dir(self._partial / "frames")
        fsync_dir(self._partial)
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
        fsync_dir(self._partial.parent)
