"""The perception stage's compiled point kernels (numba); see :mod:`robchair.perception_kernels`."""

from __future__ import annotations

import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


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


# first run after an install or a change here: say why the first cycle takes seconds
announce_compilation(sys.modules[__name__], "perception point kernels")
