"""Planar faces and a vectorised ray caster for the simulator's scenes.

A scene is a few dozen planar polygons (walls, floor, ceiling, boxes, movers). Each :class:`Face`
has a plane point (``origin``, where its surface coordinates are zero), two in-plane unit axes and
its polygon in those plane coordinates; a face's ``surface_uv`` are metres along those axes, which
move with the face, so textures stick to moving surfaces.

For casting, each face is split into convex *pieces* (most faces are rectangles: one piece; a
concave floor outline becomes triangles). Two paths:

* one origin shared by many rays (the renderer: a ray per pixel from the camera centre). Seen from
  the origin, a convex piece is a pyramid; a ray hits the piece iff its direction lies on the inner
  side of every edge plane through the origin — one small matrix product per piece. Rays are
  grouped in blocks of consecutive rays (neighbouring pixels), each with a bounding cone, so that a
  piece only looks at blocks its pyramid can reach and that are not already wholly hit nearer.
  Pieces are visited nearest first, which makes that occlusion cull effective.
* a few rays with their own origins (laser beams, visibility checks): plane intersection and an
  in-polygon test for every ray-piece pair at once.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np

from edge.rig import Pose
from edge.sim.materials import TEXTURE_FLOOR, TEXTURE_WAVES, Material, texture_waves

_BLOCK = 64  # rays per block of the shared-origin path: about a tenth of an image row
_FAST_MIN_RAYS = 256  # below this the general path is quicker than building blocks
_GENERAL_CHUNK = 256  # rays per chunk of the general path (bounds its (rays × pieces) temporaries)
_ANGLE_EPS = 1e-12  # slack of the edge tests, so that a ray along a shared edge hits a side
_PLANE_EPS_M = 1e-9
_MIN_T_M = 1e-12  # a ray starting on a surface does not hit that surface


# --- polygons in 2D ---------------------------------------------------------------------------


def polygon_area(poly: np.ndarray) -> float:
    """Signed area of a 2D polygon (K, 2): positive when counter-clockwise."""
    p = np.asarray(poly, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def polygon_self_intersects(poly: np.ndarray, eps: float = 1e-9) -> bool:
    """True if any two edges of the closed polygon meet, other than neighbours at their vertex."""
    p = np.asarray(poly, dtype=np.float64)
    n = len(p)
    edges = [(p[i], p[(i + 1) % n]) for i in range(n)]
    if any(np.linalg.norm(b - a) <= eps for a, b in edges):
        return True  # a repeated vertex
    for i in range(n):
        for j in range(i + 1, n):
            neighbours = j == i + 1 or (i == 0 and j == n - 1)
            if _segments_meet(*edges[i], *edges[j], eps, touching_ok=neighbours):
                return True
    return False


def _segments_meet(a, b, c, d, eps: float, touching_ok: bool) -> bool:
    def orient(p, q, r) -> float:
        return float((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    if touching_ok:
        # Neighbours share a vertex; they only overlap if they fold back onto each other.
        return abs(o1) <= eps and abs(o2) <= eps and float(np.dot(b - a, d - c)) < 0
    if (o1 > eps and o2 < -eps or o1 < -eps and o2 > eps) and (
        o3 > eps and o4 < -eps or o3 < -eps and o4 > eps
    ):
        return True

    def on_segment(p, q, r) -> bool:  # r on segment pq, given collinear
        return min(p[0], q[0]) - eps <= r[0] <= max(p[0], q[0]) + eps and (
            min(p[1], q[1]) - eps <= r[1] <= max(p[1], q[1]) + eps
        )

    return (
        (abs(o1) <= eps and on_segment(a, b, c))
        or (abs(o2) <= eps and on_segment(a, b, d))
        or (abs(o3) <= eps and on_segment(c, d, a))
        or (abs(o4) <= eps and on_segment(c, d, b))
    )


def points_in_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd test of 2D points (N, 2) against a polygon (K, 2); points on the boundary may go
    either way."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    p = np.asarray(poly, dtype=np.float64)
    x, y = pts[:, 0:1], pts[:, 1:2]
    x0, y0 = p[:, 0], p[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.count_nonzero(crosses & (x < x_at), axis=1) % 2) == 1


def convex_pieces(poly: np.ndarray, eps: float = 1e-12) -> list[np.ndarray]:
    """Split a simple counter-clockwise polygon into convex pieces (vertex index arrays).

    A convex polygon stays whole; anything else is ear-clipped into triangles.
    """
    p = np.asarray(poly, dtype=np.float64)
    n = len(p)

    def cross(i: int, j: int, k: int) -> float:
        (xi, yi), (xj, yj), (xk, yk) = p[i], p[j], p[k]
        return float((xj - xi) * (yk - yi) - (yj - yi) * (xk - xi))

    if all(cross(i - 1, i, (i + 1) % n) >= -eps for i in range(n)):
        return [np.arange(n)]
    idx = list(range(n))
    pieces: list[np.ndarray] = []
    while len(idx) > 3:
        for j in range(len(idx)):
            a, b, c = idx[j - 1], idx[j], idx[(j + 1) % len(idx)]
            turn = cross(a, b, c)
            if abs(turn) <= eps:  # collinear: the vertex adds nothing to the shape
                del idx[j]
                break
            if turn < 0:
                continue  # reflex vertex
            others = [k for k in idx if k not in (a, b, c)]
            if others and any(
                cross(a, b, k) >= -eps and cross(b, c, k) >= -eps and cross(c, a, k) >= -eps
                for k in others
            ):
                continue  # another vertex inside: not an ear
            pieces.append(np.array([a, b, c]))
            del idx[j]
            break
        else:
            raise ValueError("polygon is not simple")
    pieces.append(np.array(idx))
    return pieces


# --- faces --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Face:
    """A planar polygon: ``point = origin + s·u_axis + t·v_axis`` for (s, t) inside `polygon`."""

    name: str
    key: int  # stable across time: seeds the texture, identifies the face to the renderer
    material: Material
    origin: np.ndarray  # (3,) world frame
    u_axis: np.ndarray  # (3,) unit
    v_axis: np.ndarray  # (3,) unit, perpendicular to u_axis
    polygon: np.ndarray  # (K, 2) metres in (u, v); stored counter-clockwise about the normal

    def __post_init__(self) -> None:
        for name in ("origin", "u_axis", "v_axis", "polygon"):
            object.__setattr__(self, name, np.array(getattr(self, name), dtype=np.float64))
        if polygon_area(self.polygon) < 0:
            object.__setattr__(self, "polygon", self.polygon[::-1].copy())

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.u_axis, self.v_axis)

    @property
    def vertices(self) -> np.ndarray:
        """(K, 3) world frame."""
        return self.origin + self.polygon[:, :1] * self.u_axis + self.polygon[:, 1:] * self.v_axis

    def moved(self, pose: Pose) -> Face:
        """The face carried by a rigid motion; its surface coordinates move with it."""
        return Face(
            self.name, self.key, self.material, pose.apply(self.origin),
            pose.rotate(self.u_axis), pose.rotate(self.v_axis), self.polygon,
        )


def rectangle(
    name: str, key: int, material: Material, corner, u_axis, v_axis, width: float, height: float
) -> Face:
    """A width × height rectangle from `corner` along two perpendicular unit axes."""
    poly = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    return Face(name, key, material, corner, u_axis, v_axis, poly)


def box_faces(
    name: str, keys: Iterator[int], material: Material, pose: Pose, size: Sequence[float],
    bottom: bool,
) -> list[Face]:
    """Faces of a box, outward normals, placed by `pose` (box frame: origin at the centre of the
    bottom, x and y along the sides). No bottom face unless asked: a box standing on the floor
    never shows its underside."""
    hx, hy, h = size[0] / 2, size[1] / 2, size[2]
    x, y, z = np.eye(3)
    local = [
        rectangle(f"{name} +x", next(keys), material, (hx, -hy, 0), y, z, 2 * hy, h),
        rectangle(f"{name} -x", next(keys), material, (-hx, hy, 0), -y, z, 2 * hy, h),
        rectangle(f"{name} +y", next(keys), material, (hx, hy, 0), -x, z, 2 * hx, h),
        rectangle(f"{name} -y", next(keys), material, (-hx, -hy, 0), x, z, 2 * hx, h),
        rectangle(f"{name} top", next(keys), material, (-hx, -hy, h), x, y, 2 * hx, 2 * hy),
    ]
    if bottom:
        local.append(
            rectangle(f"{name} bottom", next(keys), material, (-hx, hy, 0), x, -y, 2 * hx, 2 * hy)
        )
    return [f.moved(pose) for f in local]


def footprint(pose: Pose, size_x: float, size_y: float) -> np.ndarray:
    """The 4 footprint corners (x, y) of a box frame, counter-clockwise."""
    hx, hy = size_x / 2, size_y / 2
    corners = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
    return pose.apply(corners)[:, :2]


@dataclass(frozen=True, eq=False)
class FaceSet:
    """Faces as arrays for casting: per face (F rows) and per convex piece (P rows).

    Building one costs a little (decomposition, texture seeds); moving and concatenating are cheap,
    which is what placing movers in every frame needs.
    """

    faces: tuple[Face, ...]
    origin: np.ndarray  # (F, 3)
    u_axis: np.ndarray  # (F, 3)
    v_axis: np.ndarray  # (F, 3)
    normal: np.ndarray  # (F, 3)
    key: np.ndarray  # (F,) int64
    albedo: np.ndarray  # (F, 3)
    gloss: np.ndarray  # (F,)
    shininess: np.ndarray  # (F,)
    tex_k: np.ndarray  # (F, W, 2)
    tex_phase: np.ndarray  # (F, W)
    tex_amp: np.ndarray  # (F, W)
    piece_face: np.ndarray  # (P,) int32
    piece_vertices: np.ndarray  # (P, K, 3), short pieces padded by repeating their last vertex

    @staticmethod
    def build(faces: Sequence[Face]) -> FaceSet:
        faces = tuple(faces)
        piece_face: list[int] = []
        pieces: list[np.ndarray] = []
        for i, f in enumerate(faces):
            verts = f.vertices
            for idx in convex_pieces(f.polygon):
                piece_face.append(i)
                pieces.append(verts[idx])
        waves = [texture_waves(f.material, f.key) for f in faces]
        return FaceSet(
            faces=faces,
            origin=_rows([f.origin for f in faces], 3),
            u_axis=_rows([f.u_axis for f in faces], 3),
            v_axis=_rows([f.v_axis for f in faces], 3),
            normal=_rows([f.normal for f in faces], 3),
            key=np.array([f.key for f in faces], dtype=np.int64),
            albedo=_rows([f.material.albedo for f in faces], 3),
            gloss=np.array([f.material.gloss for f in faces], dtype=np.float64),
            shininess=np.array([f.material.shininess for f in faces], dtype=np.float64),
            tex_k=np.array([w[0] for w in waves]).reshape(-1, TEXTURE_WAVES, 2),
            tex_phase=np.array([w[1] for w in waves]).reshape(-1, TEXTURE_WAVES),
            tex_amp=np.array([w[2] for w in waves]).reshape(-1, TEXTURE_WAVES),
            piece_face=np.array(piece_face, dtype=np.int32),
            piece_vertices=_pad_pieces(pieces, max((len(p) for p in pieces), default=3)),
        )

    def moved(self, pose: Pose) -> FaceSet:
        return replace(
            self,
            faces=tuple(f.moved(pose) for f in self.faces),
            origin=pose.apply(self.origin),
            u_axis=pose.rotate(self.u_axis),
            v_axis=pose.rotate(self.v_axis),
            normal=pose.rotate(self.normal),
            piece_vertices=pose.apply(self.piece_vertices),
        )

    @staticmethod
    def concat(sets: Sequence[FaceSet]) -> FaceSet:
        if len(sets) == 1:
            return sets[0]
        k = max(s.piece_vertices.shape[1] for s in sets)
        offsets = np.cumsum([0] + [len(s.faces) for s in sets[:-1]])
        joined = {
            name: np.concatenate([getattr(s, name) for s in sets])
            for name in ("origin", "u_axis", "v_axis", "normal", "key", "albedo", "gloss",
                         "shininess", "tex_k", "tex_phase", "tex_amp")
        }
        return FaceSet(
            faces=tuple(f for s in sets for f in s.faces),
            piece_face=np.concatenate(
                [s.piece_face + np.int32(o) for s, o in zip(sets, offsets)]
            ).astype(np.int32),
            piece_vertices=np.concatenate([_pad_pieces(s.piece_vertices, k) for s in sets]),
            **joined,
        )


def _rows(items: Sequence, width: int) -> np.ndarray:
    return np.array(items, dtype=np.float64).reshape(-1, width)


def _pad_pieces(pieces, k: int) -> np.ndarray:
    """Stack vertex lists to (P, k, 3), repeating each one's last vertex: the repeats make edges
    of zero length, which every edge test passes."""
    if isinstance(pieces, np.ndarray) and pieces.shape[1] == k:
        return pieces
    out = np.empty((len(pieces), k, 3))
    for i, p in enumerate(pieces):
        n = len(p)
        out[i, :n] = p
        out[i, n:] = p[n - 1]
    return out


# --- casting ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Hits:
    """What N rays hit."""

    distance: np.ndarray  # (N,) float64, inf where nothing was hit
    face: np.ndarray  # (N,) int32 index into the geometry's faces, -1 where nothing
    point: np.ndarray  # (N, 3) world frame, NaN where nothing
    normal: np.ndarray  # (N, 3) unit, facing the ray's origin; 0 where nothing
    surface_uv: np.ndarray  # (N, 2) metres in the face's own plane; 0 where nothing

    @property
    def hit(self) -> np.ndarray:
        return self.face >= 0


class SceneGeometry:
    """A scene frozen at one instant, ready for casting and shading.

    Per-face tables carry one extra zero row at the end, so that indexing them with face -1
    (nothing hit) yields zeros without a mask.
    """

    def __init__(self, faceset: FaceSet):
        self.faceset = fs = faceset

        def pad(a: np.ndarray, fill: float = 0.0) -> np.ndarray:
            return np.concatenate([a, np.full((1,) + a.shape[1:], fill, dtype=a.dtype)])

        self._origin, self._u, self._v = pad(fs.origin), pad(fs.u_axis), pad(fs.v_axis)
        self._normal, self._albedo = pad(fs.normal), pad(fs.albedo)
        self._gloss, self._shininess = pad(fs.gloss), pad(fs.shininess)
        self._key = pad(fs.key, -1)
        verts = fs.piece_vertices
        normal = fs.normal[fs.piece_face]
        lo, hi = verts.min(axis=1), verts.max(axis=1)
        centre = 0.5 * (lo + hi)
        edges = np.roll(verts, -1, axis=1) - verts
        inward = np.cross(normal[:, None, :], edges)  # counter-clockwise: interior on the left
        inward /= np.maximum(np.linalg.norm(inward, axis=2, keepdims=True), 1e-300)
        self._pieces = {
            "vertices": verts,
            # Edges of non-zero length; padding repeats make the others.
            "edges": [np.flatnonzero(row) for row in np.linalg.norm(edges, axis=2) > 0],
            "normal": normal,
            "plane_d": np.einsum("pi,pi->p", normal, verts[:, 0]),
            "centre": centre,
            "radius": np.linalg.norm(verts - centre[:, None, :], axis=2).max(axis=1),
            "inward": inward,
            "inward_d": np.einsum("pki,pki->pk", inward, verts),
        }

    @property
    def faces(self) -> tuple[Face, ...]:
        return self.faceset.faces

    @property
    def faces_count(self) -> int:
        return len(self.faceset.faces)

    def face_key(self, face: np.ndarray) -> np.ndarray:
        """Stable id of each face across time (-1 for no face)."""
        return np.take(self._key, np.asarray(face, dtype=np.intp))

    def material(self, face: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Albedo (N, 3), gloss (N,) and shininess (N,) of each face; zeros for face -1."""
        f = np.asarray(face, dtype=np.intp)
        # np.take: several times quicker than fancy indexing for a frame's worth of rays.
        albedo = np.take(self._albedo, f, axis=0)
        return albedo, np.take(self._gloss, f), np.take(self._shininess, f)

    def uv_axes(self, face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The axes (N, 3) and (N, 3) of each face's `surface_uv` (world frame); zeros for face -1."""
        f = np.asarray(face, dtype=np.intp)
        return np.take(self._u, f, axis=0), np.take(self._v, f, axis=0)

    def texture(self, face: np.ndarray, surface_uv: np.ndarray, footprint: np.ndarray | None = None) -> np.ndarray:
        """Multiplicative texture (N,): mean about 1, at least TEXTURE_FLOOR; 1 for face -1.

        With `footprint` (N, 2, 2: how `surface_uv` moves a pixel's step along the image's u, then
        v), each point's texture is the mean over the pixel it is seen by, as a sensor's pixel
        integrates the light over its area: each wave scaled by the mean of a cosine over a step
        of its phase each way (sinc). Sampled at points only, waves finer than a pixel fold into
        coarse false patterns (aliasing) that no camera's frames hold, and that do not follow the
        room when the camera turns."""
        f = np.asarray(face, dtype=np.intp).ravel()
        uv = np.asarray(surface_uv, dtype=np.float64).reshape(-1, 2)
        steps = None if footprint is None else np.asarray(footprint, dtype=np.float64).reshape(-1, 2, 2)
        out = np.ones(len(f))
        if not len(f):
            return out
        # Group rays by face (int16 keys get numpy's radix sort) so each face's waves apply in bulk.
        keys = f.astype(np.int16) if self.faces_count < 2**15 - 1 else f
        order = np.argsort(keys, kind="stable")
        sorted_f = f[order]
        starts = np.flatnonzero(np.r_[True, sorted_f[1:] != sorted_f[:-1]])
        ends = np.r_[starts[1:], len(f)]
        amp, k, phase = self.faceset.tex_amp, self.faceset.tex_k, self.faceset.tex_phase
        for s, e in zip(starts, ends):
            fi = sorted_f[s]
            if fi < 0 or not amp[fi].any():
                continue
            rows = order[s:e]
            arg = np.take(uv, rows, axis=0) @ k[fi].T
            arg += phase[fi]
            # float32 cosines are SIMD and some 30 times quicker; their ~1e-3 rad error at the
            # largest arguments (a few 10⁴ rad) is invisible in a texture.
            wave = np.cos(arg.astype(np.float32))
            if steps is not None:
                step = np.take(steps, rows, axis=0).astype(np.float32)  # (n, 2, 2)
                # Half the waves' phase over a pixel's step along u, and along v: the mean of a
                # cosine over a step of phase 2x is its value at the middle times sin x / x.
                half = (k[fi].T / 2.0).astype(np.float32)
                for along in (step[:, :, 0] @ half, step[:, :, 1] @ half):
                    wave *= np.divide(np.sin(along), along, out=np.ones_like(along), where=along != 0.0)
            out[rows] = 1.0 + wave @ amp[fi].astype(np.float32)
        return np.maximum(out, TEXTURE_FLOOR, out=out)

    def cast(
        self, origins: np.ndarray, directions: np.ndarray, max_distance: float = np.inf
    ) -> Hits:
        """Nearest hit of each ray closer than `max_distance`.

        `origins`: (3,) shared by all rays, or (N, 3); `directions`: (N, 3) unit, world frame.
        """
        d = np.asarray(directions, dtype=np.float64)
        if d.ndim != 2 or d.shape[1] != 3:
            raise ValueError(f"directions must have shape (N, 3), got {d.shape}")
        o = np.asarray(origins, dtype=np.float64)
        if o.shape == (3,) and len(d) >= _FAST_MIN_RAYS:
            # Rows of x, y, z: the hot loops then read contiguous runs and use np.take.
            d_rows = np.ascontiguousarray(d.T)
            t, face = self._cast_shared(o, d_rows, float(max_distance))
        elif o.shape == (3,) or o.shape == d.shape:
            d_rows = np.ascontiguousarray(d.T)
            t, face = self._cast_general(np.broadcast_to(o, d.shape), d, float(max_distance))
        else:
            raise ValueError(f"origins must have shape (3,) or {d.shape}, got {o.shape}")
        return self._hits(o, d_rows, t, face)

    def _cast_shared(self, o: np.ndarray, d_rows: np.ndarray, max_distance: float):
        """All rays from `o`; `d_rows` (3, N) are the directions as rows of x, y, z."""
        pc = self._pieces
        n_rays = d_rows.shape[1]
        n_blocks = -(-n_rays // _BLOCK)
        if n_blocks * _BLOCK != n_rays:  # pad with copies of the last ray; dropped at the end
            fill = np.repeat(d_rows[:, -1:], n_blocks * _BLOCK - n_rays, axis=1)
            d_rows = np.concatenate([d_rows, fill], axis=1)
        # Bounding cone of each block: mean axis and the sine of its half-angle (2 = "any").
        blocks = d_rows.reshape(3, n_blocks, _BLOCK)
        axis = blocks.sum(axis=2)
        axis /= np.maximum(np.sqrt((axis * axis).sum(axis=0)), 1e-300)
        cos_half = (blocks * axis[:, :, None]).sum(axis=0).min(axis=1)
        sin_half = np.where(cos_half > 0, np.sqrt(np.clip(1.0 - cos_half**2, 0, 1)) + 1e-9, 2.0)
        best = np.full(n_blocks * _BLOCK, max_distance)
        face = np.full(n_blocks * _BLOCK, -1, dtype=np.int32)
        block_far = np.full(n_blocks, max_distance)  # farthest current hit in each block

        # Per piece, seen from o: edge planes through o, signed plane distance, a distance bound.
        rel = pc["vertices"] - o
        h = pc["plane_d"] - pc["normal"] @ o  # n·(p0 - o): negative when o is in front
        edge_n = np.cross(np.roll(rel, -1, axis=1), rel) * -np.sign(h)[:, None, None]
        edge_n /= np.maximum(np.linalg.norm(edge_n, axis=2, keepdims=True), 1e-300)
        near = np.maximum(np.abs(h), np.linalg.norm(pc["centre"] - o, axis=1) - pc["radius"])
        lane = np.arange(_BLOCK)
        for p in np.argsort(near):
            if abs(h[p]) < _PLANE_EPS_M or near[p] >= max_distance:
                continue  # o in the piece's plane (rays graze it) or the piece is out of reach
            m = edge_n[p, pc["edges"][p]]  # (k, 3)
            reach = block_far > near[p]
            for row in m @ axis:  # a block is out if its cone lies beyond one edge plane
                reach &= row >= -sin_half
            live = np.flatnonzero(reach)
            if not live.size:
                continue
            idx = (live[:, None] * _BLOCK + lane).ravel()
            proj = np.vstack([m, pc["normal"][p]]) @ np.take(d_rows, idx, axis=1)  # (k + 1, M)
            inside = proj[0] >= -_ANGLE_EPS
            for row in proj[1:-1]:
                inside &= row >= -_ANGLE_EPS
            sel = np.flatnonzero(inside)
            if not sel.size:
                continue
            t = h[p] / proj[-1, sel]
            rows = idx[sel]
            closer = (t < best[rows]) & (t > _MIN_T_M)
            if not closer.any():
                continue
            rows = rows[closer]
            best[rows] = t[closer]
            face[rows] = self.faceset.piece_face[p]
            block_far[live] = np.take(best, idx).reshape(-1, _BLOCK).max(axis=1)
        return best[:n_rays], face[:n_rays]

    def _cast_general(self, o: np.ndarray, d: np.ndarray, max_distance: float):
        pc = self._pieces
        t_out = np.full(len(d), np.inf)
        face = np.full(len(d), -1, dtype=np.int32)
        if not len(pc["vertices"]):
            return t_out, face
        for s in range(0, len(d), _GENERAL_CHUNK):
            oc, dc = o[s : s + _GENERAL_CHUNK], d[s : s + _GENERAL_CHUNK]
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                dn = dc @ pc["normal"].T  # (n, P)
                t = (pc["plane_d"][None, :] - oc @ pc["normal"].T) / dn
                q = oc[:, None, :] + t[..., None] * dc[:, None, :]
                side = np.einsum("npj,pkj->npk", q, pc["inward"]) - pc["inward_d"][None]
                ok = (side >= -_PLANE_EPS_M).all(axis=2) & (t > _MIN_T_M) & (t < max_distance)
            t = np.where(ok, t, np.inf)
            j = np.argmin(t, axis=1)
            tj = t[np.arange(len(dc)), j]
            t_out[s : s + _GENERAL_CHUNK] = tj
            face[s : s + _GENERAL_CHUNK] = np.where(np.isfinite(tj), self.faceset.piece_face[j], -1)
        return t_out, face

    def _hits(self, o: np.ndarray, d_rows: np.ndarray, t: np.ndarray, face: np.ndarray) -> Hits:
        """Assemble the hit record. Works on rows of x, y, z and 1D gathers from per-face tables
        (np.take), which is several times quicker than fancy-indexing (N, 3) arrays."""
        hit = face >= 0
        n = len(face)
        o_rows = np.broadcast_to(np.asarray(o).T.reshape(3, -1), (3, n))
        t_hit = np.where(hit, t, np.nan)
        point = d_rows * t_hit
        point += o_rows
        normal = np.take(self._normal.T, face, axis=1)  # face -1 picks the zero row
        facing = (normal * d_rows).sum(axis=0)
        normal *= np.where(facing > 0, -1.0, 1.0)
        rel = point - np.take(self._origin.T, face, axis=1)
        uv = np.empty((2, n))
        uv[0] = (rel * np.take(self._u.T, face, axis=1)).sum(axis=0)
        uv[1] = (rel * np.take(self._v.T, face, axis=1)).sum(axis=0)
        uv[:, ~hit] = 0.0
        return Hits(
            distance=np.where(hit, t, np.inf),
            face=face,
            point=np.ascontiguousarray(point.T),
            normal=np.ascontiguousarray(normal.T),
            surface_uv=np.ascontiguousarray(uv.T),
        )
