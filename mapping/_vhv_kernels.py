"""Compiled (numba, one thread, cached) kernels of the VHV build; see :mod:`mapping.vhv` for the method.

Every kernel takes the point array in its own dtype (float32 or float64) and converts each coordinate
to float64 before indexing, so the cell of a point is exactly ``GridSpec.world_to_index`` of it.
Structures leave the kernels as three parallel arrays: cell key ``i * ny + j`` (int64), bottom and top
(float64), sorted by key then bottom.
"""

from __future__ import annotations

import math
import sys
from typing import Any

import numba
import numpy as np

from mapping._deps import announce_compilation

_JIT: dict[str, Any] = {
    "cache": True,
    "nogil": True,
    "nopython": True,
    "error_model": "numpy",
    "boundscheck": False,
}


@numba.jit(**_JIT)
def scan(pts, cu, cv, ch, step):  # type: ignore[no-untyped-def]
    """Coordinate ranges of the finite points among every ``step``-th point; count of non-finite ones.

    Returns:
        (n_nonfinite, u_min, u_max, v_min, v_max, h_min, h_max) over the visited points; ranges are
        (inf, -inf) when none of them is finite.
    """
    n = pts.shape[0]
    n_nonfinite = 0
    u_min = np.inf
    u_max = -np.inf
    v_min = np.inf
    v_max = -np.inf
    h_min = np.inf
    h_max = -np.inf
    for k in range(0, n, step):
        u = np.float64(pts[k, cu])
        v = np.float64(pts[k, cv])
        h = np.float64(pts[k, ch])
        s = u + v + h
        if s - s != 0.0:  # NaN or inf in any coordinate
            n_nonfinite += 1
            continue
        u_min = min(u_min, u)
        u_max = max(u_max, u)
        v_min = min(v_min, v)
        v_max = max(v_max, v)
        h_min = min(h_min, h)
        h_max = max(h_max, h)
    return n_nonfinite, u_min, u_max, v_min, v_max, h_min, h_max


@numba.jit(**_JIT)
def bin_minmax(pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, ni, nj, iw, b0, nb, mm, overflow):  # type: ignore[no-untyped-def]
    """Min and max height per (cell, height bin of width ``1 / iw``) inside a box of cells and bins.

    ``mm`` is a flat dense table of ``2 * ni * nj * nb`` entries, (min, max) side by side so that one
    cache line serves both, pre-filled with (+inf, -inf), for the box ``[i0, i0 + ni) x [j0, j0 + nj)
    x [b0, b0 + nb)`` (grid indices, bin indices). In-grid points whose cell or bin falls outside the
    box — including those with a non-finite height — are not binned: their indices go to ``overflow``
    (as many as fit) for the exact slow path, which also counts their non-finite heights.

    Returns:
        (n_nonfinite_uv, n_outside_grid, n_overflow); n_overflow may exceed ``overflow.shape[0]``.
    """
    n = pts.shape[0]
    n_nonfinite = 0
    n_outside = 0
    n_over = 0
    cap = overflow.shape[0]
    # Box offsets as floats: floor() values minus these are exact whenever the result is inside the box
    # (integers below 2**53, or Sterbenz subtraction), so the fast test below can stay in float64.
    fi0 = np.float64(ou + i0)
    fj0 = np.float64(ov + j0)
    fb0 = np.float64(b0)
    fni = np.float64(ni)
    fnj = np.float64(nj)
    fnb = np.float64(nb)
    for k in range(n):
        u = np.float64(pts[k, cu])
        v = np.float64(pts[k, cv])
        hv = pts[k, ch]
        di = np.floor(u * ics) - fi0
        dj = np.floor(v * ics) - fj0
        db = np.floor(np.float64(hv) * iw) - fb0
        # NaN fails every comparison, so this one test screens non-finite, out-of-grid and out-of-box
        # points, which are then told apart on the rare path.
        if di >= 0.0 and dj >= 0.0 and db >= 0.0 and di < fni and dj < fnj and db < fnb:
            idx = 2 * ((np.int64(di) * nj + np.int64(dj)) * nb + np.int64(db))
            # Branch-free min/max: which point is extreme in its bin is unpredictable.
            mm[idx] = min(mm[idx], hv)
            mm[idx + 1] = max(mm[idx + 1], hv)
            continue
        fi = np.floor(u * ics) - ou
        fj = np.floor(v * ics) - ov
        if not (fi >= 0.0 and fj >= 0.0 and fi < nx and fj < ny):
            if math.isfinite(u) and math.isfinite(v) and math.isfinite(np.float64(hv)):
                n_outside += 1
            else:
                n_nonfinite += 1
            continue
        if n_over < cap:
            overflow[n_over] = k
        n_over += 1
    return n_nonfinite, n_outside, n_over


