"""The observation's compiled and plain-float paths against the numpy expressions they replace."""

from __future__ import annotations

import numpy as np

from robchair.envs._obs_kernels import laser_observation
from robchair.envs.observation import clip_value

SPECIAL = (0.0, -0.0, 4.0, -4.0, np.inf, -np.inf, np.nan, 1e-300, -1e-300)


def _ranges(dtype, rng):  # type: ignore[no-untyped-def]
    r = rng.uniform(-1.0, 5.0, 700).astype(dtype)
    r[: len(SPECIAL)] = SPECIAL
    return r


def test_the_compiled_laser_observation_is_numpys_bit_for_bit():
    rng = np.random.default_rng(8)
    for dtype in (np.float32, np.float64):
        for rmax in (4.0, 5.6):
            r = _ranges(dtype, rng)
            r64 = np.asarray(r, dtype=np.float64)
            rr = np.where(np.isposinf(r64), rmax, np.where(np.isneginf(r64), 0.0, r64))
            want = np.clip(rr, 0.0, rmax).astype(np.float32)
            got = laser_observation(r, rmax)
            assert got.dtype == np.float32
            np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))


def test_one_clipped_value_is_numpys_clip():
    rng = np.random.default_rng(9)
    xs = [*SPECIAL, *rng.uniform(-6, 6, 300)]
    for lo, hi in ((0.0, 4.0), (-0.0, 0.0), (-1.5, 1.5), (np.float32(-0.93), np.float32(0.93))):
        for x in xs:
            want = np.clip(np.array([x]), lo, hi)[0]
            got = clip_value(float(x), float(lo), float(hi))
            assert np.array([got]).view(np.uint64)[0] == np.array([want]).view(np.uint64)[0], (x, lo, hi)
