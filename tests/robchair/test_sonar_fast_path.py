"""The sonar intake's fast path gives the old path's outputs, maps and stats bit for bit (session 11).

``Perception.add_sonar`` runs for every array reading (twice per agent step); its fast path is one
compiled arc kernel (arc, explanation by the laser and the zoom map, distance ahead), a one-pass
small-cloud VHV insert, the mount's fixed geometry kept and a leaner five-zone fusion. The old path
is kept verbatim in :mod:`tests.robchair.sonar_reference`; here both run side by side on two
perception stages fed the same readings, scans and zoom cells, and every output must be equal.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from hw.interfaces import SonarArrayReading
from mapping.grid import GridSpec
from mapping.sonar import fuse_array, zone_tables
from mapping.vhv import VHVMap
from robchair.perception import Perception
from robchair.perception_sonar import (
    MountGeometry,
    explained_arc_at,
    explained_arc_fast,
    fused_arc,
    sonar_obstacle_points,
)
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import load_spec
from tests.robchair.sonar_reference import (
    add_sonar_reference,
    explained_arc_reference,
    fuse_array_reference,
    known_surfaces_reference,
    sonar_obstacle_points_reference,
)

ARRAYS = ("sonar_array_left", "sonar_array_right")
# ranges that name every zone, the sets {2} and {1, 3}, no echo, rejected, the short range
RANGES = (math.nan, math.inf, 0.0, 0.08, 0.2, 0.25, 0.31, 0.33, 0.45, 0.5, 0.52, 0.7, 0.71, 0.99, 1.0, 1.3)


@pytest.fixture(scope="module")
def spec():
    return load_spec()


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and np.array_equal(a, b, equal_nan=True)
        )
    return repr(a) == repr(b)


def _map_state(m) -> dict:
    """What a map holds: its structures (a VHV map) or evidence intervals (a probabilistic one), counters."""
    keep = ("frames", "points_inserted", "points_dropped_nonfinite", "points_outside_grid", "sensor_origins")
    out = {k: getattr(m, k) for k in keep}
    if hasattr(m, "intervals"):
        iv = m.intervals()
        out.update({f: getattr(iv, f) for f in ("i", "j", "bottom", "top", "log_odds", "occupied", "free")})
    else:
        out.update({f: getattr(m, f) for f in ("_key", "_bottom", "_top")})
    return out


def _assert_same_stage(a: Perception, b: Perception) -> None:
    assert a._sonar == b._sonar
    assert a._sonar_arc.keys() == b._sonar_arc.keys()
    for k, (arc, pose) in a._sonar_arc.items():
        assert _same(arc, b._sonar_arc[k][0]) and pose == b._sonar_arc[k][1]
    assert a.stats == b.stats and a._servo == b._servo and a.layer_s.keys() == b.layer_s.keys()
    sa, sb = _map_state(a.sonar_map), _map_state(b.sonar_map)
    assert sa.keys() == sb.keys()
    for k in sa:
        assert _same(sa[k], sb[k]), k


def _scan_near(spec, rng, ranges, name) -> np.ndarray:
    """Laser-frame points (N, 3): returns at the readings' ranges around array ``name``, and clutter."""
    ox, oy, _ = spec.mounts[name].xyz
    lx, ly, _ = spec.mounts["laser_link"].xyz
    pts = []
    for r in ranges:
        if math.isfinite(r) and 0.0 < r <= 1.0:
            for b in rng.uniform(-math.pi, math.pi, 6):
                rr = r + rng.uniform(-0.08, 0.08)
                pts.append((ox + rr * math.cos(b) - lx, oy + rr * math.sin(b) - ly, 0.0))
    pts.extend((x, y, 0.0) for x, y in rng.uniform(-3.0, 3.0, (40, 2)))
    pts.append((math.nan, math.nan, math.nan))
    return np.asarray(pts)


