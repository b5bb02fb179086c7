"""The 3D point cloud of sweeps: each ok zone's point in the base frame, its surface normal and σ,
as a binary PLY (read by CloudCompare, MeshLab, Open3D, plyfile).

Pure: zone results and the rig in, arrays and bytes out.

Normals: a rig whose lasers are not coplanar measures one per zone (``ZoneResult.normal``); the
thesis rig's three lasers lie in one plane and measure none. Then the normal is estimated from the
neighbouring points of the same scan — the zones next to this one in pan and tilt — as the plane
that most of them lie on (so that at a wall's corner with the floor the plane of the point's own
surface wins, not a blend of both). Normals point towards the unit; a point without enough
neighbours on its plane gets (0, 0, 0), which PLY readers take as "no normal".
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge.ranging import OK, ZoneResult
from edge.rig import Rig

# Neighbours in view direction: this many nearest, within this many times the typical spacing.
_NEIGHBOURS = 8
_SPACING_FACTOR = 2.5


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


def view_direction(pan_deg: float, tilt_deg: float) -> np.ndarray:
    """Unit vector of the head's x axis (where the unit looks), base frame."""
    p, t = math.radians(pan_deg), math.radians(tilt_deg)
    return np.array([math.cos(t) * math.cos(p), math.cos(t) * math.sin(p), math.sin(t)])


def scan_cloud(rig: Rig, results: Sequence[ZoneResult]) -> Cloud:
    """The ok zones of one scan (one sweep, any number of tilts) as a cloud with normals."""
    ok = [r for r in results if r.status == OK and r.point_base_m is not None]
    if not ok:
        return Cloud.empty()
    points = np.array([r.point_base_m for r in ok], np.float64)
    sigma = np.array([r.sigma_m or 0.0 for r in ok], np.float64)
    normals = np.zeros_like(points)
    views = np.array([view_direction(r.pan_deg, r.tilt_deg) for r in ok])
    origins = np.array([rig.camera_to_base(r.pan_deg, r.tilt_deg).apply(rig.reference.o) for r in ok])
    estimated = estimate_normals(points, views, sigma, origins)
    for i, r in enumerate(ok):
        if r.normal is not None:  # measured by the lasers: camera frame to base frame
            normals[i] = rig.camera_to_base(r.pan_deg, r.tilt_deg).rotate(np.asarray(r.normal, np.float64))
        else:
            normals[i] = estimated[i]
    return Cloud(points, normals, sigma)


def estimate_normals(points: np.ndarray, views: np.ndarray, sigma: np.ndarray,
                     viewpoints: np.ndarray) -> np.ndarray:
    """Normals (N, 3) of points (N, 3) from their neighbours in view direction (`views`, unit
    (N, 3)): the plane through the point that most neighbours lie on, refitted to them, turned
    towards the point's `viewpoints` (N, 3). Zero where fewer than two neighbours agree."""
    n = len(points)
    out = np.zeros((n, 3))
    if n < 3:
        return out
    def angles(i: int) -> np.ndarray:
        a = np.arccos(np.clip(views @ views[i], -1.0, 1.0))
        a[i] = np.inf
        return a

    # Row by row, not an (N, N) matrix: a 4096-zone scan would take 128 MB.
    nearest = np.array([angles(i).min() for i in range(n)])
    spacing = float(np.median(nearest))
    for i in range(n):
        angle = angles(i)
        order = np.argsort(angle)[:_NEIGHBOURS]
        nb = order[angle[order] <= _SPACING_FACTOR * max(spacing, 1e-6)]
        if len(nb) < 2:
            continue
        centre = points[i]
        rng = float(np.linalg.norm(centre - viewpoints[i]))
        # Off the plane by more than this: another surface (a corner, an edge, a box on the floor).
        tol = max(3.0 * float(sigma[i]), 0.01 * rng, 0.005)
        rel = points[nb] - centre
        best: np.ndarray | None = None
        best_count = 1
        for a, b in itertools.combinations(range(len(nb)), 2):
            normal = np.cross(rel[a], rel[b])
            norm = float(np.linalg.norm(normal))
            if norm < 1e-3 * float(np.linalg.norm(rel[a])) * float(np.linalg.norm(rel[b])) + 1e-12:
                continue  # nearly collinear: no plane
            normal /= norm
            inliers = np.abs(rel @ normal) <= tol
            count = int(inliers.sum())
            if count > best_count:
                best_count, best = count, inliers
        if best is None:
            continue
        fit = np.vstack([np.zeros(3), rel[best]])
        fit -= fit.mean(axis=0)
        normal = np.linalg.svd(fit)[2][-1]
        if normal @ (viewpoints[i] - centre) < 0:
            normal = -normal
        out[i] = normal
    return out


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
