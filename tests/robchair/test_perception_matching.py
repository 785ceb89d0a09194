"""Scan-to-map matching and the zoom inside the perception stage."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hw.interfaces import DepthFrame
from mapping.synthetic import render_scene
from robchair.perception import SNAPSHOT_LAG, Perception
from robchair.platform.errors import ConfigError
from robchair.platform.frames import se3_planar
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import load_spec

FRAMES = {"cam": np.eye(4)}  # the clouds below are given in base_link directly


class Camera:
    """Hands out the given organized clouds, one per read."""

    def __init__(self, clouds: list[np.ndarray]) -> None:
        self.clouds = list(clouds)

    def read(self) -> DepthFrame:
        return DepthFrame(0, "cam", np.asarray(self.clouds.pop(0), np.float32))


@pytest.fixture(scope="module")
def spec():
    return load_spec()


@pytest.fixture(scope="module")
def views() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    return tuple(render_scene(rng, 212, 256, nan_fraction=0.05, pitch_deg=5.0) for _ in range(2))


def _perception(spec, **kw) -> Perception:
    from mapping.grid import GridSpec

    grid = GridSpec(cell_size=0.05, size_x=16.0, size_y=16.0, centre=(3.0, 0.0))
    return Perception(spec, grid=grid, frames=FRAMES, sonar_map=None, **kw)


def _planar(t: np.ndarray) -> tuple[float, float, float]:
    return float(t[0, 3]), float(t[1, 3]), math.atan2(t[1, 0], t[0, 0])


@pytest.mark.parametrize("error", [(0.08, -0.05, math.radians(2.0)), (-0.1, 0.06, math.radians(-3.0))])
def test_a_known_odometry_error_is_recovered_and_the_frame_inserted_where_it_belongs(
    spec, views, error
) -> None:
    first, second = views
    p = _perception(spec, pose="matched")
    cam = Camera([first, second])
    p.take_depth(cam, Pose2D(0.0, 0.0, 0.0))
    # the chair has not moved, but the odometry says it moved by ``error``
    p.take_depth(cam, Pose2D(*error))
    p.flush()
    assert p.stats["matches_accepted"] == 1 and p.stats["matches_rejected"] == 1  # the first: empty map
    # the matched base pose (map -> odom x odometry) is the true one: 1 cm and 0.5 deg (the map's
    # cells are a 5 cm lattice; the matching test states the same heading tolerance)
    x, y, yaw = _planar(p.matcher.t_map_odom @ se3_planar(*error))
    assert math.hypot(x, y) < 0.01
    assert abs(yaw) < math.radians(0.5)
    # the matched map is sharper than the odometry map of the same two frames
    occ_matched = p.occupancy_2d(p.pose_maps["matched"]).sum()
    occ_odometry = p.occupancy_2d(p.pose_maps["odometry"]).sum()
    assert occ_matched < 0.8 * occ_odometry


def _floor(n: int = 20000) -> np.ndarray:
    rng = np.random.default_rng(1)
    return np.column_stack([rng.uniform(0.5, 4.0, (n, 2)), np.zeros(n)]).reshape(100, -1, 3)


@pytest.mark.parametrize(
    ("frame", "reason"),
    [
        (np.full((40, 50, 3), np.nan), "too few frame cells"),
        (np.empty((0, 0, 3)), "too few frame cells"),
        (_floor(), "too few frame cells"),
    ],
    ids=["all NaN", "empty", "featureless floor"],
)
def test_a_frame_with_nothing_to_match_falls_back_to_odometry_is_counted_and_leaves_the_map_alone(
    spec, views, frame, reason
) -> None:
    first, _ = views
    p = _perception(spec, pose="matched")
    cam = Camera([first, frame, first])
    p.take_depth(cam, Pose2D(0.0, 0.0, 0.0))
    p.take_depth(cam, Pose2D(0.3, -0.2, 0.1))
    p.flush()
    assert p.matcher.rejections == {"too few map cells": 1, reason: 1}
    assert p.stats["matches_rejected"] == 2
    np.testing.assert_array_equal(p.matcher.t_map_odom, np.eye(4))
    # the map is what odometry gives: the same structures as the odometry map of the same frames
    assert p.map.structures().equals(p.pose_maps["odometry"].structures())
    # and the next frame still matches
    p.take_depth(cam, Pose2D(0.0, 0.0, 0.0))
    p.flush()
    assert p.matcher.results[-1].accepted


def _wall(x: float, y0: float = -0.3, y1: float = 0.3, z0: float = 0.2, z1: float = 0.8) -> np.ndarray:
    y, z = np.meshgrid(np.arange(y0, y1, 0.004), np.arange(z0, z1, 0.004))
    return np.stack([np.full_like(y, x), y, z], axis=-1)


def test_the_zoom_follows_the_chair_fed_by_the_same_insert_and_answers_fine_inside_coarse_outside(
    spec,
) -> None:
    # with the thesis (VHV) map as the main map, the zoom shares it as its coarse level: one insert feeds both
    p = _perception(spec, zoom_half_width=1.0, zoom_factor=5, map_kind="thesis")
    assert p.zoom.coarse is p.map
    # the probabilistic main map is not a VHV map: the zoom keeps a coarse level of its own
    assert _perception(spec, zoom_half_width=1.0).zoom.coarse is not None
    front = p.corridor.front_x
    gap = 0.213  # from the footprint's front edge to the wall (at x = 0.793 m, inside the 1 m region)
    wall = np.concatenate([_wall(front + gap).reshape(-1, 3), _wall(3.0).reshape(-1, 3)]).reshape(1, -1, 3)
    cam = Camera([wall] * (SNAPSHOT_LAG + 1))
    pose = Pose2D(0.0, 0.0, 0.0)
    for _ in range(SNAPSHOT_LAG + 1):
        p.take_depth(cam, pose)
    p.flush()
    assert p.zoom.region is not None and p.zoom.in_region(0.0, 0.0)
    x_near, x_far = front + gap, 3.0
    # inside the region: 1 cm cells (the fine map), outside: the coarse map's 5 cm answer
    assert p.zoom.cell_size_at(x_near, 0.0) == pytest.approx(0.01)
    s_fine = p.zoom.structures_at(x_near + 0.001, 0.0)
    # 3 cm in front of the wall: an empty fine cell, but the same 5 cm coarse cell as the wall
    assert len(s_fine) == 1 and p.zoom.structures_at(x_near - 0.028, 0.0).top.size == 0
    assert p.map.structures_at(x_near - 0.028, 0.0).top.size == 1
    assert not p.zoom.in_region(x_far, 0.0)
    assert p.zoom.structures_at(x_far, 0.0).equals(p.map.structures_at(x_far, 0.0))
    # the safety corridor's map distance is answered at the fine resolution
    d = p.zoom_distance_m(pose)
    assert d is not None and abs(d - gap) <= 0.01
    assert p.depth_distance_m(pose) == pytest.approx(min(d, p.depth_distance_m(pose)))
    # the region moves with the chair
    far = Pose2D(2.5, 0.0, 0.0)
    p.take_depth(Camera([wall]), far)
    p.flush()
    assert p.zoom.in_region(2.5, 0.0) and not p.zoom.in_region(0.0, 0.0)


def test_unknown_pose_source_and_ground_truth_without_a_source_are_refused(spec) -> None:
    with pytest.raises(ConfigError, match="pose"):
        _perception(spec, pose="gps")
    with pytest.raises(ConfigError, match="ground-truth"):
        _perception(spec, pose="ground-truth")


def test_the_bag_of_a_run_has_map_odom_base_link(sim_run: Path) -> None:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    out = sim_run  # the shared `robchair sim` run on office_corridor (tests/robchair/conftest.py)
    store = get_typestore(Stores.ROS2_HUMBLE)
    pairs: set[tuple[str, str]] = set()
    with Reader(out / "bag") as reader:
        conns = [c for c in reader.connections if c.topic == "/tf"]
        for conn, _, raw in reader.messages(connections=conns):
            msg = store.deserialize_cdr(raw, conn.msgtype)
            pairs |= {(t.header.frame_id, t.child_frame_id) for t in msg.transforms}
    assert ("map", "odom") in pairs and ("odom", "base_link") in pairs
    # one tree: base_link's only parent is odom, odom's only parent is map
    parents = {c: p for p, c in pairs}
    assert parents["base_link"] == "odom" and parents["odom"] == "map" and "map" not in parents


def test_with_a_probabilistic_main_map_the_zoom_fine_level_is_what_a_zoom_map_of_its_own_makes(spec) -> None:
    """The main (probabilistic) map is the zoom's coarse level and only the fine level is fed beside it:
    the fine structures equal those of a ZoomMap fed the same placed frames through ``insert`` (its own
    coarse VHV level), with the region following the chair; outside the region the zoom answers with the
    main map's occupied structures."""
    from mapping.zoom import ZoomMap

    rng = np.random.default_rng(11)
    clouds = [render_scene(rng, 106, 128, nan_fraction=0.05, pitch_deg=5.0) for _ in range(4)]
    p = _perception(spec, zoom_half_width=2.5, zoom_factor=5)
    assert p.zoom.coarse is p.map
    own = ZoomMap(p.grid, p.tolerance, factor=5)
    poses = [Pose2D(0.06 * k, 0.01 * k, 0.02 * k) for k in range(4)]
    cam = Camera(clouds)
    for pose in poses:
        p.take_depth(cam, pose)
    p.flush()
    for cloud, pose in zip(clouds, poses, strict=True):
        t = se3_planar(pose.x, pose.y, pose.theta)
        own.follow(pose.x, pose.y, 2.5)
        pts = np.asarray(cloud, np.float32).reshape(-1, 3)
        from robchair.platform.frames import transform_points

        own.insert(transform_points(t, pts, np.float32), sensor_origin=t[:3, 3])
    assert len(own.fine.structures()) > 100
    assert p.zoom.fine.structures().equals(own.fine.structures())
    assert p.zoom.structures_at(-5.0, 0.0).equals(p.map.structures_at(-5.0, 0.0))


