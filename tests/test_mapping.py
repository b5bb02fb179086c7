"""The map: where the points land in the picture, the room in the base frame, the error figure."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.mapping import draw_map, map_error, results_document, room_in_base_frame
from edge.ranging import NO_SPOT, OK, ZoneResult
from edge.rig import Pose, rot_z


def _ok(index: int, pan: float, r: float) -> ZoneResult:
    p = np.array([r * math.cos(math.radians(pan)), r * math.sin(math.radians(pan)), 0.0])
    return ZoneResult(index, pan, 0.0, OK, r, 0.01, np.array([0.035, 0.0, r]), p)


def test_map_error_is_over_ok_zones_with_truth() -> None:
    results = [_ok(0, 0, 2.02), _ok(1, 90, 0.99), ZoneResult(2, 180, 0, NO_SPOT)]
    err = map_error(results, [2.0, 1.0, 3.0])
    assert err.zones == 2
    assert err.mean_rel == pytest.approx((0.01 + 0.01) / 2)
    assert err.max_rel == pytest.approx(0.01)
    assert map_error([ZoneResult(0, 0, 0, NO_SPOT)], [1.0]) is None


def test_points_are_drawn_where_the_base_frame_says() -> None:
    # Base x forward is up in the picture, y left is left.
    results = [_ok(0, 0.0, 2.0), _ok(1, 90.0, 1.0)]
    img = draw_map(results, size_px=400)
    half = 2.0 * 1.1
    scale = (400 / 2 - 20) / half
    ahead = (200, int(round(200 - 2.0 * scale)))  # (u, v) of the point 2 m ahead
    left = (int(round(200 - 1.0 * scale)), 200)
    assert img.shape == (400, 400, 3)
    assert img[ahead[1], ahead[0], 1] > 150  # green point
    assert img[left[1], left[0], 1] > 150
    assert img[200 + 60, 200, 1] < 100  # nothing drawn behind the rig


def test_room_is_moved_into_the_base_frame() -> None:
    base_to_world = Pose(rot_z(math.radians(90.0)), np.array([2.0, 1.0, 1.0]))
    # A wall 1 m in front of the rig, which faces world +y.
    room = room_in_base_frame([((1.0, 2.0), (3.0, 2.0))], base_to_world)
    (ax, ay), (bx, by) = room[0]
    assert (ax, bx) == pytest.approx((1.0, 1.0))
    assert sorted([ay, by]) == pytest.approx([-1.0, 1.0])


def test_results_document() -> None:
    doc = results_document([_ok(0, 0.0, 2.0)], sweep=3)
    assert doc["format"] == "edge-ranges/1" and doc["sweep"] == 3
    assert doc["zones"][0]["range_m"] == 2.0
