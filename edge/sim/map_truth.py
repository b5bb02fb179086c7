"""Maps against the simulator's truth: how right an occupancy grid and a point cloud are.

The recordings' `truth` of each zone (the reference laser's true hit, base frame) and the scene's
floor plan say where the surfaces are; this module counts, for the grid (issue 18's targets):

- of the cells marked occupied, those within one cell of a true surface;
- of the cells holding a true surface point that a ray hit (within the working range and the
  grid's band), those marked occupied;
- of the cells along the rays up to 80 % of their true hit distance (and within the working
  range, beyond which the grid never claims anything), those marked free;

and for a cloud, the points' error against their true points relative to range, and the angle of
their normals from the true surfaces' (walls and floor).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge.grid import OccupancyGrid
from edge.mapping import room_in_base_frame
from edge.ranging import OK, ZoneResult
from edge.rig import Rig
from edge.sim.scene import Scene


@dataclass(frozen=True)
class GridScore:
    occupied: int
    occupied_near_surface: float  # fraction of occupied cells within one cell of a true surface
    surface_cells: int
    surface_cells_occupied: float  # fraction of true hit cells marked occupied (every ray)
    surface_cells_ok: int
    surface_cells_ok_occupied: float  # the same over the cells of rays that ranged (status ok)
    ray_cells: int
    ray_cells_free: float  # fraction of cells along rays to 80 % of their true hit marked free

    def lines(self) -> list[str]:
        return [
            f"occupied cells within one cell of a true surface: {100 * self.occupied_near_surface:.1f} % "
            f"of {self.occupied} (target >= 95 %)",
            f"true surface cells hit by a ray marked occupied: {100 * self.surface_cells_occupied:.1f} % "
            f"of {self.surface_cells} (target >= 95 %); of those whose ray ranged: "
            f"{100 * self.surface_cells_ok_occupied:.1f} % of {self.surface_cells_ok}",
            f"cells along rays up to 80 % of the true hit marked free: {100 * self.ray_cells_free:.1f} % "
            f"of {self.ray_cells} (target >= 98 %)",
        ]


def _mask_of_segments(grid: OccupancyGrid, segments: Sequence, step: float) -> np.ndarray:
    mask = np.zeros(grid.log_odds.shape, bool)
    for a, b in segments:
        a, b = np.asarray(a, float), np.asarray(b, float)
        n = max(2, int(math.ceil(np.linalg.norm(b - a) / step)) + 1)
        p = a + np.linspace(0, 1, n)[:, None] * (b - a)
        _mark(grid, mask, p)
    return mask


def _mark(grid: OccupancyGrid, mask: np.ndarray, points: np.ndarray) -> None:
    ix, iy = grid.cell_of(points)
    inside = (ix >= 0) & (iy >= 0) & (ix < grid.size) & (iy < grid.size)
    mask[iy[inside], ix[inside]] = True


def _cells_at(grid: OccupancyGrid, p: np.ndarray, edge_m: float = 0.001) -> tuple:
    """The cells (ix, iy) whose square, widened by `edge_m`, holds the point `p`."""
    cells = set()
    for dx in (-edge_m, 0.0, edge_m):
        for dy in (-edge_m, 0.0, edge_m):
            ix, iy = grid.cell_of(np.array([p[0] + dx, p[1] + dy]))
            cells.add((int(ix), int(iy)))
    return tuple(sorted(cells))


def _dilate(mask: np.ndarray) -> np.ndarray:
    out = mask.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out |= np.roll(np.roll(mask, dy, axis=0), dx, axis=1)
    return out


def score_grid(grid: OccupancyGrid, scene: Scene, rig: Rig,
               scans: Sequence[tuple[Sequence[ZoneResult], Sequence[dict | None]]]) -> GridScore:
    """`scans`: per sweep, its zone results and each zone's truth (recording.md's `truth`)."""
    res = grid.resolution
    lo, hi = grid.config.band_m
    far = rig.range_limits_m[1]
    # True surfaces: the floor plan at the unit's height, and every true hit inside the band.
    surfaces = _mask_of_segments(grid, room_in_base_frame(scene.floor_plan(), scene.base_to_world()), res / 4)
    # The cells each true hit lies in; a point on a cell's edge (a wall a whole number of cells
    # from the unit) lies in both, and either being occupied counts.
    hit_cells: dict[tuple, bool] = {}
    along = np.zeros_like(surfaces)
    for results, truths in scans:
        for result, truth in zip(results, truths):
            point = (truth or {}).get("point_base_m")
            if point is None:
                continue
            p = np.asarray(point, float)
            origin = rig.camera_to_base(result.pan_deg, result.tilt_deg).apply(rig.reference.o)
            dist = float(np.linalg.norm(p - origin))
            in_band = lo <= p[2] <= hi
            if in_band:
                _mark(grid, surfaces, p[None])
                if truth and truth.get("range_m") is not None and truth["range_m"] <= far:
                    cells = _cells_at(grid, p)
                    hit_cells[cells] = hit_cells.get(cells, False) or result.status == OK
            reach = min(0.8 * dist, far)
            t = np.arange(0.0, reach, res / 4)
            q = origin + t[:, None] * (p - origin) / dist
            _mark(grid, along, q[(q[:, 2] >= lo) & (q[:, 2] <= hi)])
    occupied, free = grid.occupied(), grid.free()
    near = _dilate(surfaces)

    def frac(sel: np.ndarray, of: np.ndarray) -> float:
        return float((sel & of).sum() / of.sum()) if of.any() else float("nan")

    marked = {cells: any(occupied[iy, ix] for ix, iy in cells) for cells in hit_cells}
    ok_cells = [cells for cells, ok in hit_cells.items() if ok]
    return GridScore(
        int(occupied.sum()), frac(near, occupied),
        len(marked), float(np.mean(list(marked.values()))) if marked else float("nan"),
        len(ok_cells), float(np.mean([marked[c] for c in ok_cells])) if ok_cells else float("nan"),
        int(along.sum()), frac(free, along),
    )


@dataclass(frozen=True)
class CloudScore:
    points: int
    rms_rel: float  # RMS of |point − true point| / true range
    normals: int  # points on walls and floor with a normal
    surface_points: int  # points on walls and floor
    normal_rms_deg: float
    normal_p95_deg: float
    within_10deg: float

    def lines(self) -> list[str]:
        return [
            f"points: {self.points}; error against the true points, RMS {100 * self.rms_rel:.2f} % of range "
            f"(target <= 1 %)",
            f"normals on walls and floor: {self.normals} of {self.surface_points} points; angle from the true "
            f"normal RMS {self.normal_rms_deg:.1f}°, 95th percentile {self.normal_p95_deg:.1f}°, "
            f"{100 * self.within_10deg:.1f} % within 10°",
        ]


def on_wall_or_floor(scene: Scene, point_world: np.ndarray, tol: float = 0.01) -> bool:
    """Whether a world point lies on the room's floor or one of its walls (not a box)."""
    if abs(point_world[2]) <= tol:
        return True
    outline = scene.outline
    for k, a in enumerate(outline):
        b = outline[(k + 1) % len(outline)]
        ab = b - a
        s = float(np.clip((point_world[:2] - a) @ ab / (ab @ ab), 0, 1))
        if np.linalg.norm(point_world[:2] - (a + s * ab)) <= tol:
            return True
    return False


def score_cloud(points: np.ndarray, normals: np.ndarray, truths: Sequence[dict],
                true_normals: Sequence[np.ndarray | None], on_surface: Sequence[bool]) -> CloudScore:
    """`points`/`normals` (N, 3) base frame, with each point's truth, its surface's true normal (base
    frame) and whether that surface is a wall or the floor."""
    rel, angles, surface = [], [], 0
    for p, n, truth, tn, flat in zip(points, normals, truths, true_normals, on_surface):
        surface += bool(flat and tn is not None)
        tp = np.asarray(truth["point_base_m"], float)
        rel.append(float(np.linalg.norm(p - tp)) / float(truth["range_m"]))
        if flat and tn is not None and np.linalg.norm(n) > 0.5:
            angles.append(math.degrees(math.acos(float(np.clip(n @ tn, -1.0, 1.0)))))
    a = np.array(angles)
    return CloudScore(
        len(rel), float(np.sqrt(np.mean(np.square(rel)))) if rel else float("nan"),
        len(a), surface, float(np.sqrt(np.mean(a**2))) if a.size else float("nan"),
        float(np.percentile(a, 95)) if a.size else float("nan"),
        float(np.mean(a <= 10.0)) if a.size else float("nan"),
    )
