"""The build and merge paths of :class:`mapping.vhv.VHVMap`: compiled bins, compiled sort, numpy.

Each turns one cloud into sorted structures (cell key ``i * ny + j``, bottom, top) or merges two such
lists, with exactly the result of the thesis's sort + unique + cluster (section 4.2).

Sorting 2 million heights per frame is what dominates a direct implementation. The default path never
sorts points: one pass keeps, per *(cell, height bin)* with bins of width ``w`` slightly below
``tolerance``, the minimum and maximum height; a second pass walks the non-empty bins of each cell in
order and joins a bin to the current structure when ``bin.min - structure.top <= tolerance``.
This gives exactly the sort + unique + cluster result:

* all heights inside one bin differ by at most ``w <= tolerance`` (``w`` is shrunk by a relative
  1e-6 so that floating-point rounding of ``h * (1 / w)`` cannot make a bin wider than ``tolerance``), so
  every gap between consecutive sorted values inside a bin is ``<= tolerance`` and a bin never splits;
* ``floor(h * (1 / w))`` is monotone in ``h``, so the max of one non-empty bin and the min of the next
  non-empty bin of the same cell are *consecutive* sorted values, and the test on them is the thesis's
  test (4.2.4) on the same two float64 numbers.

The dense (cell, bin) table spans only the frame's bounding box, guessed from every 32nd point and
widened by a margin; points outside the guess are not lost but clustered by the sort path and merged
in (exactly, as :mod:`mapping.vhv` merges frames). When the table would exceed the size of the input
array (or 4 MiB for small clouds) or would be mostly empty (more entries than twice the points) —
small or sparse clouds, outliers far away in height — the build takes the compiled sort path instead
(``method="sort"``, the thesis's pipeline: a counting sort by cell, then a sort per cell).
``method="numpy"`` is the bin algorithm without numba, kept for the benchmark.
"""

from __future__ import annotations

import math
import threading

import numpy as np
from numpy.typing import NDArray

from mapping.grid import GridSpec

# Bins are a relative 1e-6 narrower than the tolerance so that no bin can span more than it (see above).
_BIN_SHRINK = 1.0 - 1e-6


def _grid_args(spec: GridSpec) -> tuple[float, int, int, int, int, int, int, int]:
    (ou, ov), (nx, ny) = spec.origin, spec.shape
    cu, cv, ch = spec.columns
    return spec.inv_cell_size, ou, ov, nx, ny, cu, cv, ch


def _dense_budget_bytes(pts: NDArray[np.floating]) -> int:
    # The dense (cell, bin) min/max table may use as much memory as the input array itself, so that
    # peak extra memory stays <= 2x the input (the SPEC memory target); small clouds may use 4 MiB, which is
    # nothing next to the interpreter and keeps them on the fast path.
    return max(int(pts.nbytes), 4 << 20)


def _box_range(lo: float, hi: float, ics: float, origin: int, n: int) -> tuple[int, int]:
    """Index range [first, last] of the grid cells that the coordinate range [lo, hi] can touch."""
    first = max(_floor(lo * ics) - origin, 0)
    last = min(_floor(hi * ics) - origin, n - 1)
    return first, last


def _floor(x: float) -> int:
    """``floor`` that survives coordinates near the float64 limit (``x`` may be +-inf after scaling)."""
    return math.floor(min(max(x, -(2.0**62)), 2.0**62))


# Points sampled to guess the frame's box (every _SAMPLE_STEP-th); the guess is widened by a margin and
# points that still fall outside it are handled exactly by the sort path, so the guess never changes
# the result, only the speed. Prime steps: every 32nd point of an HD frame (a 384-byte stride) cost
# 0.86 ms, every 97th 0.11 ms when the frame is in cache; a frame that is not (the usual case: it was
# just rendered or read, and the previous build streamed through 25 MB) costs one memory access per
# sample, ~0.65 ms at every 97th point. Clouds of a million points and more take every 997th (2,080
# samples of an HD frame, whose box they guess within the margin).
_SAMPLE_STEP = 97
_SAMPLE_STEP_LARGE = 997
_MARGIN_CELLS = 2
# Table slots addressable by the binning kernel's int32 indices.
_INT32_SLOTS = 2**31 - 1


