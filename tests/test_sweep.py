"""A sweep end to end on the simulated parts: the emulated PTU on a pty through the real serial
driver, gpiozero's mock pins, the simulated camera on its frame clock."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from edge.config import load_config
from edge.errors import ConfigError, HardwareError
from edge.parts import open_parts
from edge.recording import read_recording
from edge.sweep import run_configured_sweep, sweeper_for, visiting_order, zone_views


def test_visiting_order_is_one_pass_from_the_nearer_end() -> None:
    poses = [(0.0, 0.0), (90.0, 0.0), (180.0, 0.0), (-90.0, 0.0)]
    assert visiting_order(poses, (0.0, 0.0)) == [3, 0, 1, 2]
    assert visiting_order(poses, (170.0, 0.0)) == [2, 1, 0, 3]


def test_sweep_on_the_simulated_rig_ranges_the_office() -> None:
    config = load_config(None, ["sweep.zones=6", "sweep.pan_start_deg=-90.0", "sweep.pan_step_deg=10.0"])
    sweep = run_configured_sweep(config)
    report = sweep.report
    assert [r.index for r in report.results] == list(range(6))
    ok = [r for r in report.results if r.status == "ok"]
    assert len(ok) >= 5
    # The office's west wall is 1.3 m from the rig at pan -90°.
    assert abs(report.results[0].range_m - 1.30) < 0.03
    assert report.duration_s > 0 and report.limit_s > 0
    # The simulator's truth comes with it, zone by zone, and the room's walls.
    assert abs(sweep.truth_ranges()[0] - 1.30) < 0.01 and len(sweep.room) >= 4


def test_edge_sweep_writes_results_and_map(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "sweep", "--out", str(tmp_path), "--set", "sweep.zones=3"],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "sweep.json").read_text())
    assert len(doc["zones"]) == 3
    assert (tmp_path / "map.png").stat().st_size > 1000
    for name in ("map.pgm", "map.yaml", "cloud.ply"):
        assert (tmp_path / name).stat().st_size > 0
    assert doc["rig"]["lasers"][0]["name"] == "center"  # what edge map casts the rays with


def test_a_nudge_at_a_pan_limit_goes_inward() -> None:
    config = load_config(None, ["sweep.pairs_per_zone=3"])
    assert zone_views(config, 180.0, 0.0, (-180.0, 180.0)) == [
        (180.0, 0.0), (180.0 - 0.0514, 0.0), (180.0 - 0.0514, 0.0)]
    assert zone_views(config, 10.0, 0.0, (-180.0, 180.0))[1] == (10.0 + 0.0514, 0.0)


# A sweep of 8 zones across the office's east wall, faults injected into the emulated unit after
# zone `at` has been measured.
_EIGHT = ["sweep.zones=8", "sweep.pan_start_deg=-60.0", "sweep.pan_step_deg=5.625"]


def _visits() -> list[int]:
    return visiting_order(load_config(None, _EIGHT).sweep.poses(), (0.0, 0.0))


def _sweep_with_fault(mode: str, at: int, sets: tuple[str, ...] = (), **fault) -> tuple[list, float]:
    config = load_config(None, [*_EIGHT, *sets])
    with open_parts(config) as parts:
        def inject(result) -> None:
            if result.index == at:
                parts.emulator.inject(mode, **fault)

        report = sweeper_for(parts, on_zone=inject).run()
        return report.results, report.duration_s


@pytest.mark.parametrize("mode, fault", [
    ("drop", {"count": 1}),
    ("garble", {"count": 2}),
    ("silence", {"seconds": 1.5}),
    ("notice", {"count": 2}),
    ("reset", {}),
])
def test_a_sweep_rides_out_a_unit_fault(mode: str, fault: dict) -> None:
    visits = _visits()
    results, _ = _sweep_with_fault(mode, at=visits[2], **fault)
    assert [r.index for r in results] == list(range(8))
    faults = [r.index for r in results if r.status == "fault"]
    # At most the zone measured while the unit misbehaved is lost; the others range as usual.
    assert len(faults) <= 1 and all(i == visits[3] for i in faults), faults
    assert sum(r.status == "ok" for r in results) >= 7 - len(faults)


@pytest.mark.slow
def test_a_hung_unit_ends_the_sweep_with_a_clear_error() -> None:
    # Each failed zone waits out the driver's three tries of a reply timeout and its growing pauses
    # (about 3 s a zone at the default 0.5 s): a shorter reply timeout, the same three failed zones.
    with pytest.raises(HardwareError, match="failed zones in a row.*pan-tilt unit"):
        _sweep_with_fault("hang", at=_visits()[0], sets=("ptu.timeout_s=0.2",))


def test_edge_record_saves_a_live_sweep_as_a_recording(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "record", str(rec), "--out", str(tmp_path / "out"),
         *sum((["--set", s] for s in _EIGHT[:1] + ["sweep.zones=3"]), [])],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    recording = read_recording(rec)
    assert [z.index for z in recording.zones] == [0, 1, 2]
    zone = recording.zones[0]
    assert len(zone.frames) == 4 and zone.truth["range_m"] > 0
    # Frames carry their own timing, and none straddled a laser switch.
    for frame in zone.frames:
        assert frame.t_start_ns is not None and frame.laser_switch_ns is not None
        assert frame.t_start_ns >= frame.laser_switch_ns
    replay = subprocess.run([sys.executable, "-m", "edge", "replay", str(rec)],
                            capture_output=True, text=True, timeout=60)
    assert replay.returncode == 0 and "ok 3" in replay.stdout, replay.stdout + replay.stderr


def test_no_frame_the_sweep_uses_saw_a_laser_switch() -> None:
    """The simulated camera knows, per laser, the least and most of an exposure any row saw it lit:
    every frame handed to ranging must be wholly lit or wholly dark for each laser."""
    config = load_config(None, ["sweep.zones=4", "sweep.pan_start_deg=-60.0", "sweep.pan_step_deg=5.625"])
    used = []
    with open_parts(config) as parts:
        take = parts.capture.take

        def watched(*args, **kwargs):
            shot = take(*args, **kwargs)
            used.append(shot)
            return shot

        parts.capture.take = watched
        report = sweeper_for(parts).run()
    assert len(used) == 4 * 2 * config.sweep.pairs_per_zone
    assert all(r.status == "ok" for r in report.results)
    for shot in used:
        for laser, (least, most) in shot.frame.metadata["laser_fraction_range"].items():
            if laser in shot.lasers_on:
                assert least == 1.0, (laser, least, most)
            else:
                assert most == 0.0, (laser, least, most)


def test_several_tilts_are_visited_as_a_serpentine() -> None:
    poses = load_config(None, ["sweep.zones=4", "sweep.pan_step_deg=10.0",
                               "sweep.tilts_deg=[-20.0, 0.0, 20.0]"]).sweep.poses()
    assert len(poses) == 12 and poses[0] == (0.0, -20.0) and poses[4] == (0.0, 0.0)
    order = visiting_order(poses, (0.0, 0.0))
    assert sorted(order) == list(range(12))
    steps = [(abs(poses[a][0] - poses[b][0]), abs(poses[a][1] - poses[b][1])) for a, b in zip(order, order[1:])]
    # One step at a time: along a tilt level in pan, or up to the next level (never back across).
    assert all((dp, dt) in ((10.0, 0.0), (0.0, 20.0)) for dp, dt in steps)


def test_tilt_levels_are_checked() -> None:
    with pytest.raises(ConfigError, match=r"sweep\.tilts_deg\[1\]: tilt 5° is listed twice"):
        load_config(None, ["sweep.tilts_deg=[5.0, 5.0]"])
    with pytest.raises(ConfigError, match=r"sweep\.tilts_deg\[0\]: must be within ±90°"):
        load_config(None, ["sweep.tilts_deg=[95.0]"])


def test_a_sweep_over_two_tilts_on_the_simulated_rig() -> None:
    config = load_config(None, ["sweep.zones=2", "sweep.pan_start_deg=-90.0", "sweep.pan_step_deg=10.0",
                                "sweep.tilts_deg=[0.0, -25.0]", "sweep.pairs_per_zone=1"])
    sweep = run_configured_sweep(config)
    results = sweep.report.results
    poses = [(-90.0, 0.0), (-80.0, 0.0), (-90.0, -25.0), (-80.0, -25.0)]
    assert [(r.pan_deg, r.tilt_deg) for r in results] == [pytest.approx(p, abs=0.06) for p in poses]
    # Down 25° towards the wall 1.3 m away: the beam meets it 0.6 m lower, further along.
    for r in results:
        truth = sweep.truths[r.index]
        assert r.status == "ok" and abs(r.range_m - truth["range_m"]) < 0.03 * truth["range_m"]
    assert results[2].point_base_m[2] < -0.5
