"""The latency benchmarks (`edge bench blindaid|rangefinder`): their reports' structure and sanity
on the simulated rig. Never their speed: the machines that run tests are shared."""

from __future__ import annotations

import math

import pytest

from edge import bench
from edge.cli import main
from edge.config import load_config

REAL_CLOCK = 'sim.clock="real"'


def test_chunk_start_is_the_next_boundary_of_the_players_grid() -> None:
    rate, chunk_n = 22050, 441  # 20 ms chunks
    assert bench._chunk_start_s(0.0, chunk_n, rate) == 0.0
    assert bench._chunk_start_s(0.001, chunk_n, rate) == pytest.approx(0.020)
    assert bench._chunk_start_s(0.020, chunk_n, rate) == pytest.approx(0.020)  # on a boundary: that one
    assert bench._chunk_start_s(0.0201, chunk_n, rate) == pytest.approx(0.040)


def test_spread_of_nothing_is_nan_not_an_error() -> None:
    assert math.isnan(bench.Spread.of([]).median)
    assert bench.Spread.of([1.0, 2.0, 3.0]).max == 3.0


def test_a_comparison_is_timed_in_alternating_rounds_so_that_both_sides_see_the_same_load() -> None:
    """`edge bench ranging` compares edge with the thesis' pipeline: timed one after the other,
    the machine's load fell on one side. Each round runs each call its number of times in turn."""
    order: list[str] = []
    figures = bench._interleaved_ms([(lambda: order.append("ours"), 3), (lambda: order.append("theirs"), 1)], 4)
    assert order == (["ours"] * 3 + ["theirs"]) * 4
    for median, p90, fastest in figures:
        assert 0.0 <= fastest <= median <= p90


def test_blindaid_reports_work_and_the_latency_it_makes() -> None:
    config = load_config(None, ["blindaid.fan_zones=3"])  # a short fan: the figures, not their number
    out = bench.measure_blindaid(config, passes=1)
    zones = 2 * config.blindaid.fan_zones - 2  # one pass there and back
    assert out.simulated and out.faults == 0
    assert len(out.work_ms) == len(out.stream_ms) == len(out.changed) == zones
    assert all(w > 0 for w in out.work_ms)
    # The cue sounds at the first chunk boundary after the frame's end plus the work: never sooner
    # than the work, never a whole chunk later.
    for work, stream in zip(out.work_ms, out.stream_ms):
        assert work - 1e-6 <= stream <= work + config.audio.chunk_ms + 1e-6
    lead = config.audio.lead_ms
    assert out.card_latency_ms == pytest.approx([s + lead + 2 * lead for s in out.stream_ms])
    assert any(out.changed)  # the first zone seen makes a cue at least
    text = "\n".join(out.lines())
    for label in ("simulated time", "device's work", "in the stream", "with a sound card", "cues that changed"):
        assert label in text
    assert "as it ran" not in text  # on simulated time the rig's clock holds no computing


def test_blindaid_on_real_time_says_its_rig_clock_figures_include_rendering() -> None:
    out = bench.BlindAidLatency(False, 1, 20.0, 33.3, 20.0, 40.0, work_ms=[2.0], cpu_ms=[1.9], stream_ms=[15.0],
                                as_ran_ms=[35.0], changed=[True])
    text = "\n".join(out.lines())
    assert 'real time (sim.clock = "real")' in text and "includes rendering" in text


def test_rangefinder_gives_one_range_per_frame_on_simulated_time() -> None:
    config = load_config(None, [])
    out = bench.measure_rangefinder(config, frames=12)
    assert out.simulated
    assert out.ranges == 12 and out.frames_used == 13  # the first frame has nothing to pair with
    assert out.dropped == 0 and out.straddled == 0
    assert out.rate_hz == pytest.approx(config.camera.frame_rate_hz, rel=1e-6)
    assert all(w > 0 for w in out.work_ms)
    assert out.statuses["ok"] == 12
    text = "\n".join(out.lines())
    for label in ("simulated time", "device's work", "ranges per second of rig time", "frames dropped: 0"):
        assert label in text


def test_rangefinder_on_real_time(capsys: pytest.CaptureFixture[str]) -> None:
    """Through the command, as run: the wall-clock figure says it includes rendering."""
    assert main(["bench", "rangefinder", "--repeats", "4", "--set", REAL_CLOCK]) == 0
    text = capsys.readouterr().out
    assert "range finder on real time" in text and "includes rendering" in text
    assert "4 ranges" in text
