"""The `bench` scene: a calibration board carried squarely in front of the device, standing at
2.0, 1.3, 0.8 and 0.5 m, for the interactive flat-target calibration on the simulator. Checked with
the renderer's truth at pan 0, tilt 0, as `edge.parts.Parts.truth` asks for it."""

from __future__ import annotations

import numpy as np
import pytest

from edge.config import load_config
from edge.sim.record import scene_for, true_rig, zone_truth
from edge.sim.render import Renderer
from edge.sim.scene import MOVER_KEY_BASE, available_scenes, load_scene

DISTANCES_M = (2.0, 1.3, 0.8, 0.5)  # in the order the board stands at them
STAND_S = 6.0
BACK_WALL_M = 3.7  # east wall at x = 4.5, optical centre at x = 0.8
# The stand windows as documented in the scene file's header.
WINDOWS_S = {2.0: (5.5, 11.5), 1.3: (12.5, 18.5), 0.8: (19.2143, 25.2143), 0.5: (25.6429, 31.6429)}
TOL_M = 1e-3


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    config = load_config(None, ["sim.scene=bench"])
    return Renderer(scene_for(config), true_rig(config), config.sim, config.camera)


def truth(renderer: Renderer, t_s: float) -> dict:
    spots = renderer.spots(0.0, 0.0, t_s)
    out = zone_truth(renderer.rig, spots, renderer.rig.camera_to_base(0.0, 0.0))
    for name, spot in spots.items():
        out["lasers"][name]["on_board"] = spot.face_key >= MOVER_KEY_BASE
        out["lasers"][name]["normal_world"] = spot.normal_world
    return out


def stand_windows(renderer: Renderer) -> list[tuple[float, float]]:
    """[start, end] of each stand, from the mover's own timeline: pauses at points 1..4."""
    mover = renderer.scene.movers[0]
    pts = np.array(mover.path_m)
    t, out = mover.start_s, []
    for i in range(1, 5):
        t += float(np.linalg.norm(pts[i] - pts[i - 1])) / mover.speed_mps
        out.append((t, t + mover.pause_s[i]))
        t += mover.pause_s[i]
    return out


def board_in_picture(renderer: Renderer, t_s: float) -> bool:
    to_camera = renderer.camera_to_world(0.0, 0.0).inverse()
    cam = renderer.rig.camera
    for corners in renderer.scene.mover_corners(t_s):
        p = to_camera.apply(corners)
        if (p[:, 2] <= 1e-3).all():
            continue
        assert (p[:, 2] > 1e-3).all()
        uv = cam.project(p)
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        if hi[0] >= 0 and lo[0] <= cam.width and hi[1] >= 0 and lo[1] <= cam.height:
            return True
    return False


def test_bench_loads_by_name_and_is_shipped(renderer: Renderer) -> None:
    assert "bench" in available_scenes()
    assert load_scene("bench").name == "bench"
    scene = renderer.scene
    assert scene.name == "bench"
    (board,) = scene.movers
    assert board.material == "paint-white"
    width, depth, height = board.size_m
    assert 1.0 <= width <= 1.2 and depth == pytest.approx(0.03) and height >= 1.5
    assert board.speed_mps == pytest.approx(0.7) and board.start_s == pytest.approx(3.0)
    # The optical centre is where the distances are measured from: at the device's position.
    assert np.allclose(renderer.camera_to_world(0.0, 0.0).t, scene.device.position_m)


def test_timeline_is_as_documented(renderer: Renderer) -> None:
    windows = stand_windows(renderer)
    for d, (start, end) in zip(DISTANCES_M, windows):
        assert end - start == pytest.approx(STAND_S)
        assert (start, end) == pytest.approx(WINDOWS_S[d], abs=1e-4)


@pytest.mark.parametrize("index", range(len(DISTANCES_M)))
def test_board_stands_squarely_at_each_distance(renderer: Renderer, index: int) -> None:
    d = DISTANCES_M[index]
    start, end = stand_windows(renderer)[index]
    axis = renderer.camera_to_world(0.0, 0.0).rotate(np.array([0.0, 0.0, 1.0]))
    for t in (start + 0.05, (start + end) / 2, end - 0.05):
        tr = truth(renderer, t)
        assert tr["range_m"] == pytest.approx(d, abs=TOL_M), t
        depths = []
        for name, laser in tr["lasers"].items():
            assert laser["on_board"], (t, name)
            assert laser["visible"], (t, name, laser["why"])
            # A plane z = d in the camera frame: every laser's depth is d, tilted or not.
            assert laser["range_m"] == pytest.approx(d, abs=TOL_M), (t, name)
            # The face the spot is on looks straight back along the axis.
            assert float(laser["normal_world"] @ axis) == pytest.approx(-1.0, abs=1e-9)
            depths.append(laser["range_m"])
        assert max(depths) - min(depths) < TOL_M


@pytest.mark.parametrize("t_s", [0.0, 2.9, 3.1, 5.0, 5.4])
def test_back_wall_before_the_board_arrives(renderer: Renderer, t_s: float) -> None:
    tr = truth(renderer, t_s)
    assert tr["range_m"] == pytest.approx(BACK_WALL_M, abs=TOL_M)
    for name, laser in tr["lasers"].items():
        assert laser["visible"] and not laser["on_board"], name
        assert laser["range_m"] == pytest.approx(BACK_WALL_M, abs=TOL_M), name


@pytest.mark.parametrize("t_s", [32.2, 33.0, 34.0, 40.0, 1000.0, 100_000.0])
def test_back_wall_after_the_board_has_left(renderer: Renderer, t_s: float) -> None:
    tr = truth(renderer, t_s)
    assert tr["range_m"] == pytest.approx(BACK_WALL_M, abs=TOL_M)
    for name, laser in tr["lasers"].items():
        assert laser["visible"] and not laser["on_board"], name
        assert laser["range_m"] == pytest.approx(BACK_WALL_M, abs=TOL_M), name


def test_board_comes_and_goes_out_of_the_picture(renderer: Renderer) -> None:
    assert not board_in_picture(renderer, 3.0)  # appears beside the view
    assert board_in_picture(renderer, 4.0)
    assert board_in_picture(renderer, 33.3)
    for t in (33.5, 34.7, 40.0, 1000.0):
        assert not board_in_picture(renderer, t), t
    assert renderer.scene.movers_at(1000.0) is not None  # still there, standing aside
