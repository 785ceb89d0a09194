"""The beam's half-aperture at one range on floats (:func:`mapping.sonar._crossing_bearing_deg`).

The bisection of :mod:`mapping.sonar` on a one-element array costs some 800 numpy calls (60 halvings);
a fusion meets a new range at the start of a run, in the perception stage's every-reading path. The
same operations on Python floats (IEEE float64, the C library's ``cos`` and ``sin`` that numpy calls
for float64 here) give the same value; a test compares them over the model's domain.
"""

from __future__ import annotations

import math

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
