"""Shared cases of the VHV build tests (tests/mapping/test_vhv.py, test_vhv_frames.py)."""

from __future__ import annotations

import numpy as np

from mapping.grid import GridSpec
from mapping.vhv import Structures

METHODS = ("auto", "bins", "sort", "numpy")


def as_tuples(s: Structures) -> list[tuple[int, int, float, float]]:
    return list(zip(s.i.tolist(), s.j.tolist(), s.bottom.tolist(), s.top.tolist()))


SPEC = GridSpec(cell_size=0.05, size_x=1.0, size_y=1.0, centre=(0.0, 0.0))


def chunked_edge_clouds() -> list[tuple[str, np.ndarray]]:
    """Clouds of several thousand points, so that the binning pass crosses its chunks (4096 points)."""
    rng = np.random.default_rng(20)
    n = 2 * 4096 + 123
    # random points with single NaN / inf coordinates and points off the grid (the grid is [-0.5, 0.5))
    mixed = rng.uniform(-0.6, 0.6, (n, 3))
    mixed[rng.random(n) < 0.1, 0] = np.nan
    mixed[rng.random(n) < 0.02, 1] = np.inf
    mixed[rng.random(n) < 0.02, 2] = np.nan
    # cell edges (multiples of the 5 cm cell) and bin edges (multiples of the bin width, 5 cm less 1e-6)
    edges = rng.integers(-10, 10, (n, 3)) * 0.05
    edges[::3, 2] = rng.integers(-20, 40, edges[::3].shape[0]) * (0.05 * (1.0 - 1e-6))
    edges[1::3, 2] = edges[1::3, 2] + rng.choice(
        [0.0, 0.05, -0.05, 0.05000001, 0.04999999], edges[1::3].shape[0]
    )
    # one point per cell, over all 400 cells, heights a gap of more or less than the tolerance apart
    ii, jj = np.meshgrid(np.arange(20), np.arange(20), indexing="ij")
    one = np.stack([ii.ravel() * 0.05 - 0.475, jj.ravel() * 0.05 - 0.475, rng.uniform(0, 2, 400)], 1)
    one = np.concatenate([one] * 12)[: 12 * 400 - 7]
    one[400:, 2] += rng.integers(0, 3, one.shape[0] - 400) * 0.0501
    # every point in one cell: a long column with gaps around the tolerance
    col = np.column_stack(
        [np.full(n, 0.01), np.full(n, 0.02), np.cumsum(rng.choice([0.0, 0.01, 0.05, 0.06], n))]
    )
    col[::97] = np.nan
    return [("mixed", mixed), ("edges", edges), ("one per cell", one), ("one cell", col)]
