"""The occupancy grid: what each kind of ray marks, the map_server files read back by a plain
reader of that format, and the state kept across restarts."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from edge.grid import (
    GridConfig,
    OccupancyGrid,
    grid_from_state,
    map_image,
    pgm_bytes,
    state_bytes,
    yaml_text,
    zone_ray,
)
from edge.ranging import AMBIGUOUS, FAULT, NO_SPOT, OK, OUT_OF_RANGE, ZoneResult
from edge.rig import default_rig
from edge.triangulation import LaserMeasurement

RIG = default_rig()


def beam(pan: float, tilt: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    pose = RIG.camera_to_base(pan, tilt)
    return pose.apply(RIG.reference.o), pose.rotate(RIG.reference.d)


def hit_zone(pan: float, t: float, tilt: float = 0.0, sigma: float = 0.005, index: int = 0) -> ZoneResult:
    """An ok zone whose reference beam met a surface `t` metres along it."""
    o, d = beam(pan, tilt)
    p = o + t * d
    cam = RIG.camera_to_base(pan, tilt).inverse().apply(p)
    return ZoneResult(index, pan, tilt, OK, float(cam[2]), sigma, cam, p)


def at(grid: OccupancyGrid, x: float, y: float) -> str:
    ix, iy = grid.cell_of(np.array([x, y]))
    if grid.occupied()[iy, ix]:
        return "occupied"
    return "free" if grid.free()[iy, ix] else "unknown"


def fresh() -> OccupancyGrid:
    return OccupancyGrid.for_rig(GridConfig(), RIG)


def test_a_hit_frees_the_cells_before_it_marks_its_own_and_nothing_beyond() -> None:
    grid = fresh()
    grid.add_results(RIG, [hit_zone(0.0, 2.0)])
    y = -0.035  # the reference laser is 3.5 cm right of the pan axis
    assert [at(grid, x, y) for x in (0.1, 1.0, 1.9)] == ["free"] * 3
    assert at(grid, 2.01, y) == "occupied"
    assert [at(grid, x, y) for x in (2.2, 3.0, 4.5)] == ["unknown"] * 3
    assert at(grid, 1.0, 0.5) == "unknown"  # off the beam


def test_the_hit_is_spread_along_the_beam_by_its_sigma() -> None:
    sharp, blurred = fresh(), fresh()
    sharp.add_results(RIG, [hit_zone(0.0, 3.0, sigma=0.002)])
    blurred.add_results(RIG, [hit_zone(0.0, 3.0, sigma=0.08)])
    assert sharp.occupied().sum() <= 2
    assert blurred.occupied().sum() >= 3
    # Far from a vague hit, the cells before it are still free; none near it is.
    assert at(blurred, 2.5, -0.035) == "free" and at(blurred, 2.95, -0.035) != "free"


def test_no_spot_frees_up_to_the_far_limit_and_no_further() -> None:
    grid = fresh()
    grid.add_results(RIG, [ZoneResult(0, 90.0, 0.0, NO_SPOT)])
    x = 0.035  # at pan 90° the beam runs along +y, 3.5 cm ahead of the axis
    assert at(grid, x, 4.9) == "free"
    assert at(grid, x, 5.1) == "unknown"


def test_no_spot_with_another_lasers_spot_frees_only_well_short_of_it() -> None:
    other = LaserMeasurement("parallel", np.zeros(2), 0.1, np.zeros(3), 2.0, 0.01, 30.0, 1)
    grid = fresh()
    grid.add_results(RIG, [ZoneResult(0, 90.0, 0.0, NO_SPOT, lasers={"parallel": other})])
    assert at(grid, 0.035, 1.5) == "free"
    assert at(grid, 0.035, 1.7) == "unknown"


def test_rays_that_say_nothing_mark_nothing() -> None:
    near = LaserMeasurement("center", np.zeros(2), 0.1, np.zeros(3), 0.1, 0.01, 30.0, 1)
    far = LaserMeasurement("center", np.zeros(2), 0.1, np.zeros(3), 7.0, 0.01, 30.0, 1)
    assert zone_ray(RIG, ZoneResult(0, 0.0, 0.0, AMBIGUOUS)) is None
    assert zone_ray(RIG, ZoneResult(0, 0.0, 0.0, FAULT)) is None
    # Out of range nearer than the near limit: something is right in front; no claim of free.
    assert zone_ray(RIG, ZoneResult(0, 0.0, 0.0, OUT_OF_RANGE, lasers={"center": near})) is None
    ray = zone_ray(RIG, ZoneResult(0, 0.0, 0.0, OUT_OF_RANGE, lasers={"center": far}))
    assert ray is not None and ray.hit_m is None and math.isclose(ray.free_m, 5.0)


def test_a_tilted_ray_counts_only_inside_the_band() -> None:
    # Down 30° from 1 m above the floor: the floor is 2 m away along the beam, at z = -1.
    grid = fresh()
    grid.add_results(RIG, [hit_zone(0.0, 2.0, tilt=-30.0)])
    assert not grid.occupied().any()  # the floor is no obstacle of the slice
    assert at(grid, 0.5, -0.035) == "free"  # z = -0.29: inside the band (±0.5 m)
    assert at(grid, 1.2, -0.035) == "unknown"  # z = -0.69: below it
    # A hit inside the band, tilted: marked.
    grid.add_results(RIG, [hit_zone(0.0, 0.8, tilt=-30.0)])
    assert at(grid, 0.8 * math.cos(math.radians(30)) + 0.005, -0.035) == "occupied"


def test_evidence_accumulates_and_a_moved_obstacle_is_unlearnt() -> None:
    grid = fresh()
    for _ in range(10):
        grid.add_results(RIG, [hit_zone(0.0, 2.0)])
    assert at(grid, 2.01, -0.035) == "occupied"
    for _ in range(6):  # it went: the beam now reaches a wall behind it
        grid.add_results(RIG, [hit_zone(0.0, 3.0)])
    assert at(grid, 2.01, -0.035) == "free"


def read_map_server(folder: Path) -> tuple[dict, np.ndarray]:
    """A plain reader of map_server's map.yaml + PGM: the metadata, and each pixel's class
    (+1 occupied, 0 free, -1 unknown) as map_server decides it."""
    meta: dict = {}
    for line in (folder / "map.yaml").read_text().splitlines():
        key, _, value = line.partition(":")
        value = value.strip()
        if value.startswith("["):
            meta[key.strip()] = [float(v) for v in value.strip("[]").split(",")]
        else:
            try:
                meta[key.strip()] = float(value)
            except ValueError:
                meta[key.strip()] = value
    raw = (folder / meta["image"]).read_bytes()
    fields: list[bytes] = []
    pos = 0
    while len(fields) < 4:  # magic, width, height, maxval; comments from # to the end of a line
        while raw[pos:pos + 1].isspace():
            pos += 1
        if raw[pos:pos + 1] == b"#":
            pos = raw.index(b"\n", pos) + 1
            continue
        end = pos
        while not raw[end:end + 1].isspace():
            end += 1
        fields.append(raw[pos:end])
        pos = end
    assert fields[0] == b"P5"
    width, height, maxval = (int(f) for f in fields[1:])
    pixels = np.frombuffer(raw[pos + 1:], np.uint8).reshape(height, width).astype(float)
    p = (maxval - pixels) / maxval if not meta["negate"] else pixels / maxval
    cls = np.full(pixels.shape, -1)
    cls[p > meta["occupied_thresh"]] = 1
    cls[p < meta["free_thresh"]] = 0
    return meta, cls


def test_map_server_reads_the_grid_as_we_class_it(tmp_path: Path) -> None:
    grid = fresh()
    grid.add_results(RIG, [hit_zone(0.0, 2.0), hit_zone(90.0, 1.5)])
    (tmp_path / "map.pgm").write_bytes(pgm_bytes(grid))
    (tmp_path / "map.yaml").write_text(yaml_text(grid))
    meta, cls = read_map_server(tmp_path)
    assert meta["mode"] == "trinary" and meta["resolution"] == 0.05
    ox, oy, _ = meta["origin"]
    height = cls.shape[0]

    def cell(x: float, y: float) -> int:  # map_server: origin is the lower-left pixel, row 0 on top
        col = int((x - ox) / meta["resolution"])
        row = height - 1 - int((y - oy) / meta["resolution"])
        return int(cls[row, col])

    assert cell(2.01, -0.035) == 1 and cell(1.0, -0.035) == 0 and cell(3.0, -0.035) == -1
    assert cell(0.035, 1.51) == 1 and cell(0.035, 0.7) == 0  # y up: the left of the unit is up
    ours = map_image(grid)
    assert ((ours == 0) == (cls == 1)).all() and ((ours == 254) == (cls == 0)).all()


def test_the_state_comes_back_and_another_grids_is_refused() -> None:
    grid = fresh()
    grid.add_results(RIG, [hit_zone(0.0, 2.0)])
    back = grid_from_state(GridConfig(), state_bytes(grid), grid.half_size_m)
    assert np.array_equal(back.log_odds, grid.log_odds)
    with pytest.raises(ValueError, match="another grid"):
        grid_from_state(GridConfig(resolution_m=0.1), state_bytes(grid), grid.half_size_m)
    with pytest.raises(ValueError, match="not a saved grid"):
        grid_from_state(GridConfig(), b"garbage", grid.half_size_m)


def square_room(door: tuple[float, float] = (-0.45, 0.45), cupboards: bool = False) -> list[ZoneResult]:
    """64 zones in a room 4 m square about the unit, a doorway in the wall ahead (x = 2, y within
    `door`) onto a dark corridor (no_spot); with `cupboards`, two in front of the wall to the left
    (y = 2) with a gap of 0.6 m between them."""
    out = []
    for i in range(64):
        pan = i * 5.625 - 180.0
        o, d = beam(pan)
        hits = [(s - o[k]) / d[k] for k in (0, 1) for s in (-2.0, 2.0) if abs(d[k]) > 1e-9 and (s - o[k]) / d[k] > 0]
        t = min(hits)
        p = o + t * d
        if cupboards and abs(p[1] - 2.0) < 1e-6 and not -0.3 <= p[0] <= 0.3:
            t = (1.6 - o[1]) / d[1]  # the cupboards' fronts, 0.4 m before the wall
        if abs(p[0] - 2.0) < 1e-6 and door[0] <= p[1] <= door[1]:
            out.append(ZoneResult(i, pan, 0.0, NO_SPOT))
        else:
            out.append(hit_zone(pan, t, index=i))
    return out


def test_a_ray_through_a_doorway_onto_a_dark_corridor_leaves_the_room_a_metre_past_the_door() -> None:
    from edge.maps import doorways_m

    results = square_room(cupboards=True)
    grid = OccupancyGrid.for_rig(GridConfig(), RIG)
    for _ in range(3):
        grid.add_results(RIG, results)
    doors = doorways_m(grid, RIG, results)
    through = {r.index for r in results if r.status == NO_SPOT}
    assert {31, 32, 33} <= set(doors) <= through  # pans -5.6°, 0, 5.6°: the door's middle
    for k in doors:
        assert 2.3 <= doors[k] <= 3.3, doors  # past the door (x = 2), within about a metre
    # The gap between the cupboards has the wall behind it: no doorway.
    gap = [r.index for r in results if r.point_base_m is not None and abs(r.point_base_m[1] - 2.0) < 0.01]
    assert gap and not set(gap) & set(doors)
    # A zone's ray that met a wall, and one through the door onto a lit corridor wall, end in the
    # room. (Between two zones' rays a wall seen by a sweep is dotted: the map knows its own rays.)
    o, d = beam(-28.125)
    assert grid.doorway_m(o[:2], d[:2], 5.0) is None
    corridor = grid.cell_of(np.array([4.0, 0.035]))
    grid.log_odds[corridor[1], corridor[0]] = 4.0
    assert grid.doorway_m(np.zeros(2), np.array([1.0, 0.0]), 5.0) is None


def test_an_empty_grid_has_no_doorways() -> None:
    grid = OccupancyGrid.for_rig(GridConfig(), RIG)
    assert grid.doorway_m(np.zeros(2), np.array([1.0, 0.0]), 5.0) is None