@pytest.mark.parametrize("kind", ["thesis", "probabilistic"])
def test_the_fast_path_gives_the_old_outputs_maps_and_stats(spec, kind: str) -> None:
    grid = GridSpec(cell_size=0.1, size_x=12.0, size_y=8.0, centre=(2.0, 0.0))
    old, new = (Perception(spec, grid=grid, sonar_map=None, map_kind=kind) for _ in range(2))
    rng = np.random.default_rng(11)
    x = y = th = 0.0
    for step in range(260):
        x, y, th = x + rng.uniform(-0.05, 0.1), y + rng.uniform(-0.05, 0.05), th + rng.uniform(-0.2, 0.2)
        pose = Pose2D(x, y, th)
        readings = {}
        for name in ARRAYS:
            d = float(rng.choice(RANGES))
            r = [float(rng.choice(RANGES)) if rng.random() < 0.3 else d + rng.choice((0.0, 0.01, 0.02, 0.05))
                 for _ in range(3)]  # fmt: skip
            readings[name] = SonarArrayReading(step, (r[0], r[1], r[2]), float(rng.uniform(50.0, 130.0)))
        if step % 3 == 0:  # a laser scan with returns where the sonars hear something
            pts = _scan_near(spec, rng, readings[ARRAYS[step % 2]].ranges_m, ARRAYS[step % 2])
            for p in (old, new):
                p.add_scan("laser_link", pts, pose)
        if step % 5 == 1:  # the zoom's cells in the band, in base_link at an earlier pose
            xy = rng.uniform(-1.2, 1.2, (int(rng.integers(0, 60)), 2))
            p0 = Pose2D(x - 0.1, y + 0.02, th - 0.05)
            for p in (old, new):
                p._zoom_xy = (xy, p0)
        elif step % 5 == 3:
            for p in (old, new):
                p._zoom_xy = None
        if step % 40 == 20:  # the map's arrays turn read-only once its structures are read
            for p in (old, new):
                p.occupied_2d(p.sonar_map)
        for name, reading in readings.items():
            same_pose = pose if step % 2 else Pose2D(x, y, th)  # the kept pose transform: object or value
            assert _same(
                add_sonar_reference(old, name, reading, pose), new.add_sonar(name, reading, same_pose)
            )
            _assert_same_stage(old, new)
        assert old.sonar_distance_m() == new.sonar_distance_m()
        assert _same(old.obstacle_points_base(pose), new.obstacle_points_base(pose))
    assert old.stats["sonar_fusions_with_obstacle"] > 100 and old.stats["sonar_points"] > 1000
    assert _same(old.occupancy_2d(old.sonar_map), new.occupancy_2d(new.sonar_map))


def test_the_arc_is_clipped_as_before_by_the_laser_and_by_the_zoom(spec) -> None:
    """The numpy fast path (:func:`explained_arc_at`, its pre-filter) and the kernel, on rings of known
    points around the arc's range: both clip as the old path does, and they do clip."""
    from robchair.perception_queries import Corridor

    rng = np.random.default_rng(3)
    mount = spec.mounts["sonar_array_left"]
    geo, corridor = MountGeometry(mount), Corridor.from_spec(spec)
    clipped = {"scan": 0, "zoom": 0}
    for _ in range(300):
        d = float(rng.uniform(0.1, 0.95))
        res = fuse_array(d, d + float(rng.choice((0.0, 0.01, 0.1))), d + 0.01)
        joint = float(rng.uniform(-0.6, 0.6))
        pose = Pose2D(
            float(rng.uniform(-2.0, 2.0)), float(rng.uniform(-2.0, 2.0)), float(rng.uniform(-3.0, 3.0))
        )
        arc = fused_arc(res, geo.x0, geo.y0, geo.yaw + joint)
        b, r = rng.uniform(-3.2, 3.2, 40), d + rng.uniform(-0.1, 0.1, 40)
        ring = np.array([geo.x0, geo.y0]) + r[:, None] * np.stack([np.cos(b), np.sin(b)], 1)
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        scan = np.stack(
            [c * ring[:, 0] - s * ring[:, 1] + pose.x, s * ring[:, 0] + c * ring[:, 1] + pose.y], 1
        )
        p0 = Pose2D(pose.x - 0.2, pose.y + 0.1, pose.theta + 0.3)  # the zoom's cells at an earlier pose
        c0, s0 = math.cos(-0.3), math.sin(-0.3)
        zoom = np.stack([c0 * ring[:, 0] - s0 * ring[:, 1] + 0.1, s0 * ring[:, 0] + c0 * ring[:, 1] - 0.2], 1)
        for which, scan_w, zoom_xy in (
            ("scan", scan, None),
            ("zoom", None, (zoom, p0)),
            ("both", scan, (zoom, p0)),
        ):
            stage = Perception.__new__(Perception)
            stage._scan_world, stage._zoom_xy = scan_w, zoom_xy
            known = known_surfaces_reference(stage, pose)
            ref = explained_arc_reference(arc, mount.xyz, known)
            assert _same(ref, explained_arc_at(arc, mount.xyz, pose, scan_w, zoom_xy))
            got, dist = explained_arc_fast(res, geo, joint, pose, scan_w, zoom_xy, corridor)
            assert _same(ref, got) and dist == corridor.distance_ahead(ref)
            clipped[which] = clipped.get(which, 0) + (ref is not arc)
    assert clipped["scan"] > 50 and clipped["zoom"] > 50