@numba.jit(**_JIT)
def extract_bins(mm, nb, i0, j0, nj, ny, tol, out_key, out_b, out_t):  # type: ignore[no-untyped-def]
    """Merge consecutive non-empty bins of each cell into structures (gap <= tol joins).

    Writes into ``out_*`` (capacity: at least the number of non-empty bins; pages never written are
    never touched) and returns the number of structures.
    """
    n_cells = mm.shape[0] // (2 * nb)
    n_out = 0
    for c in range(n_cells):
        base = 2 * c * nb
        open_ = False
        key = (i0 + c // nj) * ny + (j0 + c % nj)
        for b in range(nb):
            lo = np.float64(mm[base + 2 * b])
            if lo == np.inf:
                continue
            hi = np.float64(mm[base + 2 * b + 1])
            if open_ and lo - out_t[n_out - 1] <= tol:
                out_t[n_out - 1] = hi
            else:
                out_key[n_out] = key
                out_b[n_out] = lo
                out_t[n_out] = hi
                n_out += 1
                open_ = True
    return n_out


@numba.jit(**_JIT)
def count_bin_structures(mm, nb, tol):  # type: ignore[no-untyped-def]
    """Number of structures :func:`extract_bins` will write (to size its output exactly)."""
    n_cells = mm.shape[0] // (2 * nb)
    n_out = 0
    for c in range(n_cells):
        base = 2 * c * nb
        have = False
        last_top = 0.0
        for b in range(nb):
            lo = np.float64(mm[base + 2 * b])
            if lo == np.inf:
                continue
            if not (have and lo - last_top <= tol):
                n_out += 1
            have = True
            last_top = np.float64(mm[base + 2 * b + 1])
    return n_out


@numba.jit(**_JIT)
def merge_structures(k1, b1, t1, k2, b2, t2, tol):  # type: ignore[no-untyped-def]
    """Merge two structure lists (each sorted by key then bottom, disjoint per cell) into one.

    Intervals of one cell are swept in bottom order; the next joins the current one while
    ``next.bottom - running_top <= tol``. This equals clustering the union of the points (see
    :mod:`mapping.vhv`).
    """
    n1 = k1.shape[0]
    n2 = k2.shape[0]
    out_key = np.empty(n1 + n2, np.int64)
    out_b = np.empty(n1 + n2, np.float64)
    out_t = np.empty(n1 + n2, np.float64)
    p = 0
    q = 0
    n_out = 0
    while p < n1 or q < n2:
        if q >= n2 or (p < n1 and (k1[p] < k2[q] or (k1[p] == k2[q] and b1[p] <= b2[q]))):
            key = k1[p]
            lo = b1[p]
            hi = t1[p]
            p += 1
        else:
            key = k2[q]
            lo = b2[q]
            hi = t2[q]
            q += 1
        if n_out > 0 and out_key[n_out - 1] == key and lo - out_t[n_out - 1] <= tol:
            if hi > out_t[n_out - 1]:
                out_t[n_out - 1] = hi
        else:
            out_key[n_out] = key
            out_b[n_out] = lo
            out_t[n_out] = hi
            n_out += 1
    return out_key[:n_out].copy(), out_b[:n_out].copy(), out_t[:n_out].copy()


@numba.jit(**_JIT)
def cell_counts(pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, ni, nj, counts):  # type: ignore[no-untyped-def]
    """Points per cell of the box ``[i0, i0 + ni) x [j0, j0 + nj)`` (which must hold every kept point).

    ``counts`` has ``ni * nj + 1`` zeros; cell ``c`` is counted in ``counts[c + 1]`` so that a cumulative
    sum gives the start offsets. Returns (n_nonfinite, n_outside_grid).
    """
    n_nonfinite = 0
    n_outside = 0
    for k in range(pts.shape[0]):
        u = np.float64(pts[k, cu])
        v = np.float64(pts[k, cv])
        h = np.float64(pts[k, ch])
        s = u + v + h
        if s - s != 0.0:
            n_nonfinite += 1
            continue
        fi = np.floor(u * ics) - ou
        fj = np.floor(v * ics) - ov
        if not (fi >= 0.0 and fj >= 0.0 and fi < nx and fj < ny):
            n_outside += 1
            continue
        counts[(np.int64(fi) - i0) * nj + (np.int64(fj) - j0) + 1] += 1
    return n_nonfinite, n_outside


@numba.jit(**_JIT)
def scatter_heights(pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, nj, fill, out):  # type: ignore[no-untyped-def]
    """Counting sort: write each kept point's height at ``out[fill[cell]]`` and advance ``fill[cell]``."""
    for k in range(pts.shape[0]):
        u = np.float64(pts[k, cu])
        v = np.float64(pts[k, cv])
        h = np.float64(pts[k, ch])
        s = u + v + h
        if s - s != 0.0:
            continue
        fi = np.floor(u * ics) - ou
        fj = np.floor(v * ics) - ov
        if not (fi >= 0.0 and fj >= 0.0 and fi < nx and fj < ny):
            continue
        c = (np.int64(fi) - i0) * nj + (np.int64(fj) - j0)
        out[fill[c]] = pts[k, ch]
        fill[c] += 1


@numba.jit(**_JIT)
def cluster_cells(hs, offsets, i0, j0, nj, ny, tol):  # type: ignore[no-untyped-def]
    """Thesis pipeline per cell on counting-sorted heights: sort each cell in place, then cluster."""
    n_cells = offsets.shape[0] - 1
    n_out = 0
    for c in range(n_cells):
        a = offsets[c]
        b = offsets[c + 1]
        if b == a:
            continue
        if b - a <= 32:
            # insertion sort: a library sort call per cell costs more than the few heights of a fine cell
            for q in range(a + 1, b):
                z = hs[q]
                r = q - 1
                while r >= a and hs[r] > z:
                    hs[r + 1] = hs[r]
                    r -= 1
                hs[r + 1] = z
        else:
            hs[a:b].sort()
        n_out += 1
        for q in range(a + 1, b):
            if np.float64(hs[q]) - np.float64(hs[q - 1]) > tol:
                n_out += 1
    out_key = np.empty(n_out, np.int64)
    out_b = np.empty(n_out, np.float64)
    out_t = np.empty(n_out, np.float64)
    n_out = 0
    for c in range(n_cells):
        a = offsets[c]
        b = offsets[c + 1]
        if b == a:
            continue
        key = (i0 + c // nj) * ny + (j0 + c % nj)
        out_key[n_out] = key
        out_b[n_out] = hs[a]
        out_t[n_out] = hs[a]
        n_out += 1
        for q in range(a + 1, b):
            z = np.float64(hs[q])
            if z - out_t[n_out - 1] <= tol:
                out_t[n_out - 1] = z
            else:
                out_key[n_out] = key
                out_b[n_out] = z
                out_t[n_out] = z
                n_out += 1
    return out_key, out_b, out_t


# first run after an install or a change here: say why the first frame takes tens of seconds
announce_compilation(sys.modules[__name__], "mapping kernels")
