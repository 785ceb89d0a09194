"""One compiled pass over a frame of ``robchair map``: the points within ``--min-range`` of the sensor,
the grid-plane bounds of the finite points and the height-band counts, in one read of the points
(numba, cached; the numpy forms they replace read the frame five times).

Units are the points' (metres); the columns are those of the map's axes (:data:`mapping.grid.AXIS_COLUMNS`).
"""

from __future__ import annotations

import sys
from typing import Any

import numba
import numpy as np

from mapping._deps import announce_compilation

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "nopython": True, "error_model": "numpy"}


@numba.jit(**_JIT)
def frame_pass(p, ref, min_range2, cu, cv, ch, band_lo, band_hi, close, out):  # type: ignore[no-untyped-def]
    """Mark the close points and measure the finite far ones.

    Args:
        p: ``(N, 3)`` float32/float64 points.
        ref: ``(3,)`` float64 sensor position (the range is measured from it).
        min_range2: squared ``--min-range``, m²; a point with ``|p - ref|² <= min_range2`` is close
            (a non-finite point never is).
        cu, cv, ch: columns of the grid's two axes and of the kept (height) axis.
        band_lo, band_hi: the 2D band along the kept axis, m.
        close: ``(N,)`` bool output, True for the close points.
        out: ``(8,)`` float64 output over the finite points that are not close: count, count in the
            band, lowest and highest height, lowest and highest u, lowest and highest v (inf/-inf when
            there are none).

    Returns:
        The number of close points.
    """
    n_close = 0
    cnt = 0.0
    inb = 0.0
    hlo, hhi, ulo, uhi, vlo, vhi = np.inf, -np.inf, np.inf, -np.inf, np.inf, -np.inf
    for i in range(p.shape[0]):
        x = np.float64(p[i, 0])
        y = np.float64(p[i, 1])
        z = np.float64(p[i, 2])
        dx, dy, dz = x - ref[0], y - ref[1], z - ref[2]
        if dx * dx + dy * dy + dz * dz <= min_range2:
            close[i] = True
            n_close += 1
            continue
        close[i] = False
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        u, v, h = np.float64(p[i, cu]), np.float64(p[i, cv]), np.float64(p[i, ch])
        cnt += 1.0
        if band_lo <= h <= band_hi:
            inb += 1.0
        hlo, hhi = min(hlo, h), max(hhi, h)
        ulo, uhi = min(ulo, u), max(uhi, u)
        vlo, vhi = min(vlo, v), max(vhi, v)
    out[0], out[1], out[2], out[3] = cnt, inb, hlo, hhi
    out[4], out[5], out[6], out[7] = ulo, uhi, vlo, vhi
    return n_close


announce_compilation(sys.modules[__name__], "map frame kernel")
