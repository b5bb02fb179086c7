"""The pixels a spot finder reads of each frame (edge.paths.Strips): the strips along the lasers'
paths and the background grid, read by one gather in the order the finder slices them by."""

from __future__ import annotations

import numpy as np
import pytest

from edge.framenoise import NEIGHBOURS
from edge.paths import Strips
from edge.rig import default_rig


@pytest.fixture(scope="module")
def strips() -> Strips:
    rig = default_rig()
    return Strips(rig, rig.laser_names, 3.0)


def _expected(strips: Strips, plane: np.ndarray) -> np.ndarray:
    """What the gather should hold, read pixel by pixel from `plane` (full-scale units)."""
    bands = list(strips.bands.values())
    # Strips column by column: every laser's samples of column 0, then of column 1, …
    columns = [plane[b.v[:, j], b.u[:, j]] for j in range(strips.strip_width) for b in bands]
    near_v, near_u = strips.near_samples()
    near = [plane[near_v + dv, near_u + du] for du, dv in NEIGHBOURS]
    return np.concatenate([*columns, plane[strips.bg_v, strips.bg_u], *near])


def test_the_gather_reads_each_strip_and_background_pixel_where_the_finder_slices_it(strips: Strips) -> None:
    rng = np.random.default_rng(3)
    height, width = strips.height_px, strips.width_px
    frame = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    second = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)

    # Red alone, to float32's rounding (the gather scales in float32).
    red = strips.gather([frame], (0.0, 0.0, 1.0))
    assert red.dtype == np.float32
    np.testing.assert_allclose(red, _expected(strips, frame[..., 2] / 255.0), rtol=0, atol=1e-7)

    # Two frames averaged, a weighted mix of the channels (luma's weights).
    weights = (0.114, 0.587, 0.299)
    mixed = strips.gather([frame, second], weights)
    both = (frame.astype(np.float64) + second) / (2 * 255.0)
    np.testing.assert_allclose(mixed, _expected(strips, both @ np.array(weights)), rtol=0, atol=1e-6)

    # The finder's slices: each laser's rows, then the background, then the near block.
    total = sum(b.v.shape[0] for b in strips.bands.values())
    assert strips.background.start == total * strips.strip_width
    assert strips.near_block.stop == red.size
    assert strips.near_block.stop - strips.near_block.start == (1 + len(NEIGHBOURS)) * strips.near_count
    starts = [strips.rows[name].start for name in strips.bands]
    assert starts == sorted(starts) and strips.rows[next(reversed(strips.bands))].stop == total


def test_each_strip_runs_along_its_laser_path_and_the_grid_keeps_away_from_every_path(strips: Strips) -> None:
    for band in strips.bands.values():
        middle = band.u.shape[1] // 2
        centre = np.stack([band.u[:, middle], band.v[:, middle]], axis=1)
        assert np.max(np.abs(centre - band.path)) <= 0.5 + 1e-9  # the path, rounded to pixels
        assert band.step < 0.75  # sampled about every half pixel
        for u, v in zip(strips.bg_u.tolist(), strips.bg_v.tolist()):
            assert np.min(np.maximum(np.abs(band.path[:, 0] - u), np.abs(band.path[:, 1] - v))) > 6.0


def test_a_frame_of_another_size_is_refused_with_both_sizes(strips: Strips) -> None:
    with pytest.raises(ValueError, match=f"a 320x240 frame for a {strips.width_px}x{strips.height_px} camera"):
        strips.gather([np.zeros((240, 320), np.uint8)], (0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="no frames to gather"):
        strips.gather([], (0.0, 0.0, 1.0))
