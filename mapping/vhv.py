"""Variable-height voxels (VHV): a 2D grid whose cells keep vertical structures at full sensor definition.

The method (thesis section 4.2, SPEC section 2): every point goes to the grid cell of its ``(u, v)``
coordinates (:mod:`mapping.grid`); the heights ``h`` of the points of a cell are sorted, duplicates
dropped, and consecutive values stay in one *structure* while ``next - previous <= tolerance``; a
larger gap starts the next one. A structure keeps ``bottom`` (first value), ``top`` (last value) and
``middle = (top + bottom) / 2``.

How it is computed here (same result, faster than sorting)
----------------------------------------------------------
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
in (exactly, see below). When the table would exceed the size of the input array (or 4 MiB for small
clouds) or would be mostly empty (more entries than twice the points) — small or sparse clouds,
outliers far away in height — the build takes the compiled sort path instead (``method="sort"``, the
thesis's pipeline: a counting sort by cell, then a sort per cell). ``method="numpy"`` is the bin
algorithm without numba, kept for the benchmark.

Accumulating frames
-------------------
A map grows: :meth:`VHVMap.insert` builds the frame's structures and merges them into the stored ones
by sweeping each cell's intervals in bottom order, joining while ``next.bottom - running_top <=
tolerance``. Because each interval's extreme values are real points and no point of the union lies
strictly between the running top and the next bottom, this is exactly the clustering of the union of
all points ever inserted: inserting a cloud in two halves gives the same map as inserting it at once.

Storage is a structure of arrays (cell key ``i * ny + j``, bottom, top) sorted by cell then bottom.
Points that are NaN/inf or outside the bounded grid are dropped and counted in :class:`InsertStats`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.errors import MappingError, PointsError
from mapping.grid import GridSpec

Method = Literal["auto", "bins", "sort", "numpy"]
_METHODS = ("auto", "bins", "sort", "numpy")

# Bins are a relative 1e-6 narrower than the tolerance so that no bin can span more than it (see above).
_BIN_SHRINK = 1.0 - 1e-6


def _middle(bottom: NDArray[np.float64], top: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(top + bottom) / 2`` written so that it never overflows, nor leaves ``[bottom, top]``."""
    return np.asarray(bottom + (top - bottom) / 2.0)


@dataclass(frozen=True)
class InsertStats:
    """What one :meth:`VHVMap.insert` did with its points.

    Attributes:
        points_in: points given (H * W for an organized cloud).
        points_dropped_nonfinite: points with a NaN or infinite coordinate (dropped).
        points_outside_grid: finite points outside the bounded grid (dropped).
        points_inserted: points that went into the map.
        build_ms: wall-clock time of the whole insert (filtering, binning, merging), milliseconds.
        frame_structures: structures the frame alone produced (before merging into the map).
        method: the build path used: "bins", "sort" or "numpy".
    """

    points_in: int
    points_dropped_nonfinite: int
    points_outside_grid: int
    points_inserted: int
    build_ms: float
    frame_structures: int = 0
    method: str = "bins"


