"""The point cloud: normals estimated from neighbouring zones, and the PLY read back by plyfile."""

from __future__ import annotations

import io
import math

import numpy as np
from plyfile import PlyData

from edge.cloud import Cloud, ply_bytes, scan_cloud
from edge.ranging import NO_SPOT, OK, ZoneResult
from edge.rig import default_rig

RIG = default_rig()


def corner_scan() -> tuple[list[ZoneResult], list[np.ndarray]]:
    """Zones looking at a wall 2 m ahead (x = 2) and the floor 1 m below (z = -1), and the true
    normal of what each zone's beam met."""
    results, normals = [], []
    for j, tilt in enumerate(range(-45, 1, 9)):
        for i, pan in enumerate(range(-30, 31, 6)):
            pose = RIG.camera_to_base(pan, tilt)
            o, d = pose.apply(RIG.reference.o), pose.rotate(RIG.reference.d)
            t_wall = (2.0 - o[0]) / d[0]
            t_floor = (-1.0 - o[2]) / d[2] if d[2] < 0 else math.inf
            t, n = (t_wall, np.array([-1.0, 0, 0])) if t_wall < t_floor else (t_floor, np.array([0, 0, 1.0]))
            p = o + t * d
            cam = pose.inverse().apply(p)
            results.append(ZoneResult(j * 100 + i, pan, tilt, OK, float(cam[2]), 0.002 * t, cam, p))
            normals.append(n)
    results.append(ZoneResult(999, 0.0, 10.0, NO_SPOT))
    return results, normals


def test_normals_from_neighbours_follow_the_wall_and_the_floor_up_to_their_corner() -> None:
    results, truth = corner_scan()
    cloud = scan_cloud(RIG, results)
    assert len(cloud) == len(truth)  # the no_spot zone has no point
    angles = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", cloud.normals, np.array(truth)), -1, 1)))
    # Points at the corner itself lie on both surfaces; every point gets its own surface's normal.
    assert np.all(angles < 3.0), angles.max()


def test_the_ply_reads_back_with_plyfile() -> None:
    results, _ = corner_scan()
    cloud = scan_cloud(RIG, results)
    ply = PlyData.read(io.BytesIO(ply_bytes(cloud, "a corner")))
    assert not ply.text and ply.byte_order == "<" and "a corner" in ply.comments
    vertex = ply["vertex"]
    assert [p.name for p in vertex.properties] == ["x", "y", "z", "nx", "ny", "nz", "sigma"]
    assert len(vertex.data) == len(cloud)
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    assert np.allclose(xyz, cloud.points, atol=1e-5)
    assert np.allclose(vertex["sigma"], cloud.sigma, atol=1e-7)
    assert np.allclose(np.stack([vertex["nx"], vertex["ny"], vertex["nz"]], axis=1), cloud.normals, atol=1e-6)


def test_an_empty_cloud_is_a_valid_ply() -> None:
    ply = PlyData.read(io.BytesIO(ply_bytes(Cloud.empty())))
    assert len(ply["vertex"].data) == 0
