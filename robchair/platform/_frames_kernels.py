"""Compiled point transform for large float32 clouds (:func:`robchair.platform.frames.transform_points`).

``p @ R.T + t`` in numpy on a (N, 3) float32 cloud makes several passes over the points (the skinny
matrix product, then the broadcast sum). A single compiled pass is 2-2.5x faster on the 512x424 depth
frames the perception stage places several times per frame, and runs without the GIL so the mapping
thread and the loop overlap.
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


@numba.njit(cache=True, nogil=True)
def transform_points_f32(m, pts):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """``R p + t`` of the (4, 4) float64 ``m`` for (N, 3) float32 points: float64 sums, float32 out."""
    out = np.empty_like(pts)
    for k in range(pts.shape[0]):
        x, y, z = np.float64(pts[k, 0]), np.float64(pts[k, 1]), np.float64(pts[k, 2])
        for i in range(3):
            out[k, i] = m[i, 0] * x + m[i, 1] * y + m[i, 2] * z + m[i, 3]
    return out


# first run after an install or a change here: say what is being compiled
announce_compilation(sys.modules[__name__], "point transform kernel")
