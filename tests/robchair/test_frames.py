"""Tests of the one frames module against hand-computed rotations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from robchair.platform import frames

angles = st.floats(-math.pi, math.pi, allow_nan=False)


def test_yaw_of_a_quarter_turn_maps_x_onto_y() -> None:
    r = frames.rotation_rpy(0.0, 0.0, math.pi / 2)
    np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)


def test_positive_pitch_tilts_the_x_axis_down() -> None:
    r = frames.rotation_rpy(0.0, 0.3, 0.0)
    x = r @ [1.0, 0.0, 0.0]
    assert x[2] == pytest.approx(-math.sin(0.3))


def test_rpy_is_fixed_axis_roll_then_pitch_then_yaw() -> None:
    roll, pitch, yaw = 0.2, -0.4, 1.1
    cx, sx, cy, sy, cz, sz = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    np.testing.assert_allclose(frames.rotation_rpy(roll, pitch, yaw), rz @ ry @ rx, atol=1e-14)


@given(angles, st.floats(-1.5, 1.5), angles)
def test_rpy_round_trips_away_from_gimbal_lock(roll: float, pitch: float, yaw: float) -> None:
    got = frames.rpy_from_matrix(frames.rotation_rpy(roll, pitch, yaw))
    np.testing.assert_allclose(frames.rotation_rpy(*got), frames.rotation_rpy(roll, pitch, yaw), atol=1e-12)


def test_quaternion_is_ordered_x_y_z_w() -> None:
    q = frames.quat_from_yaw(math.pi / 2)
    assert q == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    assert frames.quat_from_matrix(frames.rotation_rpy(0, 0, math.pi / 2)) == pytest.approx(q)
    np.testing.assert_allclose(frames.matrix_from_quat(q), frames.rotation_rpy(0, 0, math.pi / 2), atol=1e-15)


def test_zero_quaternion_is_refused() -> None:
    with pytest.raises(ValueError, match="quaternion"):
        frames.matrix_from_quat((0, 0, 0, 0))


def test_planar_transform_moves_a_point_like_a_pose() -> None:
    t = frames.se3_planar(1.0, 2.0, math.pi / 2)
    np.testing.assert_allclose(frames.transform_points(t, [[1.0, 0.0, 0.5]]), [[1.0, 3.0, 0.5]], atol=1e-15)
    np.testing.assert_allclose(
        frames.transform_points(frames.se2(1.0, 2.0, math.pi / 2), [[1.0, 0.0]]), [[1.0, 3.0]], atol=1e-15
    )


@given(angles, angles, angles, st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5))
def test_inverse_undoes_a_transform(
    roll: float, pitch: float, yaw: float, x: float, y: float, z: float
) -> None:
    t = frames.se3_rpy((x, y, z), (roll, pitch, yaw))
    np.testing.assert_allclose(frames.invert(t) @ t, np.eye(4), atol=1e-12)


def test_se2_to_pose_wraps_the_heading() -> None:
    assert frames.se2_to_pose(frames.se2(0.0, 0.0, 3 * math.pi / 2))[2] == pytest.approx(-math.pi / 2)


def test_optical_frame_looks_along_the_link_x_axis() -> None:
    # the optical z axis (forward) is the link's x axis; optical x (right) is the link's -y
    np.testing.assert_allclose(frames.R_LINK_OPTICAL @ [0, 0, 1], [1, 0, 0])
    np.testing.assert_allclose(frames.R_LINK_OPTICAL @ [1, 0, 0], [0, -1, 0])
    assert frames.optical_frame("kinect") == "kinect_optical_frame"
    assert frames.link_frame("laser") == "laser_link"


def test_quaternion_of_rpy_matches_the_rotation_and_keeps_w_non_negative() -> None:
    # a half turn about z: (0, 0, 1, 0); 90 deg pitch: (0, sin 45, 0, cos 45)
    assert frames.quat_from_rpy(0.0, 0.0, math.pi) == pytest.approx((0.0, 0.0, 1.0, 0.0), abs=1e-12)
    h = math.sqrt(0.5)
    assert frames.quat_from_rpy(0.0, math.pi / 2, 0.0) == pytest.approx((0.0, h, 0.0, h))
    assert frames.quat_from_rpy(0.1, -0.2, 3.0)[3] >= 0.0


def test_yaw_of_a_quaternion_is_the_heading() -> None:
    assert frames.yaw_from_quat((0.0, 0.0, math.sin(0.35), math.cos(0.35))) == pytest.approx(0.7)
    assert frames.yaw_from_quat(frames.quat_from_rpy(0.05, -0.1, -2.0)) == pytest.approx(-2.0)


@given(q=st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: sum(c * c for c in q) > 1e-6))
def test_matrix_of_a_quaternion_agrees_with_scipy(q: tuple[float, float, float, float]) -> None:
    from scipy.spatial.transform import Rotation

    np.testing.assert_allclose(frames.matrix_from_quat(q), Rotation.from_quat(q).as_matrix(), atol=1e-12)


@given(roll=angles, pitch=angles, yaw=angles)
def test_rpy_matrix_and_quaternion_agree_with_scipy(roll: float, pitch: float, yaw: float) -> None:
    from scipy.spatial.transform import Rotation

    ref = Rotation.from_euler("xyz", [roll, pitch, yaw])
    np.testing.assert_allclose(frames.rotation_rpy(roll, pitch, yaw), ref.as_matrix(), atol=1e-12)
    q = np.array(frames.quat_from_rpy(roll, pitch, yaw))
    r = ref.as_quat()
    assert q[3] >= 0.0
    assert np.allclose(q, r, atol=1e-12) or np.allclose(q, -r, atol=1e-12)


def test_a_large_float32_cloud_is_placed_like_the_float64_product_and_keeps_its_nan_rows():
    from robchair.platform.frames import COMPILED_MIN_POINTS, transform_points

    rng = np.random.default_rng(5)
    pts = (rng.normal(size=(COMPILED_MIN_POINTS + 7, 3)) * 4).astype(np.float32)
    pts[::9] = np.nan
    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler("xyz", [0.1, -0.2, 1.3]).as_matrix()
    t[:3, 3] = [3.0, -1.5, 0.7]
    got = transform_points(t, pts, np.float32)
    want = pts.astype(np.float64) @ t[:3, :3].T + t[:3, 3]  # independent: float64 numpy
    assert got.dtype == np.float32 and got.shape == pts.shape
    assert np.array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    assert np.array_equal(got[ok], want.astype(np.float32)[ok])  # one rounding of the float64 result


def test_a_quarter_turn_about_z_maps_x_onto_y_and_y_onto_minus_x() -> None:
    """Hand computation: Rz(90 deg) = [[0, -1, 0], [1, 0, 0], [0, 0, 1]], whatever the axis length."""
    r = frames.rotation_axis_angle((0.0, 0.0, 2.5), math.pi / 2)
    np.testing.assert_allclose(r, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)


@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(-2 * math.pi, 2 * math.pi))
def test_axis_angle_rotation_is_scipys_rotation_vector(x: float, y: float, z: float, angle: float) -> None:
    """The closed form against scipy's ``Rotation.from_rotvec`` (an independent implementation)."""
    n = math.sqrt(x * x + y * y + z * z)
    assume(n > 1e-3)
    want = Rotation.from_rotvec(np.array([x, y, z]) / n * angle).as_matrix()
    np.testing.assert_allclose(frames.rotation_axis_angle((x, y, z), angle), want, atol=1e-14)


def test_a_zero_length_rotation_axis_is_refused() -> None:
    with pytest.raises(ValueError, match="zero length"):
        frames.rotation_axis_angle((0.0, 0.0, 0.0), 1.0)


def test_se3_takes_a_scipy_rotation_and_importing_frames_leaves_scipy_spatial_out() -> None:
    """``se3`` accepts a :class:`Rotation` without the module importing scipy.spatial at its top (each
    command that needs no Rotation would pay its import)."""
    import subprocess
    import sys

    r = Rotation.from_euler("z", 0.5)
    np.testing.assert_array_equal(frames.se3(r, (1, 2, 3))[:3, :3], r.as_matrix())
    code = "import sys, robchair.platform.frames; print('scipy.spatial' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
