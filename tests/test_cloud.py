"""The point cloud: normals estimated from the scan's pan/tilt lattice and the zone's own lasers,
refused across depth edges and creases, and the PLY read back by plyfile."""

from __future__ import annotations

import io
import math

import numpy as np
from plyfile import PlyData

from edge.cloud import Cloud, lattice_neighbours, ply_bytes, scan_cloud
from edge.ranging import NO_SPOT, OK, ZoneResult
from edge.rig import default_rig
from edge.triangulation import LaserMeasurement

RIG = default_rig()
WALL_X, FLOOR_Z = 2.0, -1.0
# A box on the floor in front of the wall: x, y, z extents (base frame, metres).
BOX = ((1.2, 1.6), (-0.25, 0.25), (FLOOR_Z, -0.45))


def cast(o: np.ndarray, d: np.ndarray, box: bool, wall_x: float = WALL_X) -> tuple[float, int, np.ndarray]:
    """Distance along the ray to the first surface, which one (0 wall, 1 floor, 2.. box faces)
    and its normal."""
    hits = [((wall_x - o[0]) / d[0], 0, np.array([-1.0, 0, 0]))]
    if d[2] < 0:
        hits.append(((FLOOR_Z - o[2]) / d[2], 1, np.array([0, 0, 1.0])))
    if box:  # slabs
        lo, hi = np.array([b[0] for b in BOX]), np.array([b[1] for b in BOX])
        with np.errstate(divide="ignore"):
            t1, t2 = (lo - o) / d, (hi - o) / d
        near, far = np.minimum(t1, t2), np.maximum(t1, t2)
        axis = int(np.argmax(near))
        if near[axis] < far.min() and near[axis] > 0:
            n = np.zeros(3)
            n[axis] = -np.sign(d[axis])
            hits.append((float(near[axis]), 2 + axis, n))
    return min(hits, key=lambda h: h[0])


Truth = dict[tuple[int, int], tuple[int, np.ndarray, float]]


def scan(pans: range, tilts: range, box: bool = False, noise: float = 0.0, seed: int = 0,
         lasers: bool = False, wall_x: float = WALL_X) -> tuple[list[ZoneResult], Truth]:
    """Zones over a pan/tilt lattice of the wall, the floor (and the box), ranged exactly or with
    relative range noise; and per (pan, tilt) the surface met, its true normal and the beam's
    angle from it (degrees)."""
    rng = np.random.default_rng(seed)
    results: list[ZoneResult] = []
    truth: Truth = {}
    for j, tilt in enumerate(tilts):
        for i, pan in enumerate(pans):
            pose = RIG.camera_to_base(pan, tilt)
            o, d = pose.apply(RIG.reference.o), pose.rotate(RIG.reference.d)
            t, surface, n = cast(o, d, box, wall_x)
            p = o + t * (1.0 + noise * rng.standard_normal()) * d
            cam = pose.inverse().apply(p)
            sigma = max(noise, 0.001) * t
            measured = {}
            if lasers:  # the other lasers' spots on the same surface
                for name in ("parallel", "sloped"):
                    laser = RIG.laser(name)
                    lo, ld = pose.apply(laser.o), pose.rotate(laser.d)
                    tl, other, _ = cast(lo, ld, box, wall_x)
                    if other == surface:
                        q = pose.inverse().apply(lo + tl * ld)
                        measured[name] = LaserMeasurement(name, np.zeros(2), 0.1, q, float(q[2]), sigma, 50.0, 1)
            results.append(ZoneResult(j * 100 + i, pan, tilt, OK, float(cam[2]), sigma, cam, p, lasers=measured))
            truth[(pan, tilt)] = (surface, n, math.degrees(math.acos(abs(float(d @ n)))))
    return results, truth


