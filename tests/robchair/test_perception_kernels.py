"""The perception stage's compiled point passes against the numpy paths they replace, bit for bit."""

from __future__ import annotations

import math

import numpy as np

from mapping.grid import GridSpec
from robchair.perception import Perception
from robchair.perception_kernels import band_xy, points_in_base_fast
from robchair.perception_queries import points_in_base
from robchair.platform.frames import se3_planar, transform_points
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import load_spec


def _pose(rng) -> Pose2D:  # type: ignore[no-untyped-def]
    return Pose2D(float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)), float(rng.uniform(-math.pi, math.pi)))


def test_the_compiled_obstacle_points_are_points_in_base_bit_for_bit():
    rng = np.random.default_rng(1)
    for _ in range(200):
        pose = _pose(rng)
        odom = rng.uniform(-8, 8, (int(rng.integers(0, 700)), 2)) if rng.random() < 0.8 else None
        arcs = []
        for _ in range(int(rng.integers(0, 4))):
            a = rng.uniform(-3, 3, (int(rng.integers(0, 40)), 3))[:, :2]  # a strided view, as add_sonar's
            arcs.append((a, _pose(rng)))
        got = points_in_base_fast(pose, odom, arcs)
        want = points_in_base(pose, odom, arcs)
        assert got is not None and got.dtype == want.dtype == np.float64 and got.shape == want.shape
        np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64))


def test_obstacle_points_of_other_types_take_the_numpy_path():
    arc = np.ones((3, 2), dtype=np.float32)
    assert points_in_base_fast(Pose2D(), None, [(arc, Pose2D())]) is None


def test_the_compiled_band_filter_is_numpys():
    rng = np.random.default_rng(2)
    w = rng.uniform(-1, 2, (900, 3))
    w[:3, 2] = (0.1, 1.3, np.nan)  # on the limits, and a NaN height (never in the band)
    got = band_xy(w, (0.1, 1.3))
    np.testing.assert_array_equal(got, w[(w[:, 2] >= 0.1) & (w[:, 2] <= 1.3), :2])


def _add_scan_reference(p: Perception, frame_id: str, points: np.ndarray, pose: Pose2D) -> None:
    """Perception.add_scan as it was: two transforms, the numpy band filter."""
    t = p._t_main_base(pose) @ p.t_base_sensor(frame_id)
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    t_odom = se3_planar(pose.x, pose.y, pose.theta) @ p.t_base_sensor(frame_id)
    w = transform_points(t_odom, pts[np.isfinite(pts).all(axis=1)])
    p._scan_world = w[(w[:, 2] >= p.band[0]) & (w[:, 2] <= p.band[1]), :2]
    p.map.insert(transform_points(t, pts), sensor_origin=t[:3, 3])
    p.stats["laser_scans"] += 1


def test_a_laser_scan_is_placed_and_mapped_as_before_bit_for_bit():
    spec = load_spec()
    grid = GridSpec(cell_size=0.1, size_x=12.0, size_y=12.0)
    for kind in ("thesis", "probabilistic"):
        a = Perception(spec, grid=grid, map_kind=kind)
        b = Perception(spec, grid=grid, map_kind=kind)
        rng = np.random.default_rng(3)
        for k in range(30):
            pose = Pose2D(float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)), float(rng.uniform(-3, 3)))
            pts = np.column_stack([rng.uniform(-4, 4, (600, 2)), rng.uniform(-1.0, 1.5, 600)])
            if k % 3 == 0:
                pts[rng.random(600) < 0.1] = np.nan  # rows without a return
            a.add_scan("laser_link", pts, pose)
            _add_scan_reference(b, "laser_link", pts, pose)
            np.testing.assert_array_equal(a.scan_points_odom(), b.scan_points_odom())
        np.testing.assert_array_equal(a.occupancy_2d(), b.occupancy_2d())
        if kind == "thesis":
            sa, sb = a.map.structures(), b.map.structures()  # type: ignore[attr-defined]
            assert sa.equals(sb)
        assert a.stats == b.stats
