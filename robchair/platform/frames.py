"""Poses and rotations for the whole project: SE(2)/SE(3) on :class:`scipy.spatial.transform.Rotation`.

Conventions (ROS REP-103 / REP-105):

- axes x forward, y left, z up; angles in radians, counter-clockwise positive;
- roll-pitch-yaw are *fixed-axis* (URDF): ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``;
- quaternions are ordered ``(x, y, z, w)`` as in ``geometry_msgs/Quaternion`` (and PyBullet);
- a transform ``T_a_b`` (4, 4) maps points from frame ``b`` into frame ``a``:
  ``p_a = T_a_b @ p_b``; chains read left to right, ``T_map_sensor = T_map_base @ T_base_sensor``;
- frame names: ``map``, ``odom``, ``base_link``, ``<sensor>_link`` and ``<sensor>_optical_frame`` (z forward,
  x right, y down) for cameras.

Every other module builds rotations and poses through these functions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

# scipy's Rotation is imported where it is used: importing scipy.spatial costs every process that
# needs a transform (each command, test worker and Ray worker) about half a second, and the hot paths
# here use closed forms

FloatArray = npt.NDArray[np.float64]

MAP = "map"
ODOM = "odom"
BASE_LINK = "base_link"

# Rotation of a camera's optical frame (z forward, x right, y down) in its body frame (x forward, z up).
R_LINK_OPTICAL: FloatArray = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def link_frame(sensor: str) -> str:
    """REP-105 name of a sensor's body frame, e.g. ``"kinect"`` -> ``"kinect_link"``."""
    return f"{sensor}_link"


def optical_frame(sensor: str) -> str:
    """REP-105 name of a camera's optical frame (z forward), e.g. ``"kinect_optical_frame"``."""
    return f"{sensor}_optical_frame"


def wrap_angle(theta: float) -> float:
    """Wrap an angle in rad to (-pi, pi]."""
    w = math.remainder(float(theta), 2.0 * math.pi)
    return math.pi if w == -math.pi else w


def rotation_rpy(roll: float, pitch: float, yaw: float) -> FloatArray:
    """Rotation matrix (3, 3) of fixed-axis roll, pitch, yaw in rad (URDF: ``Rz(yaw) Ry(pitch) Rx(roll)``)."""
    # closed form of Rotation.from_euler("xyz", ...).as_matrix() (tested against it), ~20x cheaper
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rpy_from_matrix(r: Any) -> tuple[float, float, float]:
    """Fixed-axis (roll, pitch, yaw) in rad of a rotation matrix (3, 3); inverse of :func:`rotation_rpy`."""
    from scipy.spatial.transform import Rotation

    roll, pitch, yaw = Rotation.from_matrix(np.asarray(r, dtype=float)).as_euler("xyz")
    return float(roll), float(pitch), float(yaw)


