"""The sonar group's Embree ray rows in one compiled pass (numba).

:meth:`sim.sonar._Beam.first_echo` casts every sonar of a group in one call from an ``(k * n, 6)``
float32 array of (origin, direction) rows: sonar ``s``'s origin repeated over its ``n`` rays, then the
rays' world directions. numpy fills it in two broadcasting, strided, float64 -> float32 assignments
(48 us CPU for the chair's 6 x 1102 rays, about 5 % of the sonars' cost per step); :func:`fill_rays`
writes each row once. Each value is the same float64 -> float32 rounding numpy does, so the rows are
numpy's bit for bit (the tests compare both).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _fill_rays(stack, dirs, rays):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    k = stack.shape[0]
    n = dirs.shape[0] // k
    for s in range(k):
        ox = np.float32(stack[s, 0, 3])
        oy = np.float32(stack[s, 1, 3])
        oz = np.float32(stack[s, 2, 3])
        for j in range(s * n, (s + 1) * n):
            rays[j, 0] = ox
            rays[j, 1] = oy
            rays[j, 2] = oz
            rays[j, 3] = np.float32(dirs[j, 0])
            rays[j, 4] = np.float32(dirs[j, 1])
            rays[j, 5] = np.float32(dirs[j, 2])


def fill_rays(stack: np.ndarray, dirs: np.ndarray, rays: np.ndarray) -> None:
    """Write Embree's rows for ``k`` sonars into ``rays``.

    Args:
        stack: (k, 4, 4) float64 world poses of the sonars (C-contiguous).
        dirs: (k * n, 3) float64 world ray directions, sonar by sonar (C-contiguous).
        rays: (k * n, 6) float32 output, C-contiguous: origin of the row's sonar, then its direction.

    Raises:
        ValueError: shapes, dtypes or layouts that do not fit.
    """
    k = stack.shape[0] if stack.ndim == 3 else 0
    ok = (
        stack.shape == (k, 4, 4)
        and k > 0
        and dirs.ndim == 2
        and dirs.shape[1] == 3
        and dirs.shape[0] % k == 0
        and rays.shape == (dirs.shape[0], 6)
        and stack.dtype == np.float64
        and dirs.dtype == np.float64
        and rays.dtype == np.float32
        and stack.flags.c_contiguous
        and dirs.flags.c_contiguous
        and rays.flags.c_contiguous
    )
    if not ok:
        raise ValueError(
            f"fill_rays: stack {stack.shape} {stack.dtype}, dirs {dirs.shape} {dirs.dtype}, rays "
            f"{rays.shape} {rays.dtype}: expected (k, 4, 4) and (k * n, 3) float64, (k * n, 6) float32, "
            "all C-contiguous"
        )
    import sys

    from mapping._deps import announce_compilation

    announce_compilation(sys.modules[__name__], "sonar ray kernels")
    _fill_rays(stack, dirs, rays)
