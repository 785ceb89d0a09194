"""The sonar intake of the perception stage as it was before the fast path (session 11), kept verbatim.

:func:`add_sonar_reference` is the old :meth:`robchair.perception.Perception.add_sonar` (with its
``_known_surfaces``, ``_t_base_array``, ``sonar_obstacle_points``, ``explained_arc`` and the numpy
five-zone fusion): :mod:`tests.robchair.test_sonar_fast_path` drives it and the fast path side by side
and asks for the same outputs, maps and stats bit for bit.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from mapping.errors import SonarModelError
from mapping.sonar import (
    _ZONE_OF_AGREEMENT,
    MODEL_MAX_RANGE_CM,
    FusionResult,
    ZoneTables,
    _hull,
    default_zone_tables,
    fusion_points,
    servo_command_deg,
    sonar_intervals_deg,
)
from robchair.perception_sonar import _zone_tables
from robchair.platform.frames import se3_planar, transform_points

SONAR_FREE_RANGE_M = 1.0


def _three(flags: Any) -> tuple[bool, bool, bool]:
    a, b, c = flags
    return bool(a), bool(b), bool(c)


def fuse_array_reference(
    r1_m: float, r2_m: float, r3_m: float, threshold_m: float = 0.03, tables: ZoneTables | None = None
) -> FusionResult:
    """The five-zone fusion as it was (generators over the three readings)."""
    if not (math.isfinite(threshold_m) and threshold_m >= 0.0):
        raise SonarModelError(f"threshold_m={threshold_m!r} must be a finite value >= 0")
    tables = default_zone_tables() if tables is None else tables
    r = (float(r1_m), float(r2_m), float(r3_m))
    for k, v in enumerate(r, start=1):
        if v < 0.0 or v == -math.inf:
            raise SonarModelError(f"r{k}_m={v!r} is negative: a range reading must be >= 0 or NaN")
    mis = _three(not math.isfinite(v) or v == 0.0 for v in r)
    rej = _three(not m and v > MODEL_MAX_RANGE_CM / 100.0 for v, m in zip(r, mis, strict=True))
    valid = _three(not m and not j for m, j in zip(mis, rej, strict=True))
    if not any(valid):
        return FusionResult(None, math.nan, 0.0, 0.0, (False, False, False), rej, mis, consistent=False)
    d = min(v for v, ok in zip(r, valid, strict=True) if ok)
    key = _three(ok and abs(v - d) <= threshold_m + 1e-9 for v, ok in zip(r, valid, strict=True))
    zone = _ZONE_OF_AGREEMENT.get(key)
    if zone is not None:
        alpha, theta = tables.lookup(zone, d)
        if theta > 0.0:
            return FusionResult(zone, d, alpha, theta, key, rej, mis, consistent=True)
    alpha, theta = _hull(sonar_intervals_deg(d * 100.0, tables.outer_deg)[np.array(key)])
    return FusionResult(zone, d, alpha, theta, key, rej, mis, consistent=False)


def array_points_reference(
    ranges_m: Any, threshold_m: float = 0.03, ppc: int = 40, tables: Any = None
) -> Any:
    r1, r2, r3 = (float(v) for v in ranges_m)
    res = fuse_array_reference(r1, r2, r3, threshold_m, tables)
    return res, fusion_points(res, ppc)


def sonar_obstacle_points_reference(
    reading: Any, mount: Any, arrays: Any, n_arc: int = 9, fusion: Any = None
) -> Any:
    res = fusion
    if res is None:
        r1, r2, r3 = (float(r) if math.isfinite(r) else math.nan for r in reading.ranges_m)
        res = fuse_array_reference(r1, r2, r3, tables=_zone_tables(arrays.outer_sonar_deg))
    if not res.has_obstacle:
        return np.zeros((0, 2))
    yaw0 = mount.rpy[2] + arrays.joint_angle(reading.servo_angle_deg)
    bearings = np.radians(np.linspace(res.alpha_deg, res.alpha_deg + res.theta_deg, n_arc)) + yaw0
    x0, y0 = mount.xyz[0], mount.xyz[1]
    return np.stack([x0 + res.distance_m * np.cos(bearings), y0 + res.distance_m * np.sin(bearings)], axis=1)


def explained_arc_reference(
    arc: np.ndarray, origin: Any, scan_xy: np.ndarray | None, tol: float = 0.06
) -> Any:
    if scan_xy is None or len(scan_xy) == 0 or len(arc) < 2:
        return arc
    o = np.asarray(origin, dtype=float)[:2]
    d = float(np.hypot(*(arc[0] - o)))
    b = np.arctan2(arc[:, 1] - o[1], arc[:, 0] - o[0])
    mid = b[len(b) // 2]
    rel = np.angle(np.exp(1j * (b - mid)))
    q = scan_xy - o
    at_range = np.flatnonzero(np.abs(np.hypot(q[:, 0], q[:, 1]) - d) <= tol)
    qb = np.angle(np.exp(1j * (np.arctan2(q[at_range, 1], q[at_range, 0]) - mid)))
    near = at_range[(qb >= rel.min()) & (qb <= rel.max())]
    return scan_xy[near] if len(near) else arc


def known_surfaces_reference(p: Any, pose: Any) -> Any:
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    parts = []
    if p._scan_world is not None:
        q = p._scan_world - (pose.x, pose.y)
        parts.append(np.stack([c * q[:, 0] + s * q[:, 1], c * q[:, 1] - s * q[:, 0]], 1))
    if p._zoom_xy is not None:
        xy, p0 = p._zoom_xy
        c0, s0 = math.cos(p0.theta), math.sin(p0.theta)
        qx = c0 * xy[:, 0] - s0 * xy[:, 1] + (p0.x - pose.x)
        qy = s0 * xy[:, 0] + c0 * xy[:, 1] + (p0.y - pose.y)
        parts.append(np.stack([c * qx + s * qy, c * qy - s * qx], 1))
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def add_sonar_reference(p: Any, name: str, reading: Any, pose: Any) -> float | None:
    """The old ``Perception.add_sonar`` on perception stage ``p`` (its maps, state and stats)."""
    mount = p.spec.mounts.get(name)
    p.stats["sonar_readings"] += 1
    if mount is None:
        p._sonar[name] = None
        p._sonar_arc.pop(name, None)
        return None
    ranges = tuple(float(r) if math.isfinite(r) else math.nan for r in reading.ranges_m)
    arrays = p.spec.sonar_arrays
    fusion, pts = array_points_reference(ranges, tables=_zone_tables(arrays.outer_sonar_deg))
    arc = sonar_obstacle_points_reference(reading, mount, arrays, fusion=fusion)
    if len(arc):
        known = known_surfaces_reference(p, pose)
        if known is not None:
            arc = explained_arc_reference(arc, mount.xyz, known)
    p._sonar[name] = p.corridor.distance_ahead(arc) if len(arc) else None
    if len(arc):
        p._sonar_arc[name] = (np.asarray(arc, dtype=float)[:, :2], pose)
    else:
        p._sonar_arc.pop(name, None)
    if fusion.has_obstacle:
        p.stats["sonar_fusions_with_obstacle"] += 1
    joint = arrays.joint_angle(reading.servo_angle_deg)
    insert_sonar = getattr(p.sonar_map, "insert_sonar", None)
    t0 = time.perf_counter()
    if insert_sonar is not None:
        t = se3_planar(pose.x, pose.y, pose.theta) @ mount.transform(joint)
        insert_sonar(fusion, t, max_range_m=SONAR_FREE_RANGE_M)
        p.stats["sonar_points"] += len(pts)
    elif len(pts):
        t = se3_planar(pose.x, pose.y, pose.theta) @ mount.transform(joint)
        p.sonar_map.insert(transform_points(t, pts), sensor_origin=t[:3, 3])
        p.stats["sonar_points"] += len(pts)
    with p._lock:
        p.layer_s["sonar"] = p.layer_s.get("sonar", 0.0) + time.perf_counter() - t0
    if mount.joint is None:
        return None
    cmd = servo_command_deg(fusion, p._servo.get(name, reading.servo_angle_deg), gain=0.5, max_step_deg=15.0)
    p._servo[name] = cmd
    return float(cmd)
