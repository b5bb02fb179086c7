"""The oracle the benchmark compares the estimator with: its fit reaches the Cramér–Rao bound where
the noise is white, reads a demosaiced Bayer frame's kept samples, and its figures sit beside the estimator's."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from edge.accuracy import floor as fl
from edge.accuracy.oracle import fit_centre
from edge.accuracy.score import Figures, ZoneOutcome, targets
from edge.ranging import OK


def test_the_oracle_fit_reaches_the_bound_of_a_colour_spot_in_white_noise() -> None:
    cov = np.array([[1.1, 0.2], [0.2, 0.8]])
    h = w = 20
    response = np.array([0.1, 0.3, 1.0])  # B, G, R
    total, noise = 3000.0, 8.0
    rng = np.random.default_rng(7)
    errors = []
    for _ in range(200):
        centre = np.array([9.5, 10.0]) + rng.uniform(-0.5, 0.5, 2)
        g, _ = fl.spot_profile(centre, cov, 0, 0, w, h)
        offset = rng.normal(0.0, 5.0, 3)  # what the room light left in the difference, per plane
        diff = g[..., None] * total * response + offset + rng.normal(0.0, noise, (h, w, 3))
        fitted = fit_centre(diff, np.ones((h, w), bool), centre + rng.normal(0.0, 0.1, 2), cov)
        assert fitted is not None
        errors.append(fitted - centre)
    # The bound in white noise of σ `noise` in every plane: σ² / Σ ∂I ∂Iᵀ over pixels and planes.
    _, dg = fl.spot_profile(np.array([9.5, 10.0]), cov, 0, 0, w, h)
    fisher = np.einsum("ihw,jhw->ij", dg, dg) * total**2 * float((response**2).sum()) / noise**2
    bound = np.sqrt(np.diag(np.linalg.inv(fisher)))
    e = np.array(errors)
    assert np.abs(e.mean(axis=0)).max() < 0.3 * bound.max()  # unbiased
    # Free amplitudes and offsets cost a little (6 more unknowns over some 80 pixels a plane).
    assert np.all(e.std(axis=0) >= 0.85 * bound) and np.all(e.std(axis=0) <= 1.25 * bound), (e.std(axis=0), bound)


def test_behind_a_bayer_filter_the_oracle_reads_the_samples_the_demosaicing_kept() -> None:
    """A spot as small as the filter's period: its demosaiced planes are no Gaussian, and a fit of
    them scatters 20 times the bound; the samples each pixel took of its own colour reach it."""
    cov = np.array([[0.9, 0.1], [0.1, 0.7]])
    h = w = 24
    room, total, read = 400.0, 30000.0, 4.0
    response = np.array([0.05, 0.15, 1.0])
    own = np.where((np.arange(h)[:, None] % 2 == 0) & (np.arange(w)[None, :] % 2 == 0), 2,
                   np.where((np.arange(h)[:, None] % 2 == 1) & (np.arange(w)[None, :] % 2 == 1), 0, 1))
    rng = np.random.default_rng(3)
    kept, planes = [], []
    for _ in range(80):
        centre = np.array([11.0, 11.0]) + rng.uniform(-0.5, 0.5, 2)
        g, _ = fl.spot_profile(centre, cov, 0, 0, w, h)

        def frame(light: np.ndarray) -> np.ndarray:
            electrons = rng.poisson(light) + rng.normal(0.0, read, light.shape)
            raw = np.clip(np.rint(electrons / 4.0), 0, 65535).astype(np.uint16)  # 4 e⁻ a step
            return cv2.cvtColor(raw, cv2.COLOR_BayerRGGB2BGR).astype(np.float64)  # as the simulator's camera

        diff = frame(room + total * response[own] * g) - frame(np.full((h, w), room))
        usable = np.ones((h, w), bool)
        for out, bayer in ((kept, True), (planes, False)):
            fitted = fit_centre(diff, usable, centre, cov, bayer=bayer)
            assert fitted is not None
            out.append(fitted - centre)
    spot = fl.Spot(np.array([11.0, 11.0]), cov, total, response, np.full((h, w, 3), room), 0, 0)
    fisher, _, _ = fl.pair_information(spot, fl.Sensor(read, 4.0**2 / 12.0, math.inf, bayer=True))
    bound = np.sqrt(np.diag(np.linalg.inv(fisher)))  # px, whatever the frame's scale
    rms_kept = np.sqrt((np.array(kept) ** 2).mean(axis=0))
    rms_planes = np.sqrt((np.array(planes) ** 2).mean(axis=0))
    assert np.all(rms_kept <= 1.3 * bound), (rms_kept, bound)
    assert np.all(rms_planes >= 5.0 * bound), (rms_planes, bound)


def _zone(index: int, range_m: float, oracle_error_m: float | None, floor_m: float = 0.01) -> ZoneOutcome:
    return ZoneOutcome(index, OK, range_m, 0.02, 2.0, True, floor_m, 20.0, oracle_error_m=oracle_error_m)


def test_the_estimator_is_set_beside_the_oracle_on_the_zones_both_ranged() -> None:
    zones = [
        _zone(0, 2.02, 0.01),  # ours 2 floors off, the oracle 1
        _zone(1, 2.01, -0.01),  # 1 and 1
        _zone(2, 2.05, None),  # the oracle could not fit it: not compared
    ]
    f = Figures.of(zones)
    assert f.oracle_scored == 2
    assert f.ratio_beside_oracle == pytest.approx(1.5) and f.oracle_ratio == pytest.approx(1.0)
    assert f.over_oracle == pytest.approx(1.5)
    assert f.mean_ratio == pytest.approx((2 + 1 + 5) / 3)  # the floor's figure keeps every zone
    met = {t.what: t.met for t in targets([f], f)}
    assert met["mean |error| ÷ the oracle's on the same frames ≤ 1.5"] is True
    worse = Figures.of([_zone(0, 2.04, 0.01)])
    assert not next(t.met for t in targets([worse], worse) if "oracle" in t.what)
    # Without the oracle (a replay of a recording that carries no renderer) there is no such target.
    alone = Figures.of([_zone(0, 2.01, None)])
    assert math.isnan(alone.over_oracle) and not any("oracle" in t.what for t in targets([alone], alone))


def test_coverage_is_also_told_of_the_zones_the_oracle_can_place() -> None:
    """An observable zone whose spot JPEG kept as energy in a block but whose place it erased is one
    the oracle, told the true pixel, also ranges 10 % off: the bench tells coverage of the zones the
    oracle places to 5 % apart, so that what the estimator leaves can be told from what the frames do."""
    zones = [
        _zone(0, 2.01, 0.01),  # placeable, ok
        replace(_zone(1, 2.0, 0.02), status="no_spot", range_m=None),  # placeable (1 %), missed
        replace(_zone(2, 2.0, 0.2), status="ambiguous", range_m=None),  # the oracle 10 % off: not placeable
        _zone(3, 2.01, None),  # no oracle: not placeable
    ]
    f = Figures.of(zones)
    assert (f.observable, f.covered, f.placeable, f.covered_placeable) == (4, 2, 2, 1)