def test_the_maps_beside_the_main_one_on_their_own_thread_equal_the_serial_maps_bit_for_bit(spec) -> None:
    """Threaded, the odometry map (and a layer) take their inserts on a second mapping thread while the main
    map and the matching run on the first: every map's intervals equal the serial run's."""
    rng = np.random.default_rng(5)
    clouds = [render_scene(rng, 106, 128, nan_fraction=0.05, pitch_deg=5.0) for _ in range(6)]
    maps = []
    for threaded in (False, True):
        p = _perception(spec, pose="matched", threaded=threaded)
        layer = p.new_map()
        p.add_layer("ground_truth", layer, lambda: se3_planar(0.01, 0.0, 0.0))
        assert (p._layer_pool is not None) == threaded
        cam = Camera(clouds)
        for k in range(6):
            p.take_depth(cam, Pose2D(0.02 * k, 0.0, 0.01 * k))
        p.close()
        maps.append([p.pose_maps["matched"], p.pose_maps["odometry"], layer])
    for a, b in zip(*maps, strict=True):
        ia, ib = a.intervals(), b.intervals()
        assert len(ia.i) > 100
        for f in ("i", "j", "bottom", "top", "log_odds"):
            np.testing.assert_array_equal(getattr(ia, f), getattr(ib, f))
