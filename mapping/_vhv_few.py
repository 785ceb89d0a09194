"""One compiled pass that inserts a small cloud into a VHV map (:meth:`mapping.vhv.VHVMap.insert_few`).

The general build (:mod:`mapping._vhv_build`) guesses a box, bins and extracts in several kernels,
then merges the frame into the whole map; for a cloud of a few hundred points (one sonar cone, a
handful of cells) those calls, their Python glue and the full merge cost more than the work. Here one
kernel keys each finite in-grid point by its cell exactly as the build kernels do
(``floor(u / cell) - origin``), groups the points by cell (a short list of the cells seen), sorts and
clusters each cell's heights (thesis test 4.2.4, as :func:`mapping._vhv_kernels.cluster_cells`) and
merges them into the map's structures of those cells only, copying the map's other structures in
blocks. The structures of a cloud are unique (the clustering of its points) and the merge is the one
of :func:`mapping._vhv_kernels.merge_structures`, so the map comes out the same as through
:meth:`mapping.vhv.VHVMap.insert`.
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from mapping._deps import announce_compilation
from mapping._vhv_kernels import _JIT, append_joined  # the map kernels' compile options and join rule


@numba.jit(**_JIT)
def _sort_run(h, a, b):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    if b - a > 32:
        h[a:b].sort()
        return
    for q in range(a + 1, b):  # an insertion sort for the few heights of a small cell
        z = h[q]
        r = q - 1
        while r >= a and h[r] > z:
            h[r + 1] = h[r]
            r -= 1
        h[r + 1] = z


@numba.jit(inline="always", **_JIT)
def _copy_block(k1, b1, t1, a, b, ok, ob, ot, o):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Copy the map's structures [a, b) to the output at ``o``; the new output length."""
    w = b - a
    ok[o : o + w] = k1[a:b]
    ob[o : o + w] = b1[a:b]
    ot[o : o + w] = t1[a:b]
    return o + w


@numba.jit(**_JIT)
def insert_few(pts, gf, gi, k1, b1, t1):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """The map's structures ``(k1, b1, t1)`` (sorted by key, bottom) with the cloud ``pts`` (N, 3) merged in.

    ``gf`` = (1 / cell size, tolerance) float64, ``gi`` = (ou, ov, nx, ny, cu, cv, ch) int64: the grid
    (:func:`mapping._vhv_build._grid_args`) in two arrays (a numba call types each argument).

    Returns:
        (key, bottom, top, n_nonfinite, n_outside_grid, n_frame_structures); with no point kept
        (``n_frame_structures == 0``) the arrays are empty and the map stays as it is.
    """
    ics, tol = gf[0], gf[1]
    ou, ov, nx, ny, cu, cv, ch = gi[0], gi[1], gi[2], gi[3], gi[4], gi[5], gi[6]
    n = pts.shape[0]
    hs = np.empty(n, np.float64)
    cell = np.empty(n, np.int64)
    cells = np.empty(16, np.int64)  # the distinct cell keys, in order of appearance
    nc = 0
    last = -1
    m = 0
    n_nonfinite = 0
    n_outside = 0
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
        if not (fi >= 0.0 and fj >= 0.0 and fi < nx and fj < ny):
            n_outside += 1
            continue
        key = np.int64(fi) * ny + np.int64(fj)
        if last < 0 or cells[last] != key:
            last = -1
            for c in range(nc):
                if cells[c] == key:
                    last = c
                    break
            if last < 0:
                if nc == cells.shape[0]:
                    grown = np.empty(2 * nc, np.int64)
                    grown[:nc] = cells[:nc]
                    cells = grown
                cells[nc] = key
                last = nc
                nc += 1
        cell[m] = last
        hs[m] = h
        m += 1
    if m == 0:
        e = np.empty(0, np.float64)
        return np.empty(0, np.int64), e, e.copy(), n_nonfinite, n_outside, 0
    # cells in key order; each cell's heights together (a counting sort), then sorted
    order = np.argsort(cells[:nc])
    rank = np.empty(nc, np.int64)
    for r in range(nc):
        rank[order[r]] = r
    start = np.zeros(nc + 1, np.int64)
    for q in range(m):
        start[rank[cell[q]] + 1] += 1
    for r in range(nc):
        start[r + 1] += start[r]
    fill = start[:nc].copy()
    sh = np.empty(m, np.float64)
    for q in range(m):
        r = rank[cell[q]]
        sh[fill[r]] = hs[q]
        fill[r] += 1
    # the frame's structures per cell (k2 in key order, bottoms ascending)
    k2 = np.empty(m, np.int64)
    b2 = np.empty(m, np.float64)
    t2 = np.empty(m, np.float64)
    n2 = 0
    for r in range(nc):
        a, b = start[r], start[r + 1]
        _sort_run(sh, a, b)
        key = cells[order[r]]
        k2[n2] = key
        b2[n2] = sh[a]
        t2[n2] = sh[a]
        n2 += 1
        for q in range(a + 1, b):
            z = sh[q]
            if z - t2[n2 - 1] <= tol:
                t2[n2 - 1] = z
            else:
                k2[n2] = key
                b2[n2] = z
                t2[n2] = z
                n2 += 1
    # merge: the map's structures of other cells copied in blocks, each touched cell swept in bottom
    # order (the map's first on equal bottoms), joining while next.bottom - running_top <= tol
    n1 = k1.shape[0]
    ok = np.empty(n1 + n2, np.int64)
    ob = np.empty(n1 + n2, np.float64)
    ot = np.empty(n1 + n2, np.float64)
    p = 0
    o = 0
    q = 0
    while q < n2:
        key = k2[q]
        qe = q
        while qe < n2 and k2[qe] == key:
            qe += 1
        lo = np.searchsorted(k1, key)  # left
        hi = lo
        while hi < n1 and k1[hi] == key:
            hi += 1
        o = _copy_block(k1, b1, t1, p, lo, ok, ob, ot, o)
        first = o
        i = lo
        j = q
        while i < hi or j < qe:
            if j >= qe or (i < hi and b1[i] <= b2[j]):
                lo_h = b1[i]
                hi_h = t1[i]
                i += 1
            else:
                lo_h = b2[j]
                hi_h = t2[j]
                j += 1
            o = append_joined(ok, ob, ot, o, o > first, key, lo_h, hi_h, tol)
        p = hi
        q = qe
    o = _copy_block(k1, b1, t1, p, n1, ok, ob, ot, o)
    return ok[:o], ob[:o], ot[:o], n_nonfinite, n_outside, n2


# first run after an install or a change here: say what is being compiled
announce_compilation(sys.modules[__name__], "small-cloud map kernel")
