"""Compiled (numba, one thread, cached) kernel of :func:`mapping.grid.voxel_filter`: the first point of
each voxel in one pass, with a hash table instead of a sort.

The voxel of a point ``p`` is ``floor((R p + t) / size)`` per axis (``R``, ``t``: the lattice transform),
computed in float64 as the numpy path does. Voxel indices are packed into one int64 (21 bits per axis,
offset by 2**20), so the kernel needs every index within ``[-2**20, 2**20)`` (52 km at 5 cm voxels) and
says so by returning -1 otherwise (the caller then takes the sorting path). The table is open
addressing with linear probing at a load factor of at most 1/2, grown with the voxels found (so it stays in
cache); a point in the voxel of the point before
it (most neighbouring pixels of a depth image) skips the table.
"""

from __future__ import annotations

import sys
from typing import Any

import numba
import numpy as np

from mapping._deps import announce_compilation

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "nopython": True, "error_model": "numpy"}
_BITS = 21
_OFFSET = 1 << (_BITS - 1)
_EMPTY = -1


@numba.jit(**_JIT)
def _slot(table, key, shift):  # type: ignore[no-untyped-def]
    """The slot of ``key`` in ``table`` of ``2**(64 - shift)`` slots (its own, or the empty one where it
    goes)."""
    mask = table.shape[0] - 1
    # Fibonacci hashing: the top bits of the product depend on every bit of the key
    h = np.int64((np.uint64(key) * np.uint64(11400714819323198485)) >> np.uint64(shift))
    while table[h] != _EMPTY and table[h] != key:
        h = (h + 1) & mask
    return h


@numba.jit(**_JIT)
def _grown(table, shift):  # type: ignore[no-untyped-def]
    """``table`` (of ``2**(64 - shift)`` slots) rehashed into twice its size."""
    out = np.full(2 * table.shape[0], _EMPTY, np.int64)
    for k in table:
        if k != _EMPTY:
            out[_slot(out, k, shift - 1)] = k
    return out


@numba.jit(**_JIT)
def first_per_voxel(p, r, t, inv_size, keep):  # type: ignore[no-untyped-def]
    """Indices (into ``p``, ascending) of the first finite point of each voxel, written to ``keep``.

    Args:
        p: ``(N, 3)`` float32 or float64 points.
        r: ``(3, 3)`` float64 rotation of the lattice transform.
        t: ``(3,)`` float64 translation of the lattice transform.
        inv_size: ``1 / voxel side``, 1/m.
        keep: ``(N,)`` int64 output.

    Returns:
        How many indices were written, or -1 when a voxel index does not fit the packing.
    """
    n = p.shape[0]
    table = np.full(4096, _EMPTY, np.int64)  # grows with the voxels, not the points: stays in cache
    shift = 64 - 12
    m = 0
    last = np.int64(_EMPTY)
    for i in range(n):
        x = np.float64(p[i, 0])
        y = np.float64(p[i, 1])
        z = np.float64(p[i, 2])
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        qx = x * r[0, 0] + y * r[0, 1] + z * r[0, 2] + t[0]
        qy = x * r[1, 0] + y * r[1, 1] + z * r[1, 2] + t[1]
        qz = x * r[2, 0] + y * r[2, 1] + z * r[2, 2] + t[2]
        fa = np.floor(qx * inv_size)
        fb = np.floor(qy * inv_size)
        fc = np.floor(qz * inv_size)
        if not (-_OFFSET <= fa < _OFFSET and -_OFFSET <= fb < _OFFSET and -_OFFSET <= fc < _OFFSET):
            return -1
        key = ((np.int64(fa) + _OFFSET) << (2 * _BITS)) | ((np.int64(fb) + _OFFSET) << _BITS)
        key |= np.int64(fc) + _OFFSET
        if key == last:  # neighbouring pixels share a voxel most of the time: no table look-up
            continue
        last = key
        h = _slot(table, key, shift)
        if table[h] == _EMPTY:
            table[h] = key
            keep[m] = i
            m += 1
            if 2 * m > table.shape[0]:
                table = _grown(table, shift)
                shift -= 1
    return m


announce_compilation(sys.modules[__name__], "voxel filter kernel")
