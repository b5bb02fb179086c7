"""Locating one laser spot in a difference image: the Gaussian-windowed centroid, and what clipping
does to it.

The windowed centroid (mean shift) is unbiased for a symmetric spot and, at rest, the estimator that
speckle moves least (a least-squares Gaussian fit was moved more). But a spot bright enough to clip
the sensor is no longer the pixels of a smooth spot: its top is a plateau whose edges fall within a
pixel, and the centroid of a sharp-edged plateau sampled by pixels is pulled towards the pixel grid
(pixel locking). With the simulator's spots (σ 0.55-1 px, up to 15 x full scale at 0.4 m) that is
up to 0.14 px, 0.05 px RMS, at every distance where the spot clips: as much as speckle moves it.

So a clipped spot's centroid is corrected by its own bias (:func:`clipping_correction`): a model of
the spot as the sensor shows it, min(pixel-integrated Gaussian, the pixel's headroom), is fitted to
the window, clipped pixels counting only where the model falls below them (they say "at least
this"); the centroid of the model placed at μ is then compared with μ, and μ is moved until the
model's centroid is the one measured. The model only has to be roughly right: it supplies a
correction of a tenth of a pixel, and that correction is what it gets wrong by a few percent. The
spot's position still comes from the centroid, so speckle moves it no more than before.

Pure: arrays in, arrays out.
"""

from __future__ import annotations

import math

import numpy as np

WINDOW_SIGMA_PX = 1.5  # the Gaussian centroid (mean-shift) window
CLIPPED_FRACTION = 0.998  # a frame's value at or above this share of full scale is clipped
MAX_CORRECTION_PX = 0.5  # a larger correction means the model does not fit: left uncorrected
FIT_RADIUS_PX = 5  # the model is fitted this far around the centroid (a neighbour 6 px off stays out)


