"""A spot's shape in a small square window about it: what its moments need, and the fits that place it.

A (2r + 1)² window, offsets −r … r from its centre, row by row. `window_kit` gives what a centroid
needs of such a window whatever its pixels (made once per r); `fit_gaussian` fits a Gaussian to the
log of a spot's pixels, `fit_unsaturated` to the unclipped pixels of a spot whose core is clipped,
and `fit_sites` to the pixels of a Bayer filter that saw the laser's colour. Pure numpy, no state:
`edge.vision.SpotFinder` decides which to use.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

# Fitting a spot's red pixels behind a Bayer filter: what the interpolation between them adds to the
# demosaiced spot's variance (px², bilinear's tent over the red pixels' 2 px pitch), the narrowest
# width held likely, and how far (in log width) the prior lets the red pixels move it.
_DEMOSAIC_SPREAD_PX2 = 0.5
_MIN_SITE_WIDTH_PX = 0.4
_SITE_WIDTH_PRIOR = 0.4
_PIXEL_VAR = 1.0 / 12.0  # a pixel's area widens a spot's samples by this variance (px²)


@functools.lru_cache(maxsize=16)
def monomials(r: int) -> np.ndarray:
    """(1, u, v, u², v², u·v) of every pixel of a (2r + 1)² window, row by row (v), offsets from
    its centre: (n, 6) float64."""
    v, u = np.divmod(np.arange((2 * r + 1) ** 2), 2 * r + 1)
    u, v = (u - r).astype(np.float64), (v - r).astype(np.float64)
    return np.stack([np.ones_like(u), u, v, u * u, v * v, u * v], axis=1)


def fit_gaussian(signal: np.ndarray, use: np.ndarray, r: int, round_: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A Gaussian fitted to the pixels `use` of `signal`, a (2r + 1)² window: the coefficients
    (a, b, c, d, e, f) of ln I = a + b·u + c·v + d·u² + e·v² + f·u·v (offsets from the window's
    centre), weighted by I² (the variance of ln I is σ²/I²); with the pixels' flat indices and the
    fit's values there. None when too few pixels are usable or the fit is not a peak. `round_` fits
    a round spot (d = e, f = 0): fewer unknowns, for few pixels."""
    idx = use.ravel().nonzero()[0]
    if idx.size < (6 if round_ else 10):
        return None
    mono = monomials(r)[idx]
    val = signal.ravel()[idx].astype(np.float64)
    if round_:
        mono = np.stack([mono[:, 0], mono[:, 1], mono[:, 2], mono[:, 3] + mono[:, 4]], axis=1)
    # The weighted design and, as its last column, the weighted logs: their products in one go.
    # (OpenCV's LU solve of 6 equations: a third of numpy's time, which its checks and dispatch take.)
    design = np.empty((idx.size, mono.shape[1] + 1))
    np.multiply(mono, val[:, None], out=design[:, :-1])
    np.log(val, out=design[:, -1])
    design[:, -1] *= val
    gram = design.T @ design
    solved, coef = cv2.solve(gram[:-1, :-1], gram[:-1, -1:], flags=cv2.DECOMP_LU)
    if not solved:
        return None
    coef = coef.ravel()
    got = coef.tolist()
    d, e, f = (got[3], got[3], 0.0) if round_ else got[3:]
    if d >= 0 or e >= 0 or 4.0 * d * e - f * f <= 0:
        return None
    fitted = np.exp(np.minimum(mono @ coef, 60.0))
    if round_:
        coef = np.array([*got, got[3], 0.0])
    return coef, idx, fitted


def gaussian_centre(coef: np.ndarray) -> tuple[float, float]:
    """The peak (du, dv) of a fitted Gaussian (`fit_gaussian`'s coefficients)."""
    _, b, c, d, e, f = coef.tolist()
    det = 4.0 * d * e - f * f
    return (f * c - 2.0 * e * b) / det, (f * b - 2.0 * d * c) / det


