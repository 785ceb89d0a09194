"""A laser scan's beam end points in one compiled pass (numba), numpy's arithmetic bit for bit.

:func:`hw.laser_scan.scan_to_points` took six numpy passes over the 682 beams of every scan (the
products, a stack, the validity mask and the selection); :func:`beam_points` does the same per beam:
the range (float32 or float64) widened to float64 times the beam's cosine and sine, z = 0, kept when
finite within the limits (compared in the ranges' own type, as numpy compares an array with a Python
float). ``tests/hw/test_laser_scan_kernels.py`` compares it with the numpy path.
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


@numba.njit(cache=True, nogil=True)
def _beam_points(r, c, s, lo, hi, keep_invalid):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    n = r.shape[0]
    m = 0
    for i in range(n):
        if np.isfinite(r[i]) and r[i] >= lo and r[i] <= hi:
            m += 1
    out = np.empty((n if keep_invalid else m, 3), dtype=np.float64)
    k = 0
    for i in range(n):
        if np.isfinite(r[i]) and r[i] >= lo and r[i] <= hi:
            v = np.float64(r[i])
            out[k, 0] = v * c[i]
            out[k, 1] = v * s[i]
            out[k, 2] = 0.0
            k += 1
        elif keep_invalid:
            out[k, 0] = np.nan
            out[k, 1] = np.nan
            out[k, 2] = np.nan
            k += 1
    return out


def beam_points(
    r: np.ndarray, cos_a: np.ndarray, sin_a: np.ndarray, lo: np.floating, hi: np.floating, keep_invalid: bool
) -> np.ndarray:
    """(M, 3) float64 end points of the measured beams of ``r`` (N,) (``keep_invalid``: (N, 3) with NaN
    rows); ``lo``, ``hi`` the range limits as scalars of ``r``'s dtype."""
    announce_compilation(sys.modules[__name__], "laser scan kernel")
    return _beam_points(r, cos_a, sin_a, lo, hi, bool(keep_invalid))  # type: ignore[no-any-return]