def angles_deg(cloud: Cloud, results: list[ZoneResult], truth: dict) -> np.ndarray:
    """Each point's normal's angle from its surface's (nan where it has none)."""
    ok = [r for r in results if r.status == OK]
    out = np.full(len(ok), np.nan)
    for k, r in enumerate(ok):
        if np.linalg.norm(cloud.normals[k]) > 0.5:
            cos = float(cloud.normals[k] @ truth[(int(r.pan_deg), int(r.tilt_deg))][1])
            out[k] = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
    return out


def surrounded(pans: range, tilts: range, truth: dict, pan: int, tilt: int, reach: int = 1) -> bool:
    """Whether the zones within `reach` lattice steps of (pan, tilt) all exist and see its surface,
    and it is not seen edge-on (more than 55° from its normal: beyond 60°, range steps between
    neighbours are taken for depth edges)."""
    p, t = list(pans).index(pan), list(tilts).index(tilt)
    here = truth[(pan, tilt)][0]
    if truth[(pan, tilt)][2] > 55.0:
        return False
    for dp in range(-reach, reach + 1):
        for dt in range(-reach, reach + 1):
            if not (0 <= p + dp < len(pans) and 0 <= t + dt < len(tilts)):
                return False
            if truth[(pans[p + dp], tilts[t + dt])][0] != here:
                return False
    return True


PANS, TILTS = range(-30, 31, 6), range(-45, 1, 9)


def test_normals_from_the_lattice_follow_the_wall_and_the_floor_and_are_refused_at_their_crease() -> None:
    results, truth = scan(PANS, TILTS)
    results.append(ZoneResult(999, 0.0, 10.0, NO_SPOT))
    cloud = scan_cloud(RIG, results)
    assert len(cloud) == len(results) - 1  # the no_spot zone has no point
    angles = angles_deg(cloud, results, truth)
    given = ~np.isnan(angles)
    assert np.all(angles[given] < 1.0), np.nanmax(angles)
    for k, r in enumerate(results[:-1]):
        pan, tilt = int(r.pan_deg), int(r.tilt_deg)
        if surrounded(PANS, TILTS, truth, pan, tilt):
            assert given[k], (pan, tilt)  # all round on one surface: a normal
        p, t = PANS.index(pan), TILTS.index(tilt)
        straddles = any(truth[(pan, TILTS[t + dt])][0] != truth[(pan, tilt)][0]
                        for dt in (-1, 1) if 0 <= t + dt < len(TILTS))
        if straddles or t in (0, len(TILTS) - 1) or p in (0, len(PANS) - 1):
            assert not given[k], (pan, tilt)  # a crease, or the scan's edge: no other side to confirm
    assert given.sum() >= 15


def test_normals_survive_noise_as_large_as_the_ranging_targets() -> None:
    pans, tilts = range(-40, 41, 5), range(-45, 16, 10)
    results, truth = scan(pans, tilts, noise=0.005, seed=3)
    angles = angles_deg(scan_cloud(RIG, results), results, truth)
    given = angles[~np.isnan(angles)]
    assert len(given) >= 0.4 * len(angles)
    assert np.percentile(given, 95) < 6.0 and given.max() < 10.0, np.sort(given)[-5:]


def test_a_fine_lattice_reaches_further_than_the_next_zone_and_gives_more_normals() -> None:
    """Zones 2° apart are 7 cm apart at 2 m, too near to pin a plane against 0.5 % noise: the
    neighbours reach 2, 4 and 8 zones away, and most points get a normal."""
    pans, tilts = range(-30, 31, 2), range(-45, 16, 2)
    results, truth = scan(pans, tilts, noise=0.005, seed=1)
    angles = angles_deg(scan_cloud(RIG, results), results, truth)
    given = angles[~np.isnan(angles)]
    assert len(given) >= 0.5 * len(angles)
    assert np.percentile(given, 95) < 5.0, np.sort(given)[-10:]


