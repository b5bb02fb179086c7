"""Several lasers' depths fused into the reference laser's range through a local surface model.

Depth varies linearly across the lasers' hit points: first with the slope a wall or a floor has at
the unit's tilt (`level_slopes`), else with a fitted one; the model is checked against the
measurements (χ²) before it is trusted, and a set of spots counts only if every pair could lie on
one surface. Pure: measurements in, a `Fusion` out.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from edge.rig import Pose, Rig
from edge.triangulation import LaserMeasurement

# χ² acceptance at 95 % for 1…6 degrees of freedom. At 99 %, on seeds the estimator had not been
# tuned on, one laser's spot far off the surface the other two agreed on was fused in with them and
# pulled the range 15 % off (tuning-85, zone 12); 95 % left 5 of 8 such wrong ranges.
_CHI2_95 = (3.84, 5.99, 7.81, 9.49, 11.07, 12.59)
# Two spots' depths may differ across their separation by at most this slope (tan of the surface's
# angle from facing the lasers squarely): 75° still counts as one surface.
_MAX_SLOPE = math.tan(math.radians(75.0))


# Not frozen (never changed once made; `replace` makes a new one): a frozen dataclass costs 4 × as
# much to build (vision.Candidate), and every zone makes one or more.
@dataclass
class Fusion:
    range_m: float
    sigma_m: float
    point_m: np.ndarray
    normal: np.ndarray | None
    chi2: float
    dof: int
    used: tuple[LaserMeasurement, ...]  # the reference first

    @property
    def consistent(self) -> bool:
        return self.dof == 0 or self.chi2 <= _CHI2_95[min(self.dof, len(_CHI2_95)) - 1]


def fuse(
    rig: Rig,
    reference: LaserMeasurement,
    others: Sequence[LaserMeasurement],
    slopes: bool = True,
    surface_sigma_per_m: float = 0.05,
    slope_y: float = 0.0,
) -> Fusion:
    """The reference laser's range from all measurements through a locally planar surface.

    With `slopes`, the surface is z = a + g·(y − y_ref) + h·(x − x_ref) near the reference's point,
    the slope terms kept only where the hit points spread enough to measure them (the thesis rig's
    lasers lie in one vertical plane, so only g); without, it is z = a: a surface facing the camera
    across the lasers, as walls and furniture fronts do in a level sweep, or, with `slope_y`, a
    surface of that known slope z = a + slope_y·(y − y_ref) (a wall or a floor seen with the unit
    tilted: see :func:`level_slopes`). The reference beam is then intersected with it.
    """
    ms = [reference, *others]
    if not slopes:
        return _fuse_flat(reference, ms, surface_sigma_per_m, slope_y)
    pts = np.array([m.point_m for m in ms])
    z = pts[:, 2]
    dx, dy = pts[:, 0] - pts[0, 0], pts[:, 1] - pts[0, 1]
    model = surface_sigma_per_m * np.hypot(dx, dy)
    w = 1.0 / (np.array([max(m.sigma_m, 1e-9) for m in ms]) ** 2 + model**2)
    cols = [np.ones(len(ms))]
    use_g = slopes and np.ptp(dy) >= 0.01
    use_h = slopes and np.ptp(dx) >= 0.01
    if use_g:
        cols.append(dy)
    if use_h:
        cols.append(dx)
    A = np.stack(cols, axis=1)
    if A.shape[0] < A.shape[1]:  # too few points for the slopes: the reference alone
        return Fusion(reference.depth_m, reference.sigma_m, reference.point_m, None, 0.0, 0, (reference,))
    AtW = A.T * w
    # A first fit says only where the surface puts each spot: the fit is made with each σ carried
    # to that depth (_at_depth, as _fuse_flat does).
    first = A @ np.linalg.solve(AtW @ A, AtW @ z)
    w = 1.0 / (np.array([_at_depth(m.sigma_m, zi, fi) for m, zi, fi in zip(ms, z.tolist(), first.tolist())]) ** 2
               + model**2)
    AtW = A.T * w
    cov = np.linalg.inv(AtW @ A)
    params = cov @ (AtW @ z)
    resid = z - A @ params
    chi2 = max(float((w * resid**2).sum()), _chi2_inverse(z, A @ params, w))
    dof = len(ms) - A.shape[1]
    g = float(params[1]) if use_g else 0.0
    h = float(params[1 + use_g]) if use_h else 0.0
    if abs(g) > _MAX_FITTED_SLOPE:
        # Seen 70° or more from square on: more likely one laser's spot pulled off and another's
        # on another surface than one surface lit so obliquely by all three. (Tuning 0-255: the
        # one zone ranged so was 8 % off, claiming 1.7 %: tuning-246 zone 6, a reference spot
        # 0.8 px off by demosaicing, the parallel's on the wall, the sloped's on a table.)
        chi2 = math.inf
    laser = rig.laser(reference.laser)

    def on_beam(p: np.ndarray) -> np.ndarray:
        a_, g_, h_ = float(p[0]), (float(p[1]) if use_g else 0.0), (float(p[1 + use_g]) if use_h else 0.0)
        c = a_ - g_ * pts[0, 1] - h_ * pts[0, 0]
        o, d = laser.o, laser.d
        s = (c - o[2] + g_ * o[1] + h_ * o[0]) / (d[2] - g_ * d[1] - h_ * d[0])
        return o + s * d

    point = on_beam(params)
    # First-order propagation of the parameters' covariance to the reference's depth.
    J = np.zeros(len(params))
    for k in range(len(params)):
        step = np.zeros(len(params))
        step[k] = 1e-6 * max(1.0, abs(params[k]))
        J[k] = (on_beam(params + step)[2] - point[2]) / step[k]
    sigma = math.sqrt(max(float(J @ cov @ J), 0.0))
    normal = None
    if use_g and use_h:
        n = np.array([h, g, -1.0])
        normal = n / np.linalg.norm(n)
    return Fusion(float(point[2]), sigma, point, normal, chi2, dof, tuple(ms))


def _fuse_flat(reference: LaserMeasurement, ms: list[LaserMeasurement], surface_sigma_per_m: float,
               slope_y: float = 0.0) -> Fusion:
    """`fuse` for z = a + slope_y·(y − y_ref), slope_y known: a weighted mean of the depths carried
    to the reference's height, in plain floats (this runs for every zone)."""
    # (.item: plain floats, which numpy's scalars cost several times more to make)
    rx, ry = reference.point_m.item(0), reference.point_m.item(1)
    g = slope_y
    # A surface's slope g = dz/dy is cot of the angle it is seen at: a tilt of δθ moves it by
    # (1 + g²)·δθ, so a floor seen at a grazing angle has a slope known only roughly.
    per_m = surface_sigma_per_m * (1.0 + g * g)
    weights, carried, models = [], [], []
    for m in ms:
        dx, dy = m.point_m.item(0) - rx, m.point_m.item(1) - ry
        # The known slope is across the lasers' column (dz/dy); a wall seen obliquely also slopes
        # along x, where a rig's lasers, mounted a few tenths of a degree off, hit 1-2 cm apart.
        model = math.hypot(per_m * math.hypot(dx, dy), _ACROSS_SLOPE * dx)
        models.append(model * model)
        weights.append(1.0 / (max(m.sigma_m, 1e-9) ** 2 + model * model))
        carried.append((m.depth_m, g * dy))
    total = sum(weights)
    # (Lists, not generators: the same sums, with less overhead for a few lasers.)
    a = sum([w * (z - lift) for w, (z, lift) in zip(weights, carried)]) / total
    if len(ms) > 1:
        # Weighed again, each σ at the depth the surface puts its spot at (_at_depth).
        weights = [1.0 / (_at_depth(m.sigma_m, z, a + lift) ** 2 + mm) for m, (z, lift), mm in zip(ms, carried, models)]
        total = sum(weights)
        a = sum([w * (z - lift) for w, (z, lift) in zip(weights, carried)]) / total
    chi2 = sum([w * (z - a - lift) ** 2 for w, (z, lift) in zip(weights, carried)])
    if len(ms) > 1:
        # _chi2_inverse in plain floats
        inverse = 0.0
        for w, (z, lift) in zip(weights, carried):
            zm, zf = max(abs(z), 1e-6), max(abs(a + lift), 1e-6)
            inverse += w * zm**4 * (1.0 / zm - 1.0 / zf) ** 2
        chi2 = max(chi2, inverse)
    sigma = math.sqrt(1.0 / total)
    if len(ms) == 1:
        return Fusion(reference.depth_m, sigma, reference.point_m, None, chi2, 0, tuple(ms))
    if g == 0.0:
        return Fusion(a, sigma, _point_at_depth(reference, a), None, chi2, len(ms) - 1, tuple(ms))
    # The reference beam P + s·D meets the plane z − g·y = a − g·y_ref.
    P, D = reference.point_m, reference.beam_dir
    den = float(D[2]) - g * float(D[1])
    s_ = (a - g * ry - float(P[2]) + g * float(P[1])) / den
    point = P + s_ * D
    return Fusion(float(point[2]), sigma * abs(float(D[2]) / den), point, None, chi2, len(ms) - 1, tuple(ms))


