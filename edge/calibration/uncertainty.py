"""How well a calibration knows each ray, told as the range error it implies.

The fit (:mod:`edge.calibration.fit`) writes each beam as x_n = ax + x0/D, y_n = ay + y0/D
(normalised image coordinates of its spot on a target squarely at depth D) and keeps the
covariance of (ax, x0, ay, y0) per laser. At depth D a spot moves with depth along the laser's
epipolar direction e = (x0, y0)/|b|, |b| = hypot(x0, y0) its baseline, by |b|/D² per metre; an
error δp of where the calibration puts the spot (δp = J δθ, J = [[1, 1/D, 0, 0], [0, 0, 1, 1/D]])
therefore reads as a range error D²/|b| · e·δp. So at depth D a laser's range error from its
calibration has σ_cal² = (D²/|b|)² · eᵀ J C Jᵀ e, and one range measured as the calibration's frames
were (a board at rest: one view, one speckle pattern) adds the spot's own σ_spot² = (D²/|b|)² · eᵀ S e
with S = diag(σu/fx, σv/fy)², the spot scatter the fit measured (``spot_sigma_px``; within the
distance where its spots clipped the sensor, ``clipped_spot_sigma_px``: clipping hides some speckle).
A calibration recorded with nudges (several views a distance) measured a smaller scatter, which one
view's range will exceed.

The lasers of one range are combined as ranging combines them on a surface facing the camera: by
weights 1/σ_spot², i.e. ∝ |b|² for spots located equally well. Calibration errors of different lasers
are independent, so the combined σ² is Σ wᵢ² σᵢ² / (Σ wᵢ)².
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from edge.rig import Laser

REPORT_DEPTHS_M = (1.0, 2.0, 4.0)
MIN_BASELINE_M = 0.001  # a beam through the optical centre cannot range at all


@dataclass(frozen=True)
class RangeError:
    """1-σ range errors (metres) at `depths_m`: from the calibration alone, and for one range
    measured as the calibration's frames were (calibration and the spot's own scatter). None:
    cannot range."""

    depths_m: tuple[float, ...]
    calibration: tuple[float | None, ...]
    one_range: tuple[float | None, ...]

    def to_json(self) -> dict:
        def r(xs: Sequence[float | None]) -> list[float | None]:
            return [None if x is None else round(x, 6) for x in xs]
        return {"depths_m": list(self.depths_m), "calibration": r(self.calibration), "one_range": r(self.one_range)}


def ray_parameters(laser: Laser) -> np.ndarray:
    """(ax, x0, ay, y0) of a beam: x = x0 + ax·z, y = y0 + ay·z (camera frame)."""
    o, d = laser.o, laser.d
    ax, ay = d[0] / d[2], d[1] / d[2]
    return np.array([ax, o[0] - ax * o[2], ay, o[1] - ay * o[2]])


def baseline(params: np.ndarray) -> float:
    """|b| = hypot(x0, y0) of a ray's parameters (ax, x0, ay, y0)."""
    return math.hypot(float(params[1]), float(params[3]))


def _sensitivity(params: np.ndarray, depth: float) -> np.ndarray | None:
    """d(range)/d(ax, x0, ay, y0) at `depth` (4,), or None for a ray with no baseline."""
    b = baseline(params)
    if b < MIN_BASELINE_M:
        return None
    e = np.array([params[1], params[3]]) / b
    J = np.array([[1.0, 1.0 / depth, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0 / depth]])
    return (depth * depth / b) * (e @ J)


def laser_range_error(params: np.ndarray, cov: np.ndarray, spot_sigma_n: np.ndarray,
                      depths: Sequence[float] = REPORT_DEPTHS_M) -> RangeError:
    """One laser's range errors at `depths`: `params` (ax, x0, ay, y0), `cov` their (4, 4)
    covariance, `spot_sigma_n` one spot's scatter in normalised coordinates (σu/fx, σv/fy): (2,)
    for every depth, or (len(depths), 2) one a depth."""
    cal: list[float | None] = []
    one: list[float | None] = []
    b = baseline(params)
    spots = np.broadcast_to(np.asarray(spot_sigma_n, dtype=np.float64), (len(depths), 2))
    for depth, spot in zip(depths, spots):
        g = _sensitivity(params, depth)
        if g is None:
            cal.append(None)
            one.append(None)
            continue
        c2 = max(float(g @ cov @ g), 0.0)
        e = np.array([params[1], params[3]]) / b
        s2 = (depth * depth / b) ** 2 * float((e**2) @ (spot**2))
        cal.append(math.sqrt(c2))
        one.append(math.sqrt(c2 + s2))
    return RangeError(tuple(depths), tuple(cal), tuple(one))


def combined_range_error(per_laser: Mapping[str, RangeError], baselines: Mapping[str, float]) -> RangeError:
    """The lasers' ranges combined with weights ∝ baseline² (see the module docstring)."""
    names = [n for n in per_laser if baselines.get(n, 0.0) >= MIN_BASELINE_M]
    depths = next(iter(per_laser.values())).depths_m if per_laser else REPORT_DEPTHS_M
    cal: list[float | None] = []
    one: list[float | None] = []
    for k in range(len(depths)):
        use = [n for n in names if per_laser[n].calibration[k] is not None]
        if not use:
            cal.append(None)
            one.append(None)
            continue
        w = np.array([baselines[n] ** 2 for n in use])
        w = w / w.sum()
        c = np.array([per_laser[n].calibration[k] for n in use], dtype=float)
        o = np.array([per_laser[n].one_range[k] for n in use], dtype=float)
        cal.append(math.sqrt(float((w**2) @ (c**2))))
        one.append(math.sqrt(float((w**2) @ (o**2))))
    return RangeError(tuple(depths), tuple(cal), tuple(one))


def range_weights(baselines: Mapping[str, float]) -> dict[str, float]:
    """Each laser's weight in a combined range (∝ baseline²), as :func:`combined_range_error` has it."""
    return {n: b * b for n, b in baselines.items() if b >= MIN_BASELINE_M}
