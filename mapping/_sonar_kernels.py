"""Compiled Fig. 5.7 cone of :func:`mapping.sonar.cone_points`, for :func:`mapping.sonar.fusion_points`.

A run meets each cone (range, interval) once and keeps it; the numpy build costs ~80 us of small
array calls per cone, paid at every new cone of a run (the perception stage's every-reading path).
This is the same computation element by element: the same float64 operations in numpy's order (no
fused multiply-add without ``fastmath``) and the C library's ``cos``/``sin`` numpy calls for float64
here; a test compares it with :func:`mapping.sonar.cone_points` bit for bit.
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


@numba.njit(cache=True, nogil=True)
def cone_points_compiled(range_m, theta_deg, alpha_deg, ppc, n_rings):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """``cone_points(range_m, theta_deg, alpha_deg, ppc)`` with ``n_rings = len(np.arange(0.0, theta/2))``."""
    out = np.empty((n_rings * ppc, 3))
    e0 = 90.0 - theta_deg / 2.0
    r0 = alpha_deg + theta_deg / 2.0
    for k in range(n_rings):
        i = float(k)
        elev = math.radians(e0 - i)
        rot = math.radians(r0 - i)
        se = range_m * math.sin(elev)
        ce = range_m * math.cos(elev)
        cr = math.cos(rot)
        sr = math.sin(rot)
        for j in range(ppc):
            spin = math.radians(360.0 * float(j) / ppc)
            aux_x = se * 1.0
            aux_y = ce * math.sin(spin)
            q = k * ppc + j
            out[q, 0] = cr * aux_x - sr * aux_y
            out[q, 1] = sr * aux_x + cr * aux_y
            out[q, 2] = ce * math.cos(spin)
    return out


# first run after an install or a change here: say what is being compiled
announce_compilation(sys.modules[__name__], "sonar cone kernel")
