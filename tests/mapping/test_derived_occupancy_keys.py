"""occupancy_2d of a VHV map from its flat cell keys against the (i, j) path of its structures."""

from __future__ import annotations

import copy

import numpy as np

from mapping.derived import occupancy_2d
from mapping.grid import GridSpec
from mapping.vhv import VHVMap


class _Other(VHVMap):
    """A VHV map of another type: occupancy_2d takes the structures' (i, j) path for it."""


def test_the_occupancy_from_cell_keys_is_the_structures_one():
    rng = np.random.default_rng(6)
    for grid in (GridSpec(cell_size=0.1, size_x=15.8, size_y=8.2, centre=(4.0, -1.0)),
                 GridSpec(cell_size=0.05, size_x=3.0, size_y=7.0)):  # fmt: skip
        m = VHVMap(grid, 0.05)
        x0, x1, y0, y1 = grid.extent
        for _ in range(5):
            n = 3000
            pts = np.column_stack([rng.uniform(x0 - 1, x1 + 1, n), rng.uniform(y0 - 1, y1 + 1, n),
                                   rng.uniform(-0.2, 2.0, n)])  # fmt: skip
            pts[::50, 2] = 0.1  # structures that only touch the band's edges
            pts[1::50, 2] = 1.3
            m.insert(pts, sensor_origin=(0.0, 0.0, 0.5))
            other = copy.copy(m)
            other.__class__ = _Other
            for band in ((0.1, 1.3), (0.0, 0.0), (1.99, 2.5), (-1.0, 5.0)):
                a, b = occupancy_2d(m, *band), occupancy_2d(other, *band)
                assert a.dtype == b.dtype == np.bool_ and a.shape == b.shape == grid.shape
                np.testing.assert_array_equal(a, b)
        assert 0 < occupancy_2d(m, 0.1, 1.3).sum() < m.spec.shape[0] * m.spec.shape[1]
