"""The swept-footprint check's reach filter against numpy's einsum selection, point for point."""

from __future__ import annotations

import numpy as np

from robchair.platform._safety_kernels import within_reach


def test_the_points_within_reach_are_the_einsum_selections_bit_for_bit():
    rng = np.random.default_rng(11)
    for n in (0, 1, 7, 600, 5000):
        for scale in (1e-3, 1.0, 50.0):
            xy = rng.normal(0.0, scale, (n, 2))
            for r in (0.0, 0.5, 1.2, 3.0):
                r2 = r * r
                if n:  # points exactly on the reach, both axes
                    xy[0] = (r, 0.0)
                    xy[-1] = (0.0, -r)
                want = xy[np.einsum("ij,ij->i", xy, xy) <= r2]
                got = within_reach(xy, r2)
                assert got.dtype == np.float64 and got.shape == want.shape
                np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64))
    strided = rng.normal(0.0, 1.0, (300, 3))[:, :2]  # a view, as the perception's arcs are
    np.testing.assert_array_equal(within_reach(strided, 1.0),
                                  strided[np.einsum("ij,ij->i", strided, strided) <= 1.0])  # fmt: skip
