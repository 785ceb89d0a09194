"""The 2D occupancy of a VHV map's height band from its flat cell keys in one compiled pass (numba).

:func:`mapping.derived.occupancy_2d` of a :class:`mapping.vhv.VHVMap` marks the cell ``key`` of every
structure that overlaps the band (``top >= z_min`` and ``bottom <= z_max``); a light environment asks
for it every step, of a map of thousands of structures, where the four numpy passes of the mask and
the scatter cost more than the arithmetic. The same comparisons, structure by structure, give the
same cells (``tests/mapping/test_derived_occupancy_keys.py``).
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


@numba.njit(cache=True, nogil=True)
def _mark_band(key, bottom, top, z_min, z_max, flat):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    for k in range(key.shape[0]):
        if top[k] >= z_min and bottom[k] <= z_max:
            flat[key[k]] = True


def mark_band(key: np.ndarray, bottom: np.ndarray, top: np.ndarray, z_min: float, z_max: float,
              flat: np.ndarray) -> None:  # fmt: skip
    """Set ``flat[key[k]]`` (bool, the grid's flat cells) for every structure ``k`` whose
    ``[bottom, top]`` overlaps ``[z_min, z_max]`` (m)."""
    announce_compilation(sys.modules[__name__], "occupancy kernel")
    _mark_band(key, bottom, top, float(z_min), float(z_max), flat)
