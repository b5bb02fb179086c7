"""Calibrating the laser rays (and optionally the focal length) from a flat target.

Zone i of a calibration recording shows a flat target squarely in front of the camera at distance
D_i, tape-measured from the optical centre along the optical axis: the target is the plane z = D_i
of the camera frame. A laser's spot at undistorted normalised position (x_n, y_n) in zone i is then
the beam point D_i·(x_n, y_n, 1). Writing the beam as x = x0 + ax·z, y = y0 + ay·z gives

    x_n = ax + x0 / D_i,    y_n = ay + y0 / D_i

which is linear in (ax, x0) and (ay, y0), and equal weights on x_n are equal weights in pixels: the
fit minimises the reprojection error directly. The fitted beam is origin (x0, y0, 0), direction
normalise(ax, ay, 1).

Spots are found and placed without the nominal rig's narrow epipolar bands, each with its σ from
the sensor's noise (:mod:`edge.calibration.spots`).

Weights and covariance (:func:`fit_weighted`). Each spot weighs 1/(σᵢ² + s²), s the scatter common
to all spots that frames cannot show (at rest: one speckle pattern per distance), measured from the
residuals of all lasers pooled; a stray spot is left out. Each ray comes with the covariance of its
(ax, x0, ay, y0), which :mod:`edge.calibration.uncertainty` turns into range errors. Blobs are
given to lasers from the nearest target to the farthest, each laser's nominal prediction corrected
by what the nearer distances showed: after one, by its pixel offset (an angular error shifts a spot
by a nearly constant number of pixels at every distance); after two or more, by the line through
them. So the gate can be tight after the first distance, and a spot that two lasers could own, or
two spots that one laser could own, are left out rather than guessed.

Limits. Uniformly scaled distances (wrong units, or measured from the wrong point) fit perfectly:
the whole scene scaled is the same picture. So the fitted origins are checked against the nominal,
mechanically measured ones; a shift beyond ``MAX_ORIGIN_SHIFT_M`` is refused. Spots closer than
about 4 px (the `center` and `parallel` spots beyond about 5 m) merge and cannot be calibrated there.
One wrong distance shows in the residuals when it is near; a far one (3.0 m given as 3.3 m) moves a
spot by less than the 0.5 px allowed and passes, so tape-measure the far targets with most care.

Focal length (``fit_focal``). Scaling f scales every fitted line's x and y by the same factor; the
triangulated depths come out the same either way, only the lateral coordinates scale. So f and the
laser geometry cannot both be fitted from this data. With ``fit_focal`` the laser *origins* are held
at their nominal values and the directions and one shared focal scale (fx/fy keeping the nominal
ratio) are fitted: for a given scale the directions follow linearly, and the scale minimising the
pixel residuals is found by Newton steps on that profile cost. A change beyond 10 % is refused:
something else (a distance, the config) is then wrong.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from edge.calibration.file import Calibration
from edge.calibration.limits import MIN_POINTS, MIN_SPAN
from edge.calibration.spots import Blob, zone_blobs
from edge.errors import CalibrationError
from edge.recording import Recording, timestamp
from edge.rig import CameraModel, Laser, Rig

log = logging.getLogger(__name__)

FIRST_GATE_PX = 25.0  # how far from the nominal prediction a spot may be (about 2.5° of error)
OFFSET_GATE_PX = 10.0  # ... once its offset at one nearer distance is known
GATE_PX = 6.0  # ... once its line through two or more nearer distances is known
MAX_RMS_PX = 0.5
MAX_ORIGIN_SHIFT_M = 0.008  # a mounting error of a laser beyond this is a wrong distance or config
MAX_FOCAL_CHANGE = 0.10


# --- checks -------------------------------------------------------------------------------------


def one_per_zone(zones: int, distances: Sequence[float], prefix: str = "") -> tuple[float, ...]:
    """The target distances, one positive number of metres per zone of the recording, or a
    CalibrationError saying what is wrong (after `prefix`, e.g. the option's name)."""
    d = tuple(float(x) for x in distances)
    if len(d) != zones:
        raise CalibrationError(
            f"{prefix}the recording has {zones} zones but {len(d)} distances were given: "
            "give one distance per zone, in zone order")
    bad = [x for x in d if not (math.isfinite(x) and x > 0)]
    if bad:
        raise CalibrationError(f"{prefix}distances must be positive metres, got {bad[0]:g}")
    return d


def _check_distances(zones: int, distances: Sequence[float]) -> tuple[float, ...]:
    d = one_per_zone(zones, distances)
    distinct = sorted(set(d))
    if len(distinct) < MIN_POINTS:
        raise CalibrationError(
            f"only {len(distinct)} distinct distances ({', '.join(f'{x:g}' for x in distinct)} m); "
            f"a fit needs at least {MIN_POINTS}: record the target at more distances")
    if distinct[-1] / distinct[0] < MIN_SPAN:
        raise CalibrationError(
            f"the distances span only a factor {distinct[-1] / distinct[0]:.2f} "
            f"({distinct[0]:g} to {distinct[-1]:g} m); they must span at least {MIN_SPAN} "
            "(e.g. 0.5 to 2 m) to tell each laser's origin from its direction")
    return d


# --- assignment ---------------------------------------------------------------------------------


def _clearly_nearer(d1: float, d2: float) -> bool:
    return d2 >= 2.0 * d1 and d2 - d1 >= 2.0


def _predict(rig: Rig, laser: Laser, known: dict[int, np.ndarray], distances: Sequence[float],
             depth: float) -> tuple[np.ndarray, float]:
    """Where `laser`'s spot should be at `depth`, and how far from there to look for it."""
    nominal = rig.camera.project(laser.point_at_depth(depth))
    if not known:
        return nominal, FIRST_GATE_PX
    if len(known) == 1:  # an angular error: a nearly constant pixel offset at every depth
        (i, px), = known.items()
        offset = px - rig.camera.project(laser.point_at_depth(distances[i]))
        return nominal + offset, OFFSET_GATE_PX
    # Two or more: the line through them, which also follows an origin (or distance) error.
    line = fit_line(rig.camera, np.array(list(known.values())),
                    np.array([distances[i] for i in known]), laser.name)
    return rig.camera.project(line.point_at_depth(depth)), GATE_PX


def assign_spots(rig: Rig, blobs: Sequence[Sequence[Blob]], distances: Sequence[float]
                 ) -> dict[str, dict[int, np.ndarray]]:
    """Per laser, zone index → spot pixel. Nearest distance first, each laser's prediction
    learnt from the distances already assigned (see :func:`_predict`)."""
    return {name: {i: b.pixel for i, b in got.items()}
            for name, got in assigned_blobs(rig, blobs, distances).items()}


def assigned_blobs(rig: Rig, blobs: Sequence[Sequence[Blob]], distances: Sequence[float]
                   ) -> dict[str, dict[int, Blob]]:
    """:func:`assign_spots` giving the blobs themselves (their pixel and its σ)."""
    points: dict[str, dict[int, np.ndarray]] = {ln.name: {} for ln in rig.lasers}
    chosen: dict[str, dict[int, Blob]] = {ln.name: {} for ln in rig.lasers}
    for i in sorted(range(len(distances)), key=lambda k: distances[k]):
        claims: dict[int, list[tuple[float, str]]] = {}
        for laser in rig.lasers:
            p, gate = _predict(rig, laser, points[laser.name], distances, distances[i])
            near = sorted((float(np.linalg.norm(b.pixel - p)), k) for k, b in enumerate(blobs[i])
                          if laser.name in b.lasers)
            near = [c for c in near if c[0] <= gate]
            if not near:
                log.debug("zone %d: no spot of %s within %.0f px of (%.1f, %.1f)",
                          i, laser.name, gate, *p)
            elif len(near) > 1 and not _clearly_nearer(near[0][0], near[1][0]):
                log.info("zone %d: %d spots near %s's prediction: left out", i, len(near), laser.name)
            else:
                claims.setdefault(near[0][1], []).append((near[0][0], laser.name))
        for k, wanted in claims.items():
            wanted.sort()
            if len(wanted) > 1 and not _clearly_nearer(wanted[0][0], wanted[1][0]):
                log.info("zone %d: one spot claimed by %s: left out", i, ", ".join(n for _, n in wanted))
                continue
            points[wanted[0][1]][i] = blobs[i][k].pixel
            chosen[wanted[0][1]][i] = blobs[i][k]
    return chosen


# --- fitting ------------------------------------------------------------------------------------


def _normalised(camera: CameraModel, pixels: np.ndarray) -> np.ndarray:
    r = camera.rays(pixels)
    return r[:, :2] / r[:, 2:3]


def _line(origin_xy: np.ndarray, slope: np.ndarray, name: str) -> Laser:
    d = np.array([slope[0], slope[1], 1.0])
    return Laser(name, (float(origin_xy[0]), float(origin_xy[1]), 0.0),
                 tuple(float(c) for c in d / np.linalg.norm(d)))  # type: ignore[arg-type]


def fit_line(camera: CameraModel, pixels: np.ndarray, depths: np.ndarray, name: str) -> Laser:
    """The beam through the spots: x_n = ax + x0/D, y_n = ay + y0/D by linear least squares."""
    A = np.stack([np.ones_like(depths), 1.0 / depths], axis=1)
    (ax, ay), (x0, y0) = np.linalg.lstsq(A, _normalised(camera, pixels), rcond=None)[0]
    return _line(np.array([x0, y0]), np.array([ax, ay]), name)


def residuals(camera: CameraModel, laser: Laser, pixels: np.ndarray, depths: np.ndarray) -> np.ndarray:
    """Pixel distances between the measured spots and the fitted beam reprojected at each depth."""
    return np.linalg.norm(camera.project(laser.point_at_depth(depths)) - pixels, axis=1)


def _scaled(camera: CameraModel, s: float) -> CameraModel:
    return replace(camera, fx=camera.fx * s, fy=camera.fy * s)


def _directions_for(camera: CameraModel, origins: dict[str, np.ndarray],
                    data: dict[str, tuple[np.ndarray, np.ndarray]]) -> tuple[dict[str, Laser], float]:
    """With origins fixed, each direction follows linearly (ax = mean(x_n − x0/D)); and the sum
    of squared pixel residuals."""
    lasers, cost = {}, 0.0
    for name, (px, depths) in data.items():
        slope = (_normalised(camera, px) - origins[name][None, :] / depths[:, None]).mean(axis=0)
        lasers[name] = _line(origins[name], slope, name)
        cost += float((residuals(camera, lasers[name], px, depths) ** 2).sum())
    return lasers, cost


def fit_focal_scale(camera: CameraModel, origins: dict[str, np.ndarray],
                    data: dict[str, tuple[np.ndarray, np.ndarray]]) -> float:
    """The focal scale minimising the pixel residuals. Without distortion the profile cost is
    exactly quadratic in the scale (the predictions are linear in it), so Newton's step on it by
    central differences lands on the minimum at once; a few more steps absorb distortion."""

    def cost(s: float) -> float:
        return _directions_for(_scaled(camera, s), origins, data)[1]

    s, h = 1.0, 1e-3
    for _ in range(6):
        lo, mid, hi = cost(s - h), cost(s), cost(s + h)
        curvature = hi - 2.0 * mid + lo
        if curvature <= 0:
            raise CalibrationError("the focal length cannot be fitted from these spots")
        step = h * (hi - lo) / (2.0 * curvature)
        s = min(max(s - step, 0.5), 2.0)
        if abs(step) < 1e-9:
            break
    return s


def _check_origins(nominal: Rig, fitted: dict[str, Laser]) -> None:
    """A uniform scale error of the distances fits perfectly; only the origins can show it."""
    nom = {ln.name: ln.point_at_depth(0.0)[:2] for ln in nominal.lasers}
    shift = {n: float(np.linalg.norm(fitted[n].o[:2] - nom[n])) for n in fitted}
    worst = max(shift, key=lambda n: shift[n])
    if shift[worst] <= MAX_ORIGIN_SHIFT_M:
        return
    hint = "the distances may be wrong, or the rig is not as configured"
    norm2 = sum(float(nom[n] @ nom[n]) for n in fitted)
    if norm2 > 1e-6:
        s = sum(float(fitted[n].o[:2] @ nom[n]) for n in fitted) / norm2
        if abs(s - 1.0) > 0.05:
            hint = (f"the origins all sit about {s:.2f}x their nominal distance from the optical "
                    f"axis: the distances look scaled by {s:.2f} (wrong units, or measured from "
                    "another point than the optical centre?)")
    raise CalibrationError(
        f"laser {worst!r}: fitted origin lies {1000 * shift[worst]:.1f} mm from its nominal "
        f"position (limit {1000 * MAX_ORIGIN_SHIFT_M:.0f} mm): {hint}")


@dataclass(frozen=True)
class Spots:
    """One laser's spots, one per distance it was found at."""

    pixels: np.ndarray  # (N, 2)
    depths: np.ndarray  # (N,) metres
    sigma_px: np.ndarray  # (N, 2) 1-σ per axis from the sensor's noise
    zones: np.ndarray  # (N,) zone index of each
    clipped: np.ndarray | None = None  # (N,) bool: the spot clipped the sensor (None: none did)

    def subset(self, keep: np.ndarray) -> Spots:
        return Spots(self.pixels[keep], self.depths[keep], self.sigma_px[keep], self.zones[keep],
                     None if self.clipped is None else self.clipped[keep])

    @property
    def clipped_mask(self) -> np.ndarray:
        return np.zeros(len(self.depths), bool) if self.clipped is None else self.clipped


def _laser_data(rig: Rig, chosen: dict[str, dict[int, Blob]], D: tuple[float, ...]) -> dict[str, Spots]:
    """Per laser, its spots; refused below MIN_POINTS."""
    data = {}
    for laser in rig.lasers:
        got = sorted(chosen[laser.name])
        if len(got) < MIN_POINTS:
            where = f" ({', '.join(f'{D[i]:g}' for i in got)} m)" if got else ""
            raise CalibrationError(
                f"laser {laser.name!r}: spot found at only {len(got)} of {len(D)} distances{where};"
                f" a fit needs {MIN_POINTS}: check that it is on, its spot is on the target and the"
                " distances are right")
        blobs = [chosen[laser.name][i] for i in got]
        sigma = np.array([np.zeros(2) if b.sigma_px is None else b.sigma_px for b in blobs])
        data[laser.name] = Spots(np.array([b.pixel for b in blobs]), np.array([D[i] for i in got]),
                                 sigma, np.array(got), np.array([b.clipped for b in blobs]))
    return data


# --- the weighted fit and what it knows ---------------------------------------------------------
#
# Each spot's error is its sensor noise (σ per spot, measured around it) plus what the frames
# cannot average away: with the target at rest, one speckle pattern per distance. That second
# part, s, is the same on both axes (speckle has no direction), and it is smaller for a spot that
# clips the sensor, whose plateau hides the speckle over it (simulator, at rest: 0.06 px rms
# against 0.09 px). So there are two: s_c for clipped spots and s_u for the others, both measured
# from the residuals of all lasers and both axes together (pooled, so that 3 lasers at 6
# distances give 24 degrees of freedom, not 4), each from its own spots' residuals: E[rᵢ²] =
# (1 − hᵢ)(σᵢ² + s²), hᵢ the spot's leverage. A class with fewer than MIN_CLASS_DOF degrees of
# freedom of its own takes the pooled value, and an unclipped scatter below the clipped one is
# raised to it (clipping only ever hides speckle). Each spot then weighs 1/(σᵢ² + s²) with its
# class's s. A few unclipped spots (often the farthest distance's three) measure s_u with a few
# degrees of freedom ν; what is said of a spot not yet seen (``spot_sigma_px``, the range error
# of one range) is then the Student-t's s²·ν/(ν − 2), not s².

MIN_CLASS_DOF = 3.0
OUTLIER_SIGMAS = 5.5  # a spot this far from the line through the others (robust σ, 2-D) is another blob


def _wls(inv_depth: np.ndarray, y: np.ndarray, var: np.ndarray, spread: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray, float]:
    """y = a + b·(1/D) by weighted least squares (weights 1/`var`): (a, b), their covariance
    (2, 2) and χ². With `spread`, the points' variances are taken to be those and not `var`
    (the covariance is then (AᵀWA)⁻¹ AᵀW·spread·WA (AᵀWA)⁻¹)."""
    A = np.stack([np.ones_like(inv_depth), inv_depth], axis=1)
    w = 1.0 / var
    cov = np.linalg.inv((A.T * w) @ A)
    theta = cov @ ((A.T * w) @ y)
    r = y - A @ theta
    if spread is not None:
        cov = cov @ ((A.T * (w * w * spread)) @ A) @ cov
    return theta, cov, float((w * r * r).sum())


def _leverage_moments(inv_depth: np.ndarray, y: np.ndarray, var: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Of the weighted line through (1/D, y) with variances `var`: each point's squared residual
    less what its own noise explains, rᵢ² − (1 − hᵢ)σᵢ², and 1 − hᵢ (its share of the degrees of
    freedom)."""
    A = np.stack([np.ones_like(inv_depth), inv_depth], axis=1)
    w = 1.0 / var
    cov = np.linalg.inv((A.T * w) @ A)
    r = y - A @ (cov @ ((A.T * w) @ y))
    free = 1.0 - w * np.einsum("ij,jk,ik->i", A, cov, A)
    return r * r, free


@dataclass(frozen=True)
class Scatter:
    """One class of spots' scatter beyond the sensor's noise: s² (normalised units², per axis)
    and the residual degrees of freedom ν it was measured with."""

    s2: float
    dof: float

    @property
    def predictive(self) -> float:
        """s² for a spot not yet seen: a scale measured with ν degrees of freedom leaves a new
        spot's error Student-t distributed, of variance s²·ν/(ν − 2) (ν ≥ MIN_CLASS_DOF)."""
        nu = max(self.dof, MIN_CLASS_DOF)
        return self.s2 * nu / (nu - 2.0)


def _spot_scatter(camera: CameraModel, data: dict[str, Spots]) -> tuple[Scatter, Scatter]:
    """The scatter of a clipped and of an unclipped spot (see the notes above)."""
    rows = []
    for spots in data.values():
        xy, var = _normalised_data(camera, spots)
        for axis in range(2):
            rows.append((1.0 / spots.depths, xy[:, axis], var[:, axis], spots.clipped_mask))
    s2 = {True: 0.0, False: 0.0}
    dof = {True: 0.0, False: 0.0}
    for _ in range(100):
        num = {True: 0.0, False: 0.0}
        dof = {True: 0.0, False: 0.0}
        for x, y, var, clipped in rows:
            extra = np.where(clipped, s2[True], s2[False])
            r2, free = _leverage_moments(x, y, var + extra)
            for c in (True, False):
                num[c] += float((r2 - free * var)[clipped == c].sum())
                dof[c] += float(free[clipped == c].sum())
        total = dof[True] + dof[False]
        if total <= 0:
            return Scatter(0.0, 0.0), Scatter(0.0, 0.0)
        pooled = max(0.0, (num[True] + num[False]) / total)
        new = {c: max(0.0, num[c] / dof[c]) if dof[c] >= MIN_CLASS_DOF else pooled for c in (True, False)}
        if dof[True] >= MIN_CLASS_DOF:
            new[False] = max(new[False], new[True])  # clipping only ever hides speckle
        done = all(abs(new[c] - s2[c]) <= 1e-4 * max(new[c], 1e-18) for c in (True, False))
        s2 = new
        if done:
            break
    total = dof[True] + dof[False]
    nu = {c: dof[c] if dof[c] >= MIN_CLASS_DOF else total for c in (True, False)}
    return Scatter(s2[True], nu[True]), Scatter(s2[False], nu[False])


def _normalised_data(camera: CameraModel, spots: Spots) -> tuple[np.ndarray, np.ndarray]:
    """Normalised spot positions (N, 2) and their noise variances (N, 2) (σ/f, per axis)."""
    scale = np.array([camera.fx, camera.fy])
    var = (spots.sigma_px / scale) ** 2 + 1e-18  # never exactly 0: a noiseless simulation
    return _normalised(camera, spots.pixels), var


@dataclass(frozen=True)
class WeightedFit:
    """Every laser's ray with the covariance of its parameters (ax, x0, ay, y0)."""

    lasers: dict[str, Laser]
    covariance: dict[str, np.ndarray]  # (4, 4) per laser: ax, x0 (m), ay, y0 (m)
    spot_sigma_px: tuple[float, float]  # an unclipped spot's scatter per axis (sensor noise and speckle)
    data: dict[str, Spots]  # the spots kept (outliers left out)
    clipped_spot_sigma_px: tuple[float, float] = (0.0, 0.0)  # ... a clipped spot's
    clipped_within_m: float = 0.0  # the farthest distance where most spots clipped (0: none)


def _without_worst(inv_depth: np.ndarray, xy: np.ndarray) -> tuple[int, np.ndarray, float]:
    """The point whose removal leaves the best line through the others (both axes): its index,
    its standardised residual (2,) from that line (divided by √(1 + aₖᵀ(A₋ₖᵀA₋ₖ)⁻¹aₖ)), and the
    others' sum of squared residuals. One stray point cannot hide by pulling the line to itself."""
    A = np.stack([np.ones_like(inv_depth), inv_depth], axis=1)
    best: tuple[int, np.ndarray, float] | None = None
    for k in range(len(inv_depth)):
        keep = np.arange(len(inv_depth)) != k
        inv = np.linalg.inv(A[keep].T @ A[keep])
        theta = inv @ (A[keep].T @ xy[keep])
        rss = float(((xy[keep] - A[keep] @ theta) ** 2).sum())
        if best is None or rss < best[2]:
            r = (xy[k] - A[k] @ theta) / math.sqrt(1.0 + float(A[k] @ inv @ A[k]))
            best = (k, r, rss)
    assert best is not None
    return best


def _outliers(camera: CameraModel, data: dict[str, Spots]) -> dict[str, Spots]:
    """Each laser's spots without one that lies far off the line through its others while the
    other lasers' spots at that distance do not (a stray blob taken for the spot). A distance
    where every laser's spot is off is left in: that is a wrong distance, which the residual check
    then refuses. The scale is that of all lasers' other spots about their lines, pooled."""
    while True:
        worst: dict[str, tuple[int, np.ndarray]] = {}
        rss, dof = 0.0, 0
        for name, spots in data.items():
            if len(spots.depths) <= MIN_POINTS:
                continue
            k, r, rest = _without_worst(1.0 / spots.depths, _normalised_data(camera, spots)[0])
            worst[name] = (k, r)
            rss, dof = rss + rest, dof + 2 * (len(spots.depths) - 3)
        if not worst or dof <= 0:
            return data
        scale2 = rss / dof + 1e-24  # per axis
        q = {n: float(np.sqrt((r**2).sum() / (scale2 + _normalised_data(camera, data[n])[1][k].sum() / 2)))
             for n, (k, r) in worst.items()}
        bad = [n for n in worst if q[n] > OUTLIER_SIGMAS]
        drop = None
        for name in sorted(bad, key=lambda n: -q[n]):
            zone = int(data[name].zones[worst[name][0]])
            others = [n for n in data if n != name and zone in data[n].zones]
            if others and not any(n in bad and int(data[n].zones[worst[n][0]]) == zone for n in others):
                drop = name
                break
        if drop is None:
            return data
        k = worst[drop][0]
        log.info("laser %s: spot at %.2f m lies %.1f σ off its line: left out", drop, data[drop].depths[k], q[drop])
        data = {**data, drop: data[drop].subset(np.arange(len(data[drop].depths)) != k)}


def fit_weighted(camera: CameraModel, data: dict[str, Spots]) -> WeightedFit:
    """Every laser's line by weighted least squares (weights 1/(σᵢ² + s²), s that of the spot's
    class, clipped or not), stray spots left out, with the covariance of each line's parameters
    (scaled by the laser's own χ² per degree of freedom where that exceeds 1)."""
    data = _outliers(camera, data)
    scatter = dict(zip((True, False), _spot_scatter(camera, data)))
    s2 = {c: scatter[c].s2 for c in (True, False)}
    lasers, covs, noise = {}, {}, []
    for name, spots in data.items():
        xy, var = _normalised_data(camera, spots)
        noise.append(var)
        clipped = spots.clipped_mask
        extra = np.where(clipped, s2[True], s2[False])
        # Weighed by the scatter measured; the covariance with the scatter a spot not yet seen
        # would have (Student-t: the scatter itself is only known to its degrees of freedom).
        spread = np.where(clipped, scatter[True].predictive, scatter[False].predictive)
        (ax, x0), cx, chi_x = _wls(1.0 / spots.depths, xy[:, 0], var[:, 0] + extra, var[:, 0] + spread)
        (ay, y0), cy, chi_y = _wls(1.0 / spots.depths, xy[:, 1], var[:, 1] + extra, var[:, 1] + spread)
        lasers[name] = _line(np.array([x0, y0]), np.array([ax, ay]), name)
        cov = np.zeros((4, 4))
        cov[:2, :2], cov[2:, 2:] = cx, cy
        # A laser whose spots scatter more than the pooled scatter says: its own χ² per degree
        # of freedom scales its covariance (never down: the pooled scatter is the better estimate).
        dof = 2 * (len(spots.depths) - 2)
        covs[name] = cov * max(1.0, (chi_x + chi_y) / dof)
    typical = np.median(np.concatenate(noise), axis=0)  # one spot's sensor noise, normalised²
    scale = np.array([camera.fx, camera.fy])
    spot = {c: np.sqrt(typical + scatter[c].predictive) * scale for c in (True, False)}
    within = [float(d) for d in {float(x) for sp in data.values() for x in sp.depths}
              if 2 * sum(int(sp.clipped_mask[sp.depths == d].sum()) for sp in data.values())
              > sum(int((sp.depths == d).sum()) for sp in data.values())]
    return WeightedFit(lasers, covs, (float(spot[False][0]), float(spot[False][1])), data,
                       (float(spot[True][0]), float(spot[True][1])), max(within, default=0.0))


def _fit_focal(camera: CameraModel, rig: Rig, spots: dict[str, Spots]
               ) -> tuple[CameraModel, dict[str, Laser]]:
    data = {n: (sp.pixels, sp.depths) for n, sp in spots.items()}
    origins = {ln.name: ln.point_at_depth(0.0)[:2] for ln in rig.lasers}
    s = fit_focal_scale(camera, origins, data)
    if abs(s - 1.0) > MAX_FOCAL_CHANGE:
        raise CalibrationError(
            f"the fitted focal length moves by {100 * (s - 1):+.1f} % (limit "
            f"{100 * MAX_FOCAL_CHANGE:.0f} %): a distance or the configured rig is probably wrong")
    log.info("focal length fx %.2f px (nominal %.2f, %+.2f %%)", camera.fx * s, camera.fx, 100 * (s - 1))
    camera = _scaled(camera, s)
    return camera, _directions_for(camera, origins, data)[0]


def _checked_residuals(camera: CameraModel, fitted: dict[str, Laser], data: dict[str, Spots]
                       ) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for name, spots in data.items():
        r = residuals(camera, fitted[name], spots.pixels, spots.depths)
        rms, worst = float(np.sqrt(np.mean(r**2))), float(r.max())
        if rms > MAX_RMS_PX:
            raise CalibrationError(
                f"laser {name!r}: residual {rms:.2f} px rms (max {worst:.2f} px) exceeds "
                f"{MAX_RMS_PX} px: the target may not be flat or square to the camera, or a "
                "distance is wrong")
        out[name] = {"rms": rms, "max": worst, "n": int(len(r))}
    return out


def fit_calibration(recording: Recording, distances_m: Sequence[float], fit_focal: bool = False
                    ) -> Calibration:
    """Fit every laser of `recording.rig` from zone i showing a flat target squarely at
    distances_m[i] (metres from the optical centre); with `fit_focal` also the focal length,
    the laser origins then held at their nominal values (see the module docstring). Without
    `fit_focal` each ray comes with the covariance of its parameters (see :func:`fit_weighted`)."""
    rig = recording.rig
    D = _check_distances(len(recording.zones), distances_m)
    blobs = [zone_blobs(recording, i) for i in range(len(recording.zones))]
    data = _laser_data(rig, assigned_blobs(rig, blobs, D), D)
    covariance: dict[str, tuple[tuple[float, ...], ...]] = {}
    spot_sigma: tuple[float, ...] = ()
    clipped_sigma: tuple[float, ...] = ()
    clipped_within = 0.0
    if fit_focal:
        camera, fitted = _fit_focal(rig.camera, rig, data)
    else:
        camera = rig.camera
        weighted = fit_weighted(camera, data)
        fitted, data = weighted.lasers, weighted.data
        covariance = {n: tuple(tuple(float(c) for c in row) for row in m) for n, m in weighted.covariance.items()}
        spot_sigma = weighted.spot_sigma_px
        clipped_sigma, clipped_within = weighted.clipped_spot_sigma_px, weighted.clipped_within_m
    res = _checked_residuals(camera, fitted, data)
    if not fit_focal:
        _check_origins(rig, fitted)
    lasers = tuple(replace(fitted[ln.name], reference=ln.reference) for ln in rig.lasers)
    return Calibration(lasers, camera, D, res, timestamp(), covariance, spot_sigma, clipped_sigma, clipped_within,
                       recording.lens_dioptres)