# A spot's depth σ carried to the fitted surface's depth (_at_depth) changes by at most these
# ratios of the depths: beyond, the spot is on another surface, which χ² tells, not its weight.
_AT_DEPTH_RATIO = (0.8, 1.25)


def _at_depth(sigma_m: float, measured_m: float, fitted_m: float) -> float:
    """A spot's depth σ at the depth a fit puts it at rather than the one it measured. Depth's σ
    grows as depth² (a pixel's error moves a far spot more), so a spot read short claims less than
    one read long: weighed by their own σ, the lasers' mean leans short (tuning 320-959: −0.11 %
    on average, and two in three `ok` zones outside 2σ were short). At one depth, both alike."""
    ratio = min(max(fitted_m / measured_m, _AT_DEPTH_RATIO[0]), _AT_DEPTH_RATIO[1]) if measured_m > 0 else 1.0
    return max(sigma_m, 1e-9) * ratio * ratio


def _chi2_inverse(z: np.ndarray, fitted: np.ndarray, w: np.ndarray) -> float:
    """χ² of measured depths `z` against `fitted` ones in inverse depth, where a spot's pixel error
    acts linearly (depth's σ, from the derivative at the measured depth, becomes z²-scaled): far or
    weak spots, whose depth is very non-linear in the pixel, are then judged by what their pixels
    say. A spot whose depth 9.7 ± 2.7 m looks consistent with 3.9 m is 5 σ off in its pixels."""
    z = np.maximum(np.abs(z), 1e-6)
    fitted = np.maximum(np.abs(fitted), 1e-6)
    return float((w * z**4 * (1.0 / z - 1.0 / fitted) ** 2).sum())