def test_no_normal_across_a_depth_edge() -> None:
    """A box on the floor in front of the wall: the plane through the box's top row and the wall's
    row above it is a slope that exists nowhere, and no point gets it."""
    pans, tilts = range(-30, 31, 4), range(-50, 11, 5)
    results, truth = scan(pans, tilts, box=True)
    assert {t[0] for t in truth.values()} >= {0, 1, 2, 4}  # wall, floor, box front and top
    angles = angles_deg(scan_cloud(RIG, results), results, truth)
    given = ~np.isnan(angles)
    # A point by an edge may take in a neighbour on the edge (on both planes): a few degrees.
    assert np.all(angles[given] < 6.0), np.nanmax(angles)
    for k, r in enumerate(results):
        pan, tilt = int(r.pan_deg), int(r.tilt_deg)
        if surrounded(pans, tilts, truth, pan, tilt):
            assert given[k], (pan, tilt)
        if surrounded(pans, tilts, truth, pan, tilt, reach=2):  # as far as its neighbours reach
            assert angles[k] < 1.0, (pan, tilt)
    box = [k for k, r in enumerate(results) if truth[(r.pan_deg, r.tilt_deg)][0] >= 2]
    assert any(given[k] for k in box) and not all(given[k] for k in box)


def test_one_tilt_level_takes_its_normals_from_the_zones_own_lasers() -> None:
    """A sweep at one tilt has no rows above and below: the parallel laser's spot (4 cm above)
    and the sloped one's (10° below) stand in for them, on a wall near enough (0.8 m) for 4 cm
    to pin the plane's slope."""
    pans, tilts = range(-30, 31, 6), range(0, 1)
    results, truth = scan(pans, tilts, lasers=True, wall_x=0.8)
    angles = angles_deg(scan_cloud(RIG, results), results, truth)
    inner = angles[1:-1]  # the first and last have a neighbour on one side only
    assert not np.isnan(inner).any() and np.all(inner < 1.0), angles
    plain = [ZoneResult(r.index, r.pan_deg, r.tilt_deg, r.status, r.range_m, r.sigma_m, r.point_m,
                        r.point_base_m) for r in results]
    assert np.all(scan_cloud(RIG, plain).normals == 0.0)  # without them: nothing to confirm a plane


def test_the_lattice_wraps_round_a_full_turn_and_breaks_at_a_missing_zone() -> None:
    pans = [i * 5.625 - 180.0 for i in range(64)]
    poses = [(p, t) for t in (-20.0, 0.0) for p in pans]
    keep = [k for k, pose in enumerate(poses) if pose != (-90.0, -20.0)]  # one zone of the lower row missing
    reached = [(p, t + 0.01 * (k % 3)) for k, (p, t) in enumerate(poses)]  # a position or two off
    nb = lattice_neighbours([reached[k][0] for k in keep], [reached[k][1] for k in keep], reached)
    index = {poses[k]: n for n, k in enumerate(keep)}
    beside = lambda pose: sorted(keep[j] for j, level, _ in nb[index[pose]] if level == 0)  # noqa: E731
    assert beside((-180.0, 0.0)) == [64 + 1, 64 + 63]  # across ±180°
    assert beside((-95.625, -20.0)) == [14]  # -90° is missing: not next to -84.375°
    column = [keep[j] for j, level, col in nb[index[(-90.0, 0.0)]] if col]
    assert column == []  # nothing above, and the zone below is missing
    above = sorted(keep[j] for j, level, _ in nb[index[(0.0, -20.0)]] if level == 1)
    assert above == [64 + 31, 64 + 32, 64 + 33]


def test_the_ply_reads_back_with_plyfile() -> None:
    results, _ = scan(PANS, TILTS)
    cloud = scan_cloud(RIG, results)
    ply = PlyData.read(io.BytesIO(ply_bytes(cloud, "a corner")))
    assert not ply.text and ply.byte_order == "<" and "a corner" in ply.comments
    vertex = ply["vertex"]
    assert [p.name for p in vertex.properties] == ["x", "y", "z", "nx", "ny", "nz", "sigma"]
    assert len(vertex.data) == len(cloud)
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    assert np.allclose(xyz, cloud.points, atol=1e-5)
    assert np.allclose(vertex["sigma"], cloud.sigma, atol=1e-7)
    assert np.allclose(np.stack([vertex["nx"], vertex["ny"], vertex["nz"]], axis=1), cloud.normals, atol=1e-6)


