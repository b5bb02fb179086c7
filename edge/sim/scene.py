"""Simulated scenes: the room the virtual rig looks at.

A scene is a room (a floor-plan polygon extruded to a height, with doorways), boxes standing in it
(desks, cabinets, cardboard boxes, a whiteboard as a thin box), movers (person-sized boxes walking
a path) and a dark outer shell that rays through doorways end on. :meth:`Scene.at` freezes it at an
instant as a :class:`~edge.sim.raycast.SceneGeometry` for casting rays.

World frame: x, y on the floor, z up, floor at z = 0; metres and degrees.

Scene files live in ``config/scenes/<name>.toml`` (``EDGE_SCENES`` overrides the folder)::

    name = "office"                 # required
    description = "..."             # optional, free text
    extends = "office"              # optional: start from another scene file in the same folder,
                                    # then apply this file: the lists doorways, boxes and movers are
                                    # appended, tables (device, materials) merged key by key,
                                    # anything else replaced
    height_m = 2.5                  # floor to ceiling
    outline_m = [[0, 0], [4, 0], [4, 3], [0, 3]]   # floor plan (world x, y): a simple polygon,
                                    # either winding; wall i runs from vertex i to vertex i+1
    wall_material = "paint-white"   # defaults: paint-white, carpet-grey, paint-white
    floor_material = "carpet-grey"
    ceiling_material = "paint-white"
    beyond_m = 15.0                 # the outer shell (material "beyond") lies this far outside the
                                    # room's bounding box, above, below and around

    [device]                        # the pan-tilt base: origin where its axes meet
    position_m = [2.0, 1.5, 1.0]    # inside the outline, between floor and ceiling, not in a box
    yaw_deg = 0.0                   # heading of base x, counter-clockwise from world x

    [[doorways]]                    # a gap in a wall from the floor up to its height
    wall = 1                        # outline edge index
    offset_m = 1.0                  # from the wall's start vertex to the near jamb
    width_m = 0.9
    height_m = 2.0                  # <= the room's height; a lintel fills the rest

    [[boxes]]                       # solid boxes: desks, cabinets, a whiteboard (a thin box)
    name = "desk"                   # optional label
    center_m = [1.0, 0.5]           # centre of the footprint
    size_m = [0.6, 0.4, 0.8]        # x, y extent before yaw, height; all > 0
    yaw_deg = 0.0
    base_m = 0.0                    # z of the bottom face (> 0: hanging, the bottom is a face too)
    material = "cardboard"

    [[movers]]                      # a person-sized box walking a path at constant speed
    name = "walker"                 # unique
    size_m = [0.45, 0.30, 1.75]     # width (across the walking direction), depth, height
    material = "person"
    speed_mps = 1.0                 # > 0
    start_s = 30.0                  # absent before; absent after the path's end unless loop
    path_m = [[3.0, -1.0], [2.0, 1.0], [0.5, 1.2]]   # >= 2 points, world x, y
    loop = false                    # true: walk back to the first point and around again
    pause_s = [0, 0, 0]             # optional: seconds standing at each point of path_m

    [materials.my-material]         # scene-local materials, added to the built-ins
    albedo = [0.5, 0.4, 0.3]        # (see edge.sim.materials.Material for the other keys)

Mistakes give a one-line :class:`~edge.errors.SceneError` naming the file and the dotted key.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edge.config_file import config_dir
from edge.errors import SceneError
from edge.rig import Pose, rot_z
from edge.schema import build, require, show
from edge.sim.materials import BUILTIN_MATERIALS, Material
from edge.sim.raycast import (
    Face,
    FaceSet,
    Hits,
    SceneGeometry,
    box_faces,
    footprint,
    points_in_polygon,
    polygon_area,
    polygon_self_intersects,
)

__all__ = [
    "Box", "DevicePlacement", "Doorway", "Hits", "Material", "Mover", "MOVER_KEY_BASE", "Scene",
    "SceneGeometry", "SceneSpec", "available_scenes", "load_scene", "scene_dir",
]

MOVER_KEY_BASE = 1_000_000  # face keys of mover i are MOVER_KEY_BASE·(i+1) + j: never static ones
_APPENDED_LISTS = ("doorways", "boxes", "movers")
_EPS_M = 1e-9

Segment = tuple[tuple[float, float], tuple[float, float]]


@dataclass(frozen=True)
class DevicePlacement:
    position_m: tuple[float, float, float]  # world position of the pan-tilt base origin
    yaw_deg: float = 0.0  # heading of base x in the world, counter-clockwise from world x


@dataclass(frozen=True)
class Doorway:
    wall: int
    offset_m: float
    width_m: float
    height_m: float = 2.0

    def __post_init__(self) -> None:
        require(self.offset_m >= 0, "offset_m", f"must be >= 0, got {self.offset_m}")
        require(self.width_m > 0, "width_m", f"must be positive, got {self.width_m}")
        require(self.height_m > 0, "height_m", f"must be positive, got {self.height_m}")


@dataclass(frozen=True)
class Box:
    center_m: tuple[float, float]
    size_m: tuple[float, float, float]
    yaw_deg: float = 0.0
    base_m: float = 0.0
    material: str = "cardboard"
    name: str = ""

    def __post_init__(self) -> None:
        for i, s in enumerate(self.size_m):
            require(s > 0, f"size_m[{i}]", f"must be positive, got {s}")
        require(self.base_m >= 0, "base_m", f"must be >= 0, got {self.base_m}")

    @property
    def pose(self) -> Pose:
        """Box frame (origin at the bottom face's centre) -> world."""
        return Pose(rot_z(math.radians(self.yaw_deg)), np.array([*self.center_m, self.base_m]))

    def footprint(self) -> np.ndarray:
        return footprint(self.pose, self.size_m[0], self.size_m[1])

    def contains(self, point: Sequence[float]) -> bool:
        local = self.pose.inverse().apply(np.asarray(point, dtype=np.float64))
        return bool(
            abs(local[0]) <= self.size_m[0] / 2
            and abs(local[1]) <= self.size_m[1] / 2
            and 0.0 <= local[2] <= self.size_m[2]
        )


@dataclass(frozen=True)
class Mover:
    name: str
    path_m: tuple[tuple[float, float], ...]
    size_m: tuple[float, float, float] = (0.45, 0.30, 1.75)  # width, depth, height
    material: str = "person"
    speed_mps: float = 1.0
    start_s: float = 0.0
    loop: bool = False
    # Seconds to stand at each waypoint (a person stops at a desk): one per point of path_m, or none.
    pause_s: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        require(bool(self.name.strip()), "name", "must not be empty")
        require(len(self.path_m) >= 2, "path_m", f"needs at least 2 points, got {len(self.path_m)}")
        for i in range(1, len(self.path_m)):
            same = self.path_m[i] == self.path_m[i - 1]
            require(not same, f"path_m[{i}]", "repeats the previous point")
        require(self.speed_mps > 0, "speed_mps", f"must be positive, got {self.speed_mps}")
        for i, s in enumerate(self.size_m):
            require(s > 0, f"size_m[{i}]", f"must be positive, got {s}")
        require(not self.pause_s or len(self.pause_s) == len(self.path_m), "pause_s",
                f"needs one value per point of path_m ({len(self.path_m)}), got {len(self.pause_s)}")
        for i, p in enumerate(self.pause_s):
            require(p >= 0 and math.isfinite(p), f"pause_s[{i}]", f"must be >= 0, got {p}")

    def _waypoints(self) -> np.ndarray:
        pts = np.array(self.path_m, dtype=np.float64)
        if self.loop and not np.array_equal(pts[0], pts[-1]):
            pts = np.vstack([pts, pts[:1]])
        return pts

    def _pauses(self, n: int) -> list[float]:
        """Standing time at each of the `n` waypoints (a loop's closing point stands nowhere extra)."""
        pauses = list(self.pause_s) or [0.0] * len(self.path_m)
        return (pauses + [0.0] * n)[:n]

    def _duration_s(self) -> float:
        pts = self._waypoints()
        length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
        return length / self.speed_mps + sum(self._pauses(len(pts)))

    @property
    def end_s(self) -> float:
        """When the mover leaves at the end of its path (inf when it loops)."""
        return math.inf if self.loop else self.start_s + self._duration_s()

    def pose_at(self, t_s: float) -> Pose | None:
        """Mover frame (x along the walking direction, origin on the floor) -> world; None while
        absent."""
        if t_s < self.start_s or t_s > self.end_s:
            return None
        pts = self._waypoints()
        seg = np.diff(pts, axis=0)
        lengths = np.linalg.norm(seg, axis=1)
        pauses = self._pauses(len(pts))
        tau = t_s - self.start_s
        if self.loop:
            tau %= self._duration_s()
        # Walk the timeline: stand at point i, then walk segment i.
        for i in range(len(seg)):
            heading = math.atan2(seg[i, 1], seg[i, 0])
            if tau <= pauses[i]:
                return Pose(rot_z(heading), np.array([pts[i, 0], pts[i, 1], 0.0]))
            tau -= pauses[i]
            walk = lengths[i] / self.speed_mps
            if tau <= walk:
                xy = pts[i] + seg[i] * (tau / walk)
                return Pose(rot_z(heading), np.array([xy[0], xy[1], 0.0]))
            tau -= walk
        heading = math.atan2(seg[-1, 1], seg[-1, 0])
        return Pose(rot_z(heading), np.array([pts[-1, 0], pts[-1, 1], 0.0]))


@dataclass(frozen=True)
class SceneSpec:
    """A scene file's content, checked for consistency (types by :func:`edge.schema.build`)."""

    name: str
    height_m: float
    outline_m: tuple[tuple[float, float], ...]
    device: DevicePlacement
    description: str = ""
    wall_material: str = "paint-white"
    floor_material: str = "carpet-grey"
    ceiling_material: str = "paint-white"
    beyond_m: float = 15.0
    doorways: tuple[Doorway, ...] = ()
    boxes: tuple[Box, ...] = ()
    movers: tuple[Mover, ...] = ()
    materials: Any = None  # {name: table}; the tables become Materials in Scene

    def __post_init__(self) -> None:
        require(bool(self.name.strip()), "name", "must not be empty")
        require(self.height_m > 0, "height_m", f"must be positive, got {self.height_m}")
        require(self.beyond_m > 0, "beyond_m", f"must be positive, got {self.beyond_m}")
        self._check_outline()
        self._check_doorways()
        for i, box in enumerate(self.boxes):
            top = box.base_m + box.size_m[2]
            require(
                top <= self.height_m + _EPS_M,
                f"boxes[{i}].size_m",
                f"the box reaches {top:g} m, above the ceiling at {self.height_m:g} m",
            )
        self._check_device()
        names = [m.name for m in self.movers]
        for i, name in enumerate(names):
            require(name not in names[:i], f"movers[{i}].name", f"duplicate mover name {name!r}")
        self._check_materials()

    def _check_outline(self) -> None:
        n = len(self.outline_m)
        require(n >= 3, "outline_m", f"needs at least 3 points, got {n}")
        require(
            not polygon_self_intersects(np.array(self.outline_m)),
            "outline_m",
            "the polygon intersects itself (or repeats a point)",
        )
        require(abs(polygon_area(np.array(self.outline_m))) > 1e-6, "outline_m", "has no area")

    def _check_doorways(self) -> None:
        n = len(self.outline_m)
        for i, door in enumerate(self.doorways):
            key = f"doorways[{i}]"
            require(
                0 <= door.wall < n,
                f"{key}.wall",
                f"must be an outline edge 0..{n - 1}, got {door.wall}",
            )
            length = wall_length(self.outline_m, door.wall)
            end = door.offset_m + door.width_m
            require(
                end <= length + _EPS_M,
                f"{key}.offset_m",
                f"the door spans {door.offset_m:g}..{end:g} m "
                f"but wall {door.wall} is {length:g} m long",
            )
            require(
                door.height_m <= self.height_m + _EPS_M,
                f"{key}.height_m",
                f"{door.height_m:g} m is higher than the room ({self.height_m:g} m)",
            )
            for j, other in enumerate(self.doorways[:i]):
                overlap = (
                    other.wall == door.wall
                    and door.offset_m < other.offset_m + other.width_m
                    and other.offset_m < end
                )
                require(not overlap, f"{key}.offset_m", f"overlaps doorways[{j}]")

    def _check_device(self) -> None:
        x, y, z = self.device.position_m
        require(
            bool(points_in_polygon(np.array([[x, y]]), np.array(self.outline_m))[0]),
            "device.position_m",
            f"({x:g}, {y:g}) is outside the room's outline",
        )
        require(
            0 < z < self.height_m,
            "device.position_m",
            f"z = {z:g} m must lie between the floor and the ceiling ({self.height_m:g} m)",
        )
        for i, box in enumerate(self.boxes):
            label = f" ({box.name})" if box.name else ""
            inside = box.contains((x, y, z))
            require(not inside, "device.position_m", f"is inside boxes[{i}]{label}")

    def _check_materials(self) -> None:
        local = self.materials if self.materials is not None else {}
        require(isinstance(local, Mapping), "materials", "expected a table of material tables")
        for name, table in local.items():
            require(isinstance(table, (Mapping, Material)), f"materials.{name}", "expected a table")
        known = sorted(set(BUILTIN_MATERIALS) | set(local))
        used = [
            ("wall_material", self.wall_material),
            ("floor_material", self.floor_material),
            ("ceiling_material", self.ceiling_material),
        ]
        used += [(f"boxes[{i}].material", b.material) for i, b in enumerate(self.boxes)]
        used += [(f"movers[{i}].material", m.material) for i, m in enumerate(self.movers)]
        for key, name in used:
            require(name in known, key, f"unknown material {name!r} (known: {', '.join(map(show, known))})")


def wall_length(outline: Sequence[Sequence[float]], wall: int) -> float:
    a, b = np.asarray(outline[wall], float), np.asarray(outline[(wall + 1) % len(outline)], float)
    return float(np.linalg.norm(b - a))


def _counter(start: int) -> Iterator[int]:
    while True:
        yield start
        start += 1


class Scene:
    """A room with boxes and movers; :meth:`at` gives the geometry at an instant."""

    def __init__(self, spec: SceneSpec, source: str = "<scene>"):
        self.spec = spec
        self.source = source
        self.materials: dict[str, Material] = dict(BUILTIN_MATERIALS)
        for name, table in (spec.materials or {}).items():
            if isinstance(table, Material):
                self.materials[name] = table
            else:
                self.materials[name] = build(
                    Material, {**table, "name": name}, source, f"materials.{name}", error=SceneError
                )
        self._static = SceneGeometry(FaceSet.build(self._static_faces()))
        self._mover_sets = [
            FaceSet.build(
                box_faces(
                    m.name, _counter(MOVER_KEY_BASE * (i + 1)), self.materials[m.material],
                    Pose.identity(), (m.size_m[1], m.size_m[0], m.size_m[2]), bottom=False,
                )
            )
            for i, m in enumerate(spec.movers)
        ]

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def description(self) -> str:
        return self.spec.description

    @property
    def height_m(self) -> float:
        return self.spec.height_m

    @property
    def device(self) -> DevicePlacement:
        return self.spec.device

    @property
    def movers(self) -> tuple[Mover, ...]:
        return self.spec.movers

    @property
    def outline(self) -> np.ndarray:
        """(K, 2) floor-plan polygon as written in the file."""
        return np.array(self.spec.outline_m, dtype=np.float64)

    def base_to_world(self) -> Pose:
        """Transform from the pan-tilt base frame to the world frame."""
        yaw = math.radians(self.device.yaw_deg)
        return Pose(rot_z(yaw), np.array(self.device.position_m, dtype=np.float64))

    @property
    def static(self) -> SceneGeometry:
        """The scene without its movers (what :meth:`at` gives while none is present)."""
        return self._static

    def mover_corners(self, t_s: float) -> list[np.ndarray]:
        """World corners (8, 3) of the box of each mover present at `t_s`."""
        out = []
        for m in self.movers:
            pose = m.pose_at(t_s)
            if pose is None:
                continue
            w, d, h = m.size_m
            local = np.array([[x, y, z] for x in (-d / 2, d / 2) for y in (-w / 2, w / 2) for z in (0.0, h)])
            out.append(pose.apply(local))
        return out

    def mover_poses(self, t_s: float) -> tuple:
        """Where each mover present at `t_s` is, as a hashable key: two instants with equal keys
        look the same (a person standing still), so a view patched for one serves the other."""
        out = []
        for i, m in enumerate(self.movers):
            pose = m.pose_at(t_s)
            if pose is not None:
                out.append((i, *np.round(pose.t, 9).tolist(), *np.round(pose.R.ravel(), 9).tolist()))
        return tuple(out)

    def movers_at(self, t_s: float) -> SceneGeometry | None:
        """Only the movers present at `t_s` (None when none is): what a cached view of the static
        scene needs casting again."""
        placed = [fs.moved(pose) for fs, m in zip(self._mover_sets, self.movers)
                  if (pose := m.pose_at(t_s)) is not None]
        return SceneGeometry(FaceSet.concat(placed)) if placed else None

    def at(self, t_s: float = 0.0) -> SceneGeometry:
        """The scene at time `t_s`: the cached static geometry plus the movers present."""
        placed = [
            fs.moved(pose)
            for fs, m in zip(self._mover_sets, self.movers)
            if (pose := m.pose_at(t_s)) is not None
        ]
        if not placed:
            return self._static
        return SceneGeometry(FaceSet.concat([self._static.faceset, *placed]))

    def floor_plan(self, t_s: float = 0.0) -> list[Segment]:
        """2D world segments that a horizontal scan at the device's height meets: walls without
        the doorway gaps, box outlines, movers present at `t_s`."""
        z = self.device.position_m[2]
        outline = self.outline
        segments: list[Segment] = []
        for wall, a in enumerate(outline):
            b = outline[(wall + 1) % len(outline)]
            length = float(np.linalg.norm(b - a))
            # A doorway is a gap at the scan height unless the scan passes over it (the lintel).
            gaps = [
                (d.offset_m, d.offset_m + d.width_m)
                for d in self.spec.doorways
                if d.wall == wall and d.height_m > z
            ]
            for s0, s1 in _solid_intervals(length, gaps):
                segments.append(_segment(a + (b - a) * (s0 / length), a + (b - a) * (s1 / length)))
        corners: list[np.ndarray] = [
            box.footprint()
            for box in self.spec.boxes
            if box.base_m <= z <= box.base_m + box.size_m[2]
        ]
        for m in self.movers:
            pose = m.pose_at(t_s)
            if pose is not None and z <= m.size_m[2]:
                corners.append(footprint(pose, m.size_m[1], m.size_m[0]))
        for c in corners:
            segments.extend(_segment(c[i], c[(i + 1) % 4]) for i in range(4))
        return segments

    def _static_faces(self) -> list[Face]:
        spec, mat = self.spec, self.materials
        keys = _counter(0)
        height = spec.height_m
        outline = self.outline
        wall_mat = mat[spec.wall_material]
        faces: list[Face] = []
        up = np.array([0.0, 0.0, 1.0])
        for wall, a in enumerate(outline):
            b = outline[(wall + 1) % len(outline)]
            length = float(np.linalg.norm(b - a))
            u = np.array([*(b - a) / length, 0.0])
            corner = np.array([a[0], a[1], 0.0])
            doors = [d for d in spec.doorways if d.wall == wall]
            gaps = [(d.offset_m, d.offset_m + d.width_m) for d in doors]
            # Every part of a wall shares the wall's plane coordinates: u from the start vertex.
            for j, (s0, s1) in enumerate(_solid_intervals(length, gaps)):
                poly = np.array([[s0, 0.0], [s1, 0.0], [s1, height], [s0, height]])
                name = f"wall {wall} part {j}"
                faces.append(Face(name, next(keys), wall_mat, corner, u, up, poly))
            for d in doors:
                if d.height_m < height - _EPS_M:
                    s0, s1 = d.offset_m, d.offset_m + d.width_m
                    poly = np.array([[s0, d.height_m], [s1, d.height_m], [s1, height], [s0, height]])
                    name = f"wall {wall} lintel"
                    faces.append(Face(name, next(keys), wall_mat, corner, u, up, poly))
        x, y = np.eye(3)[:2]
        faces.append(Face("floor", next(keys), mat[spec.floor_material], np.zeros(3), x, y, outline))
        faces.append(
            # Axes x, -y: the normal u × v points down, into the room.
            Face(
                "ceiling", next(keys), mat[spec.ceiling_material], np.array([0.0, 0.0, height]), x, -y,
                outline * [1, -1],
            )
        )
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        margin = spec.beyond_m
        shell = Pose(np.eye(3), np.array([*(lo + hi) / 2, -margin]))
        size = (*(hi - lo + 2 * margin), height + 2 * margin)
        faces += box_faces("beyond", keys, mat["beyond"], shell, size, bottom=True)
        for i, box in enumerate(spec.boxes):
            faces += box_faces(
                box.name or f"box {i}", keys, mat[box.material], box.pose, box.size_m,
                bottom=box.base_m > 0,
            )
        return faces


def _solid_intervals(
    length: float, gaps: Sequence[tuple[float, float]]
) -> list[tuple[float, float]]:
    """[0, length] minus the gaps, dropping slivers."""
    out, start = [], 0.0
    for g0, g1 in sorted(gaps):
        if g0 > start + _EPS_M:
            out.append((start, g0))
        start = max(start, g1)
    if length > start + _EPS_M:
        out.append((start, length))
    return out


def _segment(a: np.ndarray, b: np.ndarray) -> Segment:
    return ((float(a[0]), float(a[1])), (float(b[0]), float(b[1])))


# --- loading ------------------------------------------------------------------------------------


def scene_dir() -> Path:
    """The folder of scene files: ``$EDGE_SCENES``, else ``scenes/`` of the shipped configuration
    (:func:`edge.config_file.config_dir`)."""
    env = os.environ.get("EDGE_SCENES")
    return Path(env) if env else config_dir() / "scenes"


def available_scenes(search_dirs: Sequence[Path] | None = None) -> list[str]:
    dirs = (scene_dir(),) if search_dirs is None else search_dirs
    return sorted({p.stem for d in dirs for p in Path(d).glob("*.toml")})


def load_scene(name_or_path: str | Path, search_dirs: Sequence[Path] | None = None) -> Scene:
    """Load a scene by name (``"office"`` -> ``<dir>/office.toml``) or by a path ending .toml."""
    dirs = (scene_dir(),) if search_dirs is None else tuple(Path(d) for d in search_dirs)
    text = str(name_or_path)
    if text.endswith(".toml"):
        path = Path(text)
        if not _is_file(path):
            raise SceneError(f"{show(str(path))}: no such scene file")
    else:
        found = [Path(d) / f"{text}.toml" for d in dirs if _is_file(Path(d) / f"{text}.toml")]
        if not found:
            known = ", ".join(available_scenes(dirs)) or "none"
            where = ", ".join(str(d) for d in dirs)
            raise SceneError(f"unknown scene {text!r} (available: {known}; looked in {where})")
        path = found[0]
    source = str(path)
    spec = build(SceneSpec, _read_merged(path, ()), source, error=SceneError)
    return Scene(spec, source)


def _read_merged(path: Path, chain: tuple[Path, ...]) -> dict:
    """The file's table with its `extends` chain applied; each base is checked on its own first,
    so that a mistake there is reported against the file that holds it."""
    source = show(str(path))
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{source}: invalid TOML: {' '.join(str(exc).split())}") from None
    except OSError as exc:
        raise SceneError(f"{source}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise SceneError(f"{source}: not UTF-8 text") from None
    except RecursionError:
        raise SceneError(f"{source}: invalid TOML: nested too deeply") from None
    except ValueError as exc:  # a whole number of more digits than Python converts
        raise SceneError(f"{source}: invalid TOML: {str(exc).splitlines()[0]}") from None
    base_name = data.pop("extends", None)
    if base_name is None:
        return data
    if not isinstance(base_name, str):
        kind = type(base_name).__name__
        raise SceneError(f"{source}: extends: expected a scene name, got {kind}")
    base_path = path.parent / (base_name if base_name.endswith(".toml") else f"{base_name}.toml")
    if not _is_file(base_path):
        known = ", ".join(available_scenes([path.parent])) or "none"
        raise SceneError(
            f"{source}: extends: no scene {base_name!r} next to it (available: {known})"
        )
    here = path.resolve()
    if base_path.resolve() in (*chain, here):
        raise SceneError(f"{source}: extends: {base_name!r} leads back to this file (a cycle)")
    base = _read_merged(base_path, (*chain, here))
    Scene(build(SceneSpec, base, str(base_path), error=SceneError), str(base_path))
    return _merge(base, data)


def _merge(base: dict, child: dict) -> dict:
    out = dict(base)
    for key, value in child.items():
        old = out.get(key)
        if isinstance(old, dict) and isinstance(value, dict):
            out[key] = _merge(old, value)
        elif key in _APPENDED_LISTS and isinstance(old, list) and isinstance(value, list):
            out[key] = old + value
        else:
            out[key] = value
    return out


def _is_file(path: Path) -> bool:
    """Path.is_file, but a name too long for the file system is simply not a file."""
    try:
        return path.is_file()
    except OSError:
        return False
