"""One compiled pass that inserts a small cloud into a VHV map (:meth:`mapping.vhv.VHVMap.insert_few`).

The general build (:mod:`mapping._vhv_build`) guesses a box, bins and extracts in several kernels,
then merges; for a cloud of a few hundred points (one sonar cone) those calls and their Python glue
cost more than the work. Here one kernel keys each finite in-grid point by its cell exactly as the
build kernels do (``floor(u / cell) - origin``), sorts the (cell, height) pairs, clusters each cell
(thesis test 4.2.4, as :func:`mapping._vhv_kernels.cluster_cells`) and merges the frame's structures
into the map's (:func:`mapping._vhv_kernels.merge_structures`): the structures of a cloud are unique
(the clustering of its points), so the map comes out the same as through :meth:`mapping.vhv.VHVMap.insert`.
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from mapping import _vhv_kernels as K
from mapping._deps import announce_compilation

_merge = K.merge_structures


@numba.jit(cache=True, nogil=True, nopython=True, error_model="numpy", boundscheck=False)
def insert_few(pts, ics, ou, ov, nx, ny, cu, cv, ch, tol, k1, b1, t1):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Structures of the map ``(k1, b1, t1)`` with the cloud ``pts`` (N, 3) merged in.

    Returns:
        (key, bottom, top, n_nonfinite, n_outside_grid, n_frame_structures); with no point kept
        (``n_frame_structures == 0``) the arrays are empty and the map stays as it is.
    """
    n = pts.shape[0]
    keys = np.empty(n, np.int64)
    hs = np.empty(n, np.float64)
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
        keys[m] = np.int64(fi) * ny + np.int64(fj)
        hs[m] = h
        m += 1
    if m == 0:
        e = np.empty(0, np.float64)
        return np.empty(0, np.int64), e, e.copy(), n_nonfinite, n_outside, 0
    order = np.argsort(keys[:m], kind="mergesort")
    sk = keys[:m][order]
    sh = hs[:m][order]
    # heights of each cell in order (an insertion sort for the few of a small cell)
    a = 0
    while a < m:
        b = a + 1
        while b < m and sk[b] == sk[a]:
            b += 1
        if b - a > 32:
            sh[a:b].sort()
        else:
            for q in range(a + 1, b):
                z = sh[q]
                r = q - 1
                while r >= a and sh[r] > z:
                    sh[r + 1] = sh[r]
                    r -= 1
                sh[r + 1] = z
        a = b
    k2 = np.empty(m, np.int64)
    b2 = np.empty(m, np.float64)
    t2 = np.empty(m, np.float64)
    n2 = 0
    for q in range(m):
        z = sh[q]
        if n2 > 0 and k2[n2 - 1] == sk[q] and z - t2[n2 - 1] <= tol:
            t2[n2 - 1] = z
        else:
            k2[n2] = sk[q]
            b2[n2] = z
            t2[n2] = z
            n2 += 1
    if k1.shape[0] == 0:
        return k2[:n2].copy(), b2[:n2].copy(), t2[:n2].copy(), n_nonfinite, n_outside, n2
    key, bot, top = _merge(k1, b1, t1, k2[:n2], b2[:n2], t2[:n2], tol)
    return key, bot, top, n_nonfinite, n_outside, n2


# first run after an install or a change here: say what is being compiled
announce_compilation(sys.modules[__name__], "small-cloud map kernel")