# Largest (min, max) table kept between frames, per thread and dtype (an HD frame's is ~3 MB in float32).
_KEEP_TABLE_BYTES = 16 << 20
_tables = threading.local()


def _empty_table(entries: int, dtype: np.dtype) -> NDArray[np.floating]:
    """A flat table of at least ``entries`` (min, max) pairs, all (+inf, -inf), to be handed back empty.

    The table of the previous frame of this thread is reused when it is large enough (the extraction
    empties every bin it reads, so it comes back clean, and no page is faulted in or filled again);
    one still marked in use (an earlier build raised midway) is refilled. Larger tables than
    ``_KEEP_TABLE_BYTES`` are allocated per call.
    """
    key = np.dtype(dtype).char
    kept = getattr(_tables, key, None)
    if kept is not None and kept[0].shape[0] >= 2 * entries:
        table, clean = kept
        setattr(_tables, key, (table, False))
        if not clean:
            _fill_empty(table)
        return table
    table = np.empty(2 * entries, dtype=dtype)
    _fill_empty(table)
    if table.nbytes <= _KEEP_TABLE_BYTES:
        setattr(_tables, key, (table, False))
    return table


def _release_table(table: NDArray[np.floating]) -> None:
    """Mark this thread's kept table clean again (every bin back at (+inf, -inf))."""
    key = table.dtype.char
    kept = getattr(_tables, key, None)
    if kept is not None and kept[0] is table:
        setattr(_tables, key, (table, True))


def _fill_empty(table: NDArray[np.floating]) -> None:
    # one contiguous fill of (min, max) = (+inf, -inf) pairs, twice as fast as two strided column fills
    table.view(np.complex64 if table.dtype == np.float32 else np.complex128).fill(complex(np.inf, -np.inf))


