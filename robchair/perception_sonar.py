"""Sonar intake of the perception stage: where a fused sonar echo may lie, and what known surfaces explain.

:func:`sonar_obstacle_points` turns one array reading into the arc (N, 2) in ``base_link`` where the
five-zone fusion (:mod:`mapping.sonar`, thesis 5.2) puts the obstacle; :func:`explained_arc` keeps the
part of that arc that known surfaces (laser returns, the zoom map's cells) locate.
:class:`robchair.perception.Perception` uses both for the sonar map and the sonar distance the safety
layer checks.

The perception stage runs these for every array reading (twice per agent step), on a handful of
values, so their cost is Python and numpy call overhead: :func:`fused_arc` and :func:`explained_arc_at`
are the same computations with fewer calls (the same numpy operations on the same values, so the same
results bit for bit), :class:`MountGeometry` keeps what does not change between readings of one mount.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from hw.interfaces import SonarArrayReading
from mapping.sonar import fuse_array, fusion_points, servo_command_deg  # noqa: F401  (perception's)
from robchair.perception_queries import Corridor
from robchair.platform.frames import rotation_rpy, se3_planar
from robchair.platform.spec import SonarArrays

#: Margin, m, of the compiled pre-filter of :func:`explained_arc_at` over the exact range test: far
#: above the rounding of either computation (1e-12 m at 100 m in float64, 1e-5 m in float32).
_PREFILTER_MARGIN_M = 1e-3


@functools.lru_cache(maxsize=4)
def _zone_tables(outer_sonar_deg: float) -> Any:
    from mapping.sonar import zone_tables

    return zone_tables(outer_sonar_deg)


_LAST_POSE: tuple[Any, Any] = (None, None)  # (pose, its se3_planar) of the last reading


def pose_transform(pose: Any) -> np.ndarray:
    """``se3_planar(pose.x, pose.y, pose.theta)`` (4, 4, read-only), kept for the last pose object: both
    sonar arrays of one cycle are placed at the same odometry pose (one tuple, read and swapped whole,
    so threads with other poses only recompute)."""
    global _LAST_POSE
    last = _LAST_POSE
    if last[0] is not pose:
        t = se3_planar(pose.x, pose.y, pose.theta)
        t.setflags(write=False)
        last = _LAST_POSE = (pose, t)
    return last[1]  # type: ignore[no-any-return]


def sonar_obstacle_points(
    reading: SonarArrayReading, mount: Any, arrays: SonarArrays, n_arc: int = 9, fusion: Any = None
) -> np.ndarray:
    """Points (N, 2) in ``base_link`` where the fused obstacle of one array reading may lie.

    Five-zone fusion (thesis 5.2) gives the distance ``d`` and the bearing interval holding the
    obstacle; the obstacle may be anywhere on that arc, so the arc is sampled (conservative). The
    outer sonars' angle and the servo's centre come from ``arrays`` (``spec.sonar_arrays``).
    ``fusion``: the reading's :func:`mapping.sonar.fuse_array` result when the caller has it already.
    """
    res = fusion
    if res is None:
        r1, r2, r3 = (float(r) if math.isfinite(r) else math.nan for r in reading.ranges_m)
        res = fuse_array(r1, r2, r3, tables=_zone_tables(arrays.outer_sonar_deg))
    if not res.has_obstacle:
        return np.zeros((0, 2))
    yaw0 = mount.rpy[2] + arrays.joint_angle(reading.servo_angle_deg)
    return fused_arc(res, mount.xyz[0], mount.xyz[1], yaw0, n_arc)


@functools.lru_cache(maxsize=16)
def _steps(n: int) -> np.ndarray:
    a = np.arange(0, n, dtype=np.float64)
    a.setflags(write=False)
    return a


def fused_arc(res: Any, x0: float, y0: float, yaw0: float, n_arc: int = 9) -> np.ndarray:
    """The arc (``n_arc``, 2) in ``base_link`` of a fusion with an obstacle (:func:`sonar_obstacle_points`).

    ``(x0, y0)`` m: the array's origin in ``base_link``; ``yaw0`` rad: its heading (mount yaw plus the
    servo's joint angle). The bearings are ``np.linspace(alpha, alpha + theta, n_arc)`` deg computed
    with linspace's own operations (``arange * step + start``, the end set to ``stop``), so every
    value is the one linspace gives, without its per-call overhead.
    """
    a, d = res.alpha_deg, res.distance_m
    stop = a + res.theta_deg
    div = n_arc - 1
    b = np.array(_steps(n_arc))
    if div > 0:
        delta = stop - a
        step = delta / div
        if step == 0:  # linspace's denormal branch
            b /= div
            b *= delta
        else:
            b *= step
    else:
        b *= stop - a
    b += a
    if n_arc > 1:
        b[-1] = stop
    np.radians(b, out=b)
    b += yaw0
    out = np.empty((n_arc, 2))
    x, y = np.cos(b), np.sin(b)
    x *= d
    y *= d
    x += x0
    y += y0
    out[:, 0] = x
    out[:, 1] = y
    return out


class MountGeometry:
    """What one sonar array's mount gives every reading: its origin and ``T_base_array(joint)``.

    ``mount.transform(joint)`` recomputes the mount's fixed rotation and the joint's axis for every
    reading (the servo's measured angle differs in every reading); this keeps them and repeats the
    same operations for the joint's rotation (:func:`robchair.platform.frames.rotation_axis_angle`)
    and the product, so the transform is the same (4, 4) array bit for bit.
    """

    def __init__(self, mount: Any) -> None:
        self.mount = mount
        self.x0, self.y0 = float(mount.xyz[0]), float(mount.xyz[1])
        self.yaw = mount.rpy[2]
        self._r0 = rotation_rpy(*mount.rpy)
        self._eye = np.eye(4)  # with the mount's translation
        self._eye[:3, 3] = np.asarray(mount.xyz, dtype=float)
        self._axis: tuple[float, float, float, float] | None = None
        if mount.joint is not None:
            x, y, z = (float(v) for v in np.asarray(mount.joint.axis, dtype=float).ravel())
            n = math.sqrt(x * x + y * y + z * z)
            self._axis = (x, y, z, n) if n != 0.0 else None

    def t_base_array(self, joint: float) -> np.ndarray:
        """``mount.transform(joint)`` (4, 4): ``T_base_array`` with the servo at ``joint`` rad.

        Raises:
            ConfigError, ValueError: as ``mount.transform`` (a joint angle without a joint, a zero axis).
        """
        if joint == 0.0 or self._axis is None:
            return self.mount.transform(joint)  # type: ignore[no-any-return]
        x, y, z, n = self._axis
        h = 0.5 * float(joint)
        s = math.sin(h) / n
        qx, qy, qz, qw = x * s, y * s, z * s, math.cos(h)
        ra = np.array(
            (
                1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw),
                2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw),
                2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy),
            )
        ).reshape(3, 3)  # fmt: skip
        t = self._eye.copy()
        t[:3, :3] = self._r0 @ ra
        return t


_GEOMETRY: dict[int, MountGeometry] = {}  # by id(mount); each holds its mount, so the id stays its own


def mount_geometry(mount: Any) -> MountGeometry:
    """The :class:`MountGeometry` of a mount, built once per mount object (no hashing of the mount)."""
    geo = _GEOMETRY.get(id(mount))
    if geo is None or geo.mount is not mount:
        if len(_GEOMETRY) >= 256:
            _GEOMETRY.clear()
        geo = _GEOMETRY[id(mount)] = MountGeometry(mount)
    return geo


def explained_arc(arc: np.ndarray, origin: Any, scan_xy: np.ndarray | None, tol: float = 0.06) -> np.ndarray:
    """The part of a fused sonar arc (N, 2) that known surface points ``scan_xy`` (M, 2) explain, else all.

    All in ``base_link``. The echo comes from the nearest surface in the cone: known points (laser
    returns, the zoom map's cells) at the arc's range (within ``tol`` m) from the sonar ``origin``
    (x, y) and inside its bearing interval locate that surface (e.g. a door post beside the chair's
    path); without such points (a table top above the scan plane and not mapped) the whole arc stays.
    """
    if scan_xy is None or len(scan_xy) == 0 or len(arc) < 2:
        return arc
    o = np.asarray(origin, dtype=float)[:2]
    d = float(np.hypot(*(arc[0] - o)))
    b = np.arctan2(arc[:, 1] - o[1], arc[:, 0] - o[0])
    mid = b[len(b) // 2]
    rel = np.angle(np.exp(1j * (b - mid)))
    q = scan_xy - o
    at_range = np.flatnonzero(np.abs(np.hypot(q[:, 0], q[:, 1]) - d) <= tol)  # bearings of these only
    qb = np.angle(np.exp(1j * (np.arctan2(q[at_range, 1], q[at_range, 0]) - mid)))
    near = at_range[(qb >= rel.min()) & (qb <= rel.max())]
    return scan_xy[near] if len(near) else arc


def explained_arc_at(
    arc: np.ndarray,
    origin: Any,
    pose: Any,
    scan_world: np.ndarray | None,
    zoom_xy: tuple[np.ndarray, Any] | None,
    tol: float = 0.06,
) -> np.ndarray:
    """:func:`explained_arc` of ``arc`` against the known surfaces at odometry ``pose``, bit for bit.

    The known surfaces around the chair that may explain the echo: the last laser scan's returns in the
    band ``scan_world`` (M, 2) in ``odom``, and the zoom's fine cells in the band ``zoom_xy`` = ((K, 2)
    in ``base_link`` at pose ``p0``, ``p0``: the map remembers a door post the camera saw on the way
    in and no longer sees beside the chair), each moved to ``base_link`` at ``pose``. Only the points
    a compiled pass finds near the arc's range (with :data:`_PREFILTER_MARGIN_M` to spare) are moved,
    with the same numpy operations; the exact test then runs on those, so the answer is
    ``explained_arc(arc, origin, known)`` on all of them (None of both: the arc itself). All m, rad.
    """
    if (scan_world is None and zoom_xy is None) or len(arc) < 2:
        return arc
    from robchair._sonar_kernels import near_range

    o = np.asarray(origin, dtype=float)[:2]
    d = float(np.hypot(*(arc[0] - o)))
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    band = tol + _PREFILTER_MARGIN_M
    parts = []
    if scan_world is not None and len(scan_world):
        # base = R(-theta) (p - pose), less the sonar's origin
        tx = -(c * pose.x + s * pose.y) - o[0]
        ty = -(c * pose.y - s * pose.x) - o[1]
        idx = near_range(scan_world, c, s, -s, c, tx, ty, d, band)
        if len(idx):
            q = scan_world[idx] - (pose.x, pose.y)
            parts.append(np.stack([c * q[:, 0] + s * q[:, 1], c * q[:, 1] - s * q[:, 0]], 1))
    if zoom_xy is not None and len(zoom_xy[0]):
        xy, p0 = zoom_xy
        c0, s0 = math.cos(p0.theta), math.sin(p0.theta)
        dx, dy = p0.x - pose.x, p0.y - pose.y  # R(-theta) (R(theta0) p + (p0 - pose)), less the origin
        idx = near_range(
            xy, c * c0 + s * s0, s * c0 - c * s0, c * s0 - s * c0, s * s0 + c * c0,
            c * dx + s * dy - o[0], c * dy - s * dx - o[1], d, band,
        )  # fmt: skip
        if len(idx):
            xs, ys = xy[idx, 0], xy[idx, 1]
            qx = c0 * xs - s0 * ys + (p0.x - pose.x)  # base at p0 -> odom, less the pose
            qy = s0 * xs + c0 * ys + (p0.y - pose.y)
            parts.append(np.stack([c * qx + s * qy, c * qy - s * qx], 1))
    if not parts:
        return arc
    known = parts[0] if len(parts) == 1 else np.concatenate(parts)
    b = np.arctan2(arc[:, 1] - o[1], arc[:, 0] - o[0])
    mid = b[len(b) // 2]
    rel = np.angle(np.exp(1j * (b - mid)))
    q = known - o
    at_range = np.flatnonzero(np.abs(np.hypot(q[:, 0], q[:, 1]) - d) <= tol)
    if not len(at_range):
        return arc
    qb = np.angle(np.exp(1j * (np.arctan2(q[at_range, 1], q[at_range, 0]) - mid)))
    near = at_range[(qb >= rel.min()) & (qb <= rel.max())]
    return known[near] if len(near) else arc


_NO_POINTS = np.zeros((0, 2))  # the kernel's "no such points" (never written)
_sonar_arc: Any = None  # robchair._sonar_kernels.sonar_arc once loaded


def explained_arc_fast(
    res: Any,
    geo: MountGeometry,
    joint: float,
    pose: Any,
    scan_world: np.ndarray | None,
    zoom_xy: tuple[np.ndarray, Any] | None,
    corridor: Any,
) -> tuple[np.ndarray, float | None]:
    """The explained arc of a fusion with an obstacle and its distance ahead, in one compiled call.

    ``explained_arc_at(fused_arc(res, geo.x0, geo.y0, geo.yaw + joint), (geo.x0, geo.y0), pose,
    scan_world, zoom_xy)`` and ``corridor.distance_ahead`` of it, bit for bit
    (:func:`robchair._sonar_kernels.sonar_arc`), for float64 known points and a
    :class:`robchair.perception_queries.Corridor`; other inputs take those numpy functions.

    Returns:
        (arc (N, 2) in ``base_link`` m, distance from the corridor's front edge m or None).
    """
    global _sonar_arc
    if _sonar_arc is None:  # numba and the kernels load at the first reading with an echo
        from robchair._sonar_kernels import sonar_arc as _sonar_arc
    scan = _NO_POINTS if scan_world is None else scan_world
    zoom, p0 = (_NO_POINTS, pose) if zoom_xy is None else zoom_xy
    if scan.dtype != np.float64 or zoom.dtype != np.float64 or type(corridor) is not Corridor:
        arc = fused_arc(res, geo.x0, geo.y0, geo.yaw + joint)
        arc = explained_arc_at(arc, (geo.x0, geo.y0), pose, scan_world, zoom_xy)
        return arc, corridor.distance_ahead(arc)
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    beside = corridor.half_width if corridor.body_half_width is None else corridor.body_half_width
    prm = np.array(
        (
            res.alpha_deg, res.theta_deg, res.distance_m, geo.x0, geo.y0, geo.yaw + joint, geo.x0, geo.y0,
            pose.x, pose.y, c, s, math.cos(p0.theta), math.sin(p0.theta), p0.x - pose.x, p0.y - pose.y,
            0.06, corridor.front_x, corridor.half_width, beside,
        )
    )  # fmt: skip
    arc, x_min = _sonar_arc(prm, 9, scan, zoom)
    return arc, (None if math.isnan(x_min) else max(0.0, x_min - corridor.front_x))


def load_sonar_kernels(scratch: Any) -> None:
    """Load the sonar path's compiled kernels for the argument types of a run (compiled on a cold cache).

    The arc kernel with laser returns, and the small-cloud insert of ``scratch`` (a map with
    ``insert_few``; it gets two points) before and after its structures were read (then its arrays
    are read-only, another numba signature): called by the perception stage's warm-up, before the
    clock starts.
    """
    global _sonar_arc
    if _sonar_arc is None:
        from robchair._sonar_kernels import sonar_arc as _sonar_arc
    _sonar_arc(np.zeros(20), 9, np.zeros((1, 2)), _NO_POINTS)
    insert_few = getattr(scratch, "insert_few", None)
    if insert_few is not None:
        insert_few(np.array([[0.5, 0.0, 0.3]]), np.zeros(3))
        scratch.structures()
        insert_few(np.array([[0.5, 0.0, 0.5]]), np.zeros(3))
