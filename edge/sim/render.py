"""The virtual camera: render what the rig's camera sees in a scene, lasers on or off.

A frame is rendered in two steps. Per view (pan, tilt, and the time when movers are about) one ray
per pixel is cast into the scene and shaded under room light; that image of photo-electrons is
cached, because a zone's on and off frames share it. Per frame the ambient level flickers, the
visible laser spots are added (``edge.sim.optics``), then shot and read noise, full-well clipping,
the ADC, the output bit depth and, for a webcam, JPEG compression. For the Pi camera as it is
(``sim.sensor.isp``) a renderer of its 1640 × 1232 sensor does all that, and every frame it makes
is scaled to the rig's 640 × 480 as the camera's ISP hands it over (``edge.sim.isp``).

The renderer works with the *true* rig (which may differ from the nominal one: see
:func:`perturb_rig`); what ranging believes is the recording's business.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from edge.errors import CameraError, ConfigError
from edge.hw.camera import CameraSettings
from edge.rig import Laser, Pose, Rig
from edge.sim import isp as sim_isp
from edge.sim import optics
from edge.sim.materials import TEXTURE_FLOOR
from edge.sim.scene import Scene, SceneGeometry
from edge.sim.settings import RigErrorConfig, SimConfig
from edge.tone import linear_light, tone_curve

# Shade of room light by surface orientation: floors get most of a ceiling light, ceilings least.
_AMBIENT_BY_NORMAL_Z = (0.8, 0.2)  # factor = a + b · n_z
# Luminance weights (R, G, B) of a grey sensor's view of room light; it sees 650 nm fully.
_GREY_WEIGHTS_RGB = np.array([0.299, 0.587, 0.114])
_MAX_LASER_DISTANCE_M = 50.0
_CACHE_VIEWS = 8
_FAR_M = 1e6  # where a ray that meets nothing is taken to end (turned_pixels)
_VIEW_BAND_RAYS = 1 << 18  # rays cast at once
_EDGE_SAMPLES = 4  # rays a side over a pixel that an edge crosses (sim.optics.pixel_area)
# OpenCV's demosaicing of an RGGB sensor (R at even rows and columns), by `sensor.bayer`.
_DEMOSAIC = {"bilinear": cv2.COLOR_BayerRGGB2BGR, "vng": cv2.COLOR_BayerRGGB2BGR_VNG,
             "ea": cv2.COLOR_BayerRGGB2BGR_EA}
_JPEG_CHROMA = {"4:2:0": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420, "4:4:4": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444}


@dataclass(frozen=True)
class SpotTruth:
    """Where one laser meets the scene in one view, and whether the camera can see it."""

    laser: str
    visible: bool
    why: str  # "visible", "no_hit", "behind_camera", "occluded", "faces_away", "outside_image"
    point_world: np.ndarray | None = None  # (3,)
    point_camera: np.ndarray | None = None  # (3,)
    pixel: np.ndarray | None = None  # (2,) analytic projection of the spot's centre
    face: int = -1
    face_key: int = -1
    surface_uv: np.ndarray | None = None  # (2,)
    normal_world: np.ndarray | None = None  # (3,)

    @property
    def depth_m(self) -> float | None:
        return None if self.point_camera is None else float(self.point_camera[2])


@dataclass(frozen=True)
class SpotModel:
    """One laser's spot in one view as the renderer puts it on the sensor, before noise and
    speckle: what the physical floor of locating it needs (:mod:`edge.accuracy.floor`)."""

    truth: SpotTruth
    covariance: np.ndarray  # (2, 2) px²: the Gaussian spot's footprint and blur in the image
    total_e: float  # the spot's photo-electrons at the configured exposure, vignetting included
    response: np.ndarray  # (C,) relative response of each channel to the laser (B, G, R; or grey)
    speckle_contrast: float  # as optics.speckle_field takes them
    speckle_grain: float
    speckle_key: tuple[int, ...]  # the speckle pattern's seed: equal keys, equal patterns
    background: optics.SpotImage  # room light (h, w, C) electrons around the spot, no flicker


@dataclass
class _View:
    camera_to_world: Pose
    geometry: SceneGeometry
    electrons: np.ndarray  # (H, W, C) float32: room light at the configured exposure, no flicker
    depth: np.ndarray | None = None  # (H, W) distance along each pixel's ray (inf: nothing hit)
    # Per laser: where its spot is and its image; both fixed for a view (speckle stays put), so a
    # frame of a cached view costs only the noise.
    spots: dict[str, tuple[SpotTruth, optics.SpotImage | None]] = field(default_factory=dict)


def perturb_rig(rig: Rig, error: RigErrorConfig) -> Rig:
    """A rig as built, not as designed: each laser tilted and shifted at random, the focal length
    scaled. Seeded by ``error.seed`` so that a test can build the same flawed rig twice."""
    if error.laser_angle_deg == 0 and error.laser_offset_m == 0 and error.focal_scale == 0:
        return rig
    rng = np.random.default_rng([error.seed, 0x5EED])
    lasers = []
    for laser in rig.lasers:
        d = laser.d
        axis = np.cross(d, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        angle = math.radians(rng.normal() * error.laser_angle_deg)
        # Rodrigues: rotate d about an axis ⟂ d.
        d_new = d * math.cos(angle) + np.cross(axis, d) * math.sin(angle)
        o_new = laser.o + rng.normal(size=3) * error.laser_offset_m
        lasers.append(replace(laser, origin_m=_vec3(o_new), direction=_vec3(d_new)))
    scale = 1.0 + rng.normal() * error.focal_scale
    camera = replace(rig.camera, fx=rig.camera.fx * scale, fy=rig.camera.fy * scale)
    return replace(rig, camera=camera, lasers=tuple(lasers))


def _vec3(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


class Renderer:
    """Renders frames of `rig`'s camera in `scene` with the optics and sensor of `sim` (through
    the Pi camera's ISP where `sim.sensor.isp` says so: then a renderer of the sensor behind it
    makes the frames and the spots, and this one scales them; the sensor's photo-electrons and
    spot models, which only the accuracy family's truth reads, are refused)."""

    def __init__(self, scene: Scene, rig: Rig, sim: SimConfig,
                 camera: CameraSettings = CameraSettings()) -> None:
        self.scene = scene
        self.rig = rig
        self.sim = sim
        self.camera = camera
        cam = rig.camera
        self.channels = 3 if sim.sensor.colour else 1
        self._base_to_world = scene.base_to_world()
        # `sim.sensor.isp`: the Pi camera's sensor, rendered at its own size, whose frames and
        # spots this renderer hands over as the ISP does (`_isp_rows`: each sensor row's frame row,
        # for a laser switched mid-frame).
        self._sensor: Renderer | None = None
        if sim.sensor.isp:
            sensor_rig, sensor_sim, self._isp_rows = sim_isp.sensor_parts(rig, sim)
            self._sensor = Renderer(scene, sensor_rig, sensor_sim, camera)
            return
        v, u = np.mgrid[0 : cam.height, 0 : cam.width]
        self._pixel_rays = cam.rays(np.stack([u, v], axis=-1).reshape(-1, 2).astype(np.float64))
        # cos⁴ fall-off of a simple lens, the same for room light and spots.
        cos = self._pixel_rays[:, 2].reshape(cam.height, cam.width)
        self._vignette = (cos**4 if sim.optics.vignetting else np.ones_like(cos)).astype(np.float32)
        # Views by key; a view being rendered (by a prefetch) is a Future the others wait on.
        self._views: dict[tuple, Future[_View]] = {}
        self._patched: dict[tuple, Future[_View]] = {}  # views with movers, by the movers' poses
        self._views_lock = threading.Lock()
        self._normal_bank: np.ndarray | None = None
        exposure_ms = camera.exposure_us / 1000.0
        self._ambient_e = sim.ambient.white_e_per_ms * exposure_ms
        self._spot_e_at_1m = sim.beam.e_per_ms_at_1m * exposure_ms
        response = np.array(sim.beam.response_bgr)
        self._laser_response = response if self.channels == 3 else np.array([1.0])
        self._dn_per_e = (2**sim.sensor.adc_bits - 1) / sim.sensor.full_well_e * camera.analogue_gain

    # --- geometry -----------------------------------------------------------------------------

    def camera_to_world(self, pan_deg: float, tilt_deg: float) -> Pose:
        return self._base_to_world.compose(self.rig.camera_to_base(pan_deg, tilt_deg))

    def _view(self, pan_deg: float, tilt_deg: float, t_s: float) -> _View:
        """The view at (pan, tilt) at time `t_s`. Rendering a view is the costly part (one ray per
        pixel), so the scene without its movers is rendered once per pose and cached; while a
        mover is present, only the pixels its box can cover are cast again, at each instant. A
        swaying platform (`sim.sway`) turns the pose by its turn at `t_s`."""
        if self.sim.sway.deg:
            turned = self.sim.sway.turn(t_s)
            pan_deg, tilt_deg = pan_deg + turned[0], tilt_deg + turned[1]
        poses = self.scene.mover_poses(t_s) if self.scene.movers else ()
        static = self._static_view(pan_deg, tilt_deg)
        if not poses:
            return static  # no mover present
        box = self._mover_box(static.camera_to_world, t_s)
        if box is None:
            return static  # no mover in the picture (and the beams only go where the camera looks)
        # By where the movers are, not by instant: a standing person is cast once, not every frame
        # (and the scene with its movers is only put together when a view is cast).
        key = (round(pan_deg, 9), round(tilt_deg, 9), poses)
        return self._cached(key, lambda: self._patched_view(static, t_s, self.scene.at(t_s), box), self._patched)

    def _static_view(self, pan_deg: float, tilt_deg: float) -> _View:
        """The view at (pan, tilt) without the scene's movers, rendered once per pose and cached."""
        key = (round(pan_deg, 9), round(tilt_deg, 9), None)
        return self._cached(key, lambda: self._render_view(pan_deg, tilt_deg, self.scene.static))

    def _cached(self, key: tuple, render: Callable[[], _View], cache: dict | None = None) -> _View:
        cache = self._views if cache is None else cache
        with self._views_lock:
            pending = cache.get(key)
            mine = pending is None
            if pending is None:
                if len(cache) >= _CACHE_VIEWS:
                    cache.pop(next(iter(cache)))
                pending = cache[key] = Future()
        if mine:
            try:
                view = render()
                for laser in self.rig.lasers:  # the spots too, so a frame costs only its noise
                    self._lit_spot(view, laser.name)
            except BaseException as exc:
                with self._views_lock:
                    cache.pop(key, None)
                pending.set_exception(exc)
                raise
            pending.set_result(view)
        return pending.result()

    def prefetch(self, pan_deg: float, tilt_deg: float, t_s: float = 0.0) -> None:
        """Render the view at (pan, tilt) now (without movers: they are patched in per frame), so
        that frames there later cost little more than their noise (the simulated camera calls
        this from a thread while the unit is on its way)."""
        if self._sensor is not None:
            self._sensor.prefetch(pan_deg, tilt_deg, t_s)
            return
        key = (round(pan_deg, 9), round(tilt_deg, 9), None)
        self._cached(key, lambda: self._render_view(pan_deg, tilt_deg, self.scene.static))

    def _render_view(self, pan_deg: float, tilt_deg: float, geometry: SceneGeometry) -> _View:
        pose = self.camera_to_world(pan_deg, tilt_deg)
        cam = self.rig.camera
        img = np.empty((cam.height * cam.width, self.channels), np.float32)
        depth = np.empty(cam.height * cam.width)
        face = np.empty(cam.height * cam.width, np.int32)
        # Bands of rows: a cast's temporaries are some 300 bytes a ray, so a 1640 × 1232 view cast at
        # once held 580 MB (each ray's hit is its own: the same whichever band it is cast in).
        band = max(1, _VIEW_BAND_RAYS // cam.width) * cam.width
        for start in range(0, len(depth), band):
            rays = self._pixel_rays[start : start + band]
            hits = geometry.cast(pose.t, pose.rotate(rays))
            img[start : start + band] = self._shade(geometry, hits, rays, pose)
            depth[start : start + band] = np.where(hits.hit, hits.distance, np.inf)
            face[start : start + band] = hits.face
        if self.sim.optics.pixel_area:
            self._smooth_edges(img, face.reshape(cam.height, cam.width), geometry, pose)
        return _View(pose, geometry, img.reshape(cam.height, cam.width, self.channels),
                     depth.reshape(cam.height, cam.width))

    def _smooth_edges(self, img: np.ndarray, face: np.ndarray, geometry: SceneGeometry, pose: Pose) -> None:
        """Each pixel on an edge between faces (or between a face and nothing) given, in `img`
        (H·W, C), the mean of _EDGE_SAMPLES² rays spread over its area: a sensor's pixel that an
        edge crosses sees some of each side. Sampled at its centre only, an edge moves in whole
        pixels as the camera turns, and a frame turned back cannot match one taken from the pose."""
        edge = np.zeros(face.shape, bool)
        edge[:, 1:] |= face[:, 1:] != face[:, :-1]
        edge[:, :-1] |= face[:, :-1] != face[:, 1:]
        edge[1:, :] |= face[1:, :] != face[:-1, :]
        edge[:-1, :] |= face[:-1, :] != face[1:, :]
        index = np.flatnonzero(edge)
        if not index.size:
            return
        v, u = np.divmod(index, face.shape[1])
        offsets = (np.arange(_EDGE_SAMPLES) + 0.5) / _EDGE_SAMPLES - 0.5
        du, dv = (a.ravel() for a in np.meshgrid(offsets, offsets))
        pixels = np.stack([u[:, None] + du, v[:, None] + dv], axis=-1).reshape(-1, 2)
        shaded = np.empty((len(pixels), self.channels), np.float32)
        for start in range(0, len(pixels), _VIEW_BAND_RAYS):
            rays = self.rig.camera.rays(pixels[start : start + _VIEW_BAND_RAYS])
            hits = geometry.cast(pose.t, pose.rotate(rays))
            shaded[start : start + _VIEW_BAND_RAYS] = self._shade(geometry, hits, rays, pose)
        img[index] = shaded.reshape(index.size, du.size, self.channels).mean(axis=1)

    def _mover_box(self, pose: Pose, t_s: float) -> tuple[int, int, int, int] | None:
        """The pixel rectangle (u0, v0, u1, v1) that the movers present at `t_s` may cover in the
        view from `pose`, or None when none is in the picture."""
        cam = self.rig.camera
        to_camera = pose.inverse()
        box = None
        for corners in self.scene.mover_corners(t_s):
            p = to_camera.apply(corners)
            if (p[:, 2] <= 1e-3).all():
                continue  # behind the camera
            if (p[:, 2] <= 1e-3).any():
                return (0, 0, cam.width, cam.height)  # straddles the camera plane: cast it all
            uv = cam.project(p)
            # Lens distortion can bend a box's edges outward between its corners: a margin.
            u0, v0 = (np.floor(uv.min(axis=0)).astype(int) - 3).tolist()
            u1, v1 = (np.ceil(uv.max(axis=0)).astype(int) + 4).tolist()
            u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, cam.width), min(v1, cam.height)
            if u0 >= u1 or v0 >= v1:
                continue
            box = (u0, v0, u1, v1) if box is None else (
                min(box[0], u0), min(box[1], v0), max(box[2], u1), max(box[3], v1))
        return box

    def _patched_view(self, static: _View, t_s: float, geometry: SceneGeometry,
                      box: tuple[int, int, int, int]) -> _View:
        """`static` with the pixels in `box` that a mover present at `t_s` covers cast again."""
        cam = self.rig.camera
        pose = static.camera_to_world
        electrons = static.electrons
        if box is not None:
            # Cast the box's pixels at the movers alone; where one is nearer than the room, it
            # is what the pixel sees.
            u0, v0, u1, v1 = box
            index = (np.arange(v0, v1)[:, None] * cam.width + np.arange(u0, u1)[None, :]).ravel()
            movers = self.scene.movers_at(t_s)
            # `box` bounds the movers present at `t_s`; static views are rendered with their depth.
            assert movers is not None and static.depth is not None
            rays = self._pixel_rays[index]
            hits = movers.cast(pose.t, pose.rotate(rays))
            nearer = hits.hit & (hits.distance < static.depth.reshape(-1)[index])
            if nearer.any():
                shaded = self._shade(movers, hits, rays, pose)
                electrons = electrons.copy()
                flat = electrons.reshape(-1, self.channels)
                flat[index[nearer]] = shaded[nearer]
        return _View(pose, geometry, electrons)

    def _shade(self, geometry: SceneGeometry, hits, rays: np.ndarray, pose: Pose) -> np.ndarray:
        """Room light at the configured exposure for the `hits` of camera `rays` (N, 3, unit) from
        `pose` (the camera's in the world): (N, C) float32 photo-electrons, vignetting included."""
        albedo, _, _ = geometry.material(hits.face)
        footprint = self._footprint(geometry, hits, rays, pose) if self.sim.optics.pixel_area else None
        albedo, texture = self._surface(albedo, geometry.texture(hits.face, hits.surface_uv, footprint))
        light = _AMBIENT_BY_NORMAL_Z[0] + _AMBIENT_BY_NORMAL_Z[1] * hits.normal[:, 2]
        radiance = albedo * (texture * np.where(hits.hit, light, 0.0))[:, None]  # (N, 3) RGB
        img = radiance[:, ::-1] if self.channels == 3 else (radiance @ _GREY_WEIGHTS_RGB)[:, None]
        # cos⁴ fall-off of a simple lens: a unit ray's camera-frame z is its cosine.
        fall_off = rays[:, 2] ** 4 if self.sim.optics.vignetting else np.ones(len(rays))
        return (img * (self._ambient_e * fall_off)[:, None]).astype(np.float32)

    def _footprint(self, geometry: SceneGeometry, hits, rays: np.ndarray, pose: Pose) -> np.ndarray:
        """How far each hit's `surface_uv` moves for a pixel's step along the image's u and v
        (N, 2, 2): the ray's step (a pinhole's: the lens's distortion changes it by a few tenths at
        the corners, which does not matter to a blur) carried to the hit's plane."""
        cam = self.rig.camera
        out = np.zeros((len(rays), 2, 2))
        hit = hits.hit
        if not hit.any():
            return out
        rz = rays[hit, 2]
        ray = pose.rotate(rays[hit] / rz[:, None])  # (world; unit depth along the camera's axis)
        depth = hits.distance[hit] * rz
        normal = hits.normal[hit]
        facing = np.einsum("ij,ij->i", normal, ray)
        facing = np.where(np.abs(facing) > 1e-9, facing, 1e-9)  # (grazing: a step reaches far, and blurs all)
        u_axis, v_axis = geometry.uv_axes(hits.face[hit])
        for j, step in enumerate((pose.R[:, 0] / cam.fx, pose.R[:, 1] / cam.fy)):
            # Where the stepped ray meets the hit's plane, less where the ray met it.
            moved = depth[:, None] * (step[None, :] - ((normal @ step) / facing)[:, None] * ray)
            out[hit, 0, j] = np.einsum("ij,ij->i", moved, u_axis)
            out[hit, 1, j] = np.einsum("ij,ij->i", moved, v_axis)
        return out

    def _surface(self, albedo: np.ndarray, texture: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Albedo and texture as ``sim.surfaces`` changes every surface's."""
        change = self.sim.surfaces
        if change.texture_scale != 1.0:
            texture = np.maximum(TEXTURE_FLOOR, 1.0 + change.texture_scale * (texture - 1.0))
        if change.albedo_scale != 1.0:
            albedo = np.minimum(albedo * change.albedo_scale, 1.0)
        return albedo, texture

    def spots(self, pan_deg: float, tilt_deg: float, t_s: float = 0.0) -> dict[str, SpotTruth]:
        """Where each laser meets the scene in this view, and whether the camera sees it."""
        if self._sensor is not None:
            return sim_isp.scaled_spots(self._sensor.spots(pan_deg, tilt_deg, t_s), self.rig.camera)
        view = self._view(pan_deg, tilt_deg, t_s)
        return {laser.name: self._lit_spot(view, laser.name)[0] for laser in self.rig.lasers}

    def _lit_spot(self, view: _View, name: str) -> tuple[SpotTruth, optics.SpotImage | None]:
        cached = view.spots.get(name)
        if cached is None:
            truth = self._spot(view, self.rig.laser(name))
            image = self._spot_image(view, truth) if truth.visible else None
            cached = view.spots[name] = (truth, image)
        return cached

    def _spot(self, view: _View, laser: Laser) -> SpotTruth:
        pose, geometry = view.camera_to_world, view.geometry
        origin = pose.apply(laser.o)
        beam = pose.rotate(laser.d)
        hit = geometry.cast(origin, beam[None, :], _MAX_LASER_DISTANCE_M)
        if not hit.hit[0]:
            return SpotTruth(laser.name, False, "no_hit")
        point, normal = hit.point[0], hit.normal[0]
        face = int(hit.face[0])
        common = dict(
            point_world=point,
            face=face,
            face_key=int(geometry.face_key(hit.face)[0]),
            surface_uv=hit.surface_uv[0],
            normal_world=normal,
        )
        p_cam = pose.inverse().apply(point)
        if p_cam[2] <= 1e-3:
            return SpotTruth(laser.name, False, "behind_camera", point_camera=p_cam, **common)
        pixel = self.rig.camera.project(p_cam)
        common.update(point_camera=p_cam, pixel=pixel)
        to_point = point - pose.t
        dist = float(np.linalg.norm(to_point))
        if float(normal @ -to_point) <= 0.0:
            return SpotTruth(laser.name, False, "faces_away", **common)
        sight = geometry.cast(pose.t, (to_point / dist)[None, :], dist)
        if sight.hit[0] and sight.distance[0] < dist - max(1e-3, 1e-4 * dist):
            return SpotTruth(laser.name, False, "occluded", **common)
        if not self.rig.camera.contains(pixel):
            return SpotTruth(laser.name, False, "outside_image", **common)
        return SpotTruth(laser.name, True, "visible", **common)

    # --- photometry ---------------------------------------------------------------------------

    def _spot_image(self, view: _View, truth: SpotTruth) -> optics.SpotImage | None:
        cov, total, key = self._spot_params(view, truth)
        cam = self.rig.camera
        assert truth.pixel is not None  # `_spot_params` checked that the spot is visible
        rng = None if key is None else np.random.default_rng([w & 0xFFFFFFFF for w in key])
        return optics.render_spot(
            truth.pixel, cov, total, cam.width, cam.height, rng, self._speckle_contrast,
            self._speckle_grain,
        )

    @property
    def _speckle_contrast(self) -> float:
        return optics.SPECKLE_CONTRAST_F2 * self.sim.beam.speckle

    @property
    def _speckle_grain(self) -> float:
        return self.sim.optics.f_number / 2.0 * self.sim.beam.speckle_grain

    def _spot_params(self, view: _View, truth: SpotTruth) -> tuple[np.ndarray, float, tuple[int, ...] | None]:
        """A visible spot's image covariance (2, 2) px², its photo-electrons, and the seed of its
        speckle (None without speckle)."""
        # Only visible spots are imaged, and `_spot` gives a visible one all of its geometry.
        assert (truth.point_world is not None and truth.point_camera is not None and truth.pixel is not None
                and truth.surface_uv is not None and truth.normal_world is not None)
        cam, sim = self.rig.camera, self.sim
        pose = view.camera_to_world
        laser = self.rig.laser(truth.laser)
        beam = pose.rotate(laser.d)
        normal = truth.normal_world
        to_camera = pose.t - truth.point_world
        dist = float(np.linalg.norm(to_camera))
        travelled = float(np.linalg.norm(truth.point_world - pose.apply(laser.o)))
        albedo, gloss, shininess = view.geometry.material(np.array([truth.face]))
        albedo, texture_ = self._surface(albedo, view.geometry.texture(np.array([truth.face]), truth.surface_uv[None]))
        texture = float(texture_[0])
        gloss_ = min(1.0, float(gloss[0]) + sim.surfaces.extra_gloss)
        fraction = optics.reflected_fraction(
            float(albedo[0, 0]) * texture, gloss_, float(shininess[0]), beam, normal, to_camera / dist
        )
        u, v = truth.pixel
        row, col = min(max(int(round(v)), 0), cam.height - 1), min(max(int(round(u)), 0), cam.width - 1)
        vig = float(self._vignette[row, col])
        total = self._spot_e_at_1m * fraction * vig / dist**2
        sigma = 0.5 * optics.beam_radius(sim.beam.waist_m, sim.beam.divergence_mrad * 1e-3, travelled)
        axis1, axis2, sigmas = optics.surface_footprint(beam, normal, sigma)
        to_cam = pose.inverse()
        p_cam = truth.point_camera
        h = 1e-4
        j1 = (cam.project(to_cam.apply(truth.point_world + h * axis1)) - truth.pixel) / h
        j2 = (cam.project(to_cam.apply(truth.point_world + h * axis2)) - truth.pixel) / h
        defocus = optics.defocus_diameter_px(
            cam.fx, sim.optics.focal_length_mm, sim.optics.f_number, sim.optics.focus_m, float(p_cam[2])
        )
        cov = optics.image_covariance(np.stack([j1, j2], axis=1), sigmas, sim.optics.psf_sigma_px, defocus)
        key = None
        if sim.beam.speckle > 0:
            cell = sim.beam.speckle_cell_m
            q = np.floor(truth.surface_uv / cell).astype(np.int64)
            key = (sim.seed, truth.face_key, int(q[0]), int(q[1]))
        return cov, total, key

    def spot_model(self, pan_deg: float, tilt_deg: float, laser: str, t_s: float = 0.0) -> SpotModel | None:
        """`laser`'s spot in this view as the sensor receives it, or None when it is not visible.
        (Not through an ISP: the accuracy family records the sensor, whose spot this is, and
        scales the recording: `edge.sim.isp.scale_recording`.)"""
        self._no_isp("a spot's model")
        view = self._view(pan_deg, tilt_deg, t_s)
        truth = self._lit_spot(view, laser)[0]
        if not truth.visible or truth.pixel is None:
            return None
        cov, total, key = self._spot_params(view, truth)
        cam = self.rig.camera
        radius = int(math.ceil(4.0 * math.sqrt(float(np.linalg.eigvalsh(cov)[-1])))) + 1
        cu, cv = int(round(float(truth.pixel[0]))), int(round(float(truth.pixel[1])))
        x0, x1 = max(0, cu - radius), min(cam.width, cu + radius + 1)
        y0, y1 = max(0, cv - radius), min(cam.height, cv + radius + 1)
        room = np.array(view.electrons[y0:y1, x0:x1], dtype=np.float64)
        return SpotModel(truth, cov, total, self._laser_response.copy(), self._speckle_contrast,
                         self._speckle_grain, key or (), optics.SpotImage(x0, y0, room))

    def render_electrons(
        self,
        pan_deg: float,
        tilt_deg: float,
        lasers_on: Mapping[str, float | np.ndarray],
        t_s: float = 0.0,
        ambient_scale: float = 1.0,
    ) -> np.ndarray:
        """Mean photo-electrons per pixel (H, W, C) float32, before noise and clipping.

        `lasers_on` maps a laser's name to the fraction of the exposure it was on: a number, or an
        (H,) array with one fraction per row (a rolling shutter sees a switch mid-frame).
        """
        self._no_isp("photo-electrons")
        view = self._view(pan_deg, tilt_deg, t_s)
        img = view.electrons * np.float32(ambient_scale)
        for name, fraction in lasers_on.items():
            frac = np.asarray(fraction, dtype=np.float64)
            if frac.ndim == 0 and float(frac) <= 0.0:
                continue
            spot = self._lit_spot(view, name)[1]
            if spot is None:
                continue
            h, w = spot.electrons.shape
            e = spot.electrons
            e = e * (frac[spot.y0 : spot.y0 + h, None] if frac.ndim == 1 else float(frac))
            img[spot.y0 : spot.y0 + h, spot.x0 : spot.x0 + w, :] += (
                e[..., None] * self._laser_response
            ).astype(np.float32)
        return img

    def render(
        self,
        pan_deg: float,
        tilt_deg: float,
        lasers_on: Mapping[str, float | np.ndarray],
        t_s: float,
        rng: np.random.Generator,
        noise: bool = True,
    ) -> np.ndarray:
        """A frame as the camera delivers it: (H, W, 3) BGR or (H, W) grey, uint8 or uint16."""
        if self._sensor is not None:
            rows = {n: f if np.ndim(f) == 0 else np.asarray(f)[self._isp_rows] for n, f in lasers_on.items()}
            return sim_isp.scaled_frame(self._sensor.render(pan_deg, tilt_deg, rows, t_s, rng, noise))
        turn = self.jolt(lasers_on, rng)
        pan_deg, tilt_deg = pan_deg + turn[0], tilt_deg + turn[1]
        flicker = 1.0 + self.sim.ambient.flicker * (2.0 * rng.random() - 1.0) if noise else 1.0
        electrons = self.render_electrons(pan_deg, tilt_deg, lasers_on, t_s, flicker)
        return self.digitise(electrons, rng if noise else None)

    def jolt(self, lasers_on: Mapping[str, float | np.ndarray], rng: np.random.Generator) -> tuple[float, float]:
        """The turn (pan, tilt degrees) that `render` gives a frame with `lasers_on` and `rng`: for
        a dark frame, `sim.sway.jolt_deg` in a direction drawn first from `rng`; else none. (A
        recorder that keeps the turn in its truth calls this on a generator seeded as the frame's.)"""
        jolt = self.sim.sway.jolt_deg
        if not jolt or any(np.any(np.asarray(f) > 0) for f in lasers_on.values()):
            return 0.0, 0.0
        direction = float(rng.uniform(0.0, 2.0 * np.pi))
        return float(jolt * np.cos(direction)), float(jolt * np.sin(direction))

    def turned_pixels(self, pan_deg: float, tilt_deg: float, turn_deg: tuple[float, float], pixels: np.ndarray,
                      t_s: float = 0.0, rays: np.ndarray | None = None) -> np.ndarray:
        """Where the room seen at `pixels` (..., 2) of the view at (pan, tilt) shows in the view
        turned by `turn_deg` (pan, tilt): along each pixel's ray to the surface it meets, then into
        the turned camera. By the room's depth, not by the turn alone: a camera mounted off the
        unit's axes moves what is near more than what is far as it turns. Nothing hit counts as far
        away; movers are left out (the room's depth behind them), and so is `sim.sway.deg`'s
        turning. (The sensor's pixels, as `spot_model`'s; `rays`: theirs, `CameraModel.rays`, where
        the caller keeps them.)"""
        self._no_isp("a view's depth")
        view = self._static_view(pan_deg, tilt_deg)
        assert view.depth is not None  # (static views are rendered with their depth)
        cam = self.rig.camera
        px = np.asarray(pixels, dtype=np.float64)
        iu = np.clip(np.rint(px[..., 0]).astype(np.intp), 0, cam.width - 1)
        iv = np.clip(np.rint(px[..., 1]).astype(np.intp), 0, cam.height - 1)
        depth = view.depth[iv, iu]
        depth = np.where(np.isfinite(depth), depth, _FAR_M)
        world = view.camera_to_world.apply((cam.rays(px) if rays is None else rays) * depth[..., None])
        turned = self.camera_to_world(pan_deg + turn_deg[0], tilt_deg + turn_deg[1]).inverse().apply(world)
        return cam.project(turned)

    def _no_isp(self, what: str) -> None:
        if self._sensor is not None:
            raise ConfigError(f"sim.sensor.isp: the simulator gives {what} of the sensor only; "
                              f"render with sim.sensor.isp = false")

    def _normals(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """`n` standard normal numbers: a slice at a random offset of a bank made once. Drawing a
        frame's worth afresh takes most of a frame's render time; two slices at different offsets
        are as independent as the frames' noise needs to be (a difference image never pairs a
        pixel's noise with itself unless the offsets coincide: one chance in about a million)."""
        bank = self._normal_bank
        if bank is None or bank.size < 2 * n:
            seed = np.random.default_rng([self.sim.seed & 0xFFFFFFFF, 0xB4A1])
            bank = self._normal_bank = seed.standard_normal(2 * n + (1 << 20), dtype=np.float32)
        start = int(rng.integers(0, bank.size - n + 1))
        return bank[start : start + n]

    def digitise(self, electrons: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        """Photo-electrons → the frame the camera delivers (noise when `rng` is given)."""
        self._no_isp("frames of photo-electrons")
        sensor = self.sim.sensor
        e = np.array(electrons, dtype=np.float32)  # a copy, worked on in place from here
        mosaic = sensor.bayer != "none" and e.ndim == 3 and e.shape[-1] == 3
        if mosaic:
            e = _mosaic(e)
        if rng is not None:
            # Shot noise (Gaussian approximation of Poisson: the counts here are large) + read noise.
            sd = np.maximum(e, 0.0)
            sd += np.float32(sensor.read_noise_e**2)
            np.sqrt(sd, out=sd)
            sd *= self._normals(e.size, rng).reshape(e.shape)
            e += sd
        np.clip(e, 0.0, sensor.full_well_e, out=e)
        top = 2**sensor.adc_bits - 1
        e *= np.float32(self._dn_per_e)
        np.rint(e, out=e)
        np.clip(e, 0, top, out=e)
        if mosaic and sensor.dpc:
            e = _defects_corrected(e, sensor.dpc * top)
        # 16-bit PNGs hold the sensor's values scaled to the full 16-bit range (geometry.md).
        full = 255.0 if sensor.output_bits == 8 else 65535.0
        if sensor.gamma != 1.0:
            # (Before demosaicing, where an ISP applies it after: for a spot's few pixels the
            # order matters far less than the curve itself.)
            e *= np.float32(1.0 / top)
            e = tone_curve(e, sensor.gamma)
            e *= np.float32(full)
        else:
            e *= np.float32(full / top)
        np.rint(e, out=e)
        out: np.ndarray = e.astype(np.uint8 if sensor.output_bits == 8 else np.uint16)
        if mosaic:
            out = cv2.cvtColor(out, _DEMOSAIC[sensor.bayer])
        elif out.shape[-1] == 1:
            out = out[..., 0]
        if sensor.colour_matrix and out.ndim == 3:
            out = _colour_corrected(out, sensor.colour_matrix, sensor.gamma, full)
        if sensor.yuyv and out.ndim == 3:
            # Packed as the webcam sends it (chroma averaged over each two pixels of a row, luma in
            # video range), unpacked as OpenCV's V4L2 backend does.
            out = cv2.cvtColor(cv2.cvtColor(out, cv2.COLOR_BGR2YUV_YUYV), cv2.COLOR_YUV2BGR_YUYV)
        if sensor.jpeg_quality:
            # 8-bit only: the config refuses jpeg_quality with 16-bit output.
            params = [cv2.IMWRITE_JPEG_QUALITY, sensor.jpeg_quality]
            if out.ndim == 3:
                params += [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, _JPEG_CHROMA[sensor.jpeg_chroma]]
            ok, buf = cv2.imencode(".jpg", out, params)
            decoded = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if ok else None
            if decoded is None:
                raise CameraError(f"simulated camera: OpenCV could not round-trip a {out.shape} frame through JPEG")
            out = decoded
        return out


def _colour_corrected(out: np.ndarray, matrix: tuple[float, ...], gamma: float, full: float) -> np.ndarray:
    """A demosaiced BGR frame through an ISP's colour correction `matrix` (rows R', G', B' of
    columns R, G, B), in linear light, clipped to the frame's range: what leaves a camera's ISP.
    (The delivered values are rounded once more here; an ISP rounds once, from more bits.)"""
    x = out.astype(np.float32) * np.float32(1.0 / full)
    if gamma != 1.0:
        x = linear_light(x, gamma).astype(np.float32)
    # BGR frames: the matrix's rows and columns in reverse order.
    m = np.array(matrix, dtype=np.float32).reshape(3, 3)[::-1, ::-1]
    x = x @ m.T
    np.clip(x, 0.0, 1.0, out=x)
    if gamma != 1.0:
        x = tone_curve(x, gamma)
    x *= np.float32(full)
    np.rint(x, out=x)
    return x.astype(out.dtype)


def _defects_corrected(raw: np.ndarray, threshold: float) -> np.ndarray:
    """A raw Bayer frame's defective-pixel correction (sim.sensor.dpc): each pixel that differs from
    all 8 of its same-colour neighbours, 2 px away, by over `threshold` takes the median of the 4
    nearest of them (the frame's edges mirrored)."""
    padded = np.pad(raw, 2, mode="reflect")
    h, w = raw.shape

    def at(dv: int, du: int) -> np.ndarray:
        return padded[2 + dv: 2 + dv + h, 2 + du: 2 + du + w]

    ring = [at(dv, du) for dv in (-2, 0, 2) for du in (-2, 0, 2) if dv or du]
    odd = np.ones(raw.shape, bool)
    for n in ring:
        odd &= np.abs(n - raw) > threshold
    axial = np.median(np.stack([at(-2, 0), at(2, 0), at(0, -2), at(0, 2)]), axis=0)
    return np.where(odd, axial, raw).astype(raw.dtype)


def _mosaic(bgr: np.ndarray) -> np.ndarray:
    """What an RGGB Bayer sensor measures of a (H, W, 3) BGR image: (H, W), one colour a pixel."""
    raw = bgr[..., 1].copy()  # green on the other diagonal
    raw[0::2, 0::2] = bgr[0::2, 0::2, 2]
    raw[1::2, 1::2] = bgr[1::2, 1::2, 0]
    return raw