def test_an_empty_cloud_is_a_valid_ply() -> None:
    ply = PlyData.read(io.BytesIO(ply_bytes(Cloud.empty())))
    assert len(ply["vertex"].data) == 0


SCAN_TILTS = [-40, -20, 0, 15, 30]  # the 3D scan: the top and bottom rows have one side


def test_the_top_and_bottom_rows_take_their_normal_from_the_one_side_they_have() -> None:
    """A wall 1 m away fills all five tilt levels. The top row has nothing above it, the bottom
    row's sloped spots fall on the floor: each has only the rows on one side, with the sloped
    laser's spots between them as a third layer, and that is enough."""
    pans = range(-30, 31, 6)
    results, truth = scan(pans, SCAN_TILTS, lasers=True, wall_x=1.0)  # type: ignore[arg-type]
    assert {truth[(p, t)][0] for p in pans for t in SCAN_TILTS} == {0}
    angles = angles_deg(scan_cloud(RIG, results), results, truth)
    for k, r in enumerate(results):
        if r.tilt_deg in (SCAN_TILTS[0], SCAN_TILTS[-1]) and r.pan_deg not in (pans[0], pans[-1]):
            assert angles[k] < 1.0, (r.pan_deg, r.tilt_deg, angles[k])
    plain = [ZoneResult(r.index, r.pan_deg, r.tilt_deg, r.status, r.range_m, r.sigma_m, r.point_m,
                        r.point_base_m) for r in results]
    bare = angles_deg(scan_cloud(RIG, plain), results, truth)
    assert np.isnan(bare[[r.tilt_deg in (SCAN_TILTS[0], SCAN_TILTS[-1]) for r in results]]).all()


def test_a_row_by_a_crease_takes_its_normal_from_its_own_side() -> None:
    """The rows next to the crease of the wall and the floor have a window across it, which fails,
    and one on their own side, which holds where it has three layers; they get their own surface's
    normal, with noise too, and none gets a slope between the two. Levels 10° apart: the floor's
    row below the crease (the sloped laser's spots of the wall's row fall on their own row's
    level: two layers on that side). The issue's levels: the wall's row above it (the floor's
    row, the scan's bottom one, has two layers of floor, its own and its sloped spots: see
    test_the_bottom_rows_floor_under_a_wall_takes_its_normal_from_its_own_lasers)."""
    pans = range(-30, 31, 6)
    for tilts, own_side in ((range(-45, 16, 10), -35), (SCAN_TILTS, -20)):
        for seed, noise in ((0, 0.0), (1, 0.003), (2, 0.003)):
            results, truth = scan(pans, tilts, noise=noise, seed=seed, lasers=True)  # type: ignore[arg-type]
            surface = {pose: t[0] for pose, t in truth.items()}
            assert surface[(0, own_side)] != surface[(0, own_side + (10 if own_side == -35 else -20))]
            angles = angles_deg(scan_cloud(RIG, results), results, truth)
            given = ~np.isnan(angles)
            assert np.all(angles[given] < (1.0 if noise == 0 else 6.0)), np.nanmax(angles)
            row = [k for k, r in enumerate(results) if r.tilt_deg == own_side and r.pan_deg not in (pans[0], pans[-1])]
            assert given[row].all(), (tilts, seed, given[row])


