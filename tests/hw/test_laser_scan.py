"""LaserScan conversions: points in the sensor frame and sensor_msgs/LaserScan through rosbags."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hw.interfaces import LaserScan
from hw.laser_scan import LASER_SCAN_MSGTYPE, from_ros_laser_scan, scan_to_points, to_ros_laser_scan


def _scan() -> LaserScan:
    inc = math.pi / 2
    return LaserScan(
        stamp_ns=3_000_000_007,
        angle_min=-math.pi / 2,
        angle_max=math.pi,
        angle_increment=inc,
        time_increment=0.001,
        scan_time=0.1,
        range_min=0.02,
        range_max=4.0,
        # right 1 m, ahead 2 m, left: no return, behind: invalid; (REP-117)
        ranges=np.array([1.0, 2.0, np.inf, np.nan], dtype=np.float32),
    )


def test_points_lie_where_the_beams_end_in_rep103():
    pts = scan_to_points(_scan())
    np.testing.assert_allclose(pts, [[0.0, -1.0, 0.0], [2.0, 0.0, 0.0]], atol=1e-12)


def test_points_keep_one_row_per_beam_on_request():
    pts = scan_to_points(_scan(), keep_invalid=True)
    assert pts.shape == (4, 3)
    assert np.isnan(pts[2:]).all() and np.isfinite(pts[:2]).all()


def test_out_of_range_values_are_not_points():
    s = _scan()
    s2 = LaserScan(**{**s.__dict__, "ranges": np.array([0.01, 4.5, -np.inf, 3.0], dtype=np.float32)})
    pts = scan_to_points(s2)
    np.testing.assert_allclose(pts, [[-3.0, 0.0, 0.0]], atol=1e-6)


@pytest.mark.parametrize("ros2", [True, False])
def test_ros_message_round_trips_through_cdr_serialization(ros2):
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    msg = to_ros_laser_scan(_scan(), ros2=ros2)
    if ros2:
        raw = store.serialize_cdr(msg, LASER_SCAN_MSGTYPE)
        back_msg = store.deserialize_cdr(raw, LASER_SCAN_MSGTYPE)
    else:
        raw = store.serialize_ros1(msg, LASER_SCAN_MSGTYPE)
        back_msg = store.deserialize_ros1(raw, LASER_SCAN_MSGTYPE)
    back = from_ros_laser_scan(back_msg)
    s = _scan()
    assert back.stamp_ns == s.stamp_ns and back.frame_id == "laser_link"
    assert back.angle_increment == pytest.approx(s.angle_increment)
    assert back.ranges.dtype == np.float32
    np.testing.assert_array_equal(back.ranges, s.ranges)  # inf and NaN survive
    assert back.intensities is None


def test_points_of_a_scan_geometry_reuse_its_beam_trig_and_equal_the_angles_formula_bit_for_bit():
    """scan_to_points computes the cosines and sines of a scan geometry once (hw.laser_scan.beam_trig)
    and gives the points of the per-scan formula over LaserScan.angles(), bit for bit."""
    from hw.laser_scan import beam_trig

    rng = np.random.default_rng(2)
    n, inc = 682, 2 * np.pi / 1024
    beam_trig.cache_clear()
    for _ in range(5):
        r = rng.uniform(0.0, 4.5, n).astype(np.float32)
        r[rng.random(n) < 0.1] = np.inf
        s = LaserScan(stamp_ns=0, angle_min=-(n - 1) / 2 * inc, angle_max=(n - 1) / 2 * inc,
                      angle_increment=inc, time_increment=0.0, scan_time=0.1, range_min=0.02,
                      range_max=4.0, ranges=r)  # fmt: skip
        a, rr = s.angles(), r.astype(np.float64)
        with np.errstate(invalid="ignore"):
            ref = np.stack([rr * np.cos(a), rr * np.sin(a), np.zeros_like(a)], axis=-1)
        ok = (r >= 0.02) & (r <= 4.0)
        np.testing.assert_array_equal(scan_to_points(s, keep_invalid=True)[ok], ref[ok])
        np.testing.assert_array_equal(scan_to_points(s), ref[ok])
    assert beam_trig.cache_info().misses == 1