def test_the_fused_arc_is_the_old_arc(spec) -> None:
    from robchair.perception_queries import Corridor

    arrays, corridor = spec.sonar_arrays, Corridor.from_spec(spec)
    for name, r, servo in itertools.product(ARRAYS, (0.08, 0.25, 0.33, 0.5, 0.97), (40.0, 90.0, 123.4)):
        reading = SonarArrayReading(0, (r, r + 0.01, r + 0.2), servo)
        mount = spec.mounts[name]
        assert _same(
            sonar_obstacle_points_reference(reading, mount, arrays),
            sonar_obstacle_points(reading, mount, arrays),
        )
    rng = np.random.default_rng(8)
    geo = MountGeometry(spec.mounts[ARRAYS[0]])
    for alpha, theta, d, joint in zip(*rng.uniform((-90, 0, 0.1, -1), (60, 120, 1, 1), (2000, 4)).T):
        res = fuse_array(d, d, d)  # a fusion with this interval (the arc reads only these fields)
        res = dataclasses.replace(res, alpha_deg=float(alpha), theta_deg=float(theta))
        ref = np.radians(np.linspace(res.alpha_deg, res.alpha_deg + res.theta_deg, 9)) + (geo.yaw + joint)
        ref = np.stack([geo.x0 + d * np.cos(ref), geo.y0 + d * np.sin(ref)], axis=1)
        assert _same(ref, fused_arc(res, geo.x0, geo.y0, geo.yaw + joint))
        assert _same(
            ref, explained_arc_fast(res, geo, float(joint), Pose2D(0, 0, 0), None, None, corridor)[0]
        )


def test_the_mount_geometry_gives_the_mount_transform(spec) -> None:
    rng = np.random.default_rng(5)
    for name in ARRAYS:
        mount, geo = spec.mounts[name], MountGeometry(spec.mounts[name])
        for joint in (0.0, -0.0, 1e-300, *rng.uniform(-1.6, 1.6, 50)):
            assert _same(mount.transform(float(joint)), geo.t_base_array(float(joint)))


def test_the_fusion_is_the_old_fusion() -> None:
    values = [*RANGES, 0.149, 0.15, 0.3, 0.32, 0.49, 0.53, 1.0000001]
    for tables, threshold in ((zone_tables(30.0), 0.03), (zone_tables(25.0), 0.0), (zone_tables(30.0), 0.1)):
        for _rep, (a, b, c) in itertools.product(range(2), itertools.product(values, repeat=3)):  # 2nd: memo
            ref = fuse_array_reference(a, b, c, threshold, tables)
            assert repr(fuse_array(float(a), float(b), float(c), threshold, tables)) == repr(ref)


def _random_cloud(rng, n: int, spread: float) -> np.ndarray:
    pts = rng.normal((1.0, 0.5, 0.4), spread, (n, 3))
    pts[:, 2] = np.round(pts[:, 2] * 64.0) / 64.0  # repeated heights, gaps of exactly the tolerance
    pts[rng.random(n) < 0.03] = np.nan
    pts[rng.random(n) < 0.02, 0] = 40.0  # outside the grid
    # a column of one cell with heights exactly a tolerance apart, and more apart
    col = np.cumsum(rng.choice((4 / 64, 5 / 64), 8))
    return np.concatenate([pts, np.stack([np.full(8, 1.01), np.full(8, 0.51), col], 1)])


