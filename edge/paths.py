"""Where a spot finder reads a frame: each laser's strip along its image path over the working
range, and a sparse grid of the rest of the frame with some neighbours of each grid sample.

A laser's spot can only fall on its path (the epipolar segment the rig gives), so a finder reads
only a strip a few pixels wide along each path, and the grid to measure the room's light and the
frames' noise away from every path. `Strips` lays them out once per rig and camera, in one index
that `Strips.gather` reads every frame by: strips column by column, then the grid, then its
neighbours. Pure numpy: `edge.vision.SpotFinder` keeps one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge.framenoise import NEIGHBOURS, STRETCH
from edge.rig import Laser, Rig

# How far beyond the working range the paths are searched, so that a spot just outside it is
# reported as out of range rather than missed: z from NEAR_FACTOR·near to FAR_FACTOR·far.
NEAR_FACTOR = 0.8
FAR_FACTOR = 1.6
# The grid samples whose neighbours are read too: a few hundred tell a correlation to ±0.05.
NEAR_SAMPLES = 400


def full_scale(image: np.ndarray) -> float:
    """The value of full scale for `image`'s type (1 for floats)."""
    kind = image.dtype.type
    return 65535.0 if kind is np.uint16 else 255.0 if kind is np.uint8 else 1.0


@dataclass(frozen=True)
class Band:
    """One laser's strip: its path sampled about every half pixel, and the pixels across it."""

    laser: str
    v: np.ndarray  # (L, W) int pixel rows of the strip
    u: np.ndarray  # (L, W) int pixel columns
    path: np.ndarray  # (L, 2) path pixels (float)
    tangent: np.ndarray  # (L, 2) unit direction of the path
    inv_depth: np.ndarray  # (L,)
    step: float  # mean spacing of the path samples, px
    # Per path sample (pu, pv, tu, tv, inverse depth): `path`, `tangent` and `inv_depth` as plain
    # floats, which the finder reads a few of per spot (cheaper than numpy's scalar reads).
    samples: tuple[tuple[float, float, float, float, float], ...] = ()


