"""A point's surface normal from its neighbours on the scan's lattice, by candidate windows.

Pure: points, their σ and their neighbours (``Support``) in, unit normals or zeros out.

Each point's neighbours are cut into windows that hold the point: all of them, or only those on
its left (with the ones straight above and below it), on its right, above it (with its own row),
below it, and the four quarters; on a fine lattice each of those once with the next zones only,
and again reaching further. A window is a candidate only where it can show a bend, not just hold
a plane: its points must lie in at least three *layers* across the row (the point, and neighbours
in its row at two more distances) and in at least three up the column (the point, and points
straight above or below it at two more heights: the zones one and two levels away, the lasers'
spots of the zone and of those zones). Two layers will not do: two rows, one on the floor and one
on the wall above the crease, are two parallel lines, and a plane passes through both whatever
its slope; a third row off that plane is what shows the bend. Where the point's layer is at the
window's end, the others must reach far enough to pin the slope without it (see `_pinned`).

The zone's own lasers' spots are in every window: the ranging fused them onto the point's surface
(``edge.fusion.fuse``), so a window on the far side of a crease, which a row right at the crease
fits as well as its own side does, fails on them. Up the column two layers do where the zone's
own spots make the second one (the bottom row's floor: its row and its sloped laser's spots):
they join the two rows at the zone, and the plane is kept only at a slope at which the fusion
tests a zone's lasers against a known surface — level (a floor) or upright (a wall) within 3σ
(`_joined_at_a_known_slope`). A crease between the two rows would tilt it off both.

A candidate's plane is fitted weighted by 1/σ² and kept when its residuals are what the points' σ
makes likely (χ² within its 99.9th percentile and no point beyond _MAX_Z σ) and its points pin its
tilt well enough for that test to mean something (_TILT_SIGMA, _OWN_TILT_SIGMA): at a crease or a
depth edge the windows that span both surfaces fail and the ones on the point's own side fit. A
normal is given when the kept planes agree (within _AGREE_DEG of each other): that of the kept
window with most points. Where none is kept, or the kept ones disagree, the normal is (0, 0, 0).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# Points are layers of their own when far enough apart for the point's 2σ to be at most this
# slope between them (about 15°): the parallel laser's spot, 4 cm off the reference's, is one only
# near the unit. Wider layers would leave walls 3 m away (σ about 1 % of range) without normals,
# narrower ones let a window with a layer that hardly pins a slope hold two surfaces.
_PIN = math.tan(math.radians(15.0))
# A surface seen more obliquely than this from its normal is taken for a depth edge.
_COS_GRAZING = math.cos(math.radians(60.0))
# χ² percentile a window's residuals must stay within (as a normal deviate), and the largest
# residual of any one point, in its σ: beyond either, the window holds two surfaces.
_CHI2_Z = 3.09
_MAX_Z = 4.0
# A window whose points pin its plane's tilt (1σ, about its weaker axis) more loosely than this
# could hide a bend of several times it within its χ²: a wall's corner 15 cm beside a point 3 m
# away (σ 3 cm) tilted a plane 11.5° in the office at 8 tilt levels, its tilt's σ 2°.
_TILT_SIGMA = math.radians(1.75)
# Where the point's layer is at one end of a window, the others must span this much of the step
# from it to them. Two tilt levels 20° apart with the sloped laser's spots between span about as
# much as the step (1); a box's front below its top row, the front's parallel laser spots 4 cm
# above it, about a tenth.
_REST = 0.5
# A window whose column is two layers joined by the zone's own spots is kept when its plane lies
# within this many σ of level or upright, and its slope up the column is pinned to this (1σ): its
# normal is then within 4σ, 10°, of a floor's or a wall's. A bend hidden within χ² matters less
# there than _TILT_SIGMA says: a plane through a crease's two sides is tilted off both. (The
# floor at −40° below a wall 2.5 m away, its row and its sloped spots 23 cm apart: about 1.9°.)
_SQUARE_SIGMAS = 3.0
_OWN_TILT_SIGMA = math.radians(2.5)
# σ below a millimetre is not believed: keeps weights finite.
_SIGMA_FLOOR = 1e-3
# Kept planes further apart than this: the point's neighbourhood is not one surface.
_AGREE_DEG = 5.0
_COS_AGREE = math.cos(math.radians(_AGREE_DEG))


@dataclass(frozen=True)
class Support:
    """A point that may share a zone's surface: `point` (3,) base frame, its 1-σ `sigma` (m), its
    `level` (the tilt level of the zone it comes from, relative to the zone's: 0 its own row, ±1,
    ±2, …), `laser` (None for that zone's point, else the name of the laser whose spot it is), and
    `column`: whether it lies straight above or below the zone's point (its own lasers' spots, the
    zones at its pan at other levels and their spots) rather than beside it, and `ring`: how many
    lattice steps away its zone is (1 the next zone in pan or tilt and their neighbours; on a fine
    lattice 2, 4, 8)."""

    point: np.ndarray
    sigma: float
    level: int
    laser: str | None
    column: bool
    ring: int = 1


def estimate_normals(points: np.ndarray, sigma: np.ndarray, viewpoints: np.ndarray, ups: np.ndarray,
                     supports: Sequence[Sequence[Support]]) -> np.ndarray:
    """Normals (N, 3) of points (N, 3) with 1-σ `sigma` (N,), turned towards `viewpoints` (N, 3),
    from each point's `supports`; `ups` (N, 3): the direction in which each point's row's
    neighbours above lie. Zero where no plane holds (see the module's docstring)."""
    out = np.zeros((len(points), 3))
    for i, own in enumerate(supports):
        normal = normal_of(points[i], float(sigma[i]), viewpoints[i], ups[i], own)
        if normal is not None:
            out[i] = normal
    return out


def normal_of(centre: np.ndarray, sigma: float, viewpoint: np.ndarray, up: np.ndarray,
              own: Sequence[Support]) -> np.ndarray | None:
    """The unit normal of the point `centre` seen from `viewpoint`, or None."""
    if len(own) < 2:
        return None
    rng = float(np.linalg.norm(centre - viewpoint))
    beam = (centre - viewpoint) / max(rng, 1e-12)
    rel = np.vstack([np.zeros(3), [s.point - centre for s in own]])  # the point first
    sig = np.maximum(np.concatenate([[sigma], [s.sigma for s in own]]), _SIGMA_FLOOR)
    # Layers are told apart by the distance over which the point's 2σ is a slope of _PIN.
    gap = 2.0 * max(sigma, _SIGMA_FLOOR) / _PIN
    across = rel @ np.cross(up, beam)
    offset = rel @ up
    in_row = np.array([True] + [s.level == 0 and s.laser is None for s in own])
    # Straight above or below (a rolled camera's lasers may lie beside the point: not a layer).
    upright = np.array([True] + [s.column for s in own]) & (np.abs(offset) >= 0.5 * np.abs(across))
    # The zone's own lasers' spots: on the point's surface, by the ranging's fusion.
    mine = np.array([False] + [s.level == 0 and s.laser is not None and s.column for s in own])
    side_h = np.where(np.abs(across) < 0.5 * gap, 0, np.sign(across))
    side_v = np.where(np.abs(offset) < 0.5 * gap, 0, np.sign(offset))
    ring = np.array([0] + [s.ring for s in own])
    kept: list[tuple[int, float, np.ndarray]] = []
    # Windows: up to `reach` lattice steps; across the row both sides (0) or one (∓1); up the
    # column both or one. A neighbour level with the point in one direction is on both sides.
    for reach, h, v in itertools.product(sorted(set(ring[1:])), (0, -1, 1), (0, -1, 1)):
        mask = ((ring <= reach) & (side_h * h >= 0) & (side_v * v >= 0)) | mine
        if not _pinned(across[mask & in_row], gap):
            continue  # cannot show a bend across the row
        layered = _pinned(offset[mask & upright], gap)
        if not layered and not _joined_by_own(offset[mask & upright], offset[mine], gap):
            continue  # cannot show a bend up the column
        plane = _fit(rel[mask], sig[mask])
        if plane is None:
            continue  # two surfaces (or a bend) in the window
        if not (_well_pinned(plane) if layered else _joined_at_a_known_slope(plane, np.cross(up, beam), up)):
            continue  # its tilt too loosely pinned for its χ² to show a bend, or a crease's
        normal = plane.normal
        if abs(normal @ beam) < _COS_GRAZING:
            continue  # a plane seen edge-on: points at many depths, not a surface
        kept.append((int(mask.sum()), plane.chi2, normal if normal @ beam <= 0 else -normal))
    if not kept:
        return None
    normals = np.array([n for _, _, n in kept])
    if np.min(normals @ normals.T) < _COS_AGREE:
        return None  # windows that each fit but disagree: the point is on no one surface
    return max(kept, key=lambda k: (k[0], -k[1]))[2]


def _pinned(position: np.ndarray, gap: float) -> bool:
    """Whether points at `position` (m along one axis; the point itself at 0) lie in three layers
    or more (see `_layers`) that can show a bend next to the point: where the point's layer is at
    one end, the other layers must span at least half the step from it to them. (Else a row at a
    crease — a box's top, its front below — is a line that one plane holds together with the
    front's rows whatever the bend, the plane pinned by the front alone.)"""
    starts, ends = _layers(position, gap)
    if len(starts) < 3:
        return False
    own = int(np.searchsorted(starts, 0.0, side="right")) - 1  # the layer holding the point
    if own == 0:
        return ends[-1] - starts[1] >= _REST * (starts[1] - ends[0])
    if own == len(starts) - 1:
        return ends[-2] - starts[0] >= _REST * (starts[-1] - ends[-2])
    return True


def _joined_by_own(position: np.ndarray, own: np.ndarray, gap: float) -> bool:
    """Whether points at `position` (as for `_pinned`) lie in just two layers, one of them
    without the point but with one of its own lasers' spots (at `own`): the zone's own spots then
    join the two at the zone. (A spot `gap` or more from the point is not in the point's layer.)"""
    return len(_layers(position, gap)[0]) == 2 and bool(np.any(np.abs(own) >= gap))


def _layers(position: np.ndarray, gap: float) -> tuple[np.ndarray, np.ndarray]:
    """The first and last position of each layer of points at `position`, in order: a layer
    starts at the first point at least `gap` past the previous layer's first point."""
    x = np.sort(position)
    if len(x) == 0:
        return x, x
    first = [0]
    for k in range(1, len(x)):
        if x[k] - x[first[-1]] >= gap:
            first.append(k)
    return x[first], np.append(x[np.array(first[1:], dtype=int) - 1], x[-1])


def _well_pinned(plane: _Plane) -> bool:
    """Whether the points pin the plane's tilt about its weaker axis to _TILT_SIGMA."""
    return plane.tilt_sigma() <= _TILT_SIGMA


def _joined_at_a_known_slope(plane: _Plane, across: np.ndarray, up: np.ndarray) -> bool:
    """For a window of two layers up the column joined by the zone's own spots: whether its plane
    has a slope the ranging's fusion tests a zone's lasers against (``edge.fusion.level_slopes``),
    within _SQUARE_SIGMAS of its σ, its slope up the column pinned to _OWN_TILT_SIGMA. Level (a
    floor, a table top): the known slope then pins the normal both ways, and across the row too
    _OWN_TILT_SIGMA will do. Upright (a wall, a furniture front): it pins the plane's tilt only;
    the wall's bearing comes from the row, pinned as any window's (_TILT_SIGMA), for fronts stepped
    a few centimetres apart fit one plane turned 11° within a looser σ."""
    column, row = plane.tilt_sigma(up), plane.tilt_sigma(across)
    if column > _OWN_TILT_SIGMA:
        return False
    off_level = math.acos(min(1.0, abs(float(plane.normal[2]))))
    if off_level <= _SQUARE_SIGMAS * max(column, row):
        return row <= _OWN_TILT_SIGMA
    return math.pi / 2 - off_level <= _SQUARE_SIGMAS * column and row <= _TILT_SIGMA


@dataclass(frozen=True)
class _Plane:
    """A plane fitted to points: its unit `normal`, `chi2` per degree of freedom, and `scatter`
    (3, 3), the points' weighted (1/σ²) scatter about their mean, which says how well they pin
    its tilt."""

    normal: np.ndarray
    chi2: float
    scatter: np.ndarray

    def tilt_sigma(self, along: np.ndarray | None = None) -> float:
        """σ (radians) of the plane's slope along `along`, or about its weaker axis."""
        if along is None:
            return 1.0 / math.sqrt(max(float(np.linalg.eigvalsh(self.scatter)[1]), 1e-300))
        b = along - (along @ self.normal) * self.normal
        b = b / max(float(np.linalg.norm(b)), 1e-12)
        return 1.0 / math.sqrt(max(float(b @ self.scatter @ b), 1e-300))


def _fit(rel: np.ndarray, sig: np.ndarray) -> _Plane | None:
    """The plane through the points `rel` weighted by 1/σ², or None where the residuals are more
    than σ makes likely."""
    w = 1.0 / sig**2
    mean = (w[:, None] * rel).sum(axis=0) / w.sum()
    d = rel - mean
    scatter = (w[:, None] * d).T @ d
    normal = np.linalg.eigh(scatter)[1][:, 0]
    z = (d @ normal) / sig
    dof = len(rel) - 3
    if dof < 1 or np.max(np.abs(z)) > _MAX_Z:
        return None
    chi2 = float(z @ z)
    # The χ² distribution's percentile by Wilson and Hilferty's cube (no scipy for one number).
    limit = dof * (1.0 - 2.0 / (9.0 * dof) + _CHI2_Z * math.sqrt(2.0 / (9.0 * dof))) ** 3
    if chi2 > limit:
        return None
    return _Plane(normal, chi2 / dof, scatter)
