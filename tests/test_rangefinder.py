"""The range finder: one range per camera frame, filtered robustly, on the simulated rig."""

from __future__ import annotations

import pytest

from edge.config import load_config
from edge.modes.rangefinder import RangeFilter, Rangefinder, range_payload
from edge.parts import open_parts
from edge.ranging import Ranger


def test_filter_ignores_a_lone_outlier() -> None:
    f = RangeFilter()
    out = [f.add(r, 0.005) for r in (2.00, 2.01, 1.99, 3.50, 2.00, 2.01)]
    assert all(abs(o.range_m - 2.0) < 0.02 for o in out[2:])


def test_filter_follows_a_step_within_two_frames() -> None:
    f = RangeFilter()
    for _ in range(5):
        f.add(2.0, 0.005)
    assert abs(f.add(1.5, 0.005).range_m - 2.0) < 1e-9  # one reading: could be an outlier
    assert abs(f.add(1.5, 0.005).range_m - 1.5) < 1e-9  # two on the same side: it moved


def test_filter_sigma_shrinks_with_readings() -> None:
    f = RangeFilter()
    sigmas = [f.add(2.0, 0.01).sigma_m for _ in range(5)]
    assert sigmas[0] == pytest.approx(0.01) and sigmas[-1] < 0.007


def test_one_range_per_frame_on_the_simulated_rig() -> None:
    config = load_config(None, [])
    out = []
    with open_parts(config) as parts:
        parts.ptu.move(-90.0, 0.0)  # the office's west wall, 1.30 m away
        finder = Rangefinder(parts.capture, Ranger(config.rig.build(), config.ranging), parts.lasers.names)
        frames = finder.run(-90.0, 0.0, lambda r, f, e: out.append((r, f, e)), lambda: False, max_frames=31)
        truth = parts.truth(0, -90.0, 0.0)["range_m"]
        assert not parts.lasers.lit
    assert frames == 31 and len(out) == 30
    # Consecutive camera frames: none was skipped, so there is a range for every frame.
    numbers = [e["frame"] for _, _, e in out]
    assert numbers == list(range(numbers[0], numbers[0] + 30))
    assert all(r.status == "ok" for r, _, _ in out)
    assert all(abs(f.range_m - truth) / truth < 0.01 for _, f, _ in out)
    payload = range_payload(*out[-1])
    assert payload["status"] == "ok" and payload["filtered_m"] == pytest.approx(truth, rel=0.01)
