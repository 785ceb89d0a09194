"""Variable-height voxels (VHV): a 2D grid whose cells keep vertical structures at full sensor definition.

The method (thesis section 4.2, SPEC section 2): every point goes to the grid cell of its ``(u, v)``
coordinates (:mod:`mapping.grid`); the heights ``h`` of the points of a cell are sorted, duplicates
dropped, and consecutive values stay in one *structure* while ``next - previous <= tolerance``; a
larger gap starts the next one. A structure keeps ``bottom`` (first value), ``top`` (last value) and
``middle = (top + bottom) / 2``.

The build paths that compute this (same result, faster than sorting) are in :mod:`mapping._vhv_build`.

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
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping._vhv_build import _build_compiled, _build_numpy, _merge_compiled, _merge_numpy
from mapping.errors import MappingError, PointsError
from mapping.grid import GridSpec

Method = Literal["auto", "bins", "sort", "numpy"]
_insert_few: Any = None  # mapping._vhv_few.insert_few once loaded
_METHODS = ("auto", "bins", "sort", "numpy")


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
        self._few_grid: tuple[Any, ...] | None = None  # insert_few's grid arguments

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

    def insert_few(self, points: NDArray[np.float64], sensor_origin: NDArray[np.float64]) -> None:
        """:meth:`insert` of a small float64 cloud in one compiled pass (a sonar cone, a few hundred points).

        The same map, counters and ``sensor_origins`` as ``insert(points, sensor_origin)`` (the
        structures of a cloud are unique; :mod:`mapping._vhv_few`), without its per-call overhead;
        no :class:`InsertStats`.

        Args:
            points: (N, 3) float64 xyz in the world frame, m (NaN/inf points are dropped and counted).
            sensor_origin: (3,) finite world xyz of the sensor, m.

        Raises:
            PointsError: ``points`` is not a (N, 3) float64 array.
            MappingError: a malformed or non-finite sensor origin.
        """
        global _insert_few
        if _insert_few is None:  # numba and the kernel load at the first call
            from mapping._vhv_few import insert_few as _insert_few
        if not (type(points) is np.ndarray and points.dtype == np.float64 and points.ndim == 2):
            raise PointsError(f"insert_few: expected (N, 3) float64 points, got {type(points).__name__}")
        if points.shape[1] != 3:
            raise PointsError(f"insert_few: expected shape (N, 3), got {points.shape}")
        o = np.asarray(sensor_origin, dtype=np.float64).reshape(-1)
        x, y, z = (float(o[0]), float(o[1]), float(o[2])) if o.shape == (3,) else (math.nan,) * 3
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise MappingError(f"insert_few sensor_origin={sensor_origin!r}: expected finite (x, y, z)")
        grid = getattr(self, "_few_grid", None)
        if grid is None:
            spec = self.spec
            (ou, ov), (nx, ny) = spec.origin, spec.shape
            gi = np.array((ou, ov, nx, ny, *spec.columns), np.int64)
            grid = self._few_grid = (np.array((spec.inv_cell_size, self.tolerance)), gi)
        key, bot, top, n_nonfinite, n_outside, n_frame = _insert_few(
            points, *grid, self._key, self._bottom, self._top
        )
        if n_frame:
            self._key, self._bottom, self._top = key, bot, top
        self._cache = None
        self.frames += 1
        self.points_inserted += int(points.shape[0]) - int(n_nonfinite) - int(n_outside)
        self.points_dropped_nonfinite += int(n_nonfinite)
        self.points_outside_grid += int(n_outside)
        self.sensor_origins.append((x, y, z))

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
