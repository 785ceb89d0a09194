"""Small pure helpers of :class:`robchair.runtime.Runtime`'s cycle and result (no state, no I/O)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _has_servo(array: Any) -> bool:
    """Whether a sonar array can turn (a simulated array says so; a driver array has a ``servo``)."""
    flag = getattr(array, "has_servo", None)
    if flag is not None:
        return bool(flag)
    return getattr(array, "servo", None) is not None and hasattr(array, "set_servo_deg")


def _planar(t: np.ndarray) -> tuple[float, float, float]:
    """(x, y, yaw) of a planar (4, 4) transform."""
    return float(t[0, 3]), float(t[1, 3]), math.atan2(float(t[1, 0]), float(t[0, 0]))


def _min_or(a: float | None, b: float | None) -> float | None:
    """min of two optional values (None = no value)."""
    if a is None:
        return b
    return a if b is None else min(a, b)
