"""Two spots merged into one blob, placed together on their lasers' paths (edge/deblend.py)."""

from __future__ import annotations

import numpy as np
import pytest

from edge.deblend import place_pair
from edge.rig import default_rig


def _merged(depth: float, sigma: float, noise: float, seed: int):
    """A difference window holding the `center` and `parallel` spots of the default rig at
    `depth`, Gaussians of `sigma` px, with white noise."""
    rig = default_rig()
    center, parallel = rig.laser("center"), rig.laser("parallel")
    truth = [rig.camera.project(laser.point_at_depth(np.array([depth])))[0] for laser in (center, parallel)]
    mid = (truth[0] + truth[1]) / 2
    origin = (int(mid[0]) - 6, int(mid[1]) - 6)
    v, u = np.mgrid[0:13, 0:13]
    u, v = u + origin[0], v + origin[1]
    rng = np.random.default_rng(seed)
    window = rng.normal(0.0, noise, u.shape) + 0.02
    for p, a in zip(truth, (1.0, 0.8)):
        window += a * np.exp(-((u - p[0]) ** 2 + (v - p[1]) ** 2) / (2 * sigma**2))
    return rig, (center, parallel), window, origin, truth


def test_two_merged_spots_are_placed_on_their_paths() -> None:
    rig, lasers, window, origin, truth = _merged(4.5, 2.0, 0.02, 1)
    gap = float(np.linalg.norm(truth[0] - truth[1]))
    assert gap < 2.5 * 2.0  # one blob: no dip between the spots
    # Start both at the blob's centroid's nearest points, as the ranger does.
    placed = place_pair(window, origin, lasers, rig.camera, (1 / 3.0, 1 / 3.0), (1 / 8.0, 1 / 0.2))
    assert placed is not None
    for p, t in zip(placed, truth):
        assert np.linalg.norm(p.pixel - t) < 0.1
        assert 1.0 / p.inv_depth == pytest.approx(4.5, rel=0.03)
        assert p.snr > 20 and p.size_px == pytest.approx(2.0, rel=0.1)
    # What a windowed centroid of the blob would have said: between the two, on neither path.
    v, u = np.mgrid[0:13, 0:13]
    w = np.maximum(window - 0.1, 0)
    centroid = np.array([(w * (u + origin[0])).sum(), (w * (v + origin[1])).sum()]) / w.sum()
    assert min(np.linalg.norm(centroid - t) for t in truth) > 1.0


def test_a_blob_with_one_spot_gives_no_second() -> None:
    """Only the centre laser's spot: the second spot's amplitude fits to about nothing."""
    rig, lasers, window, origin, truth = _merged(4.5, 1.3, 0.02, 2)
    v, u = np.mgrid[0:13, 0:13]
    u, v = u + origin[0], v + origin[1]
    window -= 0.8 * np.exp(-((u - truth[1][0]) ** 2 + (v - truth[1][1]) ** 2) / (2 * 1.3**2))
    placed = place_pair(window, origin, lasers, rig.camera, (1 / 4.0, 1 / 4.0), (1 / 8.0, 1 / 0.2))
    assert placed is None or placed[1].snr < 3.0
