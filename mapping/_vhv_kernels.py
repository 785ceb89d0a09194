"""Compiled (numba, one thread, cached) kernels of the VHV build; see :mod:`mapping.vhv` for the method.

Every kernel takes the point array in its own dtype (float32 or float64) and converts each coordinate
to float64 before indexing, so the cell of a point is exactly ``GridSpec.world_to_index`` of it.
Structures leave the kernels as three parallel arrays: cell key ``i * ny + j`` (int64), bottom and top
(float64), sorted by key then bottom.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_JIT = {"cache": True, "nogil": True, "nopython": True, "error_model": "numpy", "boundscheck": False}


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
def bin_minmax(pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, ni, nj, iw, b0, nb, mins, maxs, overflow):  # type: ignore[no-untyped-def]
    """Min and max height per (cell, height bin of width ``1 / iw``) inside a box of cells and bins.

    ``mins``/``maxs`` are flat dense arrays of ``ni * nj * nb`` entries pre-filled with +inf/-inf for
    the box ``[i0, i0 + ni) x [j0, j0 + nj) x [b0, b0 + nb)`` (grid indices, bin indices). Finite
    in-grid points outside the box are not binned: their indices go to ``overflow`` (as many as fit).

    Returns:
        (n_nonfinite, n_outside_grid, n_overflow); n_overflow may exceed ``overflow.shape[0]``.
    """
    n = pts.shape[0]
    n_nonfinite = 0
    n_outside = 0
    n_over = 0
    cap = overflow.shape[0]
    uni = np.uint64(ni)
    unj = np.uint64(nj)
    unb = np.uint64(nb)
    unx = np.uint64(nx)
    uny = np.uint64(ny)
    for k in range(n):
        u = np.float64(pts[k, cu])
        v = np.float64(pts[k, cv])
        h = np.float64(pts[k, ch])
        s = u + v + h
        if s - s != 0.0:  # NaN or inf in any coordinate
            n_nonfinite += 1
            continue
        fi = np.floor(u * ics) - ou
        fj = np.floor(v * ics) - ov
        # Compare as floats first: casting a huge finite value to int64 is undefined.
        if not (fi >= 0.0 and fj >= 0.0 and fi < unx and fj < uny):
            n_outside += 1
            continue
        di = np.int64(fi) - i0
        dj = np.int64(fj) - j0
        db = np.int64(np.floor(h * iw)) - b0
        if np.uint64(di) >= uni or np.uint64(dj) >= unj or np.uint64(db) >= unb:
            if n_over < cap:
                overflow[n_over] = k
            n_over += 1
            continue
        idx = (di * nj + dj) * nb + db
        hv = pts[k, ch]
        # Branch-free min/max: which point is extreme in its bin is unpredictable.
        mins[idx] = min(mins[idx], hv)
        maxs[idx] = max(maxs[idx], hv)
    return n_nonfinite, n_outside, n_over


@numba.jit(**_JIT)
def extract_bins(mins, maxs, nb, i0, j0, nj, ny, tol):  # type: ignore[no-untyped-def]
    """Merge consecutive non-empty bins of each cell into structures (gap <= tol joins).

    Two passes over the dense table (count, then fill) so that the output is allocated at its exact
    size: the table is small next to the points, the structures smaller still.
    """
    n_cells = mins.shape[0] // nb
    n_out = 0
    for c in range(n_cells):
        base = c * nb
        have = False
        last_top = 0.0
        for b in range(nb):
            lo = np.float64(mins[base + b])
            if lo == np.inf:
                continue
            if not (have and lo - last_top <= tol):
                n_out += 1
            have = True
            last_top = np.float64(maxs[base + b])
    out_key = np.empty(n_out, np.int64)
    out_b = np.empty(n_out, np.float64)
    out_t = np.empty(n_out, np.float64)
    n_out = 0
    for c in range(n_cells):
        base = c * nb
        open_ = False
        key = (i0 + c // nj) * ny + (j0 + c % nj)
        for b in range(nb):
            lo = np.float64(mins[base + b])
            if lo == np.inf:
                continue
            hi = np.float64(maxs[base + b])
            if open_ and lo - out_t[n_out - 1] <= tol:
                out_t[n_out - 1] = hi
            else:
                out_key[n_out] = key
                out_b[n_out] = lo
                out_t[n_out] = hi
                n_out += 1
                open_ = True
    return out_key, out_b, out_t


@numba.jit(**_JIT)
def keys_and_heights(pts, ics, ou, ov, nx, ny, cu, cv, ch, n_finite):  # type: ignore[no-untyped-def]
    """Compact the finite in-grid points into (cell key, height) arrays (height in the input dtype)."""
    keys = np.empty(n_finite, np.int64)
    hs = np.empty(n_finite, pts.dtype)
    m = 0
    for k in range(pts.shape[0]):
        u = np.float64(pts[k, cu])
        v = np.float64(pts[k, cv])
        h = np.float64(pts[k, ch])
        if not (math.isfinite(u) and math.isfinite(v) and math.isfinite(h)):
            continue
        fi = np.floor(u * ics) - ou
        fj = np.floor(v * ics) - ov
        if fi < 0.0 or fi >= nx or fj < 0.0 or fj >= ny:
            continue
        keys[m] = np.int64(fi) * ny + np.int64(fj)
        hs[m] = pts[k, ch]
        m += 1
    return keys[:m], hs[:m]


@numba.jit(**_JIT)
def cluster_sorted_groups(keys, hs, order, tol):  # type: ignore[no-untyped-def]
    """Thesis pipeline per cell: sort heights, drop duplicates, cluster with gap <= tol.

    ``order`` sorts ``keys``; the heights of each cell are sorted here, cell by cell.
    """
    n = order.shape[0]
    out_key = np.empty(n, np.int64)
    out_b = np.empty(n, np.float64)
    out_t = np.empty(n, np.float64)
    scratch = np.empty(n, np.float64)
    n_out = 0
    s = 0
    while s < n:
        key = keys[order[s]]
        e = s + 1
        while e < n and keys[order[e]] == key:
            e += 1
        m = e - s
        for q in range(m):
            scratch[q] = hs[order[s + q]]
        z = np.sort(scratch[:m])
        out_key[n_out] = key
        out_b[n_out] = z[0]
        out_t[n_out] = z[0]
        n_out += 1
        for q in range(1, m):
            if z[q] - out_t[n_out - 1] <= tol:
                out_t[n_out - 1] = z[q]
            else:
                out_key[n_out] = key
                out_b[n_out] = z[q]
                out_t[n_out] = z[q]
                n_out += 1
        s = e
    return out_key[:n_out].copy(), out_b[:n_out].copy(), out_t[:n_out].copy()


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