def test_no_normal_from_a_plane_through_a_box_top_row_and_the_front_below_it() -> None:
    """A low box on the floor, 5 tilt levels: where the row at −20° meets the box's top just behind
    its front edge and the row at −40° the front, the two rows (and the front's parallel laser
    spots 4 cm above them) fit a plane that is neither: the window below the top row cannot pin a
    slope past its own two layers, and the top row gets no normal from it."""
    pans = range(-60, 61, 6)
    for front in (1.0, 1.1, 1.15, 1.2):
        for top in (-0.7, -0.45):
            box = ((front, front + 0.4), (-0.25, 0.25), (FLOOR_Z, top))
            results, truth = scan_box(pans, SCAN_TILTS, box, noise=0.004, seed=0)
            angles = angles_deg(scan_cloud(RIG, results), results, truth)
            given = ~np.isnan(angles)
            assert given.sum() >= 40, (front, top)
            assert np.all(angles[given] < 10.0), (front, top, np.nanmax(angles))


Box = tuple[tuple[float, float], tuple[float, float], tuple[float, float]]


def scan_box(pans: range, tilts: list[int], box: Box, noise: float, seed: int) -> tuple[list[ZoneResult], Truth]:
    """`scan` with the lasers' spots and another box in place of BOX (which `cast` reads)."""
    global BOX
    saved, BOX = BOX, box
    try:
        return scan(pans, tilts, box=True, noise=noise, seed=seed, lasers=True)  # type: ignore[arg-type]
    finally:
        BOX = saved


def test_the_bottom_rows_floor_under_a_wall_takes_its_normal_from_its_own_lasers() -> None:
    """The issue's levels with the wall 2 m away: the bottom row (−40°) is floor, the row above
    it wall. On the floor's side the row has two layers only, its points and its sloped laser's
    spots 10° nearer — two parallel lines that a plane of any slope holds. Each zone's own spots
    join them (the ranging fused them onto the point's surface) and the plane through both is
    level, as a floor is: that is the known slope the fusion tests its lasers against, and the
    normal is given. Without the zones' own spots the row has none."""
    pans = range(-30, 31, 6)
    for seed, noise in ((0, 0.0), (1, 0.003), (2, 0.003), (3, 0.005)):
        results, truth = scan(pans, SCAN_TILTS, noise=noise, seed=seed, lasers=True)  # type: ignore[arg-type]
        bottom = [k for k, r in enumerate(results)
                  if r.tilt_deg == SCAN_TILTS[0] and r.pan_deg not in (pans[0], pans[-1])]
        assert {truth[(results[k].pan_deg, results[k].tilt_deg)][0] for k in bottom} == {1}  # the floor
        assert truth[(0, SCAN_TILTS[1])][0] == 0  # the wall above it
        angles = angles_deg(scan_cloud(RIG, results), results, truth)
        assert not np.isnan(angles[bottom]).any(), (seed, angles[bottom])
        given = ~np.isnan(angles)
        assert np.all(angles[given] < (1.0 if noise == 0 else 6.0)), (seed, np.nanmax(angles))
    plain = [ZoneResult(r.index, r.pan_deg, r.tilt_deg, r.status, r.range_m, r.sigma_m, r.point_m,
                        r.point_base_m) for r in results]
    assert np.isnan(angles_deg(scan_cloud(RIG, plain), results, truth)[bottom]).all()


def test_no_point_by_a_walls_foot_takes_the_other_surfaces_normal() -> None:
    """Tilt levels 10° apart and the wall at every distance from 1.15 to 2.5 m: rows land on the
    floor a few centimetres before the wall's foot and on the wall just above it. Such a row lies
    on both planes; the windows on the far side of the crease hold it with their own surface, and
    only the zone's own spots (its sloped laser's, on the floor before the wall) tell which it is
    on. None takes the other surface's normal, with noise too."""
    pans = range(-30, 31, 6)
    tilts = range(-40, 31, 10)
    for k, wall_x in enumerate(np.arange(1.15, 2.51, 0.05)):
        for seed, noise in ((k, 0.0), (100 + k, 0.003)):
            results, truth = scan(pans, tilts, noise=noise, seed=seed, lasers=True, wall_x=float(wall_x))
            angles = angles_deg(scan_cloud(RIG, results), results, truth)
            given = ~np.isnan(angles)
            assert np.all(angles[given] < 10.0), (wall_x, seed, np.nanmax(angles))


