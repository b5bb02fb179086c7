"""The rig: camera model, laser rays and the camera's mount on the pan-tilt head.

Conventions are those of ``shared/spec/geometry.md``: metres and degrees at every interface,
radians inside; OpenCV camera frame (x right, y down, z forward); ROS base frame (x forward, y left,
z up); head rotation ``Rz(pan)·Ry(-tilt)``; camera-in-head rotation ``Rz(yaw)·Ry(pitch)·Rx(roll)``
applied to the nominal orientation (camera z = head x, camera x = -head y, camera y = -head z).

Everything here is pure: numbers in, numbers out.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from edge.schema import require

Vec3 = tuple[float, float, float]

# Camera axes expressed in the head frame at rpy = 0 (columns: camera x, y, z).
_NOMINAL_CAMERA_IN_HEAD = np.array(
    [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], dtype=np.float64
)


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rpy_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """ROS roll-pitch-yaw: ``Rz(yaw)·Ry(pitch)·Rx(roll)`` about fixed axes."""
    r, p, y = (math.radians(v) for v in (roll_deg, pitch_deg, yaw_deg))
    return rot_z(y) @ rot_y(p) @ rot_x(r)



def wrap_deg(a: float) -> float:
    """An angle into (-180, 180] degrees: pans read the way the unit's limits are written."""
    a = math.fmod(a, 360.0)
    if a > 180.0:
        a -= 360.0
    elif a <= -180.0:
        a += 360.0
    return a

@dataclass(frozen=True)
class Pose:
    """A rigid transform ``p_to = R·p_from + t``."""

    R: np.ndarray  # (3, 3) float64
    t: np.ndarray  # (3,) float64

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform points of shape (..., 3)."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def rotate(self, vectors: np.ndarray) -> np.ndarray:
        """Rotate direction vectors of shape (..., 3) (no translation)."""
        return np.asarray(vectors, dtype=np.float64) @ self.R.T

    def inverse(self) -> Pose:
        return Pose(self.R.T, -self.R.T @ self.t)

    def compose(self, inner: Pose) -> Pose:
        """``self ∘ inner``: first `inner`, then `self`."""
        return Pose(self.R @ inner.R, self.R @ inner.t + self.t)

    @staticmethod
    def identity() -> Pose:
        return Pose(np.eye(3), np.zeros(3))


def head_rotation(pan_deg: float, tilt_deg: float) -> np.ndarray:
    """Rotation of the head frame in the base frame: ``Rz(pan)·Ry(-tilt)``."""
    return rot_z(math.radians(pan_deg)) @ rot_y(-math.radians(tilt_deg))