def fit_sites(above: np.ndarray, sites: np.ndarray, var: np.ndarray, offs: np.ndarray, du: float, dv: float,
               size: float, width: tuple[float, float] | None = None,
               others: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
               ) -> tuple[float, float, np.ndarray, float, float, float] | None:
    """A round Gaussian fitted by weighted least squares (Levenberg–Marquardt) to the pixels `sites`
    of `above` (their noise variances `var`), started at (du, dv) with width `size`: its centre, the
    centre's covariance (2, 2) and χ² per degree of freedom; None when it does not converge to a
    spot. For the red pixels of a Bayer filter, 2 px apart: too few above the noise for a fit of
    logarithms, and the demosaiced pixels between them lock a centroid onto them.

    A spot as small as the filter's period lights one or two red pixels: their values fix the
    centre only with its width, which they cannot tell. The width is then held near what the
    demosaiced spot shows (`size`, less the interpolation's spread) by a prior, whose uncertainty
    the centre's covariance carries; a spot that lights enough red pixels overrules it.

    `others`: the same spot in another colour's own pixels, (above, sites, var) of that plane, with
    an amplitude of its own (a red laser's light reaches a green filter at a tenth of red's): the
    green pixels lie between the red ones, where a small spot's core falls when the red ones see
    only its wings, and they tell its width."""
    y, x = np.nonzero(sites)
    if y.size < 8:
        return None
    val = above[y, x].astype(np.float64)
    w = 1.0 / var[y, x]
    second = np.zeros(y.size, bool)  # (the pixels of `others`, after the red ones)
    amp2 = 0.0
    if others is not None:
        above2, sites2, var2 = others
        y2, x2 = np.nonzero(sites2)
        if y2.size:
            val2 = above2[y2, x2].astype(np.float64)
            amp2 = max(float(val2.max()), 1e-9)
            y, x = np.concatenate([y, y2]), np.concatenate([x, x2])
            val = np.concatenate([val, val2])
            w = np.concatenate([w, 1.0 / var2[y2, x2]])
            second = np.concatenate([second, np.ones(y2.size, bool)])
    xs, ys = offs[x].astype(np.float64), offs[y].astype(np.float64)
    if width is None:
        t0 = 0.5 * math.log(max(size * size - _DEMOSAIC_SPREAD_PX2, _MIN_SITE_WIDTH_PX**2))
        prior = 1.0 / _SITE_WIDTH_PRIOR**2
    else:
        t0, prior = width[0], 1.0 / width[1] ** 2

    free = 5 if second.any() else 4  # (without `others`, the fifth column would be all zero: left out)
    amps = (~second).astype(np.float64), second.astype(np.float64)  # (each amplitude's pixels, as 1 and 0)

    # (Plain floats and one array filled column by column: numpy's calls, not the arithmetic on a
    # few dozen pixels, are what a step costs; the values are the same to the digit.)
    def model(p: list[float]) -> tuple[np.ndarray, np.ndarray, float]:
        w2 = math.exp(2.0 * p[3])
        s2 = w2 + _PIXEL_VAR
        dx, dy = xs - p[1], ys - p[2]
        r2 = dx * dx + dy * dy
        g = np.exp(-0.5 * r2 / s2)
        m = (amps[0] * p[0] + amps[1] * p[4]) * g
        jac = np.empty((g.size, free))
        np.multiply(g, amps[0], out=jac[:, 0])
        jac[:, 1] = m * dx / s2
        jac[:, 2] = m * dy / s2
        jac[:, 3] = m * r2 * w2 / (s2 * s2)
        if free == 5:
            np.multiply(g, amps[1], out=jac[:, 4])
        res = val - m
        return jac, res, float((w * res * res).sum()) + prior * (p[3] - t0) ** 2

    p = [max(float(val[~second].max()), 1e-9), du, dv, t0, amp2]
    jac, res, cost = model(p)
    diagonal = np.arange(free) * (free + 1)  # (flat indices of a (free, free) matrix's diagonal)
    damping = 1e-3
    for _ in range(20):
        jw = jac * w[:, None]
        info = jw.T @ jac
        info[3, 3] += prior
        grad = jw.T @ res
        grad[3] -= prior * (p[3] - t0)
        damped = info.copy()
        damped.flat[diagonal] += damping * info.flat[diagonal]
        try:
            step = np.linalg.solve(damped, grad).tolist()
        except np.linalg.LinAlgError:
            return None
        step[1] = min(max(step[1], -0.5), 0.5)
        step[2] = min(max(step[2], -0.5), 0.5)
        step[3] = min(max(step[3], -0.3), 0.3)
        trial = [a + b for a, b in zip(p, step)] + p[free:]
        tj, tr, tc = model(trial)
        if tc <= cost:
            p, jac, res, cost = trial, tj, tr, tc
            damping = max(damping / 3.0, 1e-7)
            if abs(step[1]) < 1e-3 and abs(step[2]) < 1e-3:
                break
        else:
            damping *= 4.0
            if damping > 1e6:
                break
    amp, u, v, t = p[:4]
    if amp <= 0 or not 0.3 < math.exp(t) < 6.0 or abs(u - du) > 1.0 or abs(v - dv) > 1.0:
        return None
    info = (jac * w[:, None]).T @ jac
    info[3, 3] += prior
    try:
        full = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None
    chi2 = float((w * res * res).sum()) / max(y.size - free, 1)
    return u, v, full[1:3, 1:3], chi2, t, float(full[3, 3])


