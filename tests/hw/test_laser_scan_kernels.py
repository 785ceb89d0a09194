"""scan_to_points' compiled pass against the numpy path it replaces, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hw.interfaces import LaserScan
from hw.laser_scan import scan_to_points, scan_to_points_reference


def _scan(ranges: np.ndarray, range_min: float = 0.02, range_max: float = 4.0) -> LaserScan:
    n = len(ranges)
    inc = 2.0 * math.pi / 1024.0
    return LaserScan(stamp_ns=0, angle_min=-340 * inc, angle_max=(n - 341) * inc, angle_increment=inc,
                     time_increment=1e-4, scan_time=0.1, range_min=range_min, range_max=range_max,
                     ranges=ranges)  # fmt: skip


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("keep_invalid", [False, True])
def test_the_compiled_beam_points_are_numpys_bit_for_bit(dtype, keep_invalid):
    rng = np.random.default_rng(5)
    for _ in range(50):
        r = rng.uniform(-0.5, 5.0, 682).astype(dtype)
        r[rng.random(682) < 0.1] = np.inf
        r[rng.random(682) < 0.05] = -np.inf
        r[rng.random(682) < 0.05] = np.nan
        # on the limits: a float32 0.02 is below the float64 0.02, and numpy compares in float32
        r[:4] = (0.02, 4.0, np.nextafter(dtype(0.02), dtype(0.0)), np.nextafter(dtype(4.0), dtype(5.0)))
        scan = _scan(r)
        a = scan_to_points(scan, keep_invalid=keep_invalid)
        b = scan_to_points_reference(scan, keep_invalid=keep_invalid)
        assert a.dtype == b.dtype == np.float64 and a.shape == b.shape
        np.testing.assert_array_equal(a.view(np.uint64), b.view(np.uint64))