def test_two_rows_joined_by_the_zones_own_spots_give_a_normal_only_at_a_floors_slope() -> None:
    """A row seen 40° down and its sloped laser's spots 10° further down, nothing else: two layers
    joined by each zone's own spots. On a floor the plane through them is level and the normal
    given; sloped 15° towards the unit (a crease between the rows, or a ramp) it is neither a
    floor's nor a wall's slope, the slopes the ranging's fusion vouches for its lasers at, and
    none is given."""
    from edge.normals import Support, normal_of

    def at(tilt_deg: float, pan_deg: float, slope_deg: float) -> np.ndarray:
        """Where the ray at (pan, tilt) from 1 m above the floor meets it, the floor turned by
        slope_deg about the point's own row (1.19 m away; negative: lower nearer the unit)."""
        d = math.tan(math.radians(-tilt_deg))
        reach = 1.0 / d
        rise = math.tan(math.radians(slope_deg))
        reach = (1.0 + rise * 1.19) / (d + rise) if slope_deg else reach
        p = math.radians(pan_deg)
        return np.array([reach * math.cos(p), reach * math.sin(p), -1.0 + rise * (1.19 - reach)])

    up = np.array([math.sin(math.radians(40.0)), 0.0, math.cos(math.radians(40.0))])
    for slope, given in ((0.0, True), (-15.0, False)):
        own = [Support(at(-50.0, 0.0, slope), 0.003, 0, "sloped", True)]
        for pan in (-5.625, 5.625):
            own += [Support(at(-40.0, pan, slope), 0.003, 0, None, False),
                    Support(at(-50.0, pan, slope), 0.003, 0, "sloped", False)]
        normal = normal_of(at(-40.0, 0.0, slope), 0.003, np.zeros(3), up, own)
        assert (normal is not None) == given, (slope, normal)
        if normal is not None:
            assert float(normal @ np.array([0.0, 0.0, 1.0])) > math.cos(math.radians(1.0))


def test_a_wall_joined_by_its_own_spots_takes_its_bearing_from_a_row_pinned_as_any_windows() -> None:
    """Two layers joined by the zones' own spots, at 2 m: the row's three zones and their sloped
    laser's spots. The known slope pins a floor's normal both ways, so a row that pins the plane's
    slope across it to 2.3° will do there; a wall's only up and down, and its bearing comes from the
    row as in any window: pinned to 2.0° (σ 1.4 cm), none is given (stepped fronts fit a plane
    turned 11° at that); to 0.4° (σ 3 mm), it is."""
    from edge.normals import Support, normal_of

    def floor(tilt_deg: float, pan_deg: float) -> np.ndarray:
        reach, p = 1.0 / math.tan(math.radians(-tilt_deg)), math.radians(pan_deg)
        return np.array([reach * math.cos(p), reach * math.sin(p), -1.0])

    def wall(tilt_deg: float, pan_deg: float) -> np.ndarray:
        p, t = math.radians(pan_deg), math.radians(tilt_deg)
        return np.array([2.0, 2.0 * math.tan(p), 2.0 * math.tan(t) / math.cos(p)])

    for at, tilt, sigma, given in ((floor, -40.0, 0.008, True), (wall, 0.0, 0.014, False), (wall, 0.0, 0.003, True)):
        up = np.array([math.sin(math.radians(-tilt)), 0.0, math.cos(math.radians(tilt))])
        own = [Support(at(tilt - 10.0, 0.0), sigma, 0, "sloped", True)]
        for pan in (-5.625, 5.625):
            own += [Support(at(tilt, pan), sigma, 0, None, False),
                    Support(at(tilt - 10.0, pan), sigma, 0, "sloped", False)]
        normal = normal_of(at(tilt, 0.0), sigma, np.zeros(3), up, own)
        assert (normal is not None) == given, (at.__name__, sigma, normal)
