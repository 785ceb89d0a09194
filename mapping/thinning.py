"""Thinning a cloud without changing the VHV structures it builds: the fewest measured points per structure.

A frame's VHV structures (:mod:`mapping.vhv`, thesis section 4.2) depend only on each cell's sorted
heights: a gap larger than the tolerance starts a new structure, and a structure keeps its first and
last value. So a subset of the points builds the very same structures when, in every cell, it keeps
each structure's lowest and highest point and enough points between them that no two consecutive kept
heights are more than the tolerance apart. :func:`structure_keeping_indices` keeps such a subset,
greedily (from the bottom, the highest point still within the tolerance of the last one kept), so a
structure of height ``H`` keeps at most about ``2 H / tolerance + 2`` points, wherever the sensor
sampled it densely.

Unlike a voxel filter (:func:`mapping.grid.voxel_filter`: one point per voxel, whichever it is), the
kept cloud inserted into a map gives the same frame structures, hence the same map, as the whole cloud:
what a recorded bag needs for `robchair map` to rebuild the run's map. Every kept point is a measured
one (no point is made up).
"""

from __future__ import annotations

import sys
from typing import Any

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping._deps import announce_compilation
from mapping.grid import AXIS_COLUMNS, GridSpec

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "nopython": True, "error_model": "numpy"}


@numba.jit(**_JIT)
def _chain_keep(key, h, order, tolerance, keep):  # type: ignore[no-untyped-def]
    """Mark in ``keep`` the points (indices into ``key``/``h``, visited in ``order``: by cell, then
    height) that keep every structure's bottom, top and a chain of gaps <= ``tolerance``; returns the
    number marked."""
    n = order.shape[0]
    m = 0
    k = 0
    while k < n:
        first = order[k]
        cell = key[first]
        keep[first] = True
        m += 1
        last_kept = h[first]
        prev = first
        k += 1
        while k < n and key[order[k]] == cell:
            cur = order[k]
            if h[cur] - h[prev] > tolerance:  # a new structure: the last one's top and this bottom
                if not keep[prev]:
                    keep[prev] = True
                    m += 1
                keep[cur] = True
                m += 1
                last_kept = h[cur]
            elif h[cur] - last_kept > tolerance:  # the chain needs the point before this one
                if not keep[prev]:
                    keep[prev] = True
                    m += 1
                last_kept = h[prev]
            prev = cur
            k += 1
        if not keep[prev]:  # the cell's last structure's top
            keep[prev] = True
            m += 1
    return m


def structure_keeping_indices(points_world: ArrayLike, spec: GridSpec, tolerance: float) -> NDArray[np.int64]:
    """Indices of the points to keep so that the kept ones build the same VHV structures on ``spec``.

    Args:
        points_world: ``(N, 3)`` points in the map's frame, m, exactly as the map would receive them
            (float32 or float64; the comparisons are in float64 of these values).
        spec: the map's grid (its cells and kept axis).
        tolerance: the map's VHV tolerance, m (> 0).

    Returns:
        Sorted ``(M,)`` int64 indices into ``points_world``. Non-finite points and points outside the
        grid (which no map keeps) are left out.

    Raises:
        ValueError: ``points_world`` is not ``(N, 3)``, or ``tolerance`` is not a positive number.
    """
    p = np.asarray(points_world)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"structure_keeping_indices points_world: expected shape (N, 3), got {p.shape}")
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"structure_keeping_indices tolerance={tolerance!r}: expected metres > 0")
    cu, cv, ch = AXIS_COLUMNS[spec.axis]
    ok = np.flatnonzero(np.isfinite(p).all(axis=1))
    q = p[ok]
    i, j = spec.world_to_index(q[:, cu], q[:, cv])
    nx, ny = spec.shape
    inside = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
    ok, i, j = ok[inside], i[inside], j[inside]
    h = np.asarray(q[inside, ch], dtype=np.float64)
    key = i * ny + j
    order = np.lexsort((h, key))
    keep = np.zeros(len(ok), np.bool_)
    _chain_keep(key, h, order, float(tolerance), keep)
    return ok[keep]


announce_compilation(sys.modules[__name__], "structure-keeping thinning kernel")
