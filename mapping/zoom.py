"""Zoom: a finer VHV grid over a region of interest inside a coarse map, fed by the same points.

The thesis's future work (section 6.2) asks for a "zoom like feature in a given area with fine grid
resolution": because the kept axis has full definition already, only the two grid axes need refining.
:class:`ZoomMap` keeps a coarse :class:`~mapping.vhv.VHVMap` over the whole area and a fine one whose
cells subdivide a rectangle of coarse cells ``factor x factor`` times. Every inserted point goes into the
coarse map; the points inside the region of interest also go into the fine map.

Exactness. A fine cell lies inside exactly one coarse cell (the fine lattice is the coarse lattice
divided by ``factor``), and a point is given to the fine cell inside the coarse cell the coarse map put it
in (a point within one rounding error of a cell border, where ``floor(u / fine)`` and
``floor(u / coarse)`` could disagree, is moved by one ulp into that coarse cell's block). The coarse
clustering is a single-linkage clustering of a cell's heights with gap ``tolerance``, and merging the
clusters of the cell's parts with the same gap rule gives the clusters of the whole (the argument that
makes inserting two halves of a cloud equal inserting it whole). So :meth:`ZoomMap.coarsened` — the fine
structures re-binned into coarse cells and merged — equals the coarse map's structures over the region,
exactly; a test checks it.

The region is a world-frame box or, with :meth:`ZoomMap.follow`, a square of a given half-width that moves
with the chair: when it moves, the fine structures in the overlap are kept and the rest of the new region
starts from what is inserted from then on (the coarse map still answers there until then).

The coarse level may be the caller's own map (any map with the grid ``spec``, ``structures()`` and
``structures_at``; a perception stage sets its main map there) fed by the caller:
:meth:`ZoomMap.insert_fine` then feeds the fine level alone. The exactness above holds for a coarse
:class:`~mapping.vhv.VHVMap`; a probabilistic coarse map answers with its occupied evidence instead.
"""

from __future__ import annotations

import math
import sys
import time

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping._deps import announce_compilation
from mapping.errors import MappingError
from mapping.grid import GridSpec
from mapping.vhv import InsertStats, Structures, VHVMap, as_points


