"""Maps on disk: the sweeps a map is made of read from their files, and the map's files written.

A map folder holds ``map.pgm`` + ``map.yaml`` (ROS map_server's occupancy grid), ``map.png`` (the
same grid for people) and ``cloud.ply`` (the points, their normals and σ). Sources are recordings
(``edge-sweep/1``, ranged again here) and the results that ``edge sweep``/``edge demo`` write
(``edge-ranges/1`` in ``sweep.json``). On the device, :class:`GridKeeper` keeps one grid across
sweeps and restarts in the state folder.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import numpy as np

from edge.cloud import Cloud, ply_bytes, scan_cloud
from edge.errors import RecordingError
from edge.fsutil import atomic_write_bytes, read_small
from edge.grid import (
    GridConfig,
    OccupancyGrid,
    Segment,
    grid_from_state,
    grid_picture,
    pgm_bytes,
    state_bytes,
    yaml_text,
)
from edge.ranging import OK, STATUSES, ZoneResult
from edge.recording import SWEEP_JSON, LaserKeys, format_is, load, rig_of
from edge.rig import CameraModel, Mount, Rig
from edge.schema import Label, fail, read_json, require
from edge.triangulation import LaserMeasurement

log = logging.getLogger(__name__)

RANGES_FORMAT = "edge-ranges/1"
MAP_FILES = ("map.pgm", "map.yaml", "map.png", "cloud.ply")
GRID_STATE = "grid.npz"
# Free room the kept map must leave on the card when it is saved: the outbox comes first.
SAVE_MARGIN_BYTES = 4 << 20


# --- edge-ranges/1, as edge sweep writes it -------------------------------------------------------


@dataclass(frozen=True)
class LaserDepth:
    depth_m: float | None = None
    sigma_m: float | None = None  # the spot's depth σ: the cloud's normals weigh the spot by it


@dataclass(frozen=True)
class ZoneKeys:
    """A zone result of an ``edge-ranges/1`` document (geometry.md's fields; the rest ignored)."""

    LABEL: ClassVar[Label] = Label("index", "zone {}")

    index: int
    pan_deg: float
    tilt_deg: float
    status: Literal["ok", "no_spot", "ambiguous", "out_of_range", "fault"]
    range_m: float | None = None
    sigma_m: float | None = None
    point_m: tuple[float, float, float] | None = None
    point_base_m: tuple[float, float, float] | None = None
    normal: tuple[float, float, float] | None = None
    lasers: dict[str, LaserDepth] | None = None

    def __post_init__(self) -> None:
        if self.status == OK:
            require(self.point_base_m is not None, "point_base_m", "an ok zone needs its point")
            require(self.sigma_m is None or self.sigma_m >= 0, "sigma_m", "must not be negative")

    def result(self) -> ZoneResult:
        def arr(v: tuple[float, ...] | None) -> np.ndarray | None:
            return None if v is None else np.array(v, np.float64)

        lasers = {name: LaserMeasurement(name, np.zeros(2), 0.0, np.zeros(3), m.depth_m, m.sigma_m or 0.0, 0.0, 0)
                  for name, m in (self.lasers or {}).items() if m.depth_m is not None}
        return ZoneResult(self.index, self.pan_deg, self.tilt_deg, self.status, self.range_m, self.sigma_m,
                          arr(self.point_m), arr(self.point_base_m), arr(self.normal), lasers)


@dataclass(frozen=True)
class RigKeys:
    camera: CameraModel
    lasers: tuple[LaserKeys, ...]
    mount: Mount | None = None
    range_limits_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        self.rig()

    def rig(self) -> Rig:
        return rig_of(self.camera, self.lasers, self.mount, self.range_limits_m)


@dataclass(frozen=True, kw_only=True)
class RangesFile:
    format: Annotated[str, format_is(RANGES_FORMAT)]
    rig: RigKeys | None = None  # edge sweep writes it; other writers may not
    zones: tuple[ZoneKeys, ...]


assert set(STATUSES) == {"ok", "no_spot", "ambiguous", "out_of_range", "fault"}


@dataclass
class Scan:
    """One sweep's results and the rig that ranged them."""

    source: str
    rig: Rig
    results: list[ZoneResult] = field(default_factory=list)


def read_scan(path: str | Path, default_rig: Rig, ranging: Any = None) -> Scan:
    """The sweep in `path`: a recording (folder or its sweep.json, ranged again with its rig) or
    an ``edge-ranges/1`` file (its own rig if it names one, else `default_rig`). RecordingError
    naming the file when it is neither."""
    p = Path(path)
    file = p / SWEEP_JSON if p.is_dir() else p
    if not p.exists():
        fail(RecordingError, str(p), "", "no such file or folder")
    if not file.is_file():
        fail(RecordingError, str(p), "", f"no {SWEEP_JSON} in this folder")
    doc = read_json(file, RecordingError)
    fmt = doc.get("format") if isinstance(doc, dict) else None
    if fmt == "edge-sweep/1":
        from edge.ranging import RangingConfig
        from edge.recording import read_recording
        from edge.replay import Replayer, ranging_for

        recording = read_recording(file.parent)
        replayer = Replayer(recording.rig, "triangulate", ranging_for(recording, ranging or RangingConfig()))
        return Scan(str(file), recording.rig, list(replayer.zones(recording)))
    if not isinstance(doc, dict):
        fail(RecordingError, str(file), "", "expected a JSON object")
    if fmt != RANGES_FORMAT:
        fail(RecordingError, str(file), "format", f"expected 'edge-sweep/1' (a recording) or "
             f"{RANGES_FORMAT!r} (results of edge sweep), got {fmt!r}")
    ranges: RangesFile = load(RangesFile, doc, str(file))
    rig = ranges.rig.rig() if ranges.rig is not None else default_rig
    return Scan(str(file), rig, [z.result() for z in ranges.zones])


# --- building and writing a map -------------------------------------------------------------------


def build_map(config: GridConfig, scans: Sequence[Scan]) -> tuple[OccupancyGrid, Cloud]:
    """The grid of all scans' rays (sized for the farthest-reaching rig) and their cloud (normals
    estimated within each scan, whose neighbours are its own)."""
    if not scans:
        raise ValueError("no scans")
    far = max(s.rig.range_limits_m[1] for s in scans)
    grid = OccupancyGrid(config, far * 1.05 + 2 * config.resolution_m)
    for scan in scans:
        grid.add_results(scan.rig, scan.results)
    return grid, Cloud.concat([scan_cloud(s.rig, s.results) for s in scans])


def map_png(grid: OccupancyGrid, cloud: Cloud | None = None, room: Sequence[Segment] = (), title: str = "") -> bytes:
    """The grid's picture for people, PNG-encoded (what the service publishes)."""
    import cv2

    lo, hi = grid.config.band_m
    points = [] if cloud is None else [p for p in cloud.points if lo <= p[2] <= hi]
    ok, buf = cv2.imencode(".png", grid_picture(grid, points, room, title))
    if not ok:
        raise RuntimeError("could not encode the map as PNG")
    return buf.tobytes()


def write_map(out: Path, grid: OccupancyGrid, cloud: Cloud, room: Sequence[Segment] = (), title: str = "") -> None:
    """map.pgm, map.yaml, map.png and cloud.ply in folder `out` (made if need be), each atomically."""
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / "map.pgm", pgm_bytes(grid))
    atomic_write_bytes(out / "map.yaml", yaml_text(grid, "map.pgm").encode())
    atomic_write_bytes(out / "map.png", map_png(grid, cloud, room, title))
    atomic_write_bytes(out / "cloud.ply", ply_bytes(cloud, title))