@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera with OpenCV's ``[k1, k2, p1, p2, k3]`` distortion."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    # Physical bounds, so that no file can make us allocate or compute the absurd: no sensor we
    # could meet is wider than 8192 px; a focal length from 0.05 to 100 image sizes is a field of
    # view from about 0.6° to 170°; a principal point lies in or near the image (within 100 image
    # sizes: as loose as the focal length); real lenses' coefficients are within ±10 (±100 leaves
    # room for odd fits).
    MAX_SIDE_PX: ClassVar[int] = 8192
    MAX_DIST: ClassVar[float] = 100.0

    def __post_init__(self) -> None:
        for key, side in (("width", self.width), ("height", self.height)):
            require(1 <= side <= self.MAX_SIDE_PX, key, f"must be 1-{self.MAX_SIDE_PX} pixels, got {side}")
        size = max(self.width, self.height)
        for key, f in (("fx", self.fx), ("fy", self.fy)):
            require(f > 0, key, f"must be positive, got {f:g}")
            require(0.05 * size <= f <= 100.0 * size, key,
                    f"must be {0.05 * size:g}-{100.0 * size:g} pixels (0.05-100 times the image size), got {f:g}")
        for key, c in (("cx", self.cx), ("cy", self.cy)):
            require(abs(c) <= 100.0 * size, key, f"must be within ±{100.0 * size:g} pixels "
                    f"(100 times the image size), got {c:g}")
        require(all(abs(d) <= self.MAX_DIST for d in self.dist), "dist",
                f"each coefficient must be within ±{self.MAX_DIST:g}, got {list(self.dist)}")

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def distorted(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    def distort(self, xn: np.ndarray) -> np.ndarray:
        """Apply lens distortion to normalised coordinates (..., 2) (x/z, y/z)."""
        if not self.distorted:
            return xn
        k1, k2, p1, p2, k3 = self.dist
        x, y = xn[..., 0], xn[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def distortion_jacobian(self, x: np.ndarray, y: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """∂(xd, yd)/∂(x, y) of :meth:`distort` at normalised points (`x`, `y`): its four entries,
        xd by x, xd by y, yd by x, yd by y (radial k1, k2, k3 and tangential p1, p2)."""
        k1, k2, p1, p2, k3 = self.dist
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        slope = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # ∂radial/∂r²
        cross = 2.0 * x * y * slope + 2.0 * p1 * x + 2.0 * p2 * y
        return (radial + 2.0 * x * x * slope + 2.0 * p1 * y + 6.0 * p2 * x, cross,
                cross, radial + 2.0 * y * y * slope + 6.0 * p1 * y + 2.0 * p2 * x)

    def undistort(self, xd: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Invert :meth:`distort` by fixed-point iteration (as OpenCV's undistortPoints)."""
        if not self.distorted:
            return xd
        k1, k2, p1, p2, k3 = self.dist
        x, y = xd[..., 0].copy(), xd[..., 1].copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x = (xd[..., 0] - dx) / radial
            y = (xd[..., 1] - dy) / radial
        return np.stack([x, y], axis=-1)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project camera-frame points (..., 3) to pixels (..., 2). Points need z > 0."""
        p = np.asarray(points, dtype=np.float64)
        xn = p[..., :2] / p[..., 2:3]
        xd = self.distort(xn)
        return np.stack([self.fx * xd[..., 0] + self.cx, self.fy * xd[..., 1] + self.cy], axis=-1)

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Unit camera-frame directions (..., 3) of the rays through pixels (..., 2)."""
        uv = np.asarray(pixels, dtype=np.float64)
        xd = np.stack([(uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy], -1)
        xn = self.undistort(xd)
        d = np.concatenate([xn, np.ones(xn.shape[:-1] + (1,))], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def contains(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """True where pixel centres lie inside the image (pixel centres run 0 … width-1)."""
        uv = np.asarray(pixels, dtype=np.float64)
        return (
            (uv[..., 0] >= -0.5 + margin)
            & (uv[..., 0] <= self.width - 0.5 - margin)
            & (uv[..., 1] >= -0.5 + margin)
            & (uv[..., 1] <= self.height - 0.5 - margin)
        )


# Named camera models. `picam-v2` is the default rig (geometry.md): a Pi Camera v2 binned over its
# full field of view to 640 × 480; `picam-v2-1640` the same sensor at 1640 × 1232; `webcam-cif` a
# 352 × 288 USB webcam like the thesis' Logitech QuickCam Express, with some barrel distortion.
CAMERA_MODELS: dict[str, CameraModel] = {
    "picam-v2": CameraModel(640, 480, 530.0, 530.0, 319.5, 239.5),
    "picam-v2-1640": CameraModel(1640, 1232, 1358.125, 1358.125, 819.5, 615.5),
    "webcam-cif": CameraModel(352, 288, 400.0, 400.0, 175.5, 143.5, (-0.12, 0.05, 0.0, 0.0, 0.0)),
}


@dataclass(frozen=True)
class Laser:
    """A laser beam fixed to the camera: a point on it and a unit direction, camera frame. Geometry
    only: how it is switched (its GPIO pin) is :class:`edge.hw.lasers.LaserWiring`."""

    name: str
    origin_m: Vec3
    direction: Vec3
    reference: bool = False

    def __post_init__(self) -> None:
        require(bool(self.name.strip()), "name", "must not be empty")
        norm = math.sqrt(sum(c * c for c in self.direction))
        require(
            abs(norm - 1.0) <= 1e-3,
            "direction",
            f"must be a unit vector (its length is {norm:.6g})",
        )
        # Stored exactly unit so that geometry downstream need not renormalise.
        object.__setattr__(self, "direction", tuple(c / norm for c in self.direction))

    @property
    def o(self) -> np.ndarray:
        return np.array(self.origin_m, dtype=np.float64)

    @property
    def d(self) -> np.ndarray:
        return np.array(self.direction, dtype=np.float64)

    def point_at_depth(self, z: np.ndarray | float) -> np.ndarray:
        """Points of the beam at camera depth z (…,) → (…, 3). Undefined if the beam is ⟂ z."""
        z = np.asarray(z, dtype=np.float64)
        s = (z - self.origin_m[2]) / self.direction[2]
        return self.o + s[..., None] * self.d


@dataclass(frozen=True)
class Mount:
    """The camera's pose on the pan-tilt head."""

    origin_m: Vec3 = (0.0, 0.0, 0.0)
    rpy_deg: Vec3 = (0.0, 0.0, 0.0)

    @functools.cached_property
    def camera_in_head(self) -> Pose:
        R = rpy_matrix(*self.rpy_deg) @ _NOMINAL_CAMERA_IN_HEAD
        return Pose(R, np.array(self.origin_m, dtype=np.float64))


@dataclass(frozen=True)
class Rig:
    camera: CameraModel
    lasers: tuple[Laser, ...]
    mount: Mount = field(default_factory=Mount)
    range_limits_m: tuple[float, float] = (0.25, 5.0)

    def __post_init__(self) -> None:
        require(len(self.lasers) > 0, "lasers", "at least one laser is needed")
        names = [laser.name for laser in self.lasers]
        for i, name in enumerate(names):
            require(name not in names[:i], f"lasers[{i}].name", f"duplicate laser name {name!r}")
        flagged = [laser.name for laser in self.lasers if laser.reference]
        require(len(flagged) <= 1, "lasers", f"only one laser may be the reference, got {flagged}")
        lo, hi = self.range_limits_m
        require(0 < lo < hi <= 1000, "range_limits_m", f"must be 0 < near < far <= 1000 m, got [{lo}, {hi}]")

    @property
    def reference(self) -> Laser:
        """The reference laser: the one flagged, else the first (geometry.md)."""
        for laser in self.lasers:
            if laser.reference:
                return laser
        return self.lasers[0]

    def laser(self, name: str) -> Laser:
        for laser in self.lasers:
            if laser.name == name:
                return laser
        raise KeyError(name)

    @property
    def laser_names(self) -> tuple[str, ...]:
        return tuple(laser.name for laser in self.lasers)

    def camera_to_base(self, pan_deg: float, tilt_deg: float) -> Pose:
        """Transform from the camera frame to the base frame at this pan and tilt (shared, and
        read-only: a sweep comes back to the same poses, and every zone ranged asks for one)."""
        return _camera_to_base(self.mount, float(pan_deg), float(tilt_deg))

    def laser_image_path(self, laser: Laser, n: int = 64) -> np.ndarray:
        """Pixels (n, 2) where `laser`'s spot can appear over the working range (its epipolar
        segment), from the near to the far limit, equally spaced in inverse depth."""
        lo, hi = self.range_limits_m
        inv = np.linspace(1.0 / lo, 1.0 / hi, n)
        return self.camera.project(laser.point_at_depth(1.0 / inv))


@functools.lru_cache(maxsize=512)
def _camera_to_base(mount: Mount, pan_deg: float, tilt_deg: float) -> Pose:
    R = head_rotation(pan_deg, tilt_deg)
    inner = mount.camera_in_head
    pose = Pose(R @ inner.R, R @ inner.t)
    pose.R.flags.writeable = False
    pose.t.flags.writeable = False
    return pose


def default_rig() -> Rig:
    """geometry.md's default rig: the thesis' three lasers beside a Pi Camera v2 at 640 × 480."""
    t = math.radians(10.0)
    return Rig(
        camera=CAMERA_MODELS["picam-v2"],
        lasers=(
            Laser("center", (0.035, 0.0, 0.0), (0.0, 0.0, 1.0), reference=True),
            Laser("parallel", (0.035, -0.040, 0.0), (0.0, 0.0, 1.0)),
            Laser("sloped", (0.035, 0.0, 0.0), (0.0, math.sin(t), math.cos(t))),
        ),
    )