def _run_bounds(
    key: NDArray[np.int64], bot: NDArray[np.float64], top: NDArray[np.float64], tol: float
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """First and last index of each structure of a list sorted by (key, bottom): a new structure starts
    where the cell changes or the gap to the previous top exceeds ``tol`` (thesis test 4.2.4)."""
    start = np.ones(key.shape[0], bool)
    start[1:] = (key[1:] != key[:-1]) | (bot[1:] - top[:-1] > tol)
    s = np.flatnonzero(start)
    return s, np.r_[s[1:], key.shape[0]] - 1


def _sort_cluster(
    key: NDArray[np.int64], h: NDArray[np.floating], tol: float
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Structures of (cell key, height) pairs by a vectorised sort (the thesis's pipeline)."""
    order = np.lexsort((h, key))
    key, hs = key[order], h[order].astype(np.float64)
    s, ends = _run_bounds(key, hs, hs, tol)
    return key[s], hs[s], hs[ends]


def _sort_path(
    pts: NDArray[np.floating], spec: GridSpec, tol: float
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], int, int]:
    """Thesis pipeline (compiled): group heights by cell, sort each cell, unique, cluster.

    Grouping is a counting sort over the cells of the frame's exact bounding box (two passes, one
    height per point of extra memory); only when that box has far more cells than there are points
    (a sparse frame) does it sort (cell key, height) pairs with numpy instead.

    Returns:
        (key, bottom, top, n_nonfinite, n_outside_grid).
    """
    from mapping import _vhv_kernels as K

    ics, ou, ov, nx, ny, cu, cv, ch = _grid_args(spec)
    n = int(pts.shape[0])
    n_nonfinite, u0, u1, v0, v1, _, _ = K.scan(pts, cu, cv, ch, 1)
    n_nonfinite = int(n_nonfinite)
    e = np.empty(0, np.int64), np.empty(0, np.float64), np.empty(0, np.float64)
    if n_nonfinite == n:
        return *e, n_nonfinite, 0
    i0, i1 = _box_range(u0, u1, ics, ou, nx)
    j0, j1 = _box_range(v0, v1, ics, ov, ny)
    if i0 > i1 or j0 > j1:
        return *e, n_nonfinite, n - n_nonfinite
    ni, nj = i1 - i0 + 1, j1 - j0 + 1
    if ni * nj <= 2 * n + 1024:
        counts = np.zeros(ni * nj + 1, np.int64)
        _, n_outside = K.cell_counts(pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, ni, nj, counts)
        offsets = np.cumsum(counts)
        del counts
        # float64 whatever the input: one compiled variant of the clustering kernel, and exact.
        hs = np.empty(int(offsets[-1]), np.float64)
        fill = offsets[:-1].copy()
        K.scatter_heights(pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, nj, fill, hs)
        del fill
        key, bot, top = K.cluster_cells(hs, offsets, i0, j0, nj, ny, tol)
        return key, bot, top, n_nonfinite, int(n_outside)
    # Sparse frame in a huge box: vectorised sort of (cell key, height) pairs.
    ok = np.isfinite(pts).all(axis=1)
    i, j = spec.world_to_index(pts[ok, cu], pts[ok, cv])
    inside = spec.contains_index(i, j)
    key = i[inside] * ny + j[inside]
    k, bot, top = _sort_cluster(key, pts[ok, ch][inside], tol)
    return k, bot, top, n_nonfinite, n - n_nonfinite - int(key.shape[0])


def _build_compiled(
    pts: NDArray[np.floating], spec: GridSpec, tol: float, method: str
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], int, int, str]:
    from mapping import _vhv_kernels as K

    ics, ou, ov, nx, ny, cu, cv, ch = _grid_args(spec)
    n = int(pts.shape[0])
    empty = np.empty(0, np.int64), np.empty(0, np.float64), np.empty(0, np.float64)
    if n == 0:
        return *empty, 0, 0, "bins"
    step = _SAMPLE_STEP if n >= 64 * _SAMPLE_STEP else 1
    if n >= 1024 * _SAMPLE_STEP_LARGE:
        step = _SAMPLE_STEP_LARGE
    nf_s, u0, u1, v0, v1, h0, h1 = K.scan(pts, cu, cv, ch, step)
    if step > 1 and not math.isfinite(u0):  # the sample saw no finite point: look at all of them
        step = 1
        nf_s, u0, u1, v0, v1, h0, h1 = K.scan(pts, cu, cv, ch, step)
    if step == 1 and not math.isfinite(u0):
        return *empty, int(nf_s), 0, "bins"
    if method == "sort":
        return *_sort_path(pts, spec, tol), "sort"
    iw = 1.0 / (tol * _BIN_SHRINK)
    m = _MARGIN_CELLS if step > 1 else 0
    i0, i1 = _box_range(u0, u1, ics, ou, nx)
    j0, j1 = _box_range(v0, v1, ics, ov, ny)
    if i0 > i1 or j0 > j1:  # the sampled finite points are all outside the grid
        i0, i1, j0, j1 = 0, 0, 0, 0
    i0, i1 = max(i0 - m, 0), min(i1 + m, nx - 1)
    j0, j1 = max(j0 - m, 0), min(j1 + m, ny - 1)
    b0 = _floor(h0 * iw) - m
    nb = _floor(h1 * iw) + m - b0 + 1
    ni, nj = i1 - i0 + 1, j1 - j0 + 1
    dense = ni * nj * nb
    entry = 2 * pts.dtype.itemsize
    budget = _dense_budget_bytes(pts)
    # The table must fit the memory budget, and be worth filling: for small clouds in a large box the
    # counting-sort path is cheaper than initialising and scanning a mostly empty table.
    if dense * entry > budget or (method == "auto" and dense > 2 * n + 65536):
        if method == "auto" or ni * nj * entry > budget:
            return *_sort_path(pts, spec, tol), "sort"
        # "bins" asked for explicitly: keep the table within budget by narrowing the height window;
        # points above it overflow to the exact sort path.
        nb = max(1, budget // (ni * nj * entry))
        dense = ni * nj * nb
    if 2 * dense + 2 >= _INT32_SLOTS:  # inputs of several GB: the kernel's slots are int32
        return *_sort_path(pts, spec, tol), "sort"
    # One (min, max) pair more: the scratch slot of the points that are not binned.
    table = _empty_table(dense + 1, pts.dtype)
    flat = table[: 2 * dense + 2]
    overflow = np.empty(max(4096, n // 64), np.int64)
    n_nonfinite, n_outside, n_over = K.bin_minmax(
        pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, ni, nj, iw, b0, nb, flat, overflow
    )
    mm = flat[: 2 * dense]
    n_nonfinite, n_outside = int(n_nonfinite), int(n_outside)
    # Output capacity: the worst case (every binned point its own structure) when that is small next
    # to the input (np.empty maps pages lazily, so only written pages cost memory), else counted exactly
    # by a second walk over the table.
    cap = max(min(dense, n - n_nonfinite - n_outside - int(n_over)), 1)
    if cap * 24 > pts.nbytes // 2:
        cap = max(int(K.count_bin_structures(mm, nb, tol)), 1)
    out_key, out_b, out_t = np.empty(cap, np.int64), np.empty(cap, np.float64), np.empty(cap, np.float64)
    # The extraction empties every bin it reads; the scratch slot is emptied here.
    n_out = int(K.extract_bins(mm, nb, i0, j0, nj, ny, tol, out_key, out_b, out_t))
    flat[2 * dense] = np.inf
    flat[2 * dense + 1] = -np.inf
    _release_table(table)
    del mm, flat, table
    key, bot, top = out_key[:n_out].copy(), out_b[:n_out].copy(), out_t[:n_out].copy()
    del out_key, out_b, out_t
    if n_over:
        if n_over <= overflow.shape[0]:
            rest = pts[overflow[:n_over]]
        else:  # the guessed box was poor: take every point outside it (exact, slower)
            rest = _outside_box(pts, spec, i0, j0, ni, nj, iw, b0, nb)
        # The overflow holds finite in-grid points only (bin_minmax counted the non-finite ones).
        k2, b2, t2, _, _ = _sort_path(rest, spec, tol)
        key, bot, top = K.merge_structures(key, bot, top, k2, b2, t2, tol)
    return key, bot, top, n_nonfinite, n_outside, "bins"


def _outside_box(
    pts: NDArray[np.floating], spec: GridSpec, i0: int, j0: int, ni: int, nj: int, iw: float, b0: int, nb: int
) -> NDArray[np.floating]:
    """Finite in-grid points outside a (cell, bin) box (after a bad box guess)."""
    cu, cv, ch = spec.columns
    ok = np.isfinite(pts).all(axis=1)
    i, j = spec.world_to_index(pts[:, cu], pts[:, cv])
    with np.errstate(invalid="ignore", over="ignore"):
        b = np.floor(pts[:, ch].astype(np.float64) * iw)
    inside = (i >= i0) & (i < i0 + ni) & (j >= j0) & (j < j0 + nj) & (b >= b0) & (b < b0 + nb)
    return pts[ok & spec.contains_index(i, j) & ~inside]


def _merge_compiled(
    k1: NDArray[np.int64],
    b1: NDArray[np.float64],
    t1: NDArray[np.float64],
    k2: NDArray[np.int64],
    b2: NDArray[np.float64],
    t2: NDArray[np.float64],
    tol: float,
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    if k1.shape[0] == 0:
        return k2, b2, t2
    if k2.shape[0] == 0:
        return k1, b1, t1
    from mapping import _vhv_kernels as K

    return K.merge_structures(k1, b1, t1, k2, b2, t2, tol)  # type: ignore[no-any-return]


def _build_numpy(
    pts: NDArray[np.floating], spec: GridSpec, tol: float
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], int, int]:
    """The bin algorithm in plain numpy (no sort of the points; ``ufunc.at`` scatter min/max)."""
    ics, ou, ov, nx, ny, cu, cv, ch = _grid_args(spec)
    n = int(pts.shape[0])
    finite = np.isfinite(pts).all(axis=1)
    n_nonfinite = n - int(np.count_nonzero(finite))
    kept = pts[finite] if n_nonfinite else pts
    with np.errstate(over="ignore"):  # huge finite coordinates scale to +-inf: outside, or sorted below
        fi = np.floor(kept[:, cu].astype(np.float64) * ics) - ou
        fj = np.floor(kept[:, cv].astype(np.float64) * ics) - ov
    inside = (fi >= 0) & (fi < nx) & (fj >= 0) & (fj < ny)
    n_outside = int(kept.shape[0]) - int(np.count_nonzero(inside))
    e = np.empty(0, np.float64)
    i, j, h = fi[inside].astype(np.int64), fj[inside].astype(np.int64), kept[inside, ch]
    del fi, fj
    if h.shape[0] == 0:
        return np.empty(0, np.int64), e, e.copy(), n_nonfinite, n_outside
    iw = 1.0 / (tol * _BIN_SHRINK)
    with np.errstate(over="ignore"):
        hb = np.floor(h.astype(np.float64) * iw)
    i0, j0 = int(i.min()), int(j.min())
    nj = int(j.max()) - j0 + 1
    b_lo, b_hi = float(hb.min()), float(hb.max())
    dense = (int(i.max()) - i0 + 1) * nj * (b_hi - b_lo + 1) if math.isfinite(b_hi - b_lo) else math.inf
    if dense * 16 > max(8 * pts.nbytes, 1 << 24):
        # Far too sparse for a dense table: sort (the thesis's pipeline, vectorised).
        return *_sort_cluster(i * ny + j, h, tol), n_nonfinite, n_outside
    b0 = int(b_lo)
    nb = int(b_hi) - b0 + 1
    dense = int(dense)
    idx = ((i - i0) * nj + (j - j0)) * nb + (hb.astype(np.int64) - b0)
    hv = h.astype(np.float64)
    mins = np.full(dense, np.inf)
    maxs = np.full(dense, -np.inf)
    np.minimum.at(mins, idx, hv)
    np.maximum.at(maxs, idx, hv)
    nz = np.flatnonzero(mins != np.inf)
    cell = nz // nb
    lo, hi = mins[nz], maxs[nz]
    s, ends = _run_bounds(cell, lo, hi, tol)
    ci = cell[s] // nj + i0
    cj = cell[s] % nj + j0
    return ci * ny + cj, lo[s], hi[ends], n_nonfinite, n_outside


def _merge_numpy(
    k1: NDArray[np.int64],
    b1: NDArray[np.float64],
    t1: NDArray[np.float64],
    k2: NDArray[np.int64],
    b2: NDArray[np.float64],
    t2: NDArray[np.float64],
    tol: float,
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Vectorised interval merge (same result as the compiled sweep)."""
    if k1.shape[0] == 0 and k2.shape[0] > 0 and _is_merged(k2, b2, t2, tol):
        return k2, b2, t2
    if k2.shape[0] == 0:
        return k1, b1, t1
    key = np.concatenate([k1, k2])
    bot = np.concatenate([b1, b2])
    top = np.concatenate([t1, t2])
    order = np.lexsort((bot, key))
    key, bot, top = key[order], bot[order], top[order]
    # Running max of `top` within each cell, exactly: replace tops by their ranks (ints), offset each
    # cell's ranks above all previous cells', accumulate, and map the ranks back to values.
    n = key.shape[0]
    rank_order = np.argsort(top, kind="stable")
    rank = np.empty(n, np.int64)
    rank[rank_order] = np.arange(n)
    group = np.cumsum(np.r_[True, key[1:] != key[:-1]]) - 1
    run = np.maximum.accumulate(group * n + rank) - group * n
    run_top = top[rank_order[run]]
    s, ends = _run_bounds(key, bot, run_top, tol)
    return key[s], bot[s], run_top[ends]


def _is_merged(k: NDArray[np.int64], b: NDArray[np.float64], t: NDArray[np.float64], tol: float) -> bool:
    """True when a sorted structure list is already disjoint with gaps > tol in every cell."""
    if k.shape[0] < 2:
        return True
    same = k[1:] == k[:-1]
    ordered = (k[1:] > k[:-1]) | (same & (b[1:] >= b[:-1]))
    return bool(np.all(ordered) and np.all(~same | (b[1:] - t[:-1] > tol)))
