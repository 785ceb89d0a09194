"""The binning pass's paired (min, max) scatter against the scalar updates it replaced, bit for bit."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from mapping import _vhv_kernels as K


def _scalar_scatter(pc: np.ndarray, m: int, xh: int, buf: np.ndarray, mm: np.ndarray) -> None:
    """The scatter as numba's ``min`` / ``max`` did it (``h < x``, ``h > y``; ties keep the stored value),
    in the kernel's interleaved order (ties of +0.0 and -0.0 make the order visible in the bits)."""
    streams = K._STREAMS
    ms = m // streams
    order = [q + k * ms for q in range(ms) for k in range(streams)] + list(range(streams * ms, m))
    for r in order:
        i = int(buf[r])
        h = pc[3 * r + xh]
        if h < mm[i]:
            mm[i] = h
        if h > mm[i + 1]:
            mm[i + 1] = h


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_paired_scatter_equals_the_scalar_min_max_bit_for_bit(dtype: Any, seed: int) -> None:
    """Heights drawn from a few values (many ties, +0.0 and -0.0 in one bin, both infinities' neighbours
    and NaN only in the scratch slot), slots colliding often, a table partly empty and partly filled:
    the compiled paired update leaves exactly the bits the scalar min / max leave."""
    rng = np.random.default_rng(seed)
    n_bins = 23
    trash = 2 * n_bins
    m = 4096 + 37  # a full chunk's streams plus a tail
    values: Any = np.array([-0.0, 0.0, 1.5, -1.5, 0.25, 1e-30, -1e-30, 3.0e38, -3.0e38], dtype)
    buf = (2 * rng.integers(0, n_bins, m)).astype(np.int32)
    # bins below 8 see only signed zeros (their result depends on the tie rule and the order)
    h = np.where(buf < 16, values[rng.integers(0, 2, m)], values[rng.integers(0, values.shape[0], m)])
    scratch = rng.random(m) < 0.1
    buf[scratch] = trash
    h[scratch & (rng.random(m) < 0.5)] = np.nan  # non-finite points only ever reach the scratch slot
    pc: Any = np.zeros((m, 3), dtype)
    pc[:, 2] = h
    pc[:, 0] = rng.normal(size=m)
    flat = pc.reshape(-1)
    mm: Any = np.empty(2 * n_bins + 2, dtype)
    mm[0::2], mm[1::2] = np.inf, -np.inf
    filled = (rng.random(n_bins + 1) < 0.4) & (np.arange(n_bins + 1) >= 8)
    mm[0::2][filled] = values[rng.integers(0, values.shape[0], int(filled.sum()))]
    mm[1::2][filled] = values[rng.integers(0, values.shape[0], int(filled.sum()))]
    ref = mm.copy()
    _scalar_scatter(flat, m, 2, buf, ref)
    K._scatter_chunk(flat, m, 2, buf, mm)
    bits = np.uint32 if dtype == np.float32 else np.uint64
    assert np.array_equal(mm[:trash].view(bits), ref[:trash].view(bits))
    # both signed zeros are left in some bins (so the tie rule and the order were exercised)
    zeros = ref[:16]
    assert np.all(zeros == 0.0) and np.any(np.signbit(zeros)) and not np.all(np.signbit(zeros))
