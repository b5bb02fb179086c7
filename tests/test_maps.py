"""`edge map` and the map files of sweeps: sources read (recordings, edge sweep's results), the
files written and read back by tools nobody here wrote, the device's grid kept across restarts, and
a small map scored against the simulator's truth (tools/map_targets.py measures the full one)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData
from test_cloud import scan
from test_grid import hit_zone, read_map_server

from edge.cli import main
from edge.cloud import scan_cloud
from edge.config import load_config
from edge.grid import GridConfig
from edge.mapping import results_document
from edge.maps import GridKeeper, Scan, build_map, read_scan
from edge.recording import read_recording, rig_to_json
from edge.replay import Replayer
from edge.rig import default_rig
from edge.sim.map_truth import score_grid
from edge.sim.record import record_sweep
from edge.sim.scene import load_scene, scene_dir

RIG = default_rig()


@pytest.fixture(scope="module")
def office(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """8 zones of the office, 45° apart, one frame pair each."""
    out = tmp_path_factory.mktemp("maps") / "office"
    config = load_config(None, ["sweep.pan_step_deg=45.0"])
    return record_sweep(config, out, zones=8, pairs=1)


def ranges_file(path: Path, with_rig: bool = True) -> Path:
    results = [hit_zone(pan, 2.0, index=i) for i, pan in enumerate(range(-60, 61, 10))]
    extra = {"rig": rig_to_json(RIG)} if with_rig else {}
    path.write_text(json.dumps(results_document(results, **extra)))
    return path


def test_edge_map_of_sweep_results_writes_files_tools_read(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    source = ranges_file(tmp_path / "sweep.json")
    assert main(["map", str(source), "--out", str(tmp_path / "map"), "--resolution", "0.1"]) == 0
    meta, cls = read_map_server(tmp_path / "map")
    assert meta["resolution"] == 0.1 and (cls == 1).sum() >= 13 and (cls == 0).any()
    ply = PlyData.read(str(tmp_path / "map" / "cloud.ply"))
    assert len(ply["vertex"].data) == 13
    assert (tmp_path / "map" / "map.png").read_bytes()[:4] == b"\x89PNG"
    assert "13 points" in capsys.readouterr().out


def test_sweep_results_read_back_give_the_same_cloud_normals_and_all(tmp_path: Path) -> None:
    """The other lasers' spots of edge sweep's results keep their σ through the file: the normals
    estimated from them are those of the results themselves (with every spot at σ 0 they were
    refused nearly everywhere)."""
    results, _ = scan(range(-30, 31, 6), [-40, -20, 0, 15, 30], noise=0.003, seed=1, lasers=True, wall_x=1.0)
    path = tmp_path / "sweep.json"
    path.write_text(json.dumps(results_document(results, rig=rig_to_json(RIG))))
    read = read_scan(path, RIG).results
    assert [{n: m.sigma_m for n, m in r.lasers.items()} for r in read] == [
        {n: pytest.approx(m.sigma_m, abs=1e-5) for n, m in r.lasers.items()} for r in results]
    direct, back = scan_cloud(RIG, results), scan_cloud(RIG, read)
    given = np.linalg.norm(direct.normals, axis=1) > 0.5
    assert given.sum() >= 20 and np.allclose(back.normals, direct.normals, atol=1e-4)
    # A file that gives no σ for them: each is taken as uncertain as its zone's range.
    bare = [replace(r, lasers={n: replace(m, sigma_m=0.0) for n, m in r.lasers.items()}) for r in results]
    assert (np.linalg.norm(scan_cloud(RIG, bare).normals, axis=1) > 0.5).sum() >= 0.5 * given.sum()


def test_edge_map_fuses_recordings_and_results(office: Path, tmp_path: Path) -> None:
    source = ranges_file(tmp_path / "sweep.json", with_rig=False)  # the configured rig then
    assert main(["map", str(office), str(source), "--out", str(tmp_path / "map")]) == 0
    _, cls = read_map_server(tmp_path / "map")
    assert (cls == 1).sum() >= 13 + 6


@pytest.mark.parametrize("doc, message", [
    ({"format": "edge-ranges/2", "zones": []}, "format: expected 'edge-sweep/1' (a recording) or 'edge-ranges/1'"),
    ({"format": "edge-ranges/1", "zones": [{"index": 3, "pan_deg": 0, "tilt_deg": 0, "status": "ok"}]},
     "zone 3: point_base_m: an ok zone needs its point"),
    ({"format": "edge-ranges/1", "zones": [{"index": 1, "pan_deg": 0, "tilt_deg": 0, "status": "fine"}]},
     "zone 1: status:"),
])
def test_bad_sources_are_one_line_naming_the_file(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                  doc: dict, message: str) -> None:
    source = tmp_path / "bad.json"
    source.write_text(json.dumps(doc))
    assert main(["map", str(source), "--out", str(tmp_path / "map")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"edge: {source}") and message in err and err.count("\n") == 1


def test_the_device_keeps_its_grid_across_restarts(tmp_path: Path) -> None:
    keeper = GridKeeper(GridConfig(), RIG, tmp_path)
    keeper.add_sweep(RIG, [hit_zone(0.0, 2.0)])
    again = GridKeeper(GridConfig(), RIG, tmp_path)  # a restart
    assert np.array_equal(again.grid.log_odds, keeper.grid.log_odds) and again.grid.occupied().any()
    assert again.png()[:4] == b"\x89PNG"
    # Another resolution cannot reuse the cells: a new grid, said in the log, not a failure.
    coarse = GridKeeper(GridConfig(resolution_m=0.1), RIG, tmp_path)
    assert not coarse.grid.occupied().any()
    (tmp_path / "grid.npz").write_bytes(b"torn")
    assert not GridKeeper(GridConfig(), RIG, tmp_path).grid.occupied().any()


def test_a_small_map_of_the_office_against_the_truth(office: Path) -> None:
    recording = read_recording(office)
    results = list(Replayer(recording.rig).zones(recording))
    grid, cloud = build_map(GridConfig(), [Scan(str(office), recording.rig, results)])
    scene = load_scene("office", [scene_dir()])
    score = score_grid(grid, scene, recording.rig, [(results, [z.truth for z in recording.zones])])
    assert score.occupied_near_surface >= 0.95
    assert score.surface_cells_ok_occupied >= 0.95
    assert score.ray_cells_free >= 0.98
    assert len(cloud) == sum(r.status == "ok" for r in results) >= 6
    assert read_scan(office, RIG).results[0].status == results[0].status


def test_the_service_fuses_its_sweeps_into_the_kept_map(tmp_path: Path) -> None:
    from edge.service import Service

    sets = ["mqtt.enabled=false", 'mode="guard"', "sweep.zones=3", "sweep.pan_start_deg=-90.0",
            "sweep.pan_step_deg=10.0", f"service.state_dir={json.dumps(str(tmp_path))}", "service.watchdog=false"]
    service = Service(load_config(None, sets), run_for_s=2.0)
    assert service.run() == 0
    assert service.sweeps >= 1 and service.map.sweeps == service.sweeps
    assert (tmp_path / "grid.npz").is_file() and service.map.png()[:4] == b"\x89PNG"
    kept = service.map.grid.log_odds
    assert service.map.grid.occupied().sum() >= 3
    restarted = Service(load_config(None, sets), run_for_s=0.0)
    assert np.array_equal(restarted.map.grid.log_odds, kept)