def fit_unsaturated(signal: np.ndarray, unsaturated: np.ndarray, r: int, floor: float
                     ) -> tuple[float, float] | None:
    """Centre of a spot whose core is clipped, from a Gaussian fitted to its unclipped pixels.

    The centroid of a clipped, pixel-sampled spot is biased by up to ~0.07 px depending on where
    the spot falls within a pixel ("pixel locking"); the wings still carry the position.
    Returns (du, dv) relative to the centre of the (2r + 1)² window, or None when the fit is not a peak.
    """
    fit = fit_gaussian(signal, unsaturated & (signal > floor), r)
    return None if fit is None else gaussian_centre(fit[0])


def fit_round(above: np.ndarray, use: np.ndarray | None, var: np.ndarray, powers: np.ndarray,
              start: tuple[float, float, float], steps: int = 4) -> tuple[float, float, float, np.ndarray] | None:
    """A round Gaussian A·exp(−r²/2s²) fitted by weighted least squares to the pixels `use` of
    `above` (every pixel where None), each weighed by 1/`var`, from `start` (du, dv, s²): its
    centre (du, dv) from the window's centre, χ² per degree of freedom, and the centre's
    covariance (2, 2; px², from the noise `var` alone). `powers` is the window's `window_powers`.
    None where it leaves a spot (its centre more than a pixel from the start, a width out of
    0.3-6 px, no light).

    Where a centroid weighs every pixel over its threshold alike and drops the rest, this fit
    weighs each by its noise, and its χ² tells a spot whose shape a Gaussian does not explain
    (JPEG's blocks and ringing, speckle, another light in the window). Gauss–Newton steps in the
    amplitude, the centre and s², the amplitude solved exactly after each (it is linear), at most
    `steps` of them. (The design from the window's powers by one product, and the 3 × 3 algebra
    in plain floats: numpy's calls, not the arithmetic on a few dozen pixels, are what a step
    costs.)"""
    u, v, s2 = start
    if use is None:
        pw = powers
        val = above.ravel().astype(np.float64)
        w = 1.0 / var.ravel().astype(np.float64)
    else:
        idx = use.ravel().nonzero()[0]
        pw = powers.take(idx, axis=1)
        val = above.ravel().take(idx).astype(np.float64)
        w = 1.0 / var.ravel().take(idx).astype(np.float64)
    n = val.size
    if n < 12:
        return None
    wv = w * val
    # Rows: the Jacobian (amplitude, u, v, s²), then the residual: one product gives the normal
    # equations and their right-hand side.
    rows = np.empty((5, n))

    def shape(u: float, v: float, s2: float) -> tuple[np.ndarray, np.ndarray, float] | None:
        # (x − u)/s², (y − v)/s² and r²/2s⁴ from the powers (1, x, x², y, y²) by one product:
        # times the model, the derivatives by u, v and s²; then the Gaussian and its amplitude.
        k, h = 1.0 / s2, 0.5 / (s2 * s2)
        d = np.array([[-u * k, k, 0.0, 0.0, 0.0], [-v * k, 0.0, 0.0, k, 0.0],
                      [(u * u + v * v) * h, -2.0 * u * h, h, -2.0 * v * h, h]]).dot(pw)
        g = np.exp(d[2] * -s2)
        wg = w * g
        gg = float(wg.dot(g))
        amp = float(wv.dot(g)) / gg if gg > 0.0 else 0.0
        if amp <= 0.0:
            return None
        return d, g, amp

    def normal(d: np.ndarray, g: np.ndarray, amp: float) -> np.ndarray:
        m = amp * g
        rows[0] = g
        np.multiply(d, m, out=rows[1:4])
        np.subtract(val, m, out=rows[4])
        return (rows[:4] * w).dot(rows.T)  # (4, 5): JᵀWJ and JᵀW·residual

    start_u, start_v = u, v
    got = shape(u, v, s2)
    if got is None:
        return None
    for _ in range(steps):
        reduced = _reduced(normal(*got))
        if reduced is None:
            return None
        inverse = _inverse3(reduced[0])
        if inverse is None:
            return None
        p, q, r = reduced[1]
        su, sv, ss = (row[0] * p + row[1] * q + row[2] * r for row in inverse)
        su, sv = min(max(su, -0.5), 0.5), min(max(sv, -0.5), 0.5)
        grown = min(max(s2 + ss, 0.5 * s2), 2.0 * s2)
        # (A hundredth of a pixel: far below any spot's σ.)
        settled = abs(su) < 0.01 and abs(sv) < 0.01 and abs(grown - s2) < 0.01 * s2
        u, v, s2 = u + su, v + sv, grown
        got = shape(u, v, s2)
        if got is None:
            return None
        if settled:
            break
    if not 0.09 < s2 < 36.0 or abs(u - start_u) > 1.0 or abs(v - start_v) > 1.0:
        return None
    # The centre's covariance: its block of the inverse of the normal matrix at the fit, the
    # amplitude and s² free.
    reduced = _reduced(normal(*got))
    inverse = None if reduced is None else _inverse3(reduced[0])
    if inverse is None:
        return None
    res = rows[4]
    return u, v, float((w * res).dot(res)) / (n - 4), np.array([inverse[0][:2], inverse[1][:2]])


