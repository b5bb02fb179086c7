"""An occupancy grid that accumulates: what the rays of every sweep say about the room, in log-odds.

Pure: zone results and the rig in, arrays out; saving them as files is :mod:`edge.mapfiles`'s job.

The grid is a horizontal slice of the unit's base frame (``shared/spec/geometry.md``: the unit at
the origin, x forward, y left), ``band_m`` high. Each zone is one ray, the reference laser's beam:

- ``ok``: the cells between the laser and its hit become more likely free, the hit's cell (and its
  neighbours along the beam, as far as σ spreads the hit) more likely occupied, nothing beyond;
- ``no_spot`` and ``out_of_range`` (beyond the far limit): free up to where the working range says
  the spot would have been seen (the far limit's depth; when the zone's other lasers saw spots,
  80 % of the nearest one's depth), nothing beyond;
- ``ambiguous``, ``fault``, and ``out_of_range`` nearer than the near limit: nothing.

A tilted ray counts only where it is inside the band (a floor hit is no obstacle; the part of its
beam above the floor's band is still free space). Updates add log-odds, clamped so that a room
that changes is learnt again in a few sweeps.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from edge.ranging import NO_SPOT, OK, OUT_OF_RANGE, ZoneResult
from edge.rig import Rig
from edge.schema import require

# A hit marks the cells whose chance of holding it is at least this share of the likeliest's.
SPREAD_MIN_SHARE = 0.5
# A no_spot ray whose other lasers saw spots is free up to this fraction of their nearest depth.
OTHERS_MARGIN = 0.8
# A ray passes through a doorway where it has occupied cells (the jambs) within this on both sides.
DOOR_WIDTH_M = 1.2


def logit(p: float) -> float:
    return math.log(p / (1.0 - p))


@dataclass(frozen=True)
class GridConfig:
    """The occupancy grid (``[map]`` in the config)."""

    resolution_m: float = 0.05  # cell size
    # Heights (base z, the pan-tilt axes at 0) the grid maps: obstacles and free space of this slice.
    band_m: tuple[float, float] = (-0.5, 0.5)
    # Evidence per ray, as probabilities: a hit's cell, and a cell the beam crossed before its hit.
    hit_p: float = 0.9
    miss_p: float = 0.18
    # Log-odds are clamped to ±logit(clamp_p): a moved chair is unlearnt in a few sweeps.
    clamp_p: float = 0.98
    # A cell above occupied_p is occupied, below free_p free, else unknown (map_saver's defaults).
    occupied_p: float = 0.65
    free_p: float = 0.196

    def __post_init__(self) -> None:
        require(0.005 <= self.resolution_m <= 1.0, "resolution_m", "must be 0.005-1 m")
        lo, hi = self.band_m
        require(lo < hi, "band_m", f"must be [low, high] with low < high, got [{lo:g}, {hi:g}]")
        require(0.5 < self.hit_p < 1.0, "hit_p", "must be between 0.5 and 1")
        require(0.0 < self.miss_p < 0.5, "miss_p", "must be between 0 and 0.5")
        require(0.5 < self.clamp_p < 1.0, "clamp_p", "must be between 0.5 and 1")
        require(0.5 <= self.occupied_p < 1.0, "occupied_p", "must be 0.5-1")
        require(0.0 < self.free_p <= 0.5, "free_p", "must be 0-0.5")


@dataclass(frozen=True)
class Ray:
    """One beam, base frame: from `origin` along unit `direction`. With `hit_m`, it met a surface
    that far (σ `sigma_m` along the beam); without, it saw nothing up to `free_m`."""

    origin: np.ndarray  # (3,)
    direction: np.ndarray  # (3,) unit
    hit_m: float | None = None
    sigma_m: float = 0.0
    free_m: float = 0.0

    @property
    def end(self) -> np.ndarray | None:
        return None if self.hit_m is None else self.origin + self.hit_m * self.direction


def zone_ray(rig: Rig, result: ZoneResult) -> Ray | None:
    """The ray a zone result says something about (None: it says nothing, see the module)."""
    ref = rig.reference
    pose = rig.camera_to_base(result.pan_deg, result.tilt_deg)
    origin = pose.apply(ref.o)
    if result.status == OK and result.point_base_m is not None:
        v = np.asarray(result.point_base_m, dtype=np.float64) - origin
        d = float(np.linalg.norm(v))
        if d <= 0.0:
            return None
        # σ of the camera depth, along the beam: depth changes by d_z per metre of beam.
        sigma = (result.sigma_m or 0.0) / max(abs(ref.direction[2]), 1e-3)
        return Ray(origin, v / d, hit_m=d, sigma_m=sigma)
    near, far = rig.range_limits_m
    if result.status == OUT_OF_RANGE:
        measured = result.lasers.get(ref.name)
        if measured is None or measured.depth_m < near:
            return None  # something nearer than the working range, or we cannot tell: no claim
    elif result.status != NO_SPOT:
        return None
    if ref.direction[2] <= 1e-3:
        return None
    depth = far
    # Other lasers' spots say a surface is in range after all (a glossy edge hid the reference's
    # spot): free only well short of the nearest of them, since the beams are centimetres apart.
    others = [m.depth_m for name, m in result.lasers.items() if name != ref.name]
    if others:
        depth = min(depth, OTHERS_MARGIN * min(others))
    free = (depth - ref.origin_m[2]) / ref.direction[2]
    return Ray(origin, pose.rotate(ref.d), free_m=float(free))


def zone_rays(rig: Rig, results: Iterable[ZoneResult]) -> list[Ray]:
    return [ray for r in results if (ray := zone_ray(rig, r)) is not None]


def _phi(x: np.ndarray) -> np.ndarray:
    """The standard normal CDF."""
    from math import erf

    return 0.5 * (1.0 + np.vectorize(erf)(x / math.sqrt(2.0)))


class OccupancyGrid:
    """Log-odds (float32) of square cells, ``size`` × ``size``, centred on the unit.

    ``log_odds[iy, ix]`` is the cell whose lower-left corner is ``origin + (ix, iy)·resolution``:
    rows go up in y (map_server's image flips them, row 0 at the top)."""

    def __init__(self, config: GridConfig, half_size_m: float, log_odds: np.ndarray | None = None):
        self.config = config
        self.resolution = config.resolution_m
        cells = 2 * int(math.ceil(half_size_m / self.resolution))
        self.origin = (-cells / 2 * self.resolution, -cells / 2 * self.resolution)
        if log_odds is None:
            log_odds = np.zeros((cells, cells), np.float32)
        if log_odds.shape != (cells, cells):
            raise ValueError(f"log_odds must be {cells}x{cells}, got {log_odds.shape}")
        self.log_odds = log_odds.astype(np.float32, copy=True)
        self._hit = logit(config.hit_p)
        self._miss = logit(config.miss_p)
        self._clamp = logit(config.clamp_p)

    @classmethod
    def for_rig(cls, config: GridConfig, rig: Rig) -> OccupancyGrid:
        """A grid wide enough for everything the rig can range (its far limit, and a margin)."""
        return cls(config, rig.range_limits_m[1] * 1.05 + 2 * config.resolution_m)

    @property
    def size(self) -> int:
        return self.log_odds.shape[0]

    @property
    def half_size_m(self) -> float:
        return self.size * self.resolution / 2

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ix, iy) of base-frame points (…, 2 or 3); may lie outside the grid."""
        xy = np.asarray(xy, dtype=np.float64)
        ix = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        iy = np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        return ix, iy

    def occupied(self) -> np.ndarray:
        """(size, size) bool: the cells believed occupied."""
        return self.log_odds > logit(self.config.occupied_p)

    def free(self) -> np.ndarray:
        return self.log_odds < logit(self.config.free_p)

    def probability(self) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-self.log_odds.astype(np.float64)))

    def add_results(self, rig: Rig, results: Sequence[ZoneResult]) -> int:
        """Fuse a sweep's zone results; returns how many rays said something."""
        rays = zone_rays(rig, results)
        self.add_rays(rays)
        return len(rays)

    def _crossed(self, ray: Ray, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The stretches [t_in, t_out] of the beam from 0 to `reach` inside the band, one per cell
        crossed (exactly: where the beam's plan view crosses the cells' edges), and their cells
        (flat indices); cells outside the grid are left out."""
        lo, hi = self.config.band_m
        o, d = ray.origin, ray.direction
        t0, t1 = 0.0, reach
        if abs(d[2]) > 1e-12:
            a, b = (lo - o[2]) / d[2], (hi - o[2]) / d[2]
            t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
        elif not lo <= o[2] <= hi:
            t1 = t0
        empty = np.zeros(0), np.zeros(0), np.zeros(0, np.int64)
        if t1 <= t0:
            return empty
        cuts = [np.array([t0, t1])]
        for axis in (0, 1):
            if abs(d[axis]) > 1e-12:
                edge0 = self.origin[axis]
                a, b = sorted(((o[axis] + t0 * d[axis] - edge0) / self.resolution,
                               (o[axis] + t1 * d[axis] - edge0) / self.resolution))
                k = np.arange(math.ceil(a), math.floor(b) + 1)
                cuts.append((edge0 + k * self.resolution - o[axis]) / d[axis])
        t = np.unique(np.clip(np.concatenate(cuts), t0, t1))
        t_in, t_out = t[:-1], t[1:]
        keep = t_out - t_in > 1e-9
        t_in, t_out = t_in[keep], t_out[keep]
        ix, iy = self.cell_of(o + ((t_in + t_out) / 2)[:, None] * d)
        inside = (ix >= 0) & (iy >= 0) & (ix < self.size) & (iy < self.size)
        if not inside.any():
            return empty
        return t_in[inside], t_out[inside], (iy * self.size + ix)[inside]

    def add_rays(self, rays: Sequence[Ray]) -> None:
        """Each ray updates each cell it crosses inside the band once (see the module)."""
        if not rays:
            return
        ids, t_ins, t_outs, cells = [], [], [], []
        for k, ray in enumerate(rays):
            spread = math.hypot(ray.sigma_m, self.resolution / 4)
            reach = ray.hit_m + 4 * spread if ray.hit_m is not None else ray.free_m
            t_in, t_out, cell = self._crossed(ray, reach)
            ids.append(np.full(len(cell), k))
            t_ins.append(t_in)
            t_outs.append(t_out)
            cells.append(cell)
        ray_id, t_in, t_out, cell = (np.concatenate(a) for a in (ids, t_ins, t_outs, cells))
        if not len(cell):
            return
        lo, hi = self.config.band_m
        # A hit outside the band (the floor, the ceiling) is no obstacle of this slice.
        hit = np.array([r.hit_m if r.hit_m is not None and lo <= float(r.origin[2] + r.hit_m * r.direction[2])
                        <= hi else np.nan for r in rays])[ray_id]
        # A hit is spread by its σ and by a quarter of a cell: the obstacle's thickness of
        # Thrun's inverse sensor model. A wall on a cell's edge (rooms are often a whole number of
        # cells across) then marks both cells, not whichever side its noise fell on.
        sigma = np.hypot(np.array([r.sigma_m for r in rays]), self.resolution / 4)[ray_id]
        free_to = np.array([r.free_m for r in rays])[ray_id]
        has_hit = ~np.isnan(hit)
        delta = np.zeros(len(cell))
        # Free: the whole stretch lies before the hit with 99 % confidence (or before free_to).
        hit_m = np.array([r.hit_m if r.hit_m is not None else np.nan for r in rays])[ray_id]
        before = np.where(np.isnan(hit_m), t_out <= free_to, t_out <= hit_m - 2.33 * sigma)
        delta[before] = self._miss
        # Occupied: the chance that the hit lies in this stretch, relative to the likeliest cell.
        if has_hit.any():
            h = np.flatnonzero(has_hit)
            mass = _phi((t_out[h] - hit[h]) / sigma[h]) - _phi((t_in[h] - hit[h]) / sigma[h])
            peak = np.zeros(len(rays))
            np.maximum.at(peak, ray_id[h], mass)
            share = mass / np.maximum(peak[ray_id[h]], 1e-12)
            # Only cells about as likely as the likeliest: a far hit's σ of several centimetres would
            # otherwise thicken walls by a cell on each side, which repeated sweeps make occupied.
            spread = share >= SPREAD_MIN_SHARE
            delta[h[spread]] = self._hit * share[spread]
        flat = self.log_odds.reshape(-1)
        acc = np.zeros(flat.shape, np.float64)
        np.add.at(acc, cell, delta)
        touched = acc != 0
        flat[touched] = np.clip(flat[touched] + acc[touched], -self._clamp, self._clamp)

    def doorway_m(self, origin: np.ndarray, direction: np.ndarray, far_m: float,
                  width_m: float = DOOR_WIDTH_M) -> float | None:
        """How far along a horizontal ray from `origin` (base frame x, y) in `direction` (x, y)
        the room ends, when the ray leaves it through a doorway: the distance at which it is
        again more than `width_m` from occupied cells on one of its sides, past the last place
        where it had some on both (the jambs; a ray through the middle of a door 0.9 m wide is
        past them about a metre beyond the door). Only when the ray meets no occupied cell of
        its own up to `far_m` (a doorway onto a dark or long corridor, not a gap between two
        cupboards before a wall, nor a door onto a corridor's lit wall); else None, and None
        where it never passes between occupied cells. Meant for the rays of the zones the map
        was made from: between them a wall a sweep saw is a dotted line, and a ray through one of
        its gaps looks like one through a door (it ends in the room all the same: beyond the
        wall by about a metre)."""
        o = np.asarray(origin, np.float64)[:2]
        d = np.asarray(direction, np.float64)[:2]
        norm = float(np.linalg.norm(d))
        if norm <= 0.0 or far_m <= 0.0:
            return None
        d = d / norm
        iy, ix = np.nonzero(self.occupied())
        centres = np.stack([self.origin[0] + (ix + 0.5) * self.resolution,
                            self.origin[1] + (iy + 0.5) * self.resolution], axis=1) - o
        along, across = centres @ d, centres @ np.array([-d[1], d[0]])
        near = (along > 0) & (along < far_m + self.resolution)
        if np.any(near & (np.abs(across) < 0.75 * self.resolution)):
            return None  # the ray meets something: whatever it ranges is in the room
        s = np.arange(self.resolution / 2, far_m, self.resolution / 2)
        dist = np.hypot(along[None, :] - s[:, None], across[None, :])  # (steps, occupied cells)
        close = dist <= width_m
        both = np.any(close & (across > 0), axis=1) & np.any(close & (across < 0), axis=1)
        if not both.any():
            return None
        last = int(np.flatnonzero(both)[-1])
        return float(s[last] + self.resolution) if last + 1 < len(s) else None


# --- files: map_server's PGM + YAML, and a picture for people --------------------------------------

# map_saver's trinary values: occupied black, free white, unknown grey.
OCCUPIED_PIXEL, FREE_PIXEL, UNKNOWN_PIXEL = 0, 254, 205


def map_image(grid: OccupancyGrid) -> np.ndarray:
    """(size, size) uint8 as map_server reads it: row 0 at the top (largest y), column 0 at the
    left (smallest x)."""
    img = np.full(grid.log_odds.shape, UNKNOWN_PIXEL, np.uint8)
    img[grid.free()] = FREE_PIXEL
    img[grid.occupied()] = OCCUPIED_PIXEL
    return np.ascontiguousarray(img[::-1])


def pgm_bytes(grid: OccupancyGrid) -> bytes:
    """The map as a binary PGM (P5), map_saver's format."""
    img = map_image(grid)
    header = f"P5\n# edge occupancy grid, {grid.resolution:g} m/cell\n{img.shape[1]} {img.shape[0]}\n255\n"
    return header.encode() + img.tobytes()


def yaml_text(grid: OccupancyGrid, image: str = "map.pgm") -> str:
    """map_server's map.yaml. Its thresholds read our trinary pixels back as we classed them: 0
    occupied, 254 free, 205 (p = 0.196, not below free_thresh) unknown."""
    ox, oy = grid.origin
    return (
        f"image: {image}\n"
        "mode: trinary\n"
        f"resolution: {grid.resolution:.6g}\n"
        f"origin: [{ox:.6g}, {oy:.6g}, 0.0]\n"
        "negate: 0\n"
        "occupied_thresh: 0.65\n"
        "free_thresh: 0.196\n"
    )


Segment = tuple[tuple[float, float], tuple[float, float]]


def grid_picture(
    grid: OccupancyGrid,
    points: Sequence[Sequence[float]] = (),
    room: Sequence[Segment] = (),
    title: str = "",
    min_size_px: int = 640,
) -> np.ndarray:
    """The grid as a BGR picture for people, oriented as RViz shows map.pgm (x right, y up): free
    white, occupied black, unknown grey, a 1 m grid, measured points (green) and the true room
    (red, when known), the unit at the centre (orange, pointing along x)."""
    import cv2

    # Crop to what is known (and the room), with a margin: most of a fresh grid is unknown.
    known = np.argwhere(grid.free() | grid.occupied())
    res = grid.resolution
    mid = grid.size // 2
    ix0, iy0, ix1, iy1 = mid - 20, mid - 20, mid + 20, mid + 20
    if len(known):
        iy0, ix0 = (int(v) for v in np.minimum(known.min(axis=0), (iy0, ix0)))
        iy1, ix1 = (int(v) for v in np.maximum(known.max(axis=0) + 1, (iy1, ix1)))
    for a, b in room:
        for x, y in (a, b):
            cx, cy = (int(v) for v in grid.cell_of(np.array([x, y])))
            ix0, iy0, ix1, iy1 = min(ix0, cx), min(iy0, cy), max(ix1, cx + 1), max(iy1, cy + 1)
    pad = max(4, int(0.3 / res))
    ix0, iy0 = max(0, int(ix0) - pad), max(0, int(iy0) - pad)
    ix1, iy1 = min(grid.size, int(ix1) + pad), min(grid.size, int(iy1) + pad)
    cells = map_image(grid)[grid.size - iy1: grid.size - iy0, ix0:ix1]
    scale = max(1, int(math.ceil(min_size_px / max(cells.shape))))
    grey = np.where(cells == UNKNOWN_PIXEL, 150, np.where(cells == FREE_PIXEL, 255, 0)).astype(np.uint8)
    img = cv2.cvtColor(cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST),
                       cv2.COLOR_GRAY2BGR)
    top = 30
    img = cv2.copyMakeBorder(img, top, 0, 0, 0, cv2.BORDER_CONSTANT, value=(40, 40, 40))
    x_left = grid.origin[0] + ix0 * res
    y_top = grid.origin[1] + iy1 * res
    px_per_m = scale / res

    def px(x: float, y: float) -> tuple[int, int]:
        return int(round((x - x_left) * px_per_m)), int(round((y_top - y) * px_per_m)) + top

    for k in range(int(math.floor(x_left)), int(math.ceil(x_left + (ix1 - ix0) * res)) + 1):
        cv2.line(img, px(k, y_top), px(k, y_top - (iy1 - iy0) * res), (200, 170, 120), 1)
    for k in range(int(math.floor(y_top - (iy1 - iy0) * res)), int(math.ceil(y_top)) + 1):
        cv2.line(img, px(x_left, k), px(x_left + (ix1 - ix0) * res, k), (200, 170, 120), 1)
    for a, b in room:
        cv2.line(img, px(*a), px(*b), (60, 60, 220), 1, cv2.LINE_AA)
    for p in points:
        cv2.circle(img, px(float(p[0]), float(p[1])), 2, (40, 170, 40), -1, cv2.LINE_AA)
    tri = np.array([px(0.2, 0), px(-0.08, 0.08), px(-0.08, -0.08)], np.int32)
    cv2.fillPoly(img, [tri], (0, 140, 255), cv2.LINE_AA)
    text = (title + "; " if title else "") + f"{res * 100:g} cm cells, grid 1 m; x right, y up" + (
        "; red: true room" if room else "")
    cv2.putText(img, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (230, 230, 230), 1, cv2.LINE_AA)
    return img


# --- state: the grid kept across sweeps and restarts -------------------------------------------------

_STATE_FORMAT = "edge-grid/1"


def state_bytes(grid: OccupancyGrid) -> bytes:
    """The grid's log-odds and what they mean, as an ``.npz`` (no pickles)."""
    import io

    buf = io.BytesIO()
    np.savez_compressed(buf, format=np.array(_STATE_FORMAT), log_odds=grid.log_odds,
                        resolution_m=np.array(grid.resolution), half_size_m=np.array(grid.half_size_m),
                        band_m=np.array(grid.config.band_m, np.float64))
    return buf.getvalue()


def grid_from_state(config: GridConfig, data: bytes, half_size_m: float) -> OccupancyGrid:
    """The grid saved by :func:`state_bytes`. Raises ValueError, saying why, when the bytes are not
    one, or one of another resolution, size or band (the evidence would land in the wrong cells)."""
    import io
    import zipfile

    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            fmt = str(z["format"])
            log_odds = np.array(z["log_odds"], np.float32)
            resolution, half = float(z["resolution_m"]), float(z["half_size_m"])
            band = tuple(float(v) for v in z["band_m"])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"not a saved grid ({exc})") from None
    if fmt != _STATE_FORMAT:
        raise ValueError(f"format is {fmt!r}, not {_STATE_FORMAT!r}")
    fresh = OccupancyGrid(config, half_size_m)
    if (abs(resolution - config.resolution_m) > 1e-9 or abs(half - fresh.half_size_m) > 1e-6
            or band != tuple(config.band_m)):
        raise ValueError(f"it is of another grid ({resolution:g} m cells, {2 * half:g} m wide, band {band}); "
                         f"configured: {config.resolution_m:g} m, {2 * fresh.half_size_m:g} m, {config.band_m}")
    if not np.isfinite(log_odds).all():
        raise ValueError("it holds values that are not finite")
    return OccupancyGrid(config, half_size_m, log_odds)
