"""Compiled passes of the perception stage's per-cycle point work (numba), numpy's arithmetic bit for bit.

Every cycle the stage places the laser scan's returns in the height band (:meth:`Perception.add_scan`)
and gathers the obstacle points around the chair for the safety layer's swept footprint
(:meth:`Perception.obstacle_points_base`): a handful of small numpy passes each, whose call overhead
outweighed the arithmetic over a few hundred points. The kernels here do the same arithmetic per point,
operation for operation in numpy's order (no fast-math: the values are numpy's bit for bit; the tests
compare them with :func:`robchair.perception_queries.points_in_base` and the numpy band filter). The
rigid transform of the scan itself stays numpy's (one matrix product, shared by the map and the band).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from robchair.perception_queries import points_in_base
from robchair.platform.kinematics import Pose2D

_JIT: Any = None


def _jit() -> Any:
    """The compiled kernels' module (numba is imported at the first call, not with the stage)."""
    global _JIT
    if _JIT is None:
        import robchair._perception_jit as jit  # says so when its kernels compile

        _JIT = jit
    return _JIT


def obstacle_points(
    pose: Pose2D, odom_xy: np.ndarray | None, arcs: list[tuple[np.ndarray, Any]]
) -> np.ndarray:
    """:func:`robchair.perception_queries.points_in_base`, compiled for float64 (N, 2) inputs."""
    fast = points_in_base_fast(pose, odom_xy, arcs)
    return fast if fast is not None else points_in_base(pose, odom_xy, arcs)


def band_xy(w: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """``w[(z >= band[0]) & (z <= band[1]), :2]`` of points ``w`` (N, 3) float64: (M, 2), m."""
    if w.dtype != np.float64 or w.ndim != 2 or w.shape[1] != 3:
        return w[(w[:, 2] >= band[0]) & (w[:, 2] <= band[1]), :2]
    return _jit()._band_xy(w, float(band[0]), float(band[1]))  # type: ignore[no-any-return]


def all_finite(p: np.ndarray) -> bool:
    """Whether every value of the float64 points ``p`` (N, 3) is finite."""
    return bool(_jit()._all_finite(p))


def points_in_base_fast(
    pose: Pose2D, odom_xy: np.ndarray | None, arcs: list[tuple[np.ndarray, Any]]
) -> np.ndarray | None:
    """:func:`robchair.perception_queries.points_in_base` in compiled passes, bit for bit: (N, 2) float64
    in ``base_link``; None (the caller takes the numpy path) when an input is not float64 (N, 2)."""
    parts = [odom_xy] if odom_xy is not None and len(odom_xy) else []
    parts += [a for a, _ in arcs]
    for a in parts:
        if not (isinstance(a, np.ndarray) and a.dtype == np.float64 and a.ndim == 2 and a.shape[1] == 2):
            return None
    jit = _jit()
    out = np.empty((sum(len(a) for a in parts), 2), dtype=np.float64)
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    px, py = float(pose.x), float(pose.y)
    k = 0
    if odom_xy is not None and len(odom_xy):
        jit._odom_to_base(out, k, odom_xy, px, py, c, s)
        k += len(odom_xy)
    for arc, p0 in arcs:
        if len(arc):
            jit._arc_to_base(out, k, arc, float(p0.x), float(p0.y), math.cos(p0.theta), math.sin(p0.theta),
                         px, py, c, s)  # fmt: skip
            k += len(arc)
    return out
