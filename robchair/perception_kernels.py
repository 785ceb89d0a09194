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
import sys
from typing import Any

import numba
import numpy as np

from mapping._deps import announce_compilation
from robchair.platform.kinematics import Pose2D


@numba.njit(cache=True, nogil=True)
def _band_xy(w, z0, z1):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    n = 0
    for i in range(w.shape[0]):
        if w[i, 2] >= z0 and w[i, 2] <= z1:
            n += 1
    out = np.empty((n, 2), dtype=w.dtype)
    k = 0
    for i in range(w.shape[0]):
        if w[i, 2] >= z0 and w[i, 2] <= z1:
            out[k, 0] = w[i, 0]
            out[k, 1] = w[i, 1]
            k += 1
    return out


@numba.njit(cache=True, nogil=True)
def _all_finite(p):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    for i in range(p.shape[0]):
        for k in range(p.shape[1]):
            if not np.isfinite(p[i, k]):
                return False
    return True


@numba.njit(cache=True, nogil=True)
def _odom_to_base(out, k0, xy, px, py, c, s):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    for i in range(xy.shape[0]):
        qx = xy[i, 0] - px
        qy = xy[i, 1] - py
        out[k0 + i, 0] = c * qx + s * qy
        out[k0 + i, 1] = c * qy - s * qx


@numba.njit(cache=True, nogil=True)
def _arc_to_base(out, k0, arc, p0x, p0y, c0, s0, px, py, c, s):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    for i in range(arc.shape[0]):
        ax, ay = arc[i, 0], arc[i, 1]
        wx = p0x + c0 * ax - s0 * ay - px
        wy = p0y + s0 * ax + c0 * ay - py
        out[k0 + i, 0] = c * wx + s * wy
        out[k0 + i, 1] = c * wy - s * wx


def band_xy(w: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """``w[(z >= band[0]) & (z <= band[1]), :2]`` of points ``w`` (N, 3) float64: (M, 2), m."""
    announce_compilation(sys.modules[__name__], "perception point kernels")
    if w.dtype != np.float64 or w.ndim != 2 or w.shape[1] != 3:
        return w[(w[:, 2] >= band[0]) & (w[:, 2] <= band[1]), :2]
    return _band_xy(w, float(band[0]), float(band[1]))  # type: ignore[no-any-return]


def all_finite(p: np.ndarray) -> bool:
    """Whether every value of the float64 points ``p`` (N, 3) is finite."""
    return bool(_all_finite(p))


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
    announce_compilation(sys.modules[__name__], "perception point kernels")
    out = np.empty((sum(len(a) for a in parts), 2), dtype=np.float64)
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    px, py = float(pose.x), float(pose.y)
    k = 0
    if odom_xy is not None and len(odom_xy):
        _odom_to_base(out, k, odom_xy, px, py, c, s)
        k += len(odom_xy)
    for arc, p0 in arcs:
        if len(arc):
            _arc_to_base(out, k, arc, float(p0.x), float(p0.y), math.cos(p0.theta), math.sin(p0.theta),
                         px, py, c, s)  # fmt: skip
            k += len(arc)
    return out
