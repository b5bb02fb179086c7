"""Rig geometry against geometry.md's conventions, with property tests for the round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.rig import CAMERA_MODELS, CameraModel, Laser, Mount, Rig, default_rig, rpy_matrix
from edge.schema import FieldError

angles = st.floats(-170.0, 170.0)
tilts = st.floats(-80.0, 80.0)


def test_default_rig_matches_geometry_md() -> None:
    rig = default_rig()
    cam = rig.camera
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (640, 480, 530, 530, 319.5, 239.5)
    assert rig.reference.name == "center"
    sloped = rig.laser("sloped")
    assert sloped.direction == pytest.approx((0.0, math.sin(math.radians(10)), math.cos(math.radians(10))))
    assert rig.range_limits_m == (0.25, 5.0)


@pytest.mark.parametrize(
    ("pan", "tilt", "expected"),
    [
        (0, 0, (1, 0, 0)),  # camera z looks along base x at pan 0, tilt 0
        (90, 0, (0, 1, 0)),  # positive pan turns left (towards base +y)
        (-90, 0, (0, -1, 0)),
        (0, 90, (0, 0, 1)),  # positive tilt points up
        (0, -30, (math.cos(math.radians(30)), 0, -0.5)),
    ],
)
def test_optical_axis_in_base_frame(pan: float, tilt: float, expected: tuple) -> None:
    pose = default_rig().camera_to_base(pan, tilt)
    assert pose.rotate([0.0, 0.0, 1.0]) == pytest.approx(expected, abs=1e-12)


def test_camera_axes_at_home() -> None:
    pose = default_rig().camera_to_base(0, 0)
    assert pose.rotate([1.0, 0.0, 0.0]) == pytest.approx((0, -1, 0))  # camera x = -base y (right)
    assert pose.rotate([0.0, 1.0, 0.0]) == pytest.approx((0, 0, -1))  # camera y = -base z (down)


def test_mount_offset_and_rotation() -> None:
    rig = Rig(
        CAMERA_MODELS["picam-v2"],
        default_rig().lasers,
        Mount(origin_m=(0.05, 0.0, 0.1), rpy_deg=(0.0, 0.0, 90.0)),
    )
    pose = rig.camera_to_base(0, 0)
    assert pose.apply([0.0, 0.0, 0.0]) == pytest.approx((0.05, 0.0, 0.1))
    # yaw 90° about head z turns the view from head x to head y.
    assert pose.rotate([0.0, 0.0, 1.0]) == pytest.approx((0, 1, 0), abs=1e-12)
    assert rpy_matrix(0, 0, 90) @ np.array([1.0, 0, 0]) == pytest.approx((0, 1, 0), abs=1e-12)


@given(pan=angles, tilt=tilts, x=st.floats(-2, 2), y=st.floats(-2, 2), z=st.floats(-2, 2))
def test_camera_to_base_inverse_round_trip(pan: float, tilt: float, x: float, y: float, z: float) -> None:
    pose = default_rig().camera_to_base(pan, tilt)
    p = np.array([x, y, z])
    assert pose.inverse().apply(pose.apply(p)) == pytest.approx(p, abs=1e-9)
    assert np.linalg.det(pose.R) == pytest.approx(1.0)


cameras = st.builds(
    CameraModel,
    width=st.integers(100, 2000),
    height=st.integers(100, 2000),
    fx=st.floats(200, 2000),
    fy=st.floats(200, 2000),
    cx=st.floats(50, 1000),
    cy=st.floats(50, 1000),
    dist=st.tuples(
        st.floats(-0.2, 0.1), st.floats(-0.05, 0.05), st.floats(-0.002, 0.002),
        st.floats(-0.002, 0.002), st.floats(-0.01, 0.01),
    ),
)


@settings(max_examples=200)
@given(cam=cameras, xn=st.floats(-0.6, 0.6), yn=st.floats(-0.5, 0.5), z=st.floats(0.1, 10))
def test_project_then_ray_round_trip(cam: CameraModel, xn: float, yn: float, z: float) -> None:
    point = np.array([xn * z, yn * z, z])
    pixel = cam.project(point)
    ray = cam.rays(pixel)
    expected = point / np.linalg.norm(point)
    assert ray == pytest.approx(expected, abs=1e-7)


def _laser_rays():
    def make(ox, oy, ax, ay):
        d = np.array([ax, ay, 1.0])
        d /= np.linalg.norm(d)
        return Laser("l", (ox, oy, 0.0), tuple(d))

    return st.builds(make, st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-0.2, 0.2), st.floats(-0.2, 0.2))


@given(laser=_laser_rays(), z=st.floats(0.25, 5.0))
def test_laser_point_at_depth_lies_on_the_beam(laser: Laser, z: float) -> None:
    p = laser.point_at_depth(z)
    assert p[2] == pytest.approx(z)
    along = p - laser.o
    assert np.linalg.norm(np.cross(along, laser.d)) == pytest.approx(0.0, abs=1e-12)


def test_epipolar_paths_of_the_default_rig() -> None:
    rig = default_rig()
    center = rig.laser_image_path(rig.laser("center"), 5)
    # The centre beam is parallel to the axis 3.5 cm to the right: its spot slides from right of
    # the principal point (near) towards it (far), on the principal row.
    assert center[:, 1] == pytest.approx(239.5)
    assert center[0, 0] == pytest.approx(319.5 + 530 * 0.035 / 0.25)
    assert center[-1, 0] == pytest.approx(319.5 + 530 * 0.035 / 5.0)
    sloped = rig.laser_image_path(rig.laser("sloped"), 5)
    assert sloped[:, 1] == pytest.approx(239.5 + 530 * math.tan(math.radians(10)))


@pytest.mark.parametrize(
    ("kwargs", "key", "text"),
    [
        (dict(name="a", origin_m=(0, 0, 0), direction=(0, 0, 1.01)), "direction", "unit vector"),
        (dict(name=" ", origin_m=(0, 0, 0), direction=(0, 0, 1)), "name", "must not be empty"),
    ],
)
def test_laser_validation(kwargs: dict, key: str, text: str) -> None:
    with pytest.raises(FieldError) as info:
        Laser(**kwargs)
    assert info.value.key == key and text in info.value.message


def test_laser_direction_is_stored_exactly_unit() -> None:
    laser = Laser("a", (0, 0, 0), (0.0, 0.0, 1.0009))
    assert np.linalg.norm(laser.d) == pytest.approx(1.0, abs=1e-15)


def test_rig_validation() -> None:
    lasers = default_rig().lasers
    with pytest.raises(FieldError, match="only one laser may be the reference"):
        Rig(CAMERA_MODELS["picam-v2"], tuple(Laser(x.name, x.origin_m, x.direction, reference=True) for x in lasers))
    with pytest.raises(FieldError, match="at least one laser"):
        Rig(CAMERA_MODELS["picam-v2"], ())
    unflagged = tuple(Laser(x.name, x.origin_m, x.direction) for x in lasers)
    assert Rig(CAMERA_MODELS["picam-v2"], unflagged).reference.name == "center"  # first one


def test_the_distortions_jacobian_is_its_derivative() -> None:
    """`CameraModel.distortion_jacobian` (what a turn fitted through the lens steps by, edge.motion)
    against central differences of `distort`, radial and tangential terms all given."""
    cam = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0, (-0.21, 0.05, 0.001, -0.002, 0.01))
    x, y = np.array([0.3, -0.5, 0.1, 0.0]), np.array([-0.2, 0.4, 0.6, 0.0])
    h = 1e-6

    def at(dx: float, dy: float) -> np.ndarray:
        return cam.distort(np.column_stack([x + dx, y + dy]))

    by_x, by_y = (at(h, 0) - at(-h, 0)) / (2 * h), (at(0, h) - at(0, -h)) / (2 * h)
    expected = (by_x[:, 0], by_y[:, 0], by_x[:, 1], by_y[:, 1])
    for got, want in zip(cam.distortion_jacobian(x, y), expected):
        assert np.allclose(got, want, atol=1e-8)
