"""What a fusion meets once per new range or cone, computed without small numpy arrays.

A run meets each new range and cone once, at its start, in the perception stage's every-reading path.
The bisection of :mod:`mapping.sonar` on a one-element array costs some 800 numpy calls (60 halvings):
:func:`one_bearing_deg` makes the same operations on Python floats (IEEE float64, the C library's
``cos`` and ``sin`` that numpy calls for float64 here); :func:`cone_points_fast` is the compiled
:func:`mapping.sonar.cone_points`. Tests compare both with the numpy versions bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

#: Coefficients of the beam's boundaries (:data:`mapping.sonar.TOP_BOUNDARY_COEFFS_CM`, ``BOTTOM_...``).
_TOP = (-0.0031, 1.2082, -14.2762)
_BOTTOM = (0.0001, -0.8483, 7.7197)


def one_bearing_deg(d_cm: float, side: str) -> float:
    """``_crossing_bearing_deg(np.array([d_cm]), side)[0]``: 60 halvings of [0, 89] deg, as floats."""
    a, b, c = _TOP if side == "left" else _BOTTOM
    sign = 1.0 if side == "left" else -1.0
    lo, hi = 0.0, 89.0
    cos, sin, radians = math.cos, math.sin, math.radians
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        phi = radians(mid)
        x = d_cm * cos(phi)
        y = d_cm * sin(phi)
        bound = a * x * x + b * x + c
        if y <= (bound if sign > 0.0 else -bound):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def cone_points_fast(range_m: float, theta_deg: float, alpha_deg: float, ppc: int) -> np.ndarray:
    """:func:`mapping.sonar.cone_points` of a fusion's cone (finite, ``theta_deg > 0``, ``ppc >= 1``) in
    one compiled pass (:mod:`mapping._sonar_kernels`), the same (N, 3) float64 points bit for bit."""
    from mapping._sonar_kernels import cone_points_compiled

    n_rings = len(np.arange(0.0, theta_deg / 2.0))  # the rings cone_points makes, as it counts them
    return cone_points_compiled(float(range_m), float(theta_deg), float(alpha_deg), int(ppc), n_rings)  # type: ignore[no-any-return]