def _reduced(both: np.ndarray) -> tuple[list[list[float]], list[float]] | None:
    """The normal equations (4, 5: JᵀWJ | JᵀW·residual, the amplitude first) with the amplitude
    eliminated: the 3 × 3 system of the centre and s² (its Schur complement), exactly the same
    step for them. (Plain floats: numpy's solve costs more to call than this arithmetic.) None
    where the amplitude's own term is not positive."""
    m = both.tolist()
    a = m[0][0]
    if a <= 0.0:
        return None
    b, ra = m[0][1:4], m[0][4]
    matrix = [[m[i + 1][j + 1] - b[i] * b[j] / a for j in range(3)] for i in range(3)]
    rhs = [m[i + 1][4] - b[i] * ra / a for i in range(3)]
    return matrix, rhs


def _inverse3(matrix: list[list[float]]) -> list[list[float]] | None:
    """The inverse of a 3 × 3 matrix by its adjugate (plain floats); None where it is singular."""
    (a, b, c), (d, e, f), (g, h, i) = matrix
    ei, di, dh = e * i - f * h, d * i - f * g, d * h - e * g
    det = a * ei - b * di + c * dh
    if det == 0.0:
        return None
    return [[ei / det, (c * h - b * i) / det, (b * f - c * e) / det],
            [-di / det, (a * i - c * g) / det, (c * d - a * f) / det],
            [dh / det, (b * g - a * h) / det, (a * e - b * d) / det]]


@functools.lru_cache(maxsize=16)
def window_offsets(r: int) -> np.ndarray:
    """A window's offsets from its centre, −r … r (float32)."""
    return np.arange(-r, r + 1, dtype=np.float32)


@functools.lru_cache(maxsize=16)
def window_powers(r: int) -> np.ndarray:
    """1, x, x², y and y² of every pixel of a (2r + 1)² window (offsets −r … r from its centre,
    row by row): (5, (2r + 1)²) float64, for a window's moments by one matrix-vector product."""
    v, u = np.divmod(np.arange((2 * r + 1) ** 2), 2 * r + 1)
    u, v = (u - r).astype(np.float64), (v - r).astype(np.float64)
    return np.stack([np.ones_like(u), u, u * u, v, v * v])


@functools.lru_cache(maxsize=16)
def border_index(size: int) -> np.ndarray:
    """Flat indices of the outermost ring of a size × size window."""
    ring = np.ones((size, size), bool)
    ring[1:-1, 1:-1] = False
    return np.flatnonzero(ring)


def border_level(win: np.ndarray, border: np.ndarray) -> float:
    """The median of a square window's outermost ring, `border` (`border_index`; the upper of
    the middle two): the room's level about a spot. (The ring, a copy, sorted in place costs half
    sorted() of its values as floats, and less than np.partition, on a few dozen values.)"""
    ring = win.take(border)
    ring.sort()
    return ring.item(ring.size // 2)


@dataclass(frozen=True)
class WindowKit:
    """What `SpotFinder._refine` needs of a (2r + 1)² window, whatever its pixels: made once per
    half-size r (`window_kit`), one lookup instead of four per window."""

    border: np.ndarray  # `border_index`
    offsets: np.ndarray  # `window_offsets`
    powers: np.ndarray  # `window_powers`
    monomials: np.ndarray  # `monomials`


@functools.lru_cache(maxsize=16)
def window_kit(r: int) -> WindowKit:
    return WindowKit(border_index(2 * r + 1), window_offsets(r), window_powers(r), monomials(r))
