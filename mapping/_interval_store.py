"""The interval store of :class:`mapping.probabilistic.ProbabilisticVHV`: cell lists in a pool, the
evidence update, the dynamic decay and the map's clock.

Per grid cell a dense table holds the start, count and reserved room of the cell's list in a pool of
``(lo, hi, log_odds, stamps)`` arrays (int32, int32, float32, (2,) float64), sorted and disjoint; an
update rewrites only the cells it touches, in place when the list fits, else appended at the pool's end
(the pool is compacted when half of it is dead). The compiled kernels are in :mod:`mapping._store_kernels`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.errors import MappingError
from mapping.evidence import EvidenceParams


class IntervalStore:
    """The stored intervals of every cell and their update (a base of ``ProbabilisticVHV``)."""

    params: EvidenceParams
    _l_hit: np.float32
    _l_miss: np.float32
    _l_min: np.float32
    _l_max: np.float32
    _l_occ: np.float32
    _l_void: np.float32

    def _init_store(self, n_cells: int, track: bool) -> None:
        """An empty store over ``n_cells`` cells; ``track``: keep the stamps of dynamic hits."""
        self._cstart = np.zeros(n_cells, np.int64)
        self._ccount = np.zeros(n_cells, np.int32)
        self._ccap = np.zeros(n_cells, np.int32)
        cap = 1 << 16
        self._plo = np.empty(cap, np.int32)
        self._phi = np.empty(cap, np.int32)
        self._pl = np.empty(cap, np.float32)
        # stamps of the last and the first dynamic hit of a dynamic interval, else -inf
        self._pt = np.empty((cap, 2), np.float64)
        self._track = track
        self._now = -math.inf
        self._decayed_at = math.nan  # the clock of the last decay pass (NaN: none yet)
        # every cell that may hold a dynamic interval (``_dyn_cells[:_n_dyn]``, in no order; a superset:
        # the decay pass prunes it), flagged in ``_dyn_flag``, so that a pass visits those cells only, not
        # the whole grid; ``_dyn_due``: per cell the earliest last hit of its dynamic intervals (inf: none)
        self._dyn_cells = np.empty(1024 if track else 0, np.int64)
        self._n_dyn = 0
        self._dyn_flag = np.zeros(n_cells if track else 0, np.uint8)
        self._dyn_due = np.full(n_cells if track else 0, np.inf)
        self._used = 0
        self._garbage = 0
        self._n_intervals = 0
        self._cache: dict[str, Any] = {}

    def _advance(self, stamp: float | None) -> None:
        """Move the map's clock to ``stamp`` (seconds; None: keep it)."""
        if stamp is None:
            return
        s = float(stamp)
        if not math.isfinite(s):
            raise MappingError(f"insert stamp={stamp!r}: expected a finite time in seconds")
        if s < self._now - 1e-9:
            raise MappingError(f"insert stamp={s!r}: earlier than the map's clock {self._now!r} s")
        self._now = s

    def _update(
        self,
        okey: NDArray[np.int64],
        olo: NDArray[np.int32],
        ohi: NDArray[np.int32],
        fkey: NDArray[np.int64],
        flo: NDArray[np.int32],
        fhi: NDArray[np.int32],
    ) -> int:
        from mapping._store_update import update_store

        if self._track and self._n_dyn + okey.shape[0] + fkey.shape[0] > self._dyn_cells.shape[0]:
            grown = np.empty(2 * (self._n_dyn + okey.shape[0] + fkey.shape[0]), np.int64)
            grown[: self._n_dyn] = self._dyn_cells[: self._n_dyn]
            self._dyn_cells = grown
        a = b = cells = 0
        while True:
            a, b, n, used, freed, delta, n_dyn, need = update_store(
                self._cstart, self._ccount, self._ccap, self._plo, self._phi, self._pl, self._pt,
                self._used, okey, olo, ohi, fkey, flo, fhi, a, b,
                self._l_hit, self._l_miss, self._l_min, self._l_max, np.float32(1e-4),
                self._track, self._now, self._l_void, self._l_occ, self._max_dwell(),
                self._dyn_flag, self._dyn_due, self._dyn_cells, self._n_dyn,
            )  # fmt: skip
            cells += int(n)
            self._used = int(used)
            self._garbage += int(freed)
            self._n_intervals += int(delta)
            self._n_dyn = int(n_dyn)
            if not need:
                break
            # a cell moves to the pool's end and the pool is full: grow it, go on from that cell
            self._grow(self._plo.shape[0] + int(need))
        if self._garbage > 2 * self._n_intervals + (1 << 16):
            self._compact()
        return cells

    def _max_dwell(self) -> float:
        """``dynamic_max_dwell_s`` as a number of seconds (inf: any)."""
        dwell = self.params.dynamic_max_dwell_s
        return math.inf if dwell is None else float(dwell)

    def _decay(self) -> int:
        """Forget the dynamic occupied intervals not hit for ``dynamic_decay_s``; returns how many."""
        age = self.params.dynamic_decay_s
        if age is None or not math.isfinite(self._now) or self._n_intervals == 0:
            return 0
        if self._now == self._decayed_at:
            # Nothing can have become due since the last pass at the same clock: an update stamps every
            # dynamic piece it hits with ``now`` (age 0), lowers free pieces, and merges only pieces of
            # equal stamps, so a piece kept by that pass (too young, too long dwelt, or not occupied) is
            # kept again. A frame's free-only insert and the sonar inserts between frames skip the pass.
            return 0
        self._decayed_at = self._now
        from mapping import _store_kernels as E

        if self._n_dyn == 0:
            return 0
        # the whole-grid pass (E.decay) restricted to the cells that hold dynamic intervals, skipping those
        # with nothing old enough: the same drops
        dropped, n_dyn = E.decay_listed(
            self._dyn_cells, self._n_dyn, self._dyn_flag, self._dyn_due,
            self._ccount, self._cstart, self._plo, self._phi, self._pl, self._pt,
            self._now, float(age), self._max_dwell(), self._l_occ,
        )  # fmt: skip
        self._n_dyn = int(n_dyn)
        n = int(dropped)
        self._n_intervals -= n
        self._garbage += n
        return n

    def _grow(self, need: int) -> None:
        cap = max(2 * self._plo.shape[0], need)
        for name in ("_plo", "_phi", "_pl", "_pt"):
            old = getattr(self, name)
            new = np.empty((cap, *old.shape[1:]), old.dtype)
            new[: self._used] = old[: self._used]
            setattr(self, name, new)

    def _compact(self) -> None:
        from mapping import _store_kernels as E

        slack = 2
        cells = int(np.count_nonzero(self._ccount))
        cap = max(self._n_intervals + slack * cells + 1024, 1 << 16)
        lo, hi, lv = np.empty(cap, np.int32), np.empty(cap, np.int32), np.empty(cap, np.float32)
        lt = np.empty((cap, 2), np.float64)
        # cells with no interval keep no room
        self._ccap[self._ccount == 0] = 0
        self._used = int(
            E.compact(
                self._cstart, self._ccount, self._ccap, self._plo, self._phi, self._pl, self._pt,
                lo, hi, lv, lt, slack,
            )
        )  # fmt: skip
        self._plo, self._phi, self._pl, self._pt = lo, hi, lv, lt
        self._garbage = 0