@dataclass(frozen=True, eq=False)
class Structures:
    """Vertical structures as a structure of arrays, sorted by cell ``(i, j)`` then ``bottom``.

    Attributes:
        i, j: cell indices (int32).
        bottom, middle, top: kept-axis values in metres (float64); ``middle = (top + bottom) / 2``.
    """

    i: NDArray[np.int32]
    j: NDArray[np.int32]
    bottom: NDArray[np.float64]
    middle: NDArray[np.float64]
    top: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.i.shape[0])

    @classmethod
    def empty(cls) -> Structures:
        """A structure list with no entries."""
        z = np.empty(0, np.float64)
        return cls(np.empty(0, np.int32), np.empty(0, np.int32), z, z.copy(), z.copy())

    @classmethod
    def from_bounds(cls, i: ArrayLike, j: ArrayLike, bottom: ArrayLike, top: ArrayLike) -> Structures:
        """Build from cell indices and bounds (computes ``middle``; does not sort)."""
        b = np.asarray(bottom, dtype=np.float64)
        t = np.asarray(top, dtype=np.float64)
        return cls(np.asarray(i, dtype=np.int32), np.asarray(j, dtype=np.int32), b, _middle(b, t), t)

    def equals(self, other: Structures) -> bool:
        """True when both hold exactly the same structures in the same order."""
        return (
            len(self) == len(other)
            and bool(np.array_equal(self.i, other.i))
            and bool(np.array_equal(self.j, other.j))
            and bool(np.array_equal(self.bottom, other.bottom))
            and bool(np.array_equal(self.top, other.top))
            and bool(np.array_equal(self.middle, other.middle))
        )

    def cell(self, i: int, j: int) -> Structures:
        """The structures of cell ``(i, j)`` (sorted by bottom)."""
        sel = (self.i == i) & (self.j == j)
        return Structures(self.i[sel], self.j[sel], self.bottom[sel], self.middle[sel], self.top[sel])


def as_points(points: ArrayLike, name: str = "points") -> NDArray[np.floating]:
    """Validate a cloud and return it as a C-contiguous ``(N, 3)`` float32/float64 view or copy.

    Raises:
        PointsError: wrong shape (not (N, 3) nor (H, W, 3)) or a non-real dtype.
    """
    a = np.asarray(points)
    if a.dtype.kind not in "fiu" or a.dtype.kind == "b":
        raise PointsError(f"{name}: expected real numbers, got dtype {a.dtype}")
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float64)
    if a.ndim == 1 and a.size == 0:
        a = a.reshape(0, 3)
    if a.ndim not in (2, 3) or a.shape[-1] != 3:
        raise PointsError(f"{name}: expected shape (N, 3) or (H, W, 3), got {a.shape}")
    return np.ascontiguousarray(a.reshape(-1, 3))


