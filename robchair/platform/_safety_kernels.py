"""The swept-footprint check's first filter in one compiled pass (numba), numpy's values bit for bit.

:meth:`robchair.platform.safety.SafetyLayer.sweep_scale` keeps, of the few hundred obstacle points
around the chair, those within the footprint's reach over the stop (``x * x + y * y <= reach ** 2``,
numpy's ``einsum("ij,ij->i", xy, xy)``): the einsum and the boolean selection were most of a cycle's
check, which usually ends there (nothing within reach). :func:`within_reach` makes the same sums, in the
same order, and keeps the same points (``tests/robchair/test_safety_kernels.py``).
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


@numba.njit(cache=True, nogil=True)
def _within(xy, r2):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    n = 0
    for i in range(xy.shape[0]):
        if xy[i, 0] * xy[i, 0] + xy[i, 1] * xy[i, 1] <= r2:
            n += 1
    out = np.empty((n, 2), dtype=np.float64)
    k = 0
    for i in range(xy.shape[0]):
        if xy[i, 0] * xy[i, 0] + xy[i, 1] * xy[i, 1] <= r2:
            out[k, 0] = xy[i, 0]
            out[k, 1] = xy[i, 1]
            k += 1
    return out


def within_reach(xy: np.ndarray, reach_sq: float) -> np.ndarray:
    """The points of ``xy`` (N, 2) float64 with ``x * x + y * y <= reach_sq`` (m^2), in order: (M, 2)."""
    announce_compilation(sys.modules[__name__], "safety kernel")
    return _within(xy, float(reach_sq))  # type: ignore[no-any-return]