def rotation_axis_angle(axis: npt.ArrayLike, angle: float) -> FloatArray:
    """Rotation matrix (3, 3) of ``angle`` rad about ``axis`` (any non-zero length).

    Raises:
        ValueError: if ``axis`` has zero length.
    """
    x, y, z = (float(v) for v in np.asarray(axis, dtype=float).ravel())
    n = math.sqrt(x * x + y * y + z * z)
    if n == 0.0:
        raise ValueError(f"rotation axis {(x, y, z)} has zero length")
    # closed form of Rotation.from_rotvec(axis / n * angle).as_matrix() (tested against it): the unit
    # quaternion (sin(angle / 2) axis / n, cos(angle / 2)) to a matrix, ~50x cheaper than scipy
    h = 0.5 * float(angle)
    s = math.sin(h) / n
    qx, qy, qz, qw = x * s, y * s, z * s, math.cos(h)
    return np.array(
        [
            [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
            [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
            [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
        ]
    )


def quat_from_matrix(r: Any) -> tuple[float, float, float, float]:
    """Unit quaternion ``(x, y, z, w)`` of a rotation matrix (3, 3), with ``w >= 0``."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(r, dtype=float)[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return float(q[0]), float(q[1]), float(q[2]), float(q[3])


def matrix_from_quat(q: npt.ArrayLike) -> FloatArray:
    """Rotation matrix (3, 3) of a quaternion ``(x, y, z, w)`` (normalised first).

    Raises:
        ValueError: if the quaternion has zero length.
    """
    qa = np.asarray(q, dtype=float)
    if qa.shape != (4,):
        raise ValueError(f"quaternion {tuple(qa.ravel())} is not a non-zero (x, y, z, w)")
    x, y, z, w = (float(c) for c in qa)
    n = x * x + y * y + z * z + w * w
    if not n >= 1e-24:
        raise ValueError(f"quaternion {tuple(qa.ravel())} is not a non-zero (x, y, z, w)")
    # The closed form of Rotation.from_quat(q).as_matrix() (a test checks they agree): one rotation
    # through scipy costs about ten times more, and simulated sensors convert every moving link's
    # pose for every frame.
    s = 2.0 / n
    return np.array(
        [
            [1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y)],
        ]
    )


def quat_from_yaw(yaw: float) -> tuple[float, float, float, float]:
    """Quaternion ``(x, y, z, w)`` of a rotation by ``yaw`` rad about z (a planar heading)."""
    half = 0.5 * float(yaw)
    return 0.0, 0.0, math.sin(half), math.cos(half)


def quat_from_rpy(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Quaternion ``(x, y, z, w)`` of fixed-axis roll, pitch, yaw in rad, with ``w >= 0``."""
    # closed form of Rotation.from_euler("xyz", ...).as_quat() (tested against it), ~20x cheaper
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    q = (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )
    return q if q[3] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


def yaw_from_quat(q: npt.ArrayLike) -> float:
    """Heading in rad (about z) of a quaternion ``(x, y, z, w)``; the z-y-x Euler yaw.

    Raises:
        ValueError: if the quaternion has zero length.
    """
    return yaw_from_matrix(matrix_from_quat(q))


def yaw_from_matrix(r: Any) -> float:
    """Heading in rad (about z) of a rotation or transform matrix; the z-y-x Euler yaw."""
    m = np.asarray(r, dtype=float)
    return math.atan2(m[1, 0], m[0, 0])


def se3(rotation: Any = None, translation: npt.ArrayLike = (0.0, 0.0, 0.0)) -> FloatArray:
    """Homogeneous transform (4, 4) from a rotation ((3, 3) or :class:`Rotation`) and a translation, m."""
    t = np.eye(4)
    if rotation is not None:
        t[:3, :3] = (
            rotation.as_matrix() if hasattr(rotation, "as_matrix") else np.asarray(rotation, dtype=float)
        )
    t[:3, 3] = np.asarray(translation, dtype=float)
    return t


def se3_rpy(xyz: npt.ArrayLike, rpy: Sequence[float]) -> FloatArray:
    """Homogeneous transform (4, 4) of a URDF origin: translation ``xyz`` (m) and fixed-axis ``rpy`` (rad)."""
    return se3(rotation_rpy(*rpy), xyz)


def se3_from_quat(translation: npt.ArrayLike, quat_xyzw: npt.ArrayLike) -> FloatArray:
    """Homogeneous transform (4, 4) of a position (m) and quaternion ``(x, y, z, w)``."""
    return se3(matrix_from_quat(quat_xyzw), translation)


def se3_planar(x: float, y: float, yaw: float, z: float = 0.0) -> FloatArray:
    """Homogeneous transform (4, 4) of a planar pose: position (x, y, z) in m and heading ``yaw`` in rad."""
    c, s = math.cos(yaw), math.sin(yaw)
    t = np.eye(4)
    t[0, 0], t[0, 1], t[1, 0], t[1, 1] = c, -s, s, c
    t[0, 3], t[1, 3], t[2, 3] = x, y, z
    return t


def se2(x: float, y: float, yaw: float) -> FloatArray:
    """Homogeneous 2D transform (3, 3) of a planar pose (m, m, rad)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def se2_to_pose(t: Any) -> tuple[float, float, float]:
    """(x, y, yaw) of a 2D (3, 3) or 3D (4, 4) transform; yaw wrapped to (-pi, pi]."""
    m = np.asarray(t, dtype=float)
    n = m.shape[0] - 1
    return float(m[0, n]), float(m[1, n]), wrap_angle(math.atan2(m[1, 0], m[0, 0]))


def invert(t: Any) -> FloatArray:
    """Inverse of a rigid transform (2D (3, 3) or 3D (4, 4)) without a general matrix inverse."""
    m = np.asarray(t, dtype=float)
    n = m.shape[0] - 1
    out = np.eye(n + 1)
    r = m[:n, :n]
    out[:n, :n] = r.T
    out[:n, n] = -r.T @ m[:n, n]
    return out


COMPILED_MIN_POINTS = 4096
"""float32 clouds of at least this many (N, 3) points go through one compiled pass (float64 sums)."""


def transform_points(t: Any, points: Any, dtype: Any = np.float64) -> Any:
    """Apply a rigid transform to points.

    Args:
        t: (4, 4) transform for 3D points, or (3, 3) for 2D points.
        points: (..., 3) or (..., 2) array; NaN rows stay NaN.
        dtype: output type, and arithmetic type except for large float32 clouds (``np.float32`` keeps
            sensor clouds single precision; from :data:`COMPILED_MIN_POINTS` points a compiled pass sums
            in float64 and rounds once).

    Returns:
        Array of the same shape as ``points``, of ``dtype``.
    """
    if np.dtype(dtype) == np.float32 and np.shape(t) == (4, 4):
        p32 = np.asarray(points, dtype=np.float32)
        if p32.ndim == 2 and p32.shape[1] == 3 and len(p32) >= COMPILED_MIN_POINTS:
            from robchair.platform._frames_kernels import transform_points_f32

            return transform_points_f32(np.ascontiguousarray(t, dtype=np.float64), np.ascontiguousarray(p32))
    m = np.asarray(t, dtype=dtype)
    p = np.asarray(points, dtype=dtype)
    n = m.shape[0] - 1
    if p.shape[-1] != n:
        raise ValueError(f"points of shape {p.shape} do not match a {m.shape} transform")
    return p @ m[:n, :n].T + m[:n, n]


def transform_pose2d(t_a_b: Any, x: float, y: float, yaw: float) -> tuple[float, float, float]:
    """Express a planar pose given in frame ``b`` in frame ``a`` (``T_a_b`` (3, 3) or (4, 4))."""
    m = np.asarray(t_a_b, dtype=float)
    m2 = (
        m
        if m.shape == (3, 3)
        else np.array([[m[0, 0], m[0, 1], m[0, 3]], [m[1, 0], m[1, 1], m[1, 3]], [0, 0, 1]])
    )
    return se2_to_pose(m2 @ se2(x, y, yaw))