class VHVMap:
    """A growing variable-height-voxel map on a bounded grid.

    Args:
        spec: the grid (cell size, extent, centre, kept axis).
        tolerance: largest gap in metres between consecutive heights of one structure (> 0).

    Example:
        >>> m = VHVMap(GridSpec(cell_size=0.05, size_x=2.0, size_y=2.0), tolerance=0.05)
        >>> m.insert([[0.01, 0.01, 0.0], [0.01, 0.01, 0.02], [0.01, 0.01, 0.2]]).points_inserted
        3
        >>> m.n_structures
        2
    """

    def __init__(self, spec: GridSpec, tolerance: float = 0.05) -> None:
        if not isinstance(spec, GridSpec):
            raise MappingError(f"VHVMap spec={spec!r}: expected a mapping.grid.GridSpec")
        try:
            tol = float(tolerance)
        except (TypeError, ValueError):
            raise MappingError(f"VHVMap tolerance={tolerance!r}: expected a number of metres > 0") from None
        if not math.isfinite(tol) or tol <= 0.0:
            raise MappingError(f"VHVMap tolerance={tolerance!r}: expected a finite number of metres > 0")
        self.spec = spec
        self.tolerance = tol
        self._key = np.empty(0, np.int64)
        self._bottom = np.empty(0, np.float64)
        self._top = np.empty(0, np.float64)
        self._cache: Structures | None = None
        self.frames = 0
        self.points_inserted = 0
        self.points_dropped_nonfinite = 0
        self.points_outside_grid = 0
        self.sensor_origins: list[tuple[float, float, float]] = []

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_structures(cls, spec: GridSpec, tolerance: float, structures: Structures) -> VHVMap:
        """Rebuild a map from stored structures (e.g. read back from a file).

        The structures are sorted and merged with the map's tolerance, so any input order is accepted.
        """
        m = cls(spec, tolerance)
        ny = spec.shape[1]
        i = np.asarray(structures.i, np.int64)
        j = np.asarray(structures.j, np.int64)
        if len(i) and not bool(np.all(spec.contains_index(i, j))):
            raise MappingError("VHVMap.from_structures: some structures lie outside the grid")
        b = np.asarray(structures.bottom, np.float64)
        t = np.asarray(structures.top, np.float64)
        if bool(np.any(b > t)) or not bool(np.all(np.isfinite(b) & np.isfinite(t))):
            raise MappingError("VHVMap.from_structures: every structure needs finite bottom <= top")
        key = i * ny + j
        order = np.lexsort((b, key))
        with np.errstate(over="ignore"):
            m._key, m._bottom, m._top = _merge_numpy(
                np.empty(0, np.int64), np.empty(0), np.empty(0), key[order], b[order], t[order], m.tolerance
            )
        return m

    # ------------------------------------------------------------------ insertion
    def insert(
        self,
        points: ArrayLike,
        sensor_origin: ArrayLike | None = None,
        method: Method = "auto",
    ) -> InsertStats:
        """Insert one cloud (world frame) and merge it into the map.

        Args:
            points: ``(N, 3)`` or organized ``(H, W, 3)`` xyz in metres, float32 or float64 (other real
                dtypes are converted to float64). NaN/inf points are dropped and counted.
            sensor_origin: world xyz of the sensor for this cloud; remembered in ``sensor_origins``
                (used by :func:`mapping.derived.free_space`).
            method: "auto" (bins when the dense table fits, else sort), "bins", "sort" or "numpy".

        Returns:
            The frame's :class:`InsertStats`.

        Raises:
            PointsError: the array has the wrong shape or dtype.
            MappingError: unknown method or malformed sensor origin.
        """
        t0 = time.perf_counter()
        if method not in _METHODS:
            raise MappingError(f"VHVMap.insert method={method!r}: expected one of {_METHODS}")
        origin = None
        if sensor_origin is not None:
            o = np.asarray(sensor_origin, dtype=np.float64).reshape(-1)
            if o.shape != (3,) or not bool(np.all(np.isfinite(o))):
                raise MappingError(
                    f"VHVMap.insert sensor_origin={sensor_origin!r}: expected finite (x, y, z)"
                )
            origin = (float(o[0]), float(o[1]), float(o[2]))
        pts = as_points(points)
        n_in = int(pts.shape[0])
        if method == "numpy":
            # Gaps between heights near the float64 limit overflow to inf, which compares correctly.
            with np.errstate(over="ignore"):
                key, bot, top, n_nonfinite, n_outside = _build_numpy(pts, self.spec, self.tolerance)
                merged = _merge_numpy(self._key, self._bottom, self._top, key, bot, top, self.tolerance)
            used = "numpy"
        else:
            key, bot, top, n_nonfinite, n_outside, used = _build_compiled(
                pts, self.spec, self.tolerance, method
            )
            merged = _merge_compiled(self._key, self._bottom, self._top, key, bot, top, self.tolerance)
        self._key, self._bottom, self._top = merged
        self._cache = None
        n_ins = n_in - n_nonfinite - n_outside
        self.frames += 1
        self.points_inserted += n_ins
        self.points_dropped_nonfinite += n_nonfinite
        self.points_outside_grid += n_outside
        if origin is not None:
            self.sensor_origins.append(origin)
        return InsertStats(
            points_in=n_in,
            points_dropped_nonfinite=n_nonfinite,
            points_outside_grid=n_outside,
            points_inserted=n_ins,
            build_ms=(time.perf_counter() - t0) * 1e3,
            frame_structures=int(key.shape[0]),
            method=used,
        )

    # ------------------------------------------------------------------ queries
    def structures(self) -> Structures:
        """All structures (SoA, sorted by cell then bottom). The arrays are read-only views."""
        if self._cache is None:
            ny = self.spec.shape[1]
            i = (self._key // ny).astype(np.int32)
            j = (self._key % ny).astype(np.int32)
            s = Structures(i, j, self._bottom, _middle(self._bottom, self._top), self._top)
            for a in (s.i, s.j, s.bottom, s.middle, s.top):
                a.setflags(write=False)
            self._cache = s
        return self._cache

    def structures_in_cell(self, i: int, j: int) -> Structures:
        """Structures of cell ``(i, j)`` (empty outside the grid)."""
        nx, ny = self.spec.shape
        s = self.structures()
        if not (0 <= i < nx and 0 <= j < ny):
            return Structures.empty()
        key = int(i) * ny + int(j)
        lo, hi = np.searchsorted(self._key, [key, key + 1])
        return Structures(s.i[lo:hi], s.j[lo:hi], s.bottom[lo:hi], s.middle[lo:hi], s.top[lo:hi])

    def structures_at(self, u: float, v: float) -> Structures:
        """Structures of the cell containing world grid-plane point ``(u, v)`` ((x, y) for axis z)."""
        i, j = self.spec.world_to_index(u, v)
        return self.structures_in_cell(int(i), int(j))

    @property
    def cell_keys(self) -> NDArray[np.int64]:
        """Cell key ``i * ny + j`` of every structure (read-only view, sorted)."""
        k = self._key.view()
        k.setflags(write=False)
        return k

    @property
    def n_structures(self) -> int:
        """Number of structures in the map."""
        return int(self._key.shape[0])

    @property
    def n_cells_occupied(self) -> int:
        """Number of cells holding at least one structure."""
        if self._key.shape[0] == 0:
            return 0
        return int(np.count_nonzero(np.diff(self._key)) + 1)

    @property
    def n_voxels(self) -> int:
        """Number of standard cubic voxels of side ``cell_size`` the same structures occupy.

        A structure covers the vertical lattice cells ``spec.height_index(bottom .. top)``; two
        structures of one cell that touch the same cube count it once (SPEC: "for comparison").
        """
        if self._key.shape[0] == 0:
            return 0
        kb = self.spec.height_index(self._bottom)
        kt = self.spec.height_index(self._top)
        total = int(np.sum(kt - kb + 1))
        shared = (self._key[1:] == self._key[:-1]) & (kb[1:] == kt[:-1])
        return total - int(np.count_nonzero(shared))

    def bbox(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """World axis-aligned bounds ``(min_xyz, max_xyz)`` of all structures, or None when empty.

        Along the grid axes the bounds are the outer cell edges; along the kept axis, the lowest bottom
        and highest top.
        """
        if self._key.shape[0] == 0:
            return None
        s = self.structures()
        cs = self.spec.cell_size
        u0, v0 = self.spec.index_to_world(int(s.i.min()), int(s.j.min()))
        u1, v1 = self.spec.index_to_world(int(s.i.max()), int(s.j.max()))
        lo = np.array([float(u0) - cs / 2, float(v0) - cs / 2, float(self._bottom.min())])
        hi = np.array([float(u1) + cs / 2, float(v1) + cs / 2, float(self._top.max())])
        return self.spec.to_world_frame(lo), self.spec.to_world_frame(hi)

    def __repr__(self) -> str:
        return (
            f"VHVMap(cells={self.spec.shape}, cell_size={self.spec.cell_size}, axis={self.spec.axis!r}, "
            f"tolerance={self.tolerance}, structures={self.n_structures}, frames={self.frames})"
        )


# ---------------------------------------------------------------------- build paths
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
# the result, only the speed.
_SAMPLE_STEP = 32
_MARGIN_CELLS = 2


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
    h = pts[ok, ch][inside].astype(np.float64)
    order = np.lexsort((h, key))
    key, h = key[order], h[order]
    start = np.ones(key.shape[0], bool)
    start[1:] = (key[1:] != key[:-1]) | (h[1:] - h[:-1] > tol)
    s = np.flatnonzero(start)
    ends = np.r_[s[1:], key.shape[0]] - 1
    return key[s], h[s], h[ends], n_nonfinite, n - n_nonfinite - int(key.shape[0])


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
    mm = np.empty((dense, 2), dtype=pts.dtype)
    mm[:, 0] = np.inf
    mm[:, 1] = -np.inf
    mm = mm.reshape(-1)
    overflow = np.empty(max(4096, n // 64), np.int64)
    n_nonfinite, n_outside, n_over = K.bin_minmax(
        pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, ni, nj, iw, b0, nb, mm, overflow
    )
    n_nonfinite, n_outside = int(n_nonfinite), int(n_outside)
    # Output capacity: the worst case (every binned point its own structure) when that is small next
    # to the input (np.empty maps pages lazily, so only written pages cost memory), else counted exactly
    # by a second walk over the table.
    cap = max(min(dense, n - n_nonfinite - n_outside - int(n_over)), 1)
    if cap * 24 > pts.nbytes // 2:
        cap = max(int(K.count_bin_structures(mm, nb, tol)), 1)
    out_key, out_b, out_t = np.empty(cap, np.int64), np.empty(cap, np.float64), np.empty(cap, np.float64)
    n_out = int(K.extract_bins(mm, nb, i0, j0, nj, ny, tol, out_key, out_b, out_t))
    del mm
    key, bot, top = out_key[:n_out].copy(), out_b[:n_out].copy(), out_t[:n_out].copy()
    del out_key, out_b, out_t
    if n_over:
        if n_over <= overflow.shape[0]:
            rest = pts[overflow[:n_over]]
        else:  # the guessed box was poor: take every point outside it (exact, slower)
            rest = _outside_box(pts, spec, i0, j0, ni, nj, iw, b0, nb)
        # The overflow holds in-grid points only; some may have a non-finite height.
        k2, b2, t2, nf2, _ = _sort_path(rest, spec, tol)
        n_nonfinite += nf2
        key, bot, top = K.merge_structures(key, bot, top, k2, b2, t2, tol)
    return key, bot, top, n_nonfinite, n_outside, "bins"


def _outside_box(
    pts: NDArray[np.floating], spec: GridSpec, i0: int, j0: int, ni: int, nj: int, iw: float, b0: int, nb: int
) -> NDArray[np.floating]:
    """In-grid points outside a (cell, bin) box, non-finite heights included (after a bad box guess)."""
    cu, cv, ch = spec.columns
    ok = np.isfinite(pts[:, cu]) & np.isfinite(pts[:, cv])
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
        key = i * ny + j
        order = np.lexsort((h, key))
        key, hs = key[order], h[order].astype(np.float64)
        start = np.ones(hs.shape[0], bool)
        start[1:] = (key[1:] != key[:-1]) | (hs[1:] - hs[:-1] > tol)
        s = np.flatnonzero(start)
        ends = np.r_[s[1:], hs.shape[0]] - 1
        return key[s], hs[s], hs[ends], n_nonfinite, n_outside
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
    start = np.ones(nz.shape[0], bool)
    start[1:] = (cell[1:] != cell[:-1]) | (lo[1:] - hi[:-1] > tol)
    s = np.flatnonzero(start)
    ends = np.r_[s[1:], nz.shape[0]] - 1
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
    start = np.ones(n, bool)
    start[1:] = (key[1:] != key[:-1]) | (bot[1:] - run_top[:-1] > tol)
    s = np.flatnonzero(start)
    ends = np.r_[s[1:], n] - 1
    return key[s], bot[s], run_top[ends]


def _is_merged(k: NDArray[np.int64], b: NDArray[np.float64], t: NDArray[np.float64], tol: float) -> bool:
    """True when a sorted structure list is already disjoint with gaps > tol in every cell."""
    if k.shape[0] < 2:
        return True
    same = k[1:] == k[:-1]
    ordered = (k[1:] > k[:-1]) | (same & (b[1:] >= b[:-1]))
    return bool(np.all(ordered) and np.all(~same | (b[1:] - t[:-1] > tol)))
