"""Simulated scenes: loading, validation, ray casting, movers, textures, floor plans."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.errors import SceneError
from edge.sim.raycast import convex_pieces, polygon_area, polygon_self_intersects
from edge.sim.scene import MOVER_KEY_BASE, Scene, available_scenes, load_scene, scene_dir

SHIPPED = ("office", "kitchen", "office-walker", "office-approach", "bench")


@pytest.fixture(scope="module")
def office() -> Scene:
    return load_scene("office")


@pytest.fixture(scope="module")
def kitchen() -> Scene:
    return load_scene("kitchen")


@pytest.fixture(scope="module")
def walker() -> Scene:
    return load_scene("office-walker")


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def cast_both_ways(geometry, origin, direction):
    """Cast one ray by the few-rays path and, repeated, by the many-rays path; both must agree."""
    few = geometry.cast(np.asarray(origin, float)[None, :], unit(direction)[None, :])
    bundle = np.repeat(unit(direction)[None, :], 300, axis=0)
    many = geometry.cast(np.asarray(origin, float), bundle)
    assert np.all(many.face == few.face[0])
    assert np.allclose(many.distance, few.distance[0], rtol=0, atol=1e-9)
    return few


# --- loading --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenes_load(name):
    scene = load_scene(name)
    assert scene.name == name
    assert name in available_scenes()
    geometry = scene.at(0.0)
    assert geometry.faces_count == len(geometry.faces) > 10
    keys = geometry.face_key(np.arange(geometry.faces_count))
    assert len(set(keys.tolist())) == geometry.faces_count  # keys are unique


def test_load_by_path_and_from_other_dirs(tmp_path):
    path = scene_dir() / "office.toml"
    assert load_scene(str(path)).name == "office"
    (tmp_path / "tiny.toml").write_text(MINIMAL)
    assert load_scene("tiny", [tmp_path]).name == "tiny"


def test_scene_dir_env_override(monkeypatch, tmp_path):
    monkeypatch.setenv("EDGE_SCENES", str(tmp_path))
    assert scene_dir() == tmp_path
    (tmp_path / "tiny.toml").write_text(MINIMAL)
    assert load_scene("tiny").name == "tiny"


def test_unknown_scene_lists_available():
    with pytest.raises(SceneError, match=r"unknown scene 'nowhere' \(available: .*office"):
        load_scene("nowhere")


def test_office_faces():
    office = load_scene("office")
    names = [f.name for f in office.at().faces]
    # The east wall with a doorway below the ceiling: two side parts and a lintel.
    assert sorted(n for n in names if n.startswith("wall 1")) == [
        "wall 1 lintel", "wall 1 part 0", "wall 1 part 1",
    ]
    assert sum(n.startswith("beyond") for n in names) == 6
    assert sum(n.startswith("desk") for n in names) == 5  # on the floor: no bottom face
    assert sum(n.startswith("whiteboard") for n in names) == 6  # hanging: with bottom face


def test_base_to_world(office, kitchen):
    pose = office.base_to_world()
    assert np.allclose(pose.t, office.device.position_m)
    assert np.allclose(pose.R, np.eye(3))
    # The kitchen's base is turned by 90°: base x is world y.
    assert np.allclose(kitchen.base_to_world().rotate([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0])


# --- casting: analytic cases ----------------------------------------------------------------------


def test_ray_straight_at_wall(office):
    g = office.at()
    origin = office.device.position_m  # (1.6, 1.3, 1.0)
    north = cast_both_ways(g, origin, [0, 1, 0])
    assert north.distance[0] == pytest.approx(3.0 - 1.3, abs=1e-12)
    assert g.faces[north.face[0]].name == "wall 2 part 0"
    assert np.allclose(north.normal[0], [0, -1, 0])
    assert np.allclose(north.point[0], [1.6, 3.0, 1.0])
    # Surface coordinates of a wall: metres from its start vertex (4, 3) westward, and height.
    assert np.allclose(north.surface_uv[0], [4.0 - 1.6, 1.0])
    south = cast_both_ways(g, origin, [0, -1, 0])
    assert south.distance[0] == pytest.approx(1.3, abs=1e-12)
    assert np.allclose(south.normal[0], [0, 1, 0])
    up = cast_both_ways(g, origin, [0, 0, 1])
    assert g.faces[up.face[0]].name == "ceiling"
    assert up.distance[0] == pytest.approx(1.5)


def test_ray_through_doorway_hits_beyond(office):
    g = office.at()
    origin = np.array(office.device.position_m)
    door_centre = np.array([4.0, 1.8 + 0.45, 1.0])
    hit = cast_both_ways(g, origin, door_centre - origin)
    assert g.faces[hit.face[0]].name.startswith("beyond")
    assert hit.distance[0] > 15.0
    albedo, _, _ = g.material(hit.face)
    assert np.allclose(albedo[0], office.materials["beyond"].albedo)


def test_ray_at_box_hits_it_before_the_wall(office):
    g = office.at()
    origin = np.array(office.device.position_m)
    cabinet = np.array([3.7, 0.32, 1.0])
    hit = cast_both_ways(g, origin, cabinet - origin)
    assert g.faces[hit.face[0]].name.startswith("filing-cabinet")
    # Its west face at x = 3.45.
    assert hit.point[0, 0] == pytest.approx(3.45)
    assert hit.distance[0] < np.linalg.norm(cabinet - origin)


def test_kitchen_floor_is_missing_in_the_cut_corner(kitchen):
    g = kitchen.at()
    down = [0.0, 0.0, -1.0]
    inside = cast_both_ways(g, [2.0, 3.7, 1.0], down)  # narrow part of the L, nothing in the way
    assert g.faces[inside.face[0]].name == "floor"
    assert inside.distance[0] == pytest.approx(1.0)
    cut = cast_both_ways(g, [4.0, 3.25, 1.0], down)  # the cut-out corner: outside the room
    assert g.faces[cut.face[0]].name == "beyond bottom"
    assert cut.distance[0] == pytest.approx(1.0 + kitchen.spec.beyond_m)


def test_max_distance(office):
    g = office.at()
    north_south = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    hits = g.cast(np.array(office.device.position_m), north_south, 1.5)
    assert hits.hit.tolist() == [False, True]
    assert hits.distance[0] == np.inf and hits.face[0] == -1
    assert np.isnan(hits.point[0]).all()
    assert g.face_key(hits.face)[0] == -1
    albedo, gloss, shininess = g.material(hits.face)
    assert not albedo[0].any() and gloss[0] == 0 and shininess[0] == 0


def test_normals_face_the_origin(office):
    rng = np.random.default_rng(1)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = office.at().cast(np.array(office.device.position_m), d)
    assert hits.hit.all()  # the shell closes the scene
    assert np.allclose(np.linalg.norm(hits.normal, axis=1), 1.0)
    assert np.all(np.einsum("ij,ij->i", hits.normal, d) < 0)


def test_shared_origin_and_general_paths_agree(kitchen):
    g = kitchen.at()
    rng = np.random.default_rng(2)
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.array(kitchen.device.position_m)
    fast = g.cast(o, d)
    general = g.cast(np.repeat(o[None, :], len(d), axis=0), d)
    assert np.allclose(fast.distance, general.distance, rtol=0, atol=1e-9)
    same = fast.face == general.face
    assert same.mean() > 0.999  # only rays along shared edges may pick either face
    assert np.allclose(fast.surface_uv[same], general.surface_uv[same])


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), spread=st.floats(0.05, 3.0))
def test_property_hits_lie_on_their_faces(office, seed, spread):
    """Random bundles of rays from the device (narrow or wide, like camera views)."""
    rng = np.random.default_rng(seed)
    centre = unit(rng.normal(size=3))
    d = centre + spread * rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.array(office.device.position_m)
    g = office.at()
    hits = g.cast(o, d)
    assert hits.hit.all()
    faces = g.faces
    normals = np.array([faces[f].normal for f in hits.face])
    origins = np.array([faces[f].origin for f in hits.face])
    assert np.allclose(np.einsum("ij,ij->i", hits.point - origins, normals), 0.0, atol=1e-9)
    lo = np.array([0.0, 0.0, 0.0]) - 1e-9
    hi = np.array([4.0, 3.0, 2.5]) + 1e-9
    in_room = np.all((hits.point >= lo) & (hits.point <= hi), axis=1)
    on_shell = np.array([faces[f].name.startswith("beyond") for f in hits.face])
    assert np.all(in_room | on_shell)
    assert np.all(hits.distance[on_shell] > office.spec.beyond_m)
    # A ray reaches the shell only through the doorway (east wall x = 4, y 1.8..2.7, z < 2):
    # no cracks between faces.
    out = d[on_shell]
    with np.errstate(divide="ignore", invalid="ignore"):
        exits = np.where(out > 0, (hi - o) / out, np.where(out < 0, (lo - o) / out, np.inf))
    exit_point = o + out * exits.min(axis=1)[:, None]
    assert np.allclose(exit_point[:, 0], 4.0, atol=1e-6)
    assert np.all((exit_point[:, 1] >= 1.8 - 1e-6) & (exit_point[:, 1] <= 2.7 + 1e-6))
    assert np.all(exit_point[:, 2] <= 2.0 + 1e-6)
    # Casting again from just in front of a hit, towards it, finds the same face (or, on an edge
    # shared by two faces, the same point).
    pick = rng.choice(len(d), 8, replace=False)
    again = g.cast(hits.point[pick] - 1e-3 * d[pick], d[pick])
    assert np.allclose(again.distance, 1e-3, atol=1e-9)
    same = again.face == hits.face[pick]
    assert np.all(same | np.all(np.isclose(again.point, hits.point[pick], atol=1e-6), axis=1))


# --- movers ---------------------------------------------------------------------------------------


def test_mover_position_along_path(walker):
    mover = walker.movers[0]
    assert mover.name == "walker"
    assert mover.pose_at(41.9) is None  # before start
    static = load_scene("office").at().faces_count
    assert walker.at(41.9).faces_count == walker.at().faces_count == static
    pose = mover.pose_at(42.75)  # 0.6 m along the first segment, heading west
    assert np.allclose(pose.t, [3.8, 2.25, 0.0])
    assert np.allclose(pose.rotate([1.0, 0.0, 0.0]), [-1.0, 0.0, 0.0])
    # On the second segment, from (3.2, 2.25) towards (2.3, 2.0).
    first = 1.2
    second = math.hypot(0.9, 0.25)
    pose = mover.pose_at(42.0 + (first + second / 2) / 0.8)
    assert np.allclose(pose.t[:2], [2.75, 2.125])
    # Then it stands 15 s at (2.3, 2.0), facing the way it came.
    arrive = 42.0 + (first + second) / 0.8
    for t in (arrive + 0.01, arrive + 6.0, arrive + 14.99):
        assert np.allclose(mover.pose_at(t).t[:2], [2.3, 2.0])
    assert not np.allclose(mover.pose_at(arrive + 15.5).t[:2], [2.3, 2.0])
    assert mover.pose_at(mover.end_s - 1e-6) is not None
    assert mover.pose_at(mover.end_s + 0.01) is None  # after the end: gone
    assert walker.at(mover.end_s + 0.01).faces_count == walker.at().faces_count
    present = walker.at(44.0)
    assert present.faces_count == walker.at().faces_count + 5
    assert sorted(present.face_key(np.arange(present.faces_count))[-5:].tolist()) == list(
        range(MOVER_KEY_BASE, MOVER_KEY_BASE + 5)
    )


def test_mover_loop(tmp_path):
    path = write(tmp_path, MINIMAL + MOVER.replace("loop = false", "loop = true"))
    mover = load_scene(str(path)).movers[0]
    # A 1 m × 1 m square at 1 m/s, closed back to its start: 4 s per round.
    assert np.allclose(mover.pose_at(10.5).t[:2], mover.pose_at(14.5).t[:2])
    assert np.allclose(mover.pose_at(13.5).t[:2], [0.5, 1.0])  # on the closing leg
    assert mover.pose_at(1000.0) is not None
    assert mover.pose_at(9.0) is None


def test_surface_uv_is_stable_on_a_moving_face(walker):
    origin = np.array(walker.device.position_m)
    seen = []
    for t in (43.0, 43.8, 44.4):  # three positions on two segments: translated and turned
        g = walker.at(t)
        movers = [f for f in g.faces if f.key >= MOVER_KEY_BASE]
        centre = np.mean([f.vertices.mean(axis=0) for f in movers], axis=0)
        # The mover's side that faces the device.
        face = max(movers, key=lambda f: float(f.normal @ unit(origin - centre)))
        local = np.array([0.1, 1.2])
        target = face.origin + local[0] * face.u_axis + local[1] * face.v_axis
        hit = g.cast(origin[None, :], unit(target - origin)[None, :])
        assert g.face_key(hit.face)[0] == face.key
        assert np.allclose(hit.surface_uv[0], local, atol=1e-9)
        seen.append((face.key, float(g.texture(hit.face, hit.surface_uv)[0])))
    for key, tex in seen:
        same = [t for k, t in seen if k == key]
        assert np.allclose(same, tex)  # the same spot of the same face looks the same


def _rectangles_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex quadrilaterals (4, 2)."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return False
    return True


def test_walker_path_avoids_boxes_and_device(walker):
    from edge.sim.raycast import footprint as _footprint

    mover = walker.movers[0]
    device = np.array(walker.device.position_m[:2])
    width, depth, _ = mover.size_m
    for t in np.arange(mover.start_s, mover.end_s, 0.05):
        pose = mover.pose_at(t)
        outline = _footprint(pose, depth, width)
        for box in walker.spec.boxes:
            if box.base_m < mover.size_m[2]:
                assert not _rectangles_overlap(outline, box.footprint()), (t, box.name)
        assert np.linalg.norm(pose.t[:2] - device) - math.hypot(width, depth) / 2 >= 0.5
    # It enters and leaves through the doorway (east wall x = 4, y 1.8..2.7).
    for t in (mover.start_s, mover.end_s):
        x, y = mover.pose_at(t).t[:2]
        assert x > 4.0 and 1.8 + width / 2 < y < 2.7 - width / 2


# --- floor plan -----------------------------------------------------------------------------------


def _covers(segments, point, tol=1e-9) -> bool:
    p = np.asarray(point, float)
    for a, b in segments:
        a, b = np.asarray(a), np.asarray(b)
        ab = b - a
        s = np.clip((p - a) @ ab / (ab @ ab), 0, 1)
        if np.linalg.norm(a + s * ab - p) <= tol:
            return True
    return False


def test_floor_plan_has_doorway_gap_and_obstacles(walker):
    plan = walker.floor_plan(0.0)
    assert _covers(plan, (4.0, 1.0)) and _covers(plan, (4.0, 2.9))  # east wall either side
    assert not _covers(plan, (4.0, 2.25))  # the doorway
    assert _covers(plan, (3.45, 0.3))  # filing cabinet (1.3 m) reaches the scan height
    assert not _covers(plan, (1.0, 2.25))  # the desk (0.75 m) does not
    assert len(walker.floor_plan(44.0)) == len(plan) + 4  # the walker while present
    assert len(walker.floor_plan(85.0)) == len(plan)


# --- extends --------------------------------------------------------------------------------------


def test_extends_appends_lists_and_merges_tables(tmp_path):
    base = write(tmp_path, MINIMAL + BOX, "base.toml")
    text = f'name = "child"\nextends = "{base.stem}"\n[device]\nyaw_deg = 45.0\n'
    child = write(tmp_path, text + BOX.replace("0.5, 0.5", "1.5, 0.5"), "child.toml")
    scene = load_scene(str(child))
    assert scene.name == "child"
    assert scene.device.yaw_deg == 45.0
    assert scene.device.position_m == (1.0, 1.5, 1.0)  # kept from the base
    assert [b.center_m for b in scene.spec.boxes] == [(0.5, 0.5), (1.5, 0.5)]


def test_office_walker_extends_office(office, walker):
    assert walker.spec.boxes == office.spec.boxes
    assert walker.spec.outline_m == office.spec.outline_m
    assert len(walker.movers) == 1 and not office.movers


# --- textures and materials -----------------------------------------------------------------------


def test_texture(office):
    g = office.at()
    wall = next(i for i, f in enumerate(g.faces) if f.name == "wall 0 part 0")
    rng = np.random.default_rng(3)
    uv = rng.uniform([0, 0], [4, 2.5], size=(20000, 2))
    face = np.full(len(uv), wall)
    tex = g.texture(face, uv)
    assert np.array_equal(tex, office.at().texture(face, uv))  # deterministic
    assert tex.mean() == pytest.approx(1.0, abs=0.03)
    assert tex.std() == pytest.approx(office.materials["cardboard"].texture, rel=0.3)
    assert tex.min() >= 0.05
    assert np.all(g.texture(np.full(5, -1), uv[:5]) == 1.0)
    beyond = next(i for i, f in enumerate(g.faces) if f.name.startswith("beyond"))
    assert np.all(g.texture(np.full(5, beyond), uv[:5]) == 1.0)  # texture 0: flat
    other = next(i for i, f in enumerate(g.faces) if f.name == "wall 2 part 0")
    assert not np.allclose(g.texture(np.full(len(uv), other), uv), tex)  # keyed per face


def test_scene_local_material(tmp_path):
    text = MINIMAL.replace('wall_material = "paint-white"', 'wall_material = "mine"')
    text += '[materials.mine]\nalbedo = [0.5, 0.4, 0.3]\ngloss = 0.1\n'
    scene = load_scene(str(write(tmp_path, text)))
    assert scene.materials["mine"].albedo == (0.5, 0.4, 0.3)
    albedo, gloss, _ = scene.at().material(np.array([0]))
    assert np.allclose(albedo[0], [0.5, 0.4, 0.3]) and gloss[0] == 0.1


# --- polygons -------------------------------------------------------------------------------------


def test_polygon_helpers():
    ell = np.array([[0, 0], [5, 0], [5, 2.5], [3, 2.5], [3, 4], [0, 4]], float)
    pieces = convex_pieces(ell)
    assert len(pieces) > 1
    assert sum(polygon_area(ell[p]) for p in pieces) == pytest.approx(polygon_area(ell))
    assert all(polygon_area(ell[p]) > 0 for p in pieces)
    assert not polygon_self_intersects(ell)
    assert polygon_self_intersects(np.array([[0, 0], [1, 1], [1, 0], [0, 1]], float))
    assert polygon_self_intersects(np.array([[0, 0], [2, 0], [1, 0], [1, 1]], float))


# --- validation -----------------------------------------------------------------------------------

MINIMAL = textwrap.dedent(
    """\
    name = "tiny"
    height_m = 2.5
    outline_m = [[0, 0], [2, 0], [2, 3], [0, 3]]
    wall_material = "paint-white"
    [device]
    position_m = [1.0, 1.5, 1.0]
    [[doorways]]
    wall = 0
    offset_m = 0.5
    width_m = 0.9
    height_m = 2.0
    """
)
BOX = textwrap.dedent(
    """\
    [[boxes]]
    center_m = [0.5, 0.5]
    size_m = [0.4, 0.4, 0.5]
    material = "cardboard"
    """
)
MOVER = textwrap.dedent(
    """\
    [[movers]]
    name = "m"
    speed_mps = 1.0
    start_s = 10.0
    path_m = [[0.5, 0.5], [1.5, 0.5], [1.5, 1.5], [0.5, 1.5]]
    loop = false
    """
)


def write(tmp_path: Path, text: str, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _swap(old: str, new: str):
    def edit(text: str) -> str:
        assert old in text
        return text.replace(old, new)

    return edit


def _add(extra: str):
    return lambda text: text + extra


SQUARE = "[[0, 0], [2, 0], [2, 3], [0, 3]]"
PATH = "[[0.5, 0.5], [1.5, 0.5], [1.5, 1.5], [0.5, 1.5]]"
BAD = [
    ("outline-too-short", _swap(SQUARE, "[[0, 0], [2, 0]]"), "outline_m"),
    ("outline-bow-tie", _swap(SQUARE, "[[0, 0], [2, 3], [2, 0], [0, 3]]"), "outline_m"),
    ("door-wall-index", _swap("wall = 0", "wall = 4"), "doorways[0].wall"),
    ("door-past-edge", _swap("offset_m = 0.5", "offset_m = 1.5"), "doorways[0].offset_m"),
    ("door-too-high", _swap("height_m = 2.0", "height_m = 2.6"), "doorways[0].height_m"),
    ("door-negative-width", _swap("width_m = 0.9", "width_m = -0.9"), "doorways[0].width_m"),
    ("box-size", _add(BOX.replace("0.4, 0.4, 0.5", "0.4, 0.0, 0.5")), "boxes[0].size_m[1]"),
    ("box-size-count", _add(BOX.replace("0.4, 0.4, 0.5", "0.4, 0.4")), "boxes[0].size_m"),
    ("box-material", _add(BOX.replace('"cardboard"', '"unobtainium"')), "boxes[0].material"),
    ("wall-material", _swap('"paint-white"', '"plaid"'), "wall_material"),
    ("device-outside", _swap("[1.0, 1.5, 1.0]", "[3.0, 1.5, 1.0]"), "device.position_m"),
    ("device-below-floor", _swap("[1.0, 1.5, 1.0]", "[1.0, 1.5, -0.1]"), "device.position_m"),
    ("device-above-ceiling", _swap("[1.0, 1.5, 1.0]", "[1.0, 1.5, 2.6]"), "device.position_m"),
    ("device-in-box", _add(BOX.replace("[0.5, 0.5]", "[1.0, 1.5]").replace("0.5]", "1.2]")),
     "device.position_m"),
    ("mover-path", _add(MOVER.replace(PATH, "[[0.5, 0.5]]")), "movers[0].path_m"),
    ("mover-speed", _add(MOVER.replace("speed_mps = 1.0", "speed_mps = 0.0")),
     "movers[0].speed_mps"),
    ("mover-material", _add(MOVER + 'material = "ghost"\n'), "movers[0].material"),
    ("unknown-key", _swap('name = "tiny"', 'name = "tiny"\ncolour = "red"'), "colour"),
    ("unknown-box-key", _add(BOX + "colour = 1\n"), "boxes[0].colour"),
    ("wrong-type", _swap("height_m = 2.5", 'height_m = "tall"'), "height_m"),
    ("missing-key", _swap("height_m = 2.5\n", ""), "height_m"),
    ("material-value", _add("[materials.mine]\nalbedo = [1.5, 0.4, 0.3]\n"),
     "materials.mine.albedo[0]"),
    ("material-key", _add("[materials.mine]\nalbedo = [0.5, 0.4, 0.3]\nshine = 3\n"),
     "materials.mine.shine"),
    ("extends-missing", _swap('name = "tiny"', 'name = "tiny"\nextends = "nowhere"'), "extends"),
    ("extends-self", _swap('name = "tiny"', 'name = "tiny"\nextends = "scene"'), "extends"),
    ("bad-toml", _add("[device\n"), "invalid TOML"),
]


@pytest.mark.parametrize("edit, key", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_validation_errors_are_one_line_with_file_and_key(tmp_path, edit, key):
    path = write(tmp_path, edit(MINIMAL))
    with pytest.raises(SceneError) as info:
        load_scene(str(path))
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path) + ": ")
    assert key in message


def test_unknown_material_message_lists_known(tmp_path):
    path = write(tmp_path, MINIMAL.replace('"paint-white"', '"plaid"'))
    known = r"wall_material: unknown material 'plaid' \(known: .*cardboard.*paint-white"
    with pytest.raises(SceneError, match=known):
        load_scene(str(path))


def test_error_in_base_names_the_base_file(tmp_path):
    write(tmp_path, MINIMAL.replace("offset_m = 0.5", "offset_m = 1.5"), "base.toml")
    child = write(tmp_path, 'name = "child"\nextends = "base"\n', "child.toml")
    with pytest.raises(SceneError, match=r"base\.toml: doorways\[0\]\.offset_m"):
        load_scene(str(child))
