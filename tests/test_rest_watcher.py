"""The pure half of `cmd/calibrate`: which rests of a carried target it takes, for which distance.

Spots are made the way a rig half a degree off makes them: where the nominal rig projects each
laser's point at the target's depth, plus a few pixels of error that the calibration is there to
find (so the nominal rig cannot tell 2 m from 1.3 m by where the spots are)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from edge.calibration.session import RestWatcher
from edge.rig import default_rig

RIG = default_rig()
ERROR_PX = np.array([4.6, -2.0])  # half a degree of laser error, mostly along the baseline
RATE_HZ = 15.0  # laser-off/on pairs a second
DISTANCES = [2.0, 1.3, 0.8, 0.5]


def spots_at(depth_m: float, rng: np.random.Generator, noise_px: float = 0.1) -> list[np.ndarray]:
    return [RIG.camera.project(laser.point_at_depth(depth_m)) + ERROR_PX + rng.normal(0, noise_px, 2)
            for laser in RIG.lasers]


def play(watcher: RestWatcher, script: list[tuple[float, Callable[[float], float]]],
         noise_px: float = 0.1) -> list[tuple[float, float]]:
    """Feed pairs for each (seconds, depth at time u within the part) of `script`; returns
    (time, distance) of each take."""
    rng = np.random.default_rng(7)
    t, taken = 0.0, []
    for seconds, depth in script:
        start = t
        while t < start + seconds:
            awaited = watcher.waiting_for
            if watcher.add(t, spots_at(depth(t - start), rng, noise_px)):
                taken.append((t, awaited))
            t += 1.0 / RATE_HZ
    return taken


def rest(d: float, seconds: float = 3.0) -> tuple[float, Callable[[float], float]]:
    return seconds, lambda u: d


def walk(a: float, b: float, speed: float = 0.7) -> tuple[float, Callable[[float], float]]:
    seconds = abs(b - a) / speed
    return seconds, lambda u: a + (b - a) * min(u / seconds, 1.0)


def test_each_rest_is_taken_in_order_while_the_target_stands_there():
    watcher = RestWatcher(RIG, DISTANCES)
    script = [rest(3.7, 2.5), walk(3.7, 2.0), rest(2.0), walk(2.0, 1.3), rest(1.3), walk(1.3, 0.8), rest(0.8),
              walk(0.8, 0.5), rest(0.5)]
    taken = play(watcher, script)
    assert [d for _, d in taken] == DISTANCES
    # Each take falls within its rest (the rests end at the cumulative times below).
    ends = np.cumsum([s for s, _ in script])
    for (t, _), k in zip(taken, (2, 4, 6, 8)):
        assert ends[k - 1] + 1.0 <= t <= ends[k], (t, ends[k - 1], ends[k])
    assert watcher.waiting_for is None and len(watcher.taken) == 4


def test_a_pause_half_way_and_a_move_the_wrong_way_are_not_taken():
    watcher = RestWatcher(RIG, DISTANCES)
    taken = play(watcher, [rest(3.7, 2.5), walk(3.7, 2.0), rest(2.0),
                           walk(2.0, 1.65), rest(1.65),   # half-way to 1.3: not it
                           walk(1.65, 2.6), rest(2.6),    # the wrong way
                           walk(2.6, 1.3), rest(1.3)])
    assert [d for _, d in taken] == [2.0, 1.3]
    assert taken[1][0] > 2.5 + 2.4 + 3 + 0.5 + 3 + 1.4 + 3  # only in the last rest


def test_a_target_already_in_place_or_left_in_place_is_not_taken_again():
    watcher = RestWatcher(RIG, DISTANCES)
    assert play(watcher, [rest(2.0, 6.0)]) == []  # there when the command came: bring it afterwards
    watcher = RestWatcher(RIG, DISTANCES)
    taken = play(watcher, [rest(3.7, 2.5), walk(3.7, 2.0), rest(2.0, 20.0)])
    assert [d for _, d in taken] == [2.0] and watcher.waiting_for == 1.3


def test_a_target_that_never_rests_is_never_taken():
    watcher = RestWatcher(RIG, DISTANCES)
    assert play(watcher, [rest(3.7, 2.5), walk(3.7, 2.0), rest(2.0)], noise_px=1.0) == []


@pytest.mark.parametrize("first", [0.6, 4.5])
def test_the_first_rest_must_be_where_the_nominal_rig_puts_the_first_distance(first):
    watcher = RestWatcher(RIG, DISTANCES)
    assert play(watcher, [rest(3.7, 2.5), walk(3.7, first), rest(first)]) == []