class ZoomMap:
    """A coarse VHV map with a ``factor`` times finer grid over a region of interest.

    Args:
        coarse: The coarse grid (kept axis ``z`` only).
        tolerance: VHV gap tolerance, m, for both maps (the thesis's single ``tolerance``).
        factor: Integer refinement (fine cell = coarse cell / factor), >= 2.
        region: ``(x_min, y_min, x_max, y_max)`` world box of the fine region, m; snapped outwards to
            whole coarse cells and clipped to the coarse grid. None: no fine region until :meth:`follow`.

    Raises:
        MappingError: ``factor`` not an integer >= 2, an axis other than ``z``, or an empty region.
    """

    def __init__(
        self,
        coarse: GridSpec,
        tolerance: float = 0.05,
        factor: int = 5,
        region: tuple[float, float, float, float] | None = None,
    ) -> None:
        if isinstance(factor, bool) or not isinstance(factor, int | np.integer) or factor < 2:
            raise MappingError(f"ZoomMap factor={factor!r}: expected an integer >= 2")
        if coarse.axis != "z":
            raise MappingError(f"ZoomMap: the zoom refines x and y; the grid's kept axis is {coarse.axis!r}")
        self.coarse = VHVMap(coarse, tolerance)
        self.factor = int(factor)
        self.tolerance = self.coarse.tolerance
        self.fine: VHVMap | None = None
        self._block: tuple[int, int, int, int] | None = None  # coarse lattice cells [a0, a1) x [b0, b1)
        if region is not None:
            self.set_region(region)

    # ------------------------------------------------------------------ region
    @property
    def fine_cell_size(self) -> float:
        """Side of a fine cell, m."""
        return self.coarse.spec.cell_size / self.factor

    @property
    def region(self) -> tuple[float, float, float, float] | None:
        """The fine region's world box ``(x_min, y_min, x_max, y_max)`` (whole coarse cells), or None."""
        if self._block is None:
            return None
        cs = self.coarse.spec.cell_size
        a0, a1, b0, b1 = self._block
        return a0 * cs, b0 * cs, a1 * cs, b1 * cs

    def _block_of(self, region: tuple[float, float, float, float]) -> tuple[int, int, int, int]:
        x0, y0, x1, y1 = (float(v) for v in region)
        if not all(math.isfinite(v) for v in (x0, y0, x1, y1)) or x1 <= x0 or y1 <= y0:
            raise MappingError(
                f"ZoomMap region={region!r}: expected finite (x_min, y_min, x_max, y_max), min < max"
            )
        spec = self.coarse.spec
        ou, ov = spec.origin
        nx, ny = spec.shape
        ics = spec.inv_cell_size
        a0 = max(math.floor(x0 * ics), ou)
        b0 = max(math.floor(y0 * ics), ov)
        a1 = min(math.ceil(x1 * ics), ou + nx)
        b1 = min(math.ceil(y1 * ics), ov + ny)
        if a1 <= a0 or b1 <= b0:
            raise MappingError(f"ZoomMap region={region!r}: lies outside the coarse grid {spec.extent}")
        return a0, a1, b0, b1

    def _fine_spec(self, block: tuple[int, int, int, int]) -> GridSpec:
        a0, a1, b0, b1 = block
        f, fcs = self.factor, self.fine_cell_size
        nx, ny = (a1 - a0) * f, (b1 - b0) * f
        # choose the centre so that the fine grid's origin is the block's first fine lattice cell
        centre = ((a0 * f + nx // 2 + 0.5) * fcs, (b0 * f + ny // 2 + 0.5) * fcs)
        spec = GridSpec(cell_size=fcs, size_x=nx * fcs, size_y=ny * fcs, centre=centre)
        if spec.origin != (a0 * f, b0 * f) or spec.shape != (nx, ny):  # pragma: no cover - guards rounding
            raise MappingError(f"ZoomMap: fine grid {spec} does not align with coarse block {block}")
        return spec

    def set_region(self, region: tuple[float, float, float, float]) -> None:
        """Move the fine region to a world box; fine structures in the overlap are kept, the rest dropped."""
        block = self._block_of(region)
        if block == self._block:
            return
        spec = self._fine_spec(block)
        kept = Structures.empty()
        if self.fine is not None:
            s = self.fine.structures()
            ou, ov = self.fine.spec.origin
            nu, nv = spec.origin
            i, j = s.i.astype(np.int64) + ou - nu, s.j.astype(np.int64) + ov - nv
            inside = spec.contains_index(i, j)
            kept = Structures.from_bounds(i[inside], j[inside], s.bottom[inside], s.top[inside])
        self.fine = (
            VHVMap.from_structures(spec, self.tolerance, kept) if len(kept) else VHVMap(spec, self.tolerance)
        )
        self._block = block

    def follow(self, x: float, y: float, half_width: float) -> None:
        """Centre a square fine region of ``half_width`` m on the chair at world ``(x, y)``."""
        if not (math.isfinite(half_width) and half_width > 0):
            raise MappingError(f"ZoomMap.follow half_width={half_width!r}: expected metres > 0")
        self.set_region((x - half_width, y - half_width, x + half_width, y + half_width))

    # ------------------------------------------------------------------ insertion
    def insert(
        self, points: ArrayLike, sensor_origin: ArrayLike | None = None
    ) -> tuple[InsertStats, InsertStats | None]:
        """Insert one world-frame cloud into the coarse map and its in-region part into the fine map.

        Args:
            points: ``(N, 3)`` or ``(H, W, 3)`` xyz, m; NaN rows are dropped (and counted by the coarse map).
            sensor_origin: World xyz of the sensor, passed to both maps.

        Returns:
            The coarse and the fine map's :class:`~mapping.vhv.InsertStats` (None without a region).
        """
        pts = as_points(points)
        coarse_stats = self.coarse.insert(pts, sensor_origin)
        if self.fine is None or self._block is None:
            return coarse_stats, None
        return coarse_stats, self._insert_fine(pts, sensor_origin)

    def insert_fine(self, points: ArrayLike, sensor_origin: ArrayLike | None = None) -> InsertStats | None:
        """Insert one world-frame cloud's in-region part into the fine map only.

        For a caller that feeds the coarse level itself with the same points (a perception stage whose
        main map is the coarse level, e.g. a :class:`mapping.probabilistic.ProbabilisticVHV` set as
        :attr:`coarse`): the fine map is then exactly what :meth:`insert` would make of it.

        Args:
            points: ``(N, 3)`` or ``(H, W, 3)`` xyz, m; NaN rows are skipped.
            sensor_origin: World xyz of the sensor (recorded by the fine map).

        Returns:
            The fine map's :class:`~mapping.vhv.InsertStats` (None without a region).
        """
        if self.fine is None or self._block is None:
            return None
        return self._insert_fine(as_points(points), sensor_origin)

    def _insert_fine(self, pts: NDArray[np.floating], sensor_origin: ArrayLike | None) -> InsertStats:
        """The in-region points into the fine map, in one compiled pass over the frame.

        The thesis's pipeline as :meth:`VHVMap.insert`'s counting-sort path runs it (group the heights by
        cell, sort each cell, cluster with the tolerance: the same clustering kernel), but the frame is
        walked once: the region test and the fine cell of each point come from the same pass, only the
        in-region points are grouped, over the fine grid's cells (the region), and nothing is copied.
        """
        from mapping import _vhv_kernels as K
        from mapping.vhv import _merge_compiled

        assert self._block is not None and self.fine is not None
        t0 = time.perf_counter()
        fine = self.fine
        a0, a1, b0, b1 = self._block
        nfx, nfy = fine.spec.shape
        counts = np.zeros(nfx * nfy + 1, np.int64)
        fkey = np.empty(pts.shape[0], np.int64)
        hz = np.empty(pts.shape[0], np.float64)
        n = _fine_cells(pts, self.coarse.spec.inv_cell_size, fine.spec.inv_cell_size, self.factor,
                        a0, a1, b0, b1, nfy, counts, fkey, hz)  # fmt: skip
        offsets = np.cumsum(counts)
        hs = np.empty(n, np.float64)
        _scatter(fkey, hz, n, offsets[:-1].copy(), hs)
        key, bot, top = K.cluster_cells(hs, offsets, 0, 0, nfy, nfy, self.tolerance)
        # the bookkeeping of VHVMap.insert: merge the frame's structures, count the frame
        fine._key, fine._bottom, fine._top = _merge_compiled(
            fine._key, fine._bottom, fine._top, key, bot, top, self.tolerance
        )
        fine._cache = None
        fine.frames += 1
        fine.points_inserted += n
        if sensor_origin is not None:
            o = np.asarray(sensor_origin, dtype=np.float64).reshape(-1)
            fine.sensor_origins.append((float(o[0]), float(o[1]), float(o[2])))
        return InsertStats(points_in=n, points_dropped_nonfinite=0, points_outside_grid=0, points_inserted=n,
                           build_ms=(time.perf_counter() - t0) * 1e3, frame_structures=int(key.shape[0]),
                           method="sort")  # fmt: skip

    # ------------------------------------------------------------------ queries
    def in_region(self, x: float, y: float) -> bool:
        """True where the fine map answers (world ``(x, y)`` inside the fine region)."""
        if self._block is None:
            return False
        ics = self.coarse.spec.inv_cell_size
        a0, a1, b0, b1 = self._block
        return a0 <= math.floor(x * ics) < a1 and b0 <= math.floor(y * ics) < b1

    def structures_at(self, x: float, y: float) -> Structures:
        """Structures of the finest cell at world ``(x, y)``: a fine cell inside the region, else coarse."""
        if self.fine is not None and self.in_region(x, y):
            return self.fine.structures_at(x, y)
        return self.coarse.structures_at(x, y)

    def cell_size_at(self, x: float, y: float) -> float:
        """Cell side, m, of the answer :meth:`structures_at` gives at world ``(x, y)``."""
        return self.fine_cell_size if self.in_region(x, y) else self.coarse.spec.cell_size

    def occupied_at(self, x: float, y: float, band: tuple[float, float]) -> bool:
        """True if the finest cell at ``(x, y)`` holds a structure overlapping the band ``[lo, hi]``, m."""
        s = self.structures_at(x, y)
        return bool(np.any((s.top >= band[0]) & (s.bottom <= band[1])))

    def elevation_at(self, x: float, y: float) -> float:
        """Highest structure top, m, in the finest cell at ``(x, y)``; NaN where the cell is empty."""
        s = self.structures_at(x, y)
        return float(s.top.max()) if len(s) else math.nan

    def coarsened(self) -> Structures:
        """The fine structures re-binned into coarse cells and merged with the tolerance.

        Returns structures in the coarse grid's indices; over the region they equal the coarse map's
        (see the module docstring). Empty without a region.
        """
        if self.fine is None:
            return Structures.empty()
        s = self.fine.structures()
        fu, fv = self.fine.spec.origin
        cu, cv = self.coarse.spec.origin
        f = self.factor
        i = (s.i.astype(np.int64) + fu) // f - cu
        j = (s.j.astype(np.int64) + fv) // f - cv
        merged = VHVMap.from_structures(
            self.coarse.spec, self.tolerance, Structures.from_bounds(i, j, s.bottom, s.top)
        )
        return merged.structures()

    def coarse_in_region(self) -> Structures:
        """The coarse map's structures inside the fine region (coarse grid indices)."""
        s = self.coarse.structures()
        if self._block is None:
            return Structures.empty()
        a0, a1, b0, b1 = self._block
        cu, cv = self.coarse.spec.origin
        keep = (s.i + cu >= a0) & (s.i + cu < a1) & (s.j + cv >= b0) & (s.j + cv < b1)
        return Structures(s.i[keep], s.j[keep], s.bottom[keep], s.middle[keep], s.top[keep])


@numba.njit(cache=True, nogil=True)
def _fine_cells(pts, ics, fics, f, a0, a1, b0, b1, nfy, counts, fkey, hz):  # type: ignore[no-untyped-def]
    """Fine-grid cell key and height of each finite point whose coarse cell lies in ``[a0, a1) x [b0, b1)``.

    Writes the keys (``i * nfy + j`` in the fine grid) to ``fkey`` and the heights to ``hz`` (the first
    ``n`` entries), counts the points per fine cell into ``counts[key + 1]``; returns ``n``. A fine index
    that a rounding error puts outside its coarse cell's ``f x f`` block is clamped into it (the point moved
    by one ulp into the block).
    """
    n = 0
    fa0 = a0 * f
    fb0 = b0 * f
    for k in range(pts.shape[0]):
        # floor(p) < a0 exactly when p < a0 (a0 an integer); NaN fails every comparison
        px = np.float64(pts[k, 0]) * ics
        if not (px >= a0 and px < a1):
            continue
        py = np.float64(pts[k, 1]) * ics
        if not (py >= b0 and py < b1):
            continue
        z = np.float64(pts[k, 2])
        if not np.isfinite(z) or not (np.isfinite(px) and np.isfinite(py)):
            continue
        ca = np.floor(px)
        cb = np.floor(py)
        fa = min(max(np.floor(np.float64(pts[k, 0]) * fics), ca * f), ca * f + (f - 1))
        fb = min(max(np.floor(np.float64(pts[k, 1]) * fics), cb * f), cb * f + (f - 1))
        key = (int(fa) - fa0) * nfy + (int(fb) - fb0)
        counts[key + 1] += 1
        fkey[n] = key
        hz[n] = z
        n += 1
    return n


@numba.njit(cache=True, nogil=True)
def _scatter(fkey, hz, n, fill, hs):  # type: ignore[no-untyped-def]
    """Counting sort of the heights ``hz[:n]`` into ``hs`` by ``fkey`` (``fill``: each group's start)."""
    for k in range(n):
        c = fkey[k]
        hs[fill[c]] = hz[k]
        fill[c] += 1


# first run after an install or a change here: say what is being compiled
announce_compilation(sys.modules[__name__], "zoom map kernels")