def _point_at_depth(m: LaserMeasurement, z: float) -> np.ndarray:
    """The point of `m`'s beam at depth z: from its measured point along its beam direction."""
    # In plain floats, the same operations as m.point_m + (z − depth)·beam_dir / beam_dir[2] on
    # arrays: three numpy calls cost more than the arithmetic on three numbers.
    t = z - m.depth_m
    (px, py, pz), (bx, by, bz) = m.point_m.tolist(), m.beam_dir.tolist()
    return np.array((px + t * bx / bz, py + t * by / bz, pz + t * bz / bz))


# The slope dz/dx of a surface across the lasers' column, which no known slope gives (a wall seen
# at any angle in pan), taken as this much (1 σ) in a fusion by a known slope.
_ACROSS_SLOPE = 1.0


# A known slope is used while the surface it stands for is seen at most this obliquely in the
# lasers' plane: |slope| ≤ 3 is 72° from facing the camera (a floor seen with the unit tilted less
# than 18° down is left to the sloped model, or to the reference alone).
_MAX_KNOWN_SLOPE = 3.0


# A plane fitted through the spots (no known slope) may be seen at most this obliquely: tan 70°.
_MAX_FITTED_SLOPE = math.tan(math.radians(70.0))


def level_slopes(to_base: Pose) -> tuple[float, ...]:
    """The slopes dz/dy (camera frame) of a vertical surface (a wall, a furniture front) and of a
    horizontal one (a floor, a table top) at this pose: the surfaces rooms are made of. Level, a
    wall's slope is 0 (z = a) and a floor's is not seen across the lasers' column; tilted by t, a
    wall's is ±tan t and a floor's ∓cot t. The lasers' column is vertical in the camera, so the
    slope across it (dz/dx) is not needed."""
    # Base's up in the camera, R.T·(0, 0, 1): R's last row, as plain floats (cheaper than numpy's).
    _, up_y, up_z = to_base.R[2].tolist()
    out = []
    if abs(up_y) > 1e-9 and abs(up_z / up_y) <= _MAX_KNOWN_SLOPE:
        out.append(0.0 if abs(up_z) < 1e-9 else up_z / up_y)  # contains up: z changes by up_z per up_y
    if abs(up_z) > 1e-9 and abs(up_y / up_z) <= _MAX_KNOWN_SLOPE:
        out.append(-up_y / up_z)  # normal up: up·p constant
    return tuple(out) or (0.0,)


