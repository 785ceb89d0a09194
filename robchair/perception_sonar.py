"""Sonar intake of the perception stage: where a fused sonar echo may lie, and what known surfaces explain.

:func:`sonar_obstacle_points` turns one array reading into the arc (N, 2) in ``base_link`` where the
five-zone fusion (:mod:`mapping.sonar`, thesis 5.2) puts the obstacle; :func:`explained_arc` keeps the
part of that arc that known surfaces (laser returns, the zoom map's cells) locate.
:class:`robchair.perception.Perception` uses both for the sonar map and the sonar distance the safety
layer checks.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from hw.interfaces import SonarArrayReading
from robchair.platform.spec import SonarArrays


@functools.lru_cache(maxsize=4)
def _zone_tables(outer_sonar_deg: float) -> Any:
    from mapping.sonar import zone_tables

    return zone_tables(outer_sonar_deg)


def sonar_obstacle_points(
    reading: SonarArrayReading, mount: Any, arrays: SonarArrays, n_arc: int = 9, fusion: Any = None
) -> np.ndarray:
    """Points (N, 2) in ``base_link`` where the fused obstacle of one array reading may lie.

    Five-zone fusion (thesis 5.2) gives the distance ``d`` and the bearing interval holding the
    obstacle; the obstacle may be anywhere on that arc, so the arc is sampled (conservative). The
    outer sonars' angle and the servo's centre come from ``arrays`` (``spec.sonar_arrays``).
    ``fusion``: the reading's :func:`mapping.sonar.fuse_array` result when the caller has it already.
    """
    from mapping.sonar import fuse_array

    res = fusion
    if res is None:
        r1, r2, r3 = (float(r) if math.isfinite(r) else math.nan for r in reading.ranges_m)
        res = fuse_array(r1, r2, r3, tables=_zone_tables(arrays.outer_sonar_deg))
    if not res.has_obstacle:
        return np.zeros((0, 2))
    yaw0 = mount.rpy[2] + arrays.joint_angle(reading.servo_angle_deg)
    bearings = np.radians(np.linspace(res.alpha_deg, res.alpha_deg + res.theta_deg, n_arc)) + yaw0
    x0, y0 = mount.xyz[0], mount.xyz[1]
    return np.stack([x0 + res.distance_m * np.cos(bearings), y0 + res.distance_m * np.sin(bearings)], axis=1)


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
