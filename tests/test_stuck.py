"""`edge.stuck`: where a laser's spot shows in a laser-off frame, along its strip, on frames made
here (pure numpy, the default rig's strips)."""

from __future__ import annotations

import numpy as np
import pytest

from edge.config import load_config
from edge.stuck import lit_in_off, lit_spots
from edge.vision import SpotFinder


@pytest.fixture(scope="module")
def band_and_finder():
    rig = load_config(None).rig.build()
    finder = SpotFinder(rig)
    return finder.bands["center"], finder


def _frame(spots: list[tuple[int, int]], level: float = 40.0, peak: float = 120.0) -> np.ndarray:
    """A grey 640 × 480 frame at `level` with a 3 × 3 fleck of `peak` at each (u, v)."""
    image = np.full((480, 640), level, np.float64)
    for u, v in spots:
        image[v - 1:v + 2, u - 1:u + 2] = peak
        image[v, u] = peak + 20.0
    return image.astype(np.uint8)


def test_a_fleck_on_the_path_is_found_where_it_is_and_once(band_and_finder):
    band, finder = band_and_finder
    near, far = band.path[len(band.path) // 4], band.path[3 * len(band.path) // 4]
    flecks = [(int(round(near[0])), int(round(near[1]))), (int(round(far[0])), int(round(far[1])))]
    found = lit_spots(band, _frame(flecks), finder.max_spot_px)
    assert found == [(float(u), float(v)) for u, v in flecks]  # (in the path's order: its brightest pixels)
    assert lit_in_off(band, _frame(flecks), finder.max_spot_px)
    # `near`: only a peak there counts.
    assert lit_spots(band, _frame(flecks), finder.max_spot_px, near=near) == found[:1]


def test_a_plain_frame_or_a_fleck_off_the_path_shows_nothing(band_and_finder):
    band, finder = band_and_finder
    assert lit_spots(band, _frame([]), finder.max_spot_px) == []
    u, v = band.path[len(band.path) // 2]
    assert lit_spots(band, _frame([(int(round(u)) + 60, int(round(v)))]), finder.max_spot_px) == []
    assert not lit_in_off(band, _frame([]), finder.max_spot_px)