def band(rig: Rig, laser: Laser, halfwidth: float) -> Band:
    """`laser`'s strip, `halfwidth` px either side of its path, over the working range and its margins."""
    cam = rig.camera
    lo, hi = rig.range_limits_m
    lo, hi = lo * NEAR_FACTOR, hi * FAR_FACTOR
    # Sample the path about every half pixel: find its length first, then resample.
    coarse = cam.project(laser.point_at_depth(1.0 / np.linspace(1 / lo, 1 / hi, 64)))
    length = float(np.linalg.norm(np.diff(coarse, axis=0), axis=1).sum())
    n = max(8, int(length * 2))
    inv = np.linspace(1 / lo, 1 / hi, n)
    path = cam.project(laser.point_at_depth(1.0 / inv))
    tangent = np.gradient(path, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    offsets = np.arange(-math.ceil(halfwidth), math.ceil(halfwidth) + 1)
    pts = path[:, None, :] + offsets[None, :, None] * normal[:, None, :]
    u = np.clip(np.rint(pts[..., 0]), 0, cam.width - 1).astype(np.intp)
    v = np.clip(np.rint(pts[..., 1]), 0, cam.height - 1).astype(np.intp)
    step = float(np.linalg.norm(np.diff(path, axis=0), axis=1).mean())
    samples = tuple(map(tuple, np.column_stack([path, tangent, inv]).tolist()))
    return Band(laser.name, v, u, path, tangent, inv, step, samples)


class Strips:
    """The pixels a finder reads of each frame, for one rig and camera: `bands` (each laser's
    strip), `rows` (each laser's path samples among all strips' rows), `background` (the grid's
    slice of what `gather` returns) and `near_block` (the last NEAR_SAMPLES grid samples and their
    neighbours at NEIGHBOURS: one (1 + len(NEIGHBOURS), near) block)."""

    def __init__(self, rig: Rig, lasers: Sequence[str], halfwidth: float) -> None:
        cam = rig.camera
        self.width_px = cam.width
        self.height_px = cam.height
        self.bands = {name: band(rig, rig.laser(name), halfwidth) for name in lasers}
        # Sparse background sample for the flicker gain: a grid over the frame minus the bands.
        step = max(4, int(math.sqrt(cam.width * cam.height / 1200)))
        gv, gu = np.mgrid[step // 2 : cam.height : step, step // 2 : cam.width : step]
        keep = np.ones(gv.shape, bool)
        for b in self.bands.values():
            for (pu, pv) in b.path[:: max(1, len(b.path) // 64)]:
                keep &= (np.abs(gu - pu) > 12) | (np.abs(gv - pv) > 12)
        keep &= (gu + 2 < cam.width) & (gv + 2 < cam.height)
        bg_v, bg_u = gv[keep], gu[keep]
        self.near_count = near = min(bg_v.size, NEAR_SAMPLES)
        # Those samples last, their neighbours right after them: one (6, near) block.
        order = np.roll(np.arange(bg_v.size), -near)
        self.bg_v, self.bg_u = bg_v[order], bg_u[order]
        first = self.bg_v.size - near
        near_v = [self.bg_v[first:] + dv for _, dv in NEIGHBOURS]
        near_u = [self.bg_u[first:] + du for du, _ in NEIGHBOURS]
        # Every strip pixel in one gather: cheaper than one gather per laser.
        # The strips column by column (strip width × all paths' samples): numpy reduces across a
        # strip's few columns far faster along the first axis than along a short last one.
        strip_v = np.concatenate([b.v for b in self.bands.values()]).T.ravel()
        strip_u = np.concatenate([b.u for b in self.bands.values()]).T.ravel()
        self._all_v = np.concatenate([strip_v, self.bg_v, *near_v])
        self._all_u = np.concatenate([strip_u, self.bg_u, *near_u])
        self.strip_width = next(iter(self.bands.values())).v.shape[1]
        self.rows: dict[str, slice] = {}
        start = 0
        for name, b in self.bands.items():
            self.rows[name] = slice(start, start + b.v.shape[0])
            start += b.v.shape[0]
        # How many path samples each stretch of STRETCH has (the last takes the rest): `local_noise`'s.
        stretch = np.minimum(np.arange(start) // STRETCH, max(1, start // STRETCH) - 1)
        self.stretch_counts = np.bincount(stretch)
        start *= self.strip_width
        self.background = slice(start, start + self.bg_v.size)
        start += self.bg_v.size
        self.near_block = slice(start - near, start + len(NEIGHBOURS) * near)
        # The four (row, column) parities' squared noise, from the samples and their neighbours
        # one column, one row and one diagonal away (rows of the near block; the flip of the
        # parity each makes): by one product with a one-hot matrix (4·near, 4), and each parity's count.
        phase = (self.bg_v[first:] % 2) * 2 + self.bg_u[first:] % 2
        flips = ((0, 0), (1, NEIGHBOURS.index((1, 0)) + 1), (2, NEIGHBOURS.index((0, 1)) + 1),
                 (3, NEIGHBOURS.index((1, 1)) + 1))
        parity = np.concatenate([phase ^ flip for flip, _ in flips])
        onehot = (parity[:, None] == np.arange(4)[None, :]).astype(np.float32)
        # (rows, one-hot matrix, counts): `noise_texture`'s `parity`, made once here.
        self.parity = ([row for _, row in flips], onehot, [max(float(c), 1.0) for c in onehot.sum(axis=0)])
        self._flat: dict[tuple[int, tuple[float, ...]], list[tuple[np.ndarray, float]]] = {}

    def near_samples(self) -> tuple[np.ndarray, np.ndarray]:
        """(v, u) of the grid samples whose neighbours are read (the near block's first row)."""
        first = self.bg_v.size - self.near_count
        return self.bg_v[first:], self.bg_u[first:]

    def _flat_index(self, image: np.ndarray, weights: tuple[float, float, float]) -> list[tuple[np.ndarray, float]]:
        """(indices into ``image.ravel()``, weight) per channel read, for every strip and
        background pixel."""
        channels = image.shape[2] if image.ndim == 3 else 1
        index = self._flat.get((channels, weights))
        if index is None:
            pixel = self._all_v.astype(np.intp) * self.width_px + self._all_u
            if channels == 1:
                index = [(pixel, 1.0)]
            else:
                index = [(pixel * channels + c, w) for c, w in enumerate(weights) if w]
            self._flat[(channels, weights)] = index
        return index

    def gather(self, frames: Sequence[np.ndarray], weights: tuple[float, float, float]) -> np.ndarray:
        """The channel `weights` (B, G, R) make of colour frames (grey frames as they are) at
        every strip and background pixel, averaged over `frames`, in [0, 1] (float32)."""
        if not frames:
            raise ValueError("no frames to gather: a pose needs at least one laser-on and one laser-off frame")
        scale = 1.0 / (len(frames) * full_scale(frames[0]))
        acc: np.ndarray | None = None
        for image in frames:
            if image.shape[0] != self.height_px or image.shape[1] != self.width_px:
                raise ValueError(f"a {image.shape[1]}x{image.shape[0]} frame for a "
                                 f"{self.width_px}x{self.height_px} camera")
            flat = image.reshape(-1)  # (a view, or for a frame that is not contiguous a copy in C order)
            for index, weight in self._flat_index(image, weights):
                # Every index is inside a frame of the camera's size (checked above; `band` clips
                # the strips, the background grid keeps its neighbours inside): mode="wrap" reads
                # the same pixels as the default "raise", whose bounds check costs a fifth of this.
                # (astype, then scaling in place: the float32 product np.multiply(…, dtype=float32)
                # makes, without its buffered casting loop. A Python float, not np.float32: numpy
                # casts it to the array's float32 all the same, and a numpy scalar operand costs
                # a ufunc more to resolve; so throughout the finder.)
                values = flat.take(index, mode="wrap").astype(np.float32)
                values *= weight * scale
                acc = values if acc is None else np.add(acc, values, out=acc)
        assert acc is not None
        return acc

    def stretch_of(self, laser: str, lo: float, hi: float, first: int, stop: int) -> tuple[int, int]:
        """The samples of `laser`'s path at inverse depths lo … hi, as a range first … stop − 1
        of the strips' sample indices, kept within the given one; empty (first, first) where no
        sample of the path is."""
        start = self.rows[laser].start
        inv = self.bands[laser].inv_depth
        inside = ((inv >= lo) & (inv <= hi)).nonzero()[0]
        if not inside.size:
            return first, first
        return max(first, start + int(inside[0])), min(stop, start + int(inside[-1]) + 1)

    def inv_depth_range(self) -> tuple[float, float]:
        """The inverse depths (1/m) every laser's path is searched over, nearest last (one range:
        the rig's working range with its margins)."""
        inv = next(iter(self.bands.values())).inv_depth
        return float(inv.min()), float(inv.max())

    def path_mask(self, laser: str, within_px: float) -> np.ndarray:
        """The image's pixels within `within_px` of `laser`'s path, and some a little farther
        (bool, height × width): a square about each path sample, which lie half a pixel apart.
        For set-up, not per frame."""
        mask = np.zeros((self.height_px, self.width_px), bool)
        r = math.ceil(within_px + 0.5)
        for u, v in np.rint(self.bands[laser].path).astype(int).tolist():
            mask[max(v - r, 0): max(v + r + 1, 0), max(u - r, 0): max(u + r + 1, 0)] = True
        return mask

    def nearest_on_path(self, laser: str, pixel: np.ndarray) -> tuple[float, float]:
        """The distance (px) from `pixel` to `laser`'s path, and the inverse depth there."""
        b = self.bands[laser]
        d = np.hypot(b.path[:, 0] - float(pixel[0]), b.path[:, 1] - float(pixel[1]))
        i = int(d.argmin())
        return float(d[i]), float(b.inv_depth[i])
