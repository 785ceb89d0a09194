"""The laser observation from a scan's REP-117 ranges in one compiled pass (numba), numpy's values.

:meth:`robchair.envs.observation.ObservationBuilder.take_readings` mapped the 682 ranges to the
observation's box in five numpy passes (``+inf`` -> ``range_max``, ``-inf`` -> 0, a clip, the float32
cast); :func:`laser_observation` does it per beam with numpy's clip rule (``NaN`` stays, and so does
the value on a tie: ``clip(-0.0, 0.0, 1.0)`` is ``-0.0``), so the values are the same bit for bit
(``tests/robchair/test_env_obs_kernels.py``).
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


@numba.njit(cache=True, nogil=True)
def _laser_obs(r, rmax, out):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    for i in range(r.shape[0]):
        v = float(r[i])
        if v == np.inf:
            v = rmax
        elif v == -np.inf:
            v = 0.0
        v = 0.0 if v < 0.0 else v  # numpy's clip: the value stays on a tie (-0.0), NaN stays
        v = rmax if v > rmax else v
        out[i] = np.float32(v)


def laser_observation(ranges: np.ndarray, range_max: float, out: np.ndarray | None = None) -> np.ndarray:
    """(N,) float32 ``clip(where(+inf, range_max, where(-inf, 0, r)), 0, range_max)`` of the float32 or
    float64 ``ranges`` (N,); written into ``out`` (N,) float32 when given."""
    announce_compilation(sys.modules[__name__], "observation kernel")
    res = np.empty(ranges.shape[0], dtype=np.float32) if out is None else out
    _laser_obs(ranges, float(range_max), res)
    return res
