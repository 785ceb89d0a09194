"""Derived views of :class:`mapping.probabilistic.ProbabilisticVHV`: intervals, structures, 2D maps.

Everything here reads the interval store (:mod:`mapping._interval_store`) and never changes it; the
results of a state are cached until the next update clears ``_cache``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.errors import MappingError
from mapping.evidence import EvidenceIntervals
from mapping.grid import GridSpec
from mapping.vhv import Structures, VHVMap


def _structures_from(
    key: NDArray[np.int64], lo: NDArray[np.float64], hi: NDArray[np.float64], ny: int
) -> Structures:
    return Structures.from_bounds((key // ny).astype(np.int32), (key % ny).astype(np.int32), lo, hi)


def _join_touching(
    key: NDArray[np.int64], lo: NDArray[np.int32], hi: NDArray[np.int32]
) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int32]]:
    """Join consecutive intervals of one cell that touch (sorted, disjoint input)."""
    if key.shape[0] == 0:
        return key, lo, hi
    start = np.ones(key.shape[0], bool)
    start[1:] = (key[1:] != key[:-1]) | (lo[1:] != hi[:-1])
    s = np.flatnonzero(start)
    ends = np.r_[s[1:], key.shape[0]] - 1
    return key[s], lo[s], hi[ends]


def _check_band(band: tuple[float, float]) -> tuple[float, float]:
    try:
        z0, z1 = (float(b) for b in band)
    except (TypeError, ValueError):
        raise MappingError(f"height band {band!r}: expected (z_min, z_max) in metres") from None
    if not (math.isfinite(z0) and math.isfinite(z1)) or z0 > z1:
        raise MappingError(f"height band [{z0!r}, {z1!r}]: expected finite z_min <= z_max")
    return z0, z1


def _of_occupied(name: str, doc: str) -> Any:
    """A read-only property answered by the occupied view (a :class:`mapping.vhv.VHVMap`)."""
    return property(lambda self: getattr(self._occupied_view(), name), doc=doc)


class EvidenceViews:
    """Read-only views of the stored intervals (a base of ``ProbabilisticVHV``)."""

    spec: GridSpec
    tolerance: float
    _cache: dict[str, Any]
    _r: float
    _l_occ: np.float32
    _l_free: np.float32
    _n_intervals: int
    _now: float
    _cstart: NDArray[np.int64]
    _ccount: NDArray[np.int32]
    _plo: NDArray[np.int32]
    _phi: NDArray[np.int32]
    _pl: NDArray[np.float32]
    _pt: NDArray[np.float64]

    def _flat(self) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int32], NDArray[np.float32]]:
        if "flat" not in self._cache:
            from mapping import _store_kernels as E

            self._cache["flat"] = E.gather(
                self._cstart, self._ccount, self._plo, self._phi, self._pl, self._pt, self._n_intervals
            )[:4]
        flat: tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int32], NDArray[np.float32]] = (
            self._cache["flat"]
        )
        return flat

    def intervals(self) -> EvidenceIntervals:
        """Every stored interval (occupied, free or in between) with its log-odds and probability."""
        key, lo, hi, lv = self._flat()
        ny = self.spec.shape[1]
        with np.errstate(over="ignore"):
            prob = 1.0 / (1.0 + np.exp(-lv.astype(np.float64)))
        return EvidenceIntervals(
            i=(key // ny).astype(np.int32),
            j=(key % ny).astype(np.int32),
            bottom=lo.astype(np.float64) * self._r,
            top=hi.astype(np.float64) * self._r,
            log_odds=lv.copy(),
            probability=prob,
            occupied=lv >= self._l_occ,
            free=lv < self._l_free,
        )

    def _state(self, which: str) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
        if which not in self._cache:
            key, lo, hi, lv = self._flat()
            sel = lv >= self._l_occ if which == "occupied" else lv < self._l_free
            k, a, b = _join_touching(key[sel], lo[sel], hi[sel])
            self._cache[which] = (k, a.astype(np.float64) * self._r, b.astype(np.float64) * self._r)
        out: tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]] = self._cache[which]
        return out

    def _occupied_view(self) -> VHVMap:
        if "view" not in self._cache:
            k, b, t = self._state("occupied")
            v = VHVMap(self.spec, self.tolerance)
            v._key, v._bottom, v._top = k, b, t
            self._cache["view"] = v
        view: VHVMap = self._cache["view"]
        return view

    def structures(self) -> Structures:
        """Occupied intervals as VHV structures (touching occupied pieces of a cell joined).

        Bounds are those of the stored slabs: the hits' extent widened by ``surface_half_thickness``
        and snapped outward to the height lattice.
        """
        return self._occupied_view().structures()

    def free_structures(self) -> Structures:
        """Free intervals (touching free pieces of a cell joined), same layout as :meth:`structures`."""
        k, b, t = self._state("free")
        return _structures_from(k, b, t, self.spec.shape[1])

    def structures_in_cell(self, i: int, j: int) -> Structures:
        """Occupied structures of cell ``(i, j)``."""
        return self._occupied_view().structures_in_cell(i, j)

    def structures_at(self, u: float, v: float) -> Structures:
        """Occupied structures of the cell containing grid-plane point ``(u, v)``."""
        return self._occupied_view().structures_at(u, v)

    cell_keys = _of_occupied("cell_keys", "Cell key ``i * ny + j`` of every occupied structure (sorted).")
    n_structures = _of_occupied("n_structures", "Number of occupied structures.")
    n_cells_occupied = _of_occupied("n_cells_occupied", "Cells holding at least one occupied structure.")
    n_voxels = _of_occupied("n_voxels", "Standard voxels the occupied structures cover.")

    @property
    def now(self) -> float:
        """The map's clock: the latest insertion stamp, seconds (-inf before any)."""
        return self._now

    @property
    def n_intervals(self) -> int:
        """Stored intervals of every state."""
        return self._n_intervals

    def bbox(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """World bounds of the occupied structures, or None."""
        return self._occupied_view().bbox()

    def elevation(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """2.5D elevation ``(top_max, bottom_min)`` of the occupied structures, ``(nx, ny)`` float64.

        NaN where a cell holds no occupied interval: unknown, or known free with no surface.
        """
        from mapping.derived import elevation

        return elevation(self._occupied_view())

    def occupancy_2d(
        self,
        band: tuple[float, float],
        unknown: int = -1,
        min_free_fraction: float = 0.5,
    ) -> NDArray[np.int8]:
        """Three-valued 2D map of the height band, ``nav_msgs/OccupancyGrid`` codes, ``(nx, ny)`` int8.

        * 100: an occupied interval overlaps ``[band[0], band[1]]``;
        * 0: no occupied interval there, and free intervals cover at least ``min_free_fraction`` of
          the band;
        * ``unknown`` (default -1) otherwise. Pass ``unknown=100`` to plan as if unknown were blocked,
          or 0 to treat it as free (the default keeps it apart: not free).

        Raises:
            MappingError: a malformed band, ``unknown`` not one of -1, 0, 100, or a fraction outside [0, 1].
        """
        z0, z1 = _check_band(band)
        if unknown not in (-1, 0, 100):
            raise MappingError(f"occupancy_2d unknown={unknown!r}: expected -1, 0 or 100")
        if not (math.isfinite(min_free_fraction) and 0.0 <= min_free_fraction <= 1.0):
            raise MappingError(
                f"occupancy_2d min_free_fraction={min_free_fraction!r}: expected a value in [0, 1]"
            )
        nx, ny = self.spec.shape
        codes = np.full(nx * ny, unknown, np.int8)
        fk, fb, ft = self._state("free")
        touch = (fb <= z1) & (ft > z0)
        cover = np.minimum(ft, z1) - np.maximum(fb, z0)
        covered = np.bincount(fk[touch], weights=np.maximum(cover[touch], 0.0), minlength=nx * ny)
        any_free = np.bincount(fk[touch], minlength=nx * ny) > 0
        free = any_free & (covered >= min_free_fraction * (z1 - z0) - 1e-12)
        codes[free] = 0
        ok, ob, ot = self._state("occupied")
        hit = (ob <= z1) & (ot > z0)
        codes[ok[hit]] = 100
        return codes.reshape(nx, ny)

    def free_cells(
        self, band: tuple[float, float], unknown_is_free: bool = False, min_free_fraction: float = 0.5
    ) -> NDArray[np.bool_]:
        """``(nx, ny)`` True where the band is free; unknown counts as free only if asked."""
        codes = self.occupancy_2d(
            band, unknown=0 if unknown_is_free else 100, min_free_fraction=min_free_fraction
        )
        return np.asarray(codes == 0)
