"""The 3D point cloud of sweeps: each ok zone's point in the base frame, its surface normal and σ,
as a binary PLY (read by CloudCompare, MeshLab, Open3D, plyfile).

Pure: zone results and the rig in, arrays and bytes out.

Normals: a rig whose lasers are not coplanar measures one per zone (``ZoneResult.normal``); the
thesis rig's three lasers lie in one plane and measure none. Then the normal is estimated
(`edge.normals`) from the zone's neighbours on the scan's pan/tilt lattice — the zones next to it
in pan at its tilt level, the zone at its pan one level up and one level down and their neighbours
in pan (on a lattice finer than 10°, also those 2, 4, 8 zones away within 10°) — and from the other
lasers' spots of the zone and of those neighbours (the thesis rig's sloped laser meets a wall about
0.18 × range below the reference's: a layer between two tilt levels). Nearest neighbours by
distance will not do: with tilt levels 20° apart, a point's nearest ones all lie in its own row, on
one line, and any plane through that line fits them.

A neighbour whose range differs from the point's by more than a surface seen 60° from its normal
would make it differ is across a depth edge and left out. Of the rest, windows on each side of the
point that can show a bend (three layers across the row and up the column) are fitted, weighted by
1/σ², and a normal is given where those whose residuals σ accounts for agree: at a crease or a depth
edge the window across it fails and the one on the point's side holds, so the scan's top and bottom
rows and points by a crease get one from one side. The zone's own spots, which the ranging fused
onto its surface, are in every window; where they make a side's second layer (the bottom row's
floor under a wall: its row and its sloped laser's spots) two layers do, at a floor's or a wall's
slope. Where none holds — a side of two layers otherwise, a neighbour on one side only, corners,
thin things, surfaces seen edge-on — the normal is (0, 0, 0), which PLY readers take as "no
normal". Denser tilt levels leave fewer such points.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge.normals import Support, estimate_normals
from edge.ranging import OK, ZoneResult
from edge.rig import Rig

# Tilts closer than this are one level (the unit reaches a pose to within a position or two).
_LEVEL_TOL_DEG = 0.5
# Zones of a level are next to each other in pan when at most this many pan steps apart (a zone
# without a point between two makes them not next to each other).
_GAP_STEPS = 1.5
# Neighbours reach this far in pan and tilt on a lattice finer than it (at least the next zone).
_REACH_DEG = 10.0
# A surface seen more obliquely than this from its normal is taken for a depth edge.
_GRAZING_DEG = 60.0


@dataclass(frozen=True)
class Cloud:
    """N points: `points` (N, 3) base frame, `normals` (N, 3) unit or zero, `sigma` (N,) metres."""

    points: np.ndarray
    normals: np.ndarray
    sigma: np.ndarray

    @staticmethod
    def empty() -> Cloud:
        return Cloud(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))

    def __len__(self) -> int:
        return len(self.points)

    @staticmethod
    def concat(clouds: Sequence[Cloud]) -> Cloud:
        if not clouds:
            return Cloud.empty()
        return Cloud(np.concatenate([c.points for c in clouds]), np.concatenate([c.normals for c in clouds]),
                     np.concatenate([c.sigma for c in clouds]))


def scan_cloud(rig: Rig, results: Sequence[ZoneResult]) -> Cloud:
    """The ok zones of one scan (one sweep, any number of tilts) as a cloud with normals."""
    ok = [r for r in results if r.status == OK and r.point_base_m is not None]
    if not ok:
        return Cloud.empty()
    points = np.array([r.point_base_m for r in ok], np.float64)
    sigma = np.array([r.sigma_m or 0.0 for r in ok], np.float64)
    poses = [rig.camera_to_base(r.pan_deg, r.tilt_deg) for r in ok]
    origins = np.array([pose.apply(rig.reference.o) for pose in poses])
    neighbours = lattice_neighbours([r.pan_deg for r in ok], [r.tilt_deg for r in ok],
                                    [(r.pan_deg, r.tilt_deg) for r in results])
    # Each zone's other lasers' spots (by their depth): they add layers between the tilt levels (the
    # thesis rig's sloped laser meets a wall about 0.18 × range below the reference's).
    spots: list[list[tuple[str, np.ndarray, float]]] = []
    for i, r in enumerate(ok):
        spots.append([])
        for name, m in r.lasers.items():
            if name == rig.reference.name or name not in rig.laser_names or not m.depth_m:
                continue
            laser = rig.laser(name)
            if abs(laser.d[2]) < 1e-6:
                continue
            # A spot whose σ a file did not give is taken to be as uncertain as the zone's range (a
            # σ of nothing would fail every plane through it).
            spots[i].append((name, poses[i].apply(laser.point_at_depth(m.depth_m)), float(m.sigma_m or sigma[i])))
    supports = []
    for i in range(len(ok)):
        own = [Support(q, s, 0, name, True) for name, q, s in spots[i]
               if not depth_edge(points[i], origins[i], q, origins[i])]
        rings = _rings(i, neighbours[i], [r.pan_deg for r in ok])
        for (k, level, column), ring in zip(neighbours[i], rings):
            if depth_edge(points[i], origins[i], points[k], origins[k]):
                continue
            own.append(Support(points[k], float(sigma[k]), level, None, column, ring))
            own += [Support(q, s, level, name, column, ring) for name, q, s in spots[k]
                    if not depth_edge(points[i], origins[i], q, origins[k])]
        supports.append(own)
    ups = np.array([_up(r.pan_deg, r.tilt_deg) for r in ok])
    estimated = estimate_normals(points, sigma, origins, ups, supports)
    normals = np.zeros_like(points)
    for i, r in enumerate(ok):
        if r.normal is not None:  # measured by the lasers: camera frame to base frame
            normals[i] = poses[i].rotate(np.asarray(r.normal, np.float64))
        else:
            normals[i] = estimated[i]
    return Cloud(points, normals, sigma)


def _rings(i: int, neighbours: Sequence[tuple[int, int, bool]], pans: Sequence[float]) -> list[int]:
    """How many lattice steps away each of zone i's neighbours is: beside it in its row, the
    nearest on each side 1, the next 2, …; straight up or down, the nearest level 1, the next 2,
    …; the zones beside those one level away, 1."""
    out = []
    for k, level, column in neighbours:
        if level == 0:
            d = float(_wrap(pans[k] - pans[i]))
            out.append(1 + sum(1 for j, lv, _ in neighbours if lv == 0 and
                               0 < float(_wrap(pans[j] - pans[i])) * np.sign(d) < abs(d)))
        elif column:
            out.append(1 + sum(1 for _, lv, col in neighbours if col and 0 < lv * np.sign(level) < abs(level)))
        else:
            out.append(1)
    return out


def _up(pan_deg: float, tilt_deg: float) -> np.ndarray:
    """The unit vector in which a point moves as the tilt rises (base frame)."""
    p, t = math.radians(pan_deg), math.radians(tilt_deg)
    return np.array([-math.sin(t) * math.cos(p), -math.sin(t) * math.sin(p), math.cos(t)])


def depth_edge(p: np.ndarray, o: np.ndarray, q: np.ndarray, o_q: np.ndarray) -> bool:
    """Whether points `p` and `q`, seen along beams from `o` and `o_q`, lie across a depth edge:
    their ranges differ more than a plane seen at _GRAZING_DEG from its normal would make them
    differ (two zones 5.6° apart in pan at 2 m: more than 0.34 m)."""
    a, b = p - o, q - o_q
    ra, rb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    angle = math.acos(float(np.clip(a @ b / max(ra * rb, 1e-12), -1.0, 1.0)))
    return abs(ra - rb) > math.tan(math.radians(_GRAZING_DEG)) * angle * 0.5 * (ra + rb)


def _wrap(a: np.ndarray | float) -> np.ndarray:
    return (np.asarray(a, np.float64) + 180.0) % 360.0 - 180.0


def lattice_neighbours(pans_deg: Sequence[float], tilts_deg: Sequence[float],
                       all_poses: Sequence[tuple[float, float]] = ()) -> list[list[tuple[int, int, bool]]]:
    """Each zone's neighbours on the scan's pan/tilt lattice, as (zone, level, column): the zones
    beside it in pan at its own tilt level (level 0); at the levels just above and below (+1, −1),
    the zone nearest in pan (within half a pan step; column True) and that zone's own neighbours
    in pan; and further up and down (±2, ±4, …; column True) the zones nearest in pan while within
    _REACH_DEG of its tilt. Beside means the next zone in pan, and on a lattice finer than
    _REACH_DEG those 2, 4, … steps away within it. `all_poses`, the (pan, tilt) of every zone of the scan whether it
    has a point or not, set the levels and steps: zones with a pointless one between them are not
    neighbours, and a column stops at a level without a zone there."""
    pans, tilts = _wrap(np.asarray(pans_deg, np.float64)), np.asarray(tilts_deg, np.float64)
    every = np.array(all_poses, np.float64).reshape(-1, 2) if len(all_poses) else np.stack([pans, tilts], 1)
    every = every if len(every) else np.zeros((0, 2))
    # Tilt levels: clusters of tilt values.
    values = np.sort(np.concatenate([every[:, 1], tilts]))
    levels: list[float] = []
    for t in values:
        if not levels or t - levels[-1] > _LEVEL_TOL_DEG:
            levels.append(float(t))
    level_of = lambda t: int(np.searchsorted(np.array(levels) + _LEVEL_TOL_DEG, t))  # noqa: E731

    # Per level: the zones with points, the pans of those without, and the pan step.
    nlev = len(levels)
    lev = [level_of(t) for t in tilts]
    members: list[list[int]] = [[] for _ in range(nlev)]
    for i, k in enumerate(lev):
        members[k].append(i)
    pointed = {(float(p), float(t)) for p, t in zip(pans_deg, tilts_deg)}
    missing: list[list[float]] = [[] for _ in range(nlev)]
    for p, t in every:
        if (float(p), float(t)) not in pointed:
            missing[level_of(t)].append(float(_wrap(p)))
    steps = []
    for k in range(nlev):
        row = np.unique(np.round(np.concatenate([pans[members[k]], missing[k]]), 6))
        gaps = np.diff(row)
        gaps = gaps[gaps > 1e-6]
        steps.append(float(np.median(gaps)) if len(gaps) else 360.0)

    def gap_between(k: int, a: float, b: float) -> bool:
        """Whether level k has a pointless zone strictly between pans a and b (up from a)."""
        span = float(_wrap(b - a)) % 360.0
        rel = (np.array(missing[k]) - a) % 360.0
        return bool(np.any((rel > 1e-6) & (rel < span - 1e-6)))

    def beside(i: int) -> list[int]:
        k = lev[i]
        reach = max(_GAP_STEPS * steps[k], _REACH_DEG)
        out = []
        for j in members[k]:
            d = float(_wrap(pans[j] - pans[i]))
            if j != i and 1e-6 < abs(d) <= reach and _power_of_two(round(abs(d) / steps[k])):
                a, b = (pans[i], pans[j]) if d > 0 else (pans[j], pans[i])
                if not gap_between(k, a, b):
                    out.append(j)
        return out

    def nearest(i: int, k: int) -> int | None:
        if not 0 <= k < nlev or not members[k]:
            return None
        cand = np.array(members[k])
        d = np.abs(_wrap(pans[cand] - pans[i]))
        j = int(np.argmin(d))
        return int(cand[j]) if d[j] <= 0.5 * max(steps[k], steps[lev[i]]) + 1e-6 else None

    out: list[list[tuple[int, int, bool]]] = []
    for i in range(len(pans)):
        k = lev[i]
        nb = [(j, 0, False) for j in beside(i)]
        for side in (-1, 1):
            j = nearest(i, k + side)
            if j is None:
                continue
            diagonal = [d for d in beside(j) if abs(_wrap(pans[d] - pans[j])) < _GAP_STEPS * steps[k + side]]
            nb += [(j, side, True)] + [(d, side, False) for d in diagonal]
            m = 2
            while 0 <= k + side * m < nlev and abs(levels[k + side * m] - levels[k]) <= _REACH_DEG:
                j = nearest(i, k + side * m)
                if j is None:
                    break
                if _power_of_two(m):
                    nb.append((j, side * m, True))
                m += 1
        out.append(nb)
    return out


def _power_of_two(n: int) -> bool:
    """1, 2, 4, 8, …: the neighbours taken on a fine lattice (all of them would cost much and add
    little)."""
    return n >= 1 and n & (n - 1) == 0


def ply_bytes(cloud: Cloud, comment: str = "") -> bytes:
    """The cloud as a binary little-endian PLY: float x y z (base frame, m), nx ny nz, sigma (m)."""
    header = ["ply", "format binary_little_endian 1.0",
              "comment edge point cloud: base frame of the pan-tilt unit (x forward, y left, z up), metres",
              "comment sigma: 1-sigma range uncertainty of each point; a zero normal means none"]
    if comment:
        header.append("comment " + " ".join(comment.split()))
    header += [f"element vertex {len(cloud)}"]
    header += [f"property float {name}" for name in ("x", "y", "z", "nx", "ny", "nz", "sigma")]
    header.append("end_header")
    data = np.zeros(len(cloud), dtype=[(k, "<f4") for k in ("x", "y", "z", "nx", "ny", "nz", "sigma")])
    for k, name in enumerate("xyz"):
        data[name] = cloud.points[:, k]
        data["n" + name] = cloud.normals[:, k]
    data["sigma"] = cloud.sigma
    return ("\n".join(header) + "\n").encode("ascii") + data.tobytes()
