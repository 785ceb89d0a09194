"""Thinning a cloud without changing the VHV structures it builds: per cell and height slice, two points.

A frame's VHV structures (:mod:`mapping.vhv`, thesis section 4.2) depend only on each cell's sorted
heights: a gap larger than the tolerance ``tau`` starts a new structure, and a structure keeps its lowest
and highest height. Cut every cell's height axis into slices narrower than ``tau`` and keep, per cell and
slice, the lowest and the highest point. The kept points build the very same structures as the whole
cloud:

* the lowest and highest point of every structure are the lowest (highest) of their slice: kept;
* two consecutive kept heights ``a < b`` of one cell either share a slice (then ``b - a < tau``, no split
  in either cloud, and the dropped points between them are inside that structure), or lie in different
  slices, and then no point of the whole cloud lies between them (it would lie in a slice between, whose
  lowest point would have been kept): ``a``, ``b`` are consecutive in the whole cloud too, with the same
  gap, hence the same split or join.

The same holds for every map cell that is a union of the thinning's cells (the structures of a union of
slices thinned this way are those of the union of the whole sets), so the thinning is exact for any
grid on the same lattice ``floor(u / cell_size)`` (:meth:`mapping.grid.GridSpec.world_to_index`),
whatever its extent. A structure of height ``H`` keeps at most ``2 (H / tau + 1)`` points, wherever the
sensor sampled it densely: about twice a voxel filter of cell size ``tau`` (one point per voxel, which
changes the structures: :func:`mapping.grid.voxel_filter`). Every kept point is a measured one.

One pass with an open-addressing hash table over (cell, slice) keys (the scheme of
:mod:`mapping._voxel_first`): the cost of the voxel filter, not of a sort.
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping._deps import announce_compilation

# the lattice packing and the open-addressing hash slot are the voxel filter's (one key per cell)
from mapping._voxel_first import _BITS, _EMPTY, _JIT, _OFFSET, _slot
from mapping.grid import AXIS_COLUMNS

#: The height slices are this fraction of the tolerance (strictly narrower: two points of one slice are
#: less than the tolerance apart, even after the float64 rounding of the slice index).
SLICE_FRACTION = 1.0 - 1e-6


@numba.jit(**_JIT)
def _grown(keys, idx, hts, shift):  # type: ignore[no-untyped-def]
    """The table rehashed into twice its size (``shift`` is the old one's)."""
    n = 2 * keys.shape[0]
    k2 = np.full(n, _EMPTY, np.int64)
    idx2 = np.empty((n, 2), np.int64)
    hts2 = np.empty((n, 2), np.float32)
    for s in range(keys.shape[0]):
        if keys[s] != _EMPTY:
            d = _slot(k2, keys[s], shift - 1)
            k2[d] = keys[s]
            idx2[d, 0], idx2[d, 1], hts2[d, 0], hts2[d, 1] = idx[s, 0], idx[s, 1], hts[s, 0], hts[s, 1]
    return k2, idx2, hts2


@numba.jit(**_JIT)
def slice_extremes(p, r, t, inv_cell, inv_slice, keep):  # type: ignore[no-untyped-def]
    """Mark in ``keep`` the lowest and highest point of every (cell, height slice); one pass.

    Args:
        p: ``(N, 3)`` float32 or float64 points (the sensor's frame).
        r: ``(3, 3)`` float64 rotation into the map's frame, its rows ordered as the grid's axes u, v
            and the kept axis.
        t: ``(3,)`` float64 translation into the map's frame, in the same order.
        inv_cell: ``1 / cell size``, 1/m (the grid's lattice ``floor(u * inv_cell)``).
        inv_slice: ``1 / slice height``, 1/m.
        keep: ``(N,)`` bool output, all False on entry.

    Returns:
        How many points were marked, or -1 when a cell or slice index does not fit the key packing
        (``[-2**20, 2**20)`` each: 52 km at 5 cm).

    Points are placed as the map receives them: ``R p + t`` in float64, rounded to float32. The table
    keeps per slot the key, the (lowest, highest) point indices and their heights, each pair side by side.
    """
    n = p.shape[0]
    keys = np.full(4096, _EMPTY, np.int64)
    idx = np.empty((4096, 2), np.int64)
    hts = np.empty((4096, 2), np.float32)
    shift = 64 - 12
    used = 0
    last = np.int64(_EMPTY)
    s = 0
    for i in range(n):
        x = np.float64(p[i, 0])
        y = np.float64(p[i, 1])
        z = np.float64(p[i, 2])
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        # the map's coordinates, as it receives them (float32); rows of r: grid u, grid v, kept axis
        u = np.float32(x * r[0, 0] + y * r[0, 1] + z * r[0, 2] + t[0])
        v = np.float32(x * r[1, 0] + y * r[1, 1] + z * r[1, 2] + t[1])
        h = np.float32(x * r[2, 0] + y * r[2, 1] + z * r[2, 2] + t[2])
        fa = np.floor(np.float64(u) * inv_cell)
        fb = np.floor(np.float64(v) * inv_cell)
        fc = np.floor(np.float64(h) * inv_slice)
        if not (-_OFFSET <= fa < _OFFSET and -_OFFSET <= fb < _OFFSET and -_OFFSET <= fc < _OFFSET):
            return -1
        key = ((np.int64(fa) + _OFFSET) << (2 * _BITS)) | ((np.int64(fb) + _OFFSET) << _BITS)
        key |= np.int64(fc) + _OFFSET
        if key != last:  # neighbouring pixels share a slice most of the time: no table look-up
            last = key
            s = _slot(keys, key, shift)
            if keys[s] == _EMPTY:
                keys[s] = key
                idx[s, 0] = idx[s, 1] = i
                hts[s, 0] = hts[s, 1] = h
                used += 1
                if 2 * used > keys.shape[0]:
                    keys, idx, hts = _grown(keys, idx, hts, shift)
                    shift -= 1
                    s = _slot(keys, key, shift)
                continue
        if h < hts[s, 0]:
            idx[s, 0], hts[s, 0] = i, h
        elif h > hts[s, 1]:
            idx[s, 1], hts[s, 1] = i, h
    m = 0
    for s in range(keys.shape[0]):
        if keys[s] != _EMPTY:
            for k in range(2):
                i = idx[s, k]
                if not keep[i]:
                    keep[i] = True
                    m += 1
    return m


def _check(points: ArrayLike, t_map_points: ArrayLike | None, cell_size: float, tolerance: float,
           axis: str) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    p = np.asarray(points)
    if p.shape[-1:] != (3,):
        raise ValueError(f"structure_keeping_indices points: expected shape (..., 3), got {p.shape}")
    for name, value in (("cell_size", cell_size), ("tolerance", tolerance)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"structure_keeping_indices {name}={value!r}: expected metres > 0")
    if axis not in AXIS_COLUMNS:
        raise ValueError(
            f"structure_keeping_indices axis={axis!r}: expected one of {', '.join(AXIS_COLUMNS)}"
        )
    t = np.eye(4) if t_map_points is None else np.asarray(t_map_points, dtype=np.float64)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        raise ValueError(f"structure_keeping_indices t_map_points: expected a finite (4, 4), got {t.shape}")
    p = p.reshape(-1, 3)
    if p.dtype not in (np.float32, np.float64):
        p = p.astype(np.float64)
    return p, t


def structure_keeping_indices(points: ArrayLike, t_map_points: ArrayLike | None, cell_size: float,
                              tolerance: float, axis: str = "z") -> NDArray[np.int64]:  # fmt: skip
    """Indices of the points to keep so that they build the same VHV structures as the whole cloud.

    Exact for every grid of ``cell_size`` cells on the lattice ``floor(u / cell_size)`` and every VHV
    tolerance >= ``tolerance`` (module docstring); the map receives ``T p`` in float32, as here.

    Args:
        points: ``(..., 3)`` points, m, in their own frame (an organized ``(H, W, 3)`` frame is taken
            row by row; float32 or float64).
        t_map_points: ``(4, 4)`` transform of the points into the map's frame (None: identity), e.g.
            the pose the map places the frame with times the sensor's mount.
        cell_size: the map's cell side, m (> 0).
        tolerance: the map's VHV tolerance, m (> 0).
        axis: the map's kept axis (``"z"``, ``"x"`` or ``"y"``).

    Returns:
        Ascending ``(M,)`` int64 indices into the flattened points. Non-finite points are left out.

    Raises:
        ValueError: ``points`` is not ``(..., 3)``, ``t_map_points`` is not a finite ``(4, 4)``,
            ``cell_size`` or ``tolerance`` is not a positive number, or ``axis`` is unknown.
    """
    p, t = _check(points, t_map_points, cell_size, tolerance, axis)
    cu, cv, ch = AXIS_COLUMNS[axis]  # type: ignore[index]
    inv_cell, inv_slice = 1.0 / cell_size, 1.0 / (tolerance * SLICE_FRACTION)
    keep = np.zeros(p.shape[0], np.bool_)
    if p.shape[0]:
        rows = [cu, cv, ch]
        r, tr = np.ascontiguousarray(t[rows, :3]), np.ascontiguousarray(t[rows, 3])
        if slice_extremes(p, r, tr, inv_cell, inv_slice, keep) < 0:
            return structure_keeping_indices_numpy(p, t, cell_size, tolerance, axis)
    return np.flatnonzero(keep)


def structure_keeping_indices_numpy(points: ArrayLike, t_map_points: ArrayLike | None, cell_size: float,
                                    tolerance: float, axis: str = "z") -> NDArray[np.int64]:  # fmt: skip
    """:func:`structure_keeping_indices` by sorting (no packing limit; the reference of its kernel):
    the same indices."""
    p, t = _check(points, t_map_points, cell_size, tolerance, axis)
    cu, cv, ch = AXIS_COLUMNS[axis]  # type: ignore[index]
    ok = np.flatnonzero(np.isfinite(p).all(axis=1))
    q = (p[ok].astype(np.float64) @ t[:3, :3].T + t[:3, 3]).astype(np.float32)
    if not len(ok):
        return ok.astype(np.int64)
    h = q[:, ch]
    cells = np.floor(q[:, [cu, cv]].astype(np.float64) * (1.0 / cell_size)).astype(np.int64)
    slices = np.floor(h.astype(np.float64) * (1.0 / (tolerance * SLICE_FRACTION))).astype(np.int64)
    keys = np.column_stack([cells, slices])
    _, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.reshape(-1)
    # per group: the first lowest and the first highest point in input order (the kernel's ties)
    order = np.lexsort((np.arange(len(h)), h, group))
    first = np.flatnonzero(np.r_[True, group[order][1:] != group[order][:-1]])
    lowest = order[first]
    order_hi = np.lexsort((np.arange(len(h)), -h.astype(np.float64), group))
    highest = order_hi[first]
    return np.unique(ok[np.concatenate([lowest, highest])])


announce_compilation(sys.modules[__name__], "structure-keeping thinning kernel")
