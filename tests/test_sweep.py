"""A sweep end to end on the simulated parts: the emulated PTU on a pty through the real serial
driver, gpiozero's mock pins, the simulated camera on its frame clock."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from edge.config import load_config
from edge.sweep import run_configured_sweep, visiting_order


def test_visiting_order_is_one_pass_from_the_nearer_end() -> None:
    poses = [(0.0, 0.0), (90.0, 0.0), (180.0, 0.0), (-90.0, 0.0)]
    assert visiting_order(poses, (0.0, 0.0)) == [3, 0, 1, 2]
    assert visiting_order(poses, (170.0, 0.0)) == [2, 1, 0, 3]


def test_sweep_on_the_simulated_rig_ranges_the_office() -> None:
    config = load_config(None, ["sweep.zones=6", "sweep.pan_start_deg=-90.0", "sweep.pan_step_deg=10.0"])
    report = run_configured_sweep(config)
    assert [r.index for r in report.results] == list(range(6))
    ok = [r for r in report.results if r.status == "ok"]
    assert len(ok) >= 5
    # The office's west wall is 1.3 m from the rig at pan -90°.
    assert abs(report.results[0].range_m - 1.30) < 0.03
    assert report.duration_s > 0 and report.limit_s > 0


def test_edge_sweep_writes_results_and_map(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "edge", "sweep", "--out", str(tmp_path), "--set", "sweep.zones=3"],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "sweep.json").read_text())
    assert len(doc["zones"]) == 3
    assert (tmp_path / "map.png").stat().st_size > 1000
