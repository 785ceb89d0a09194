"""The simulated laser's per-beam arithmetic around the ray cast in three compiled passes (numba).

:meth:`sim.laser.LaserSim.ranges` turned the beams into Embree's rays, the hits into ranges and the
ranges into REP-117 readings with noise in about twenty numpy passes over the 682 beams (a third of
a light environment step's laser read, more than the cast). Each kernel does one of those stages per
beam, operation for operation in numpy's order (no fast-math, so the values are numpy's bit for bit;
``tests/sim/test_laser_kernels.py`` compares them with the numpy path). The noise itself is still
drawn by the caller's ``numpy.random.Generator``, as many normals as before, so a seed gives the same
scans.
"""

from __future__ import annotations

import sys
from typing import Any

import numba
import numpy as np

from mapping._deps import announce_compilation


@numba.njit(cache=True, nogil=True)
def _fill_rays(t, dirs, rays):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    for a in range(4):
        for b in range(4):
            if not np.isfinite(t[a, b]):
                return False
    n = dirs.shape[0]
    for i in range(n):
        for k in range(3):
            if not np.isfinite(dirs[i, k]):
                return False
    ox, oy, oz = np.float32(t[0, 3]), np.float32(t[1, 3]), np.float32(t[2, 3])
    for i in range(n):
        rays[i, 0] = ox
        rays[i, 1] = oy
        rays[i, 2] = oz
        rays[i, 3] = np.float32(dirs[i, 0])
        rays[i, 4] = np.float32(dirs[i, 1])
        rays[i, 5] = np.float32(dirs[i, 2])
    return True


@numba.njit(cache=True, nogil=True)
def _hit_ranges(t_hit, gid, invalid, rmin, rmax, out):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    n = 0
    for i in range(t_hit.shape[0]):
        d = np.float64(t_hit[i])
        if gid[i] == invalid or not d <= rmax:
            out[i] = np.inf
        else:
            out[i] = d
            if not d < rmin:
                n += 1
    return n


@numba.njit(cache=True, nogil=True)
def _count_measured(r, rmin, rmax):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    n = 0
    for i in range(r.shape[0]):
        v = r[i]
        if np.isfinite(v) and v <= rmax and not v < rmin:
            n += 1
    return n


@numba.njit(cache=True, nogil=True)
def _readings(r, z, noise, rmin, rmax, near_m, knee_m, relative, sigmas, res, out):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    k = 0
    for i in range(r.shape[0]):
        v = r[i]
        if not (np.isfinite(v) and v <= rmax):
            out[i] = np.float32(np.inf)
        elif v < rmin:
            out[i] = np.float32(-np.inf)
        else:
            if noise:
                acc = near_m if v <= knee_m else relative * v  # LaserModel.accuracy
                v = v + z[k] * (acc / sigmas)
            k += 1
            out[i] = np.float32(np.rint(v / res) * res)


_NO_NOISE = np.empty(0, dtype=np.float64)


def fill_rays(t: np.ndarray, dirs: np.ndarray, rays: np.ndarray) -> bool:
    """Write Embree's rays ``(origin, direction)`` (N, 6) float32 into ``rays``: the origin is ``t``'s
    translation, the directions ``dirs`` (N, 3) (world frame, float64). False (nothing written) when
    ``t`` (4, 4) or ``dirs`` holds a non-finite value."""
    announce_compilation(sys.modules[__name__], "laser kernels")
    return bool(_fill_rays(t, dirs, rays))


def hit_ranges(
    t_hit: np.ndarray, gid: np.ndarray, invalid_id: int, range_min: float, range_max: float
) -> tuple[np.ndarray, int]:
    """(N,) float64 ranges of Embree's hits: ``t_hit``, or ``inf`` for a miss (``gid == invalid_id``)
    and beyond ``range_max`` (m); and how many are measurements (:func:`count_measured`)."""
    out = np.empty(t_hit.shape[0], dtype=np.float64)
    n = _hit_ranges(t_hit, gid, np.uint32(invalid_id), float(range_min), float(range_max), out)
    return out, int(n)


def count_measured(r: np.ndarray, range_min: float, range_max: float) -> int:
    """Beams of ``r`` (N,) float64 ranges that are measurements: finite, ``range_min <= r <= range_max``."""
    return int(_count_measured(r, float(range_min), float(range_max)))


def readings(r: np.ndarray, z: np.ndarray | None, model: Any, sigmas: float) -> np.ndarray:
    """(N,) float32 REP-117 readings of the true ranges ``r`` (N,) float64 (see :meth:`LaserSim.ranges`).

    Args:
        r: true ranges, m (``inf``: no hit).
        z: one standard normal per measured beam (:func:`count_measured` of them) in beam order, or
            None for no noise.
        model: the :class:`sim.laser.LaserModel` (limits, accuracy, resolution).
        sigmas: the datasheet's accuracy bound is this many standard deviations.
    """
    m = model
    out = np.empty(r.shape[0], dtype=np.float32)
    zz = z if z is not None else _NO_NOISE
    _readings(r, zz, z is not None, float(m.range_min), float(m.range_max), float(m.accuracy_near_m),
              float(m.accuracy_knee_m), float(m.accuracy_relative), float(sigmas), float(m.resolution_m),
              out)  # fmt: skip
    return out