def pixel_gaussian(x: np.ndarray, mu: float, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A unit 1-D Gaussian integrated over the pixels centred at `x` (consecutive, ascending), and
    its derivatives by mu and by sigma."""
    edges = np.append(x - 0.5, x[-1] + 0.5)
    t = (edges - mu) / sigma
    cdf = 0.5 * np.array([1.0 + math.erf(float(c) / math.sqrt(2.0)) for c in t])
    pdf = np.exp(-0.5 * t * t) / math.sqrt(2.0 * math.pi)
    return np.diff(cdf), -np.diff(pdf) / sigma, -np.diff(pdf * t) / sigma


def windowed_centroid(signal: np.ndarray, gu: np.ndarray, gv: np.ndarray, start: tuple[float, float]
                      ) -> tuple[float, float] | None:
    """The mean shift of `signal` (h, w) (pixel coordinates `gu`, `gv`) under a Gaussian window of
    WINDOW_SIGMA_PX from `start`: its fixed point, or None if the window holds no signal."""
    cu, cv, s2 = float(start[0]), float(start[1]), 2.0 * WINDOW_SIGMA_PX**2
    for _ in range(40):
        w = np.exp(-((gu - cu) ** 2 + (gv - cv) ** 2) / s2) * signal
        total = float(w.sum())
        if total <= 0:
            return None
        nu, nv = float((w * gu).sum() / total), float((w * gv).sum() / total)
        done = abs(nu - cu) < 1e-4 and abs(nv - cv) < 1e-4
        cu, cv = nu, nv
        if done:
            break
    return cu, cv


def background_free(win: np.ndarray) -> np.ndarray:
    """A window's signal: less the median of its border, negatives cut (what the centroid weighs)."""
    border = np.concatenate([win[0], win[-1], win[1:-1, 0], win[1:-1, -1]])
    return np.clip(win - np.median(border), 0.0, None)


# --- clipping -------------------------------------------------------------------------------------


def _model(theta: np.ndarray, us: np.ndarray, vs: np.ndarray, headroom: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The clipped spot (A, μu, μv, σu, σv, background) on the window: min(A·g + b, headroom), the
    unclipped part's Jacobian (h, w, 6), and where the model is below the headroom."""
    a, mu, mv, su, sv, b = theta
    pu, du, dsu = pixel_gaussian(us, mu, su)
    pv, dv, dsv = pixel_gaussian(vs, mv, sv)
    g = np.outer(pv, pu)
    raw = a * g + b
    free = raw < headroom
    jac = np.stack([g, a * np.outer(pv, du), a * np.outer(dv, pu), a * np.outer(pv, dsu),
                    a * np.outer(dsv, pu), np.ones_like(g)], axis=-1)
    return np.where(free, raw, headroom), jac * free[..., None], free


def _residuals(theta: np.ndarray, win: np.ndarray, clipped: np.ndarray, us: np.ndarray, vs: np.ndarray,
               headroom: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (data − model) and their Jacobian rows (∂model): a clipped pixel counts only where
    the model lies below it (it is a lower bound)."""
    model, jac, _ = _model(theta, us, vs, headroom)
    r = win - model
    count = ~clipped | (r > 0)
    return np.where(count, r, 0.0).ravel(), (jac * count[..., None]).reshape(-1, 6)


def fit_clipped(win: np.ndarray, clipped: np.ndarray, headroom: np.ndarray, us: np.ndarray, vs: np.ndarray,
                start: tuple[float, float]) -> np.ndarray | None:
    """The clipped-Gaussian model (A, μu, μv, σu, σv, background) of a spot by Levenberg-Marquardt
    from a coarse search over brightness and width (a clipped spot's brightness is many times what
    its window shows), or None if it does not settle."""
    best: tuple[float, np.ndarray] | None = None
    for a in max(float(win.sum()), 1e-9) * np.geomspace(1.0, 100.0, 7):
        for s in (0.6, 1.0, 1.6):
            theta = np.array([a, start[0], start[1], s, s, 0.0])
            cost = float((_residuals(theta, win, clipped, us, vs, headroom)[0] ** 2).sum())
            if best is None or cost < best[0]:
                best = (cost, theta)
    assert best is not None
    cost, theta = best
    lam = 1e-3
    for _ in range(100):
        r, jac = _residuals(theta, win, clipped, us, vs, headroom)
        jtj, grad = jac.T @ jac, jac.T @ r
        while lam < 1e8:
            step = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-12), grad)
            trial = theta + step
            trial[3:5] = np.clip(trial[3:5], 0.3, 4.0)
            c = float((_residuals(trial, win, clipped, us, vs, headroom)[0] ** 2).sum())
            if c <= cost:
                theta, cost, lam = trial, c, lam * 0.3
                break
            lam *= 10.0
        else:
            break
        if np.abs(step[1:3]).max() < 1e-6:
            break
    if theta[0] <= 0 or np.hypot(theta[1] - start[0], theta[2] - start[1]) > 2.0:
        return None
    return theta


def clipping_correction(win: np.ndarray, clipped: np.ndarray, headroom: np.ndarray, gu: np.ndarray,
                        gv: np.ndarray, centroid: tuple[float, float]) -> np.ndarray | None:
    """What to add (2,) to the windowed `centroid` of a spot with clipped pixels (window `win` of
    the difference image, `clipped` where an on frame was at full scale, `headroom` the difference a
    clipped pixel shows, coordinates `gu`, `gv`) for the centroid's pixel locking; None when the
    spot's model does not fit (then the centroid is left as it is)."""
    us, vs = gu[0].astype(np.float64), gv[:, 0].astype(np.float64)
    near_u = np.abs(us - round(centroid[0])) <= FIT_RADIUS_PX
    near_v = np.abs(vs - round(centroid[1])) <= FIT_RADIUS_PX
    near = np.ix_(near_v, near_u)
    theta = fit_clipped(win[near], clipped[near], headroom[near], us[near_u], vs[near_v], centroid)
    if theta is None:
        return None
    measured = np.array(centroid)
    mu = measured.copy()
    for _ in range(4):  # μ such that the model placed there shows the measured centroid
        model = _model(np.array([theta[0], mu[0], mu[1], theta[3], theta[4], theta[5]]), us, vs, headroom)[0]
        seen = windowed_centroid(background_free(model), gu, gv, centroid)
        if seen is None:
            return None
        mu = mu + (measured - np.array(seen))
    correction = mu - measured
    return correction if float(np.hypot(*correction)) <= MAX_CORRECTION_PX else None