@pytest.mark.parametrize("spread", [0.02, 0.15, 1.5])
def test_insert_few_gives_the_map_insert_gives(spread: float) -> None:
    """Clouds of a few cells (more than 32 points in a cell) to many (the cell list grows)."""
    grid = GridSpec(cell_size=0.05, size_x=6.0, size_y=6.0)
    rng = np.random.default_rng(int(spread * 100))
    ref, fast = VHVMap(grid, 4 / 64), VHVMap(grid, 4 / 64)
    for k in range(40):
        pts = _random_cloud(rng, int(rng.integers(0, 700)), spread)
        origin = np.array([0.1 * k, 0.0, 0.5])
        ref.insert(pts, sensor_origin=origin)
        fast.insert_few(pts, origin)
        if k % 7 == 3:  # read-only arrays from here on
            assert ref.structures().equals(fast.structures())
        for f in ("_key", "_bottom", "_top"):
            assert _same(getattr(ref, f), getattr(fast, f)), (k, f)
        assert (ref.frames, ref.points_inserted, ref.points_dropped_nonfinite, ref.points_outside_grid) == (
            fast.frames, fast.points_inserted, fast.points_dropped_nonfinite, fast.points_outside_grid,
        )  # fmt: skip
        assert ref.sensor_origins == fast.sensor_origins
    assert ref.n_structures > 10


def test_insert_few_refuses_what_insert_refuses() -> None:
    from mapping.errors import MappingError, PointsError

    m = VHVMap(GridSpec(cell_size=0.05, size_x=2.0, size_y=2.0), 0.05)
    with pytest.raises(PointsError):
        m.insert_few(np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(PointsError):
        m.insert_few(np.zeros((3, 3), np.float32), np.zeros(3))
    with pytest.raises(MappingError):
        m.insert_few(np.zeros((3, 3)), np.array([0.0, math.nan, 0.0]))
    with pytest.raises(MappingError):
        m.insert_few(np.zeros((3, 3)), np.zeros(2))
    assert m.frames == 0 and m.n_structures == 0


def test_the_bisection_on_floats_is_the_numpy_bisection() -> None:
    """One range's half-apertures (what a fusion meets first) solved on floats, as on a numpy array."""
    from mapping import sonar
    from mapping._sonar_one import _BOTTOM, _TOP, one_bearing_deg

    assert (_TOP, _BOTTOM) == (sonar.TOP_BOUNDARY_COEFFS_CM, sonar.BOTTOM_BOUNDARY_COEFFS_CM)
    rng = np.random.default_rng(2)
    ranges = [15.0, 100.0, *(k / 100 * 100 for k in range(15, 101)), *rng.uniform(15.0, 100.0, 400)]
    for d, side in itertools.product(ranges, ("left", "right")):
        assert one_bearing_deg(float(d), side) == sonar._crossing_bearing_deg(np.array([d]), side)[0]
    sonar._SOLVED.clear()  # the cached path gives the vectorised solve's values too
    left, right = sonar.half_apertures_deg(np.array([37.0]))
    assert (left[0], right[0]) == tuple(a[7] for a in sonar.half_apertures_deg(np.arange(30.0, 45.0)))


def test_the_compiled_cone_is_the_printed_cone() -> None:
    from mapping._sonar_one import cone_points_fast
    from mapping.sonar import cone_points

    rng = np.random.default_rng(4)
    for k, (d, theta, alpha) in enumerate(rng.uniform((0.0, 0.01, -100.0), (1.0, 125.0, 100.0), (1500, 3))):
        theta = float(round(theta)) if k % 3 == 0 else float(theta)  # whole ring counts too
        ppc = 40 if k % 2 else int(rng.integers(1, 50))
        assert _same(cone_points(float(d), theta, float(alpha), ppc), cone_points_fast(d, theta, alpha, ppc))