def doorways_m(grid: OccupancyGrid, rig: Rig, results: Sequence[ZoneResult]) -> dict[int, float]:
    """Zone index → where the room ends along its ray (horizontally from the pan axis), for the
    zones whose rays leave it through a doorway (see ``OccupancyGrid.doorway_m``)."""
    out = {}
    far = rig.range_limits_m[1]
    for r in results:
        pose = rig.camera_to_base(r.pan_deg, r.tilt_deg)
        origin, direction = pose.apply(rig.reference.o), pose.rotate(rig.reference.d)
        flat = float(np.hypot(direction[0], direction[1]))
        if flat < 0.5:  # looking steeply up or down: no doorway to look through
            continue
        end = grid.doorway_m(origin[:2], direction[:2], far * flat)
        if end is not None:
            out[r.index] = end + float(np.hypot(origin[0], origin[1]))
    return out


# --- the device's grid, kept across sweeps and restarts -------------------------------------------


class GridKeeper:
    """The service's grid: every complete sweep is fused into it and it is saved at once
    (atomically) as ``<state_dir>/grid.npz``, which the next start continues from. A saved grid
    of another resolution, size or band, or an unreadable one, is set aside and a new one begun."""

    def __init__(self, config: GridConfig, rig: Rig, state_dir: Path):
        self.config = config
        self.path = state_dir / GRID_STATE
        half = OccupancyGrid.for_rig(config, rig).half_size_m
        self.grid = OccupancyGrid(config, half)
        self.sweeps = 0
        self._short = False  # the last save was skipped for want of room
        if self.path.exists():
            try:
                self.grid = grid_from_state(config, read_small(self.path, 256 << 20), half)
                log.info("%s: continuing the map kept there", self.path)
            except (OSError, ValueError) as exc:
                log.warning("%s: cannot continue the map kept there (%s); starting a new one", self.path, exc)

    def add_sweep(self, rig: Rig, results: Sequence[ZoneResult]) -> None:
        self.grid.add_results(rig, results)
        self.sweeps += 1
        data = state_bytes(self.grid)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # On a nearly full card the outbox (alerts, sweeps not yet delivered) comes first: the
            # map is saved only while it leaves SAVE_MARGIN_BYTES free, and lives on in memory.
            stat = os.statvfs(self.path.parent)
            if stat.f_bavail * stat.f_frsize < len(data) + SAVE_MARGIN_BYTES:
                if not self._short:
                    log.warning("%s: not saving the map while the card is nearly full (the queue of "
                                "messages comes first); it is kept in memory", self.path)
                self._short = True
                return
            atomic_write_bytes(self.path, data)
            self._short = False
        except OSError as exc:  # a full card must not stop the device; the map lives on in memory
            log.warning("%s: cannot save the map: %s", self.path, exc)

    def outside_m(self, rig: Rig, results: Sequence[ZoneResult]) -> dict[int, float]:
        """For the guard (``Guard.update``'s `outside_m`): each zone whose ray leaves the room
        through a doorway (``OccupancyGrid.doorway_m``) and how far, horizontally, the room ends
        along it. Empty until the grid has walls to tell a doorway by."""
        return doorways_m(self.grid, rig, results)

    def png(self) -> bytes:
        """The map picture (what the service publishes after each sweep)."""
        return map_png(self.grid, title=f"{self.sweeps} sweeps since start")