def apart(a: LaserMeasurement, b: LaserMeasurement) -> float:
    """How far apart two spots' points are across the view (x, y; m)."""
    (ax, ay, _), (bx, by, _) = a.point_m.tolist(), b.point_m.tolist()  # (plain floats: cheaper than numpy's)
    return math.hypot(ax - bx, ay - by)


def pair_plausible(a: LaserMeasurement, b: LaserMeasurement) -> bool:
    """Could two spots lie on one surface? Their depth change across their separation must be a
    slope a surface can have while both lasers still light it."""
    sep = apart(a, b)
    dz = abs(a.depth_m - b.depth_m) - 3.0 * math.hypot(a.sigma_m, b.sigma_m)
    return dz <= _MAX_SLOPE * max(sep, 1e-3)


def best_fusion(
    rig: Rig,
    reference: LaserMeasurement,
    others: Mapping[str, Sequence[LaserMeasurement]],
    surface_sigma_per_m: float = 0.05,
    slopes_y: Sequence[float] = (0.0,),
) -> Fusion:
    """The most informative consistent fusion of the reference with the other lasers' spots.

    First the largest set of lasers whose depths agree on a surface of a known slope (`slopes_y`,
    from :func:`level_slopes`: at a level pose, z = a, a surface facing the camera across the
    lasers; tilted, a wall's or a floor's slope), the strongest model; failing that, all lasers on
    a sloped plane, which has fewer checks; failing both, the reference alone. A set counts only if
    every pair is plausible on one surface and χ² accepts it; of the sets of the most lasers that
    count, the one that places the reference best (least σ). Not the least χ²: beside a loose
    reference spot any one other laser fits, and the least χ² then chose by chance between the
    parallel laser 5 cm away on a wall and the sloped laser 30 cm away carried through a floor's
    slope (tuning-239, a wall's foot: 11 % off).
    """
    names = [n for n, ms in others.items() if ms]
    for slopes in (False, True):
        for k in range(len(names), 0, -1):
            best: Fusion | None = None
            for subset in itertools.combinations(names, k):
                for choice in itertools.product(*(others[n] for n in subset)):
                    group = [reference, *choice]
                    if any(same_blob(x, y) for x, y in itertools.combinations(group, 2)):
                        continue
                    if not all(pair_plausible(x, y) for x, y in itertools.combinations(group, 2)):
                        continue
                    for g in ((0.0,) if slopes else slopes_y):
                        fusion = fuse(rig, reference, choice, slopes, surface_sigma_per_m, g)
                        if fusion.dof > 0 and fusion.consistent and (best is None or fusion.sigma_m < best.sigma_m):
                            best = fusion
            if best is not None:
                return best
            if slopes:
                break  # a sloped plane is only worth it with every laser on it
    return fuse(rig, reference, ())


def scatter_grown(fusion: Fusion) -> Fusion:
    """`fusion` with its σ grown by the lasers' scatter (the Birge ratio √(χ²/dof)) where they agree
    less well than their σ say, yet well enough for the χ² test: on the tuning family, fused σ
    were half the reference's own and too small as often as not where one laser's spot was
    pulled (demosaicing, JPEG) or the surface was not quite the model's. Never shrunk."""
    if fusion.dof == 0 or fusion.chi2 <= fusion.dof:
        return fusion
    return replace(fusion, sigma_m=fusion.sigma_m * math.sqrt(fusion.chi2 / fusion.dof))


def common_grown(fusion: Fusion, reference: LaserMeasurement, common_px: float) -> Fusion:
    """`fusion` with what the frames' pipeline moves every spot by alike (`common_px`, of the
    reference's spot: vision.SpotFinder.common_px) added to its σ: fusing spots does not average
    it. A reference alone keeps its own σ, which holds it already."""
    if not common_px or len(fusion.used) < 2 or reference.sigma_px <= 0:
        return fusion
    shared = common_px * reference.sigma_m / reference.sigma_px
    return replace(fusion, sigma_m=math.hypot(fusion.sigma_m, shared))


def same_blob(a: LaserMeasurement, b: LaserMeasurement) -> bool:
    """Are two lasers' spots one blob (within 1.5 px)? Where their paths cross, a blob is found on
    both, and it confirms neither."""
    (au, av), (bu, bv) = a.pixel.tolist(), b.pixel.tolist()  # (plain floats: cheaper than numpy's)
    return math.hypot(au - bu, av - bv) < 1.5
