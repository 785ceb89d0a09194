"""One frame's evidence in :class:`mapping.probabilistic.ProbabilisticVHV`: its VHV structures, their
occupied slabs on the height lattice and the merged free intervals of their fans (steps 1-3 of the
module docs of :mod:`mapping.probabilistic`), without touching the stored map. The compiled kernels are
in :mod:`mapping._evidence_kernels`; the update of the stored intervals with this evidence is in
:mod:`mapping._interval_store`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.errors import MappingError
from mapping.evidence import EvidenceParams
from mapping.grid import GridSpec

# Heights farther than this many lattice steps from 0 cannot be stored (int32 bounds).
_LATTICE_LIMIT = float(2**30)


class FrameEvidence:
    """A frame's occupied and free evidence, in lattice units (a base of ``ProbabilisticVHV``)."""

    spec: GridSpec
    tolerance: float
    params: EvidenceParams
    _r: float
    _half: float
    _margin: float
    _gap: float

    def _build(self, pts: NDArray[np.floating], method: str) -> tuple[Any, ...]:
        """The frame's VHV structures: (key, bottom, top, n_nonfinite, n_outside, path)."""
        from mapping.vhv import _build_compiled, _build_numpy

        if method not in ("auto", "bins", "sort", "numpy"):
            raise MappingError(f"insert method={method!r}: expected one of ('auto', 'bins', 'sort', 'numpy')")
        if method == "numpy":
            with np.errstate(over="ignore"):
                return (*_build_numpy(pts, self.spec, self.tolerance), "numpy")
        return tuple(_build_compiled(pts, self.spec, self.tolerance, method))

    def _within(
        self,
        key: NDArray[np.int64],
        bot: NDArray[np.float64],
        top: NDArray[np.float64],
        origin: tuple[float, float, float],
        max_range: float,
    ) -> bool:
        """True when the box of the structures' cells and heights lies within ``max_range`` of origin."""
        if key.shape[0] == 0:
            return True
        ny, cs = self.spec.shape[1], self.spec.cell_size
        (ou, ov) = self.spec.origin
        i, j = key // ny, key % ny
        su, sv, sh = (float(c) for c in self.spec.to_grid_frame(np.asarray(origin)))
        du = max(abs((int(i.min()) + ou) * cs - su), abs((int(i.max()) + ou + 1) * cs - su))
        dv = max(abs((int(j.min()) + ov) * cs - sv), abs((int(j.max()) + ov + 1) * cs - sv))
        dh = max(abs(float(bot.min()) - sh), abs(float(top.max()) - sh))
        return math.sqrt(du * du + dv * dv + dh * dh) <= max_range

    def _evidence(
        self,
        pts: NDArray[np.floating],
        free_only: NDArray[np.float64] | None,
        origin: tuple[float, float, float] | None,
        method: str,
        built: tuple[Any, ...] | None = None,
        defer: bool = False,
    ) -> dict[str, Any]:
        """One frame's occupied slabs and merged free intervals (lattice units), without touching the map.

        With ``defer`` the free intervals are left to a :class:`FanJob` (``"fans"``; None when there are
        none): ``fkey``/``flo``/``fhi`` are empty until its ``extract`` fills them in."""
        from mapping import _evidence_kernels as E
        from mapping.vhv import _build_compiled, _build_numpy

        spec, tol = self.spec, self.tolerance
        key, bot, top, n_nf, n_out, used = built if built is not None else self._build(pts, method)
        r = self._r
        lim = _LATTICE_LIMIT * r * 0.5
        ok = (bot > -lim) & (top < lim)
        if not bool(ok.all()):
            key, bot, top = key[ok], bot[ok], top[ok]
        okey, olo, ohi = E.occupied_evidence(
            key, bot, top, 1.0 / r, self._half, -_LATTICE_LIMIT, _LATTICE_LIMIT
        )
        fkey = np.empty(0, np.int64)
        flo = np.empty(0, np.int32)
        fhi = np.empty(0, np.int32)
        passages = 0
        job = None
        if origin is not None:
            tkey, tbot, ttop = key, bot, top
            if free_only is not None and free_only.shape[0]:
                k2, b2, t2, _, _ = (
                    _build_numpy(free_only, spec, tol)
                    if method == "numpy"
                    else _build_compiled(free_only, spec, tol, "auto")[:5]
                )
                ok2 = (b2 > -lim) & (t2 < lim)
                tkey = np.concatenate([key, k2[ok2]])
                tbot = np.concatenate([bot, b2[ok2]])
                ttop = np.concatenate([top, t2[ok2]])
            if tkey.shape[0]:
                job = self._fan_job(tkey, tbot, ttop, origin, okey, olo, ohi)
                if not defer:
                    fkey, flo, fhi, passages = job.extract()
                    job = None
        return {
            "n_nonfinite": int(n_nf),
            "n_outside": int(n_out),
            "frame_structures": int(key.shape[0]),
            "method": used,
            "free_intervals": int(fkey.shape[0]),
            "occupied_slabs": int(okey.shape[0]),
            "fan_passages": int(passages),
            "okey": okey,
            "olo": olo,
            "ohi": ohi,
            "fkey": fkey,
            "flo": flo,
            "fhi": fhi,
            "fans": job,
        }

    def _fan_job(
        self,
        key: NDArray[np.int64],
        bot: NDArray[np.float64],
        top: NDArray[np.float64],
        origin: tuple[float, float, float],
        okey: NDArray[np.int64],
        olo: NDArray[np.int32],
        ohi: NDArray[np.int32],
    ) -> FanJob:
        """The frame's merged free intervals to compute (fans of every target structure), see the module
        docs: the table's box and bins."""
        spec = self.spec
        nx, ny = spec.shape
        su, sv, sh = (float(c) for c in spec.to_grid_frame(np.asarray(origin)))
        si, sj = (int(c) for c in spec.world_to_index(su, sv))
        ti = key // ny
        tj = key % ny
        i0 = max(min(int(ti.min()), si), 0)
        i1 = min(max(int(ti.max()), si), nx - 1)
        j0 = max(min(int(tj.min()), sj), 0)
        j1 = min(max(int(tj.max()), sj), ny - 1)
        ni, nj = i1 - i0 + 1, j1 - j0 + 1
        r = self._r
        inv_r = 1.0 / r
        b0 = math.floor(min(sh, float(bot.min())) * inv_r)
        b1 = math.floor(max(sh, float(top.max())) * inv_r)
        span = b1 - b0 + 1
        words_budget = max(1, int(self.params.max_table_bytes) // (8 * ni * nj))
        m = max(1, math.ceil(span / (64 * words_budget)))
        nbins = math.ceil(span / m)
        erode = math.ceil(self._margin / (m * r) - 1e-9)
        gap = math.floor(self._gap / (m * r) + 1e-9)
        nw = _row_words(nbins, words_budget)
        return FanJob(key, bot, top, okey, olo, ohi, spec, (su, sv, sh), (i0, j0, ni, nj), inv_r, b0, m,
                      nbins, erode, gap, nw)  # fmt: skip


def _row_words(nbins: int, words_budget: int) -> int:
    """uint64 words per cell row of a fan bit table of ``nbins`` bins: ``ceil(nbins / 64)``, rows of 5 to
    7 words padded to 8 when ``words_budget`` (words per cell the table may take) allows it, so that
    :func:`mapping._evidence_kernels.fan_bits` sets runs four aligned words per access (the bins past
    ``nbins`` stay empty)."""
    nw = (nbins + 63) // 64
    return 8 if 4 < nw < 8 and 8 <= words_budget else nw


@dataclass
class FanJob:
    """The free intervals of one frame still to compute: its fans marked in a (cell, height bin) bit
    table (:meth:`mark`), then the merged runs read out of it (:meth:`extract`). Fields as the kernels
    :func:`mapping._evidence_kernels.fan_bits` and ``extract_free`` take them."""

    key: NDArray[np.int64]
    bot: NDArray[np.float64]
    top: NDArray[np.float64]
    okey: NDArray[np.int64]
    olo: NDArray[np.int32]
    ohi: NDArray[np.int32]
    spec: GridSpec
    sensor: tuple[float, float, float]
    box: tuple[int, int, int, int]
    inv_r: float
    b0: int
    m: int
    nbins: int
    erode: int
    gap: int
    nw: int  # uint64 words per cell row of the bit table (>= ceil(nbins / 64); the bins past nbins stay 0)
    bits: NDArray[np.uint64] | None = None
    passages: int = 0

    def mark(self) -> None:
        """Mark every fan in the table (once)."""
        if self.bits is not None:
            return
        from mapping import _evidence_kernels as E

        ny = self.spec.shape[1]
        (ou, ov), cs = self.spec.origin, self.spec.cell_size
        i0, j0, ni, nj = self.box
        nw = self.nw
        self.bits = np.zeros(ni * nj * nw, np.uint64)
        self.passages = int(
            E.fan_bits(self.key, self.bot, self.top, ny, cs, ou, ov, *self.sensor, i0, j0, ni, nj, nw,
                       self.inv_r, self.b0, self.m, self.nbins, self.bits)
        )  # fmt: skip

    def extract(self) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int32], int]:
        """(key, lo, hi, passages): the merged free intervals (marking the fans first if needed)."""
        from mapping import _evidence_kernels as E

        self.mark()
        i0, j0, ni, nj = self.box
        nw = self.nw
        fkey, flo, fhi = E.extract_free(
            self.bits, i0, j0, ni, nj, nw, self.nbins, self.spec.shape[1], self.b0, self.m, self.gap,
            self.erode, self.okey, self.olo, self.ohi,
        )  # fmt: skip
        self.bits = None
        return fkey, flo, fhi, self.passages


@dataclass
class PreparedFrame:
    """One frame's evidence, ready for ``ProbabilisticVHV.insert_prepared`` (from ``prepare_frame``).

    A frame prepared with ``defer_fans`` still has its free intervals to compute: :meth:`mark_fans`
    then :meth:`extract_free` do it (on any thread, once each; ``insert_prepared`` does what is left).

    Attributes:
        layout: ``(spec, tolerance, params)`` of the map that prepared it; only a map of the same
            layout takes it.
        evidence: ``FrameEvidence._evidence``'s dict: counts, and the occupied slabs (``okey``,
            ``olo``, ``ohi``: int64 cell keys, int32 lattice bounds) and merged free intervals
            (``fkey``, ``flo``, ``fhi``), sorted by key then bound; read-only.
        points_in: points of the frame (``(N, 3)`` rows given).
        free_only: of them (or of the free-only targets), how many gave free space only.
        origin: sensor origin, world metres (None: no free space).
        prepare_ms: wall milliseconds the preparation took (every phase done so far).
    """

    layout: tuple[Any, ...]
    evidence: dict[str, Any]
    points_in: int
    free_only: int
    origin: tuple[float, float, float] | None
    prepare_ms: float

    @property
    def complete(self) -> bool:
        """True when the free intervals are computed."""
        return self.evidence["fans"] is None

    def mark_fans(self) -> None:
        """Mark the fans of the frame's targets (the first half of the free intervals' work)."""
        job = self.evidence["fans"]
        if job is not None:
            t0 = time.perf_counter()
            job.mark()
            self.prepare_ms += (time.perf_counter() - t0) * 1e3

    def extract_free(self) -> None:
        """Compute the merged free intervals (marking the fans first if needed)."""
        job = self.evidence["fans"]
        if job is None:
            return
        t0 = time.perf_counter()
        fkey, flo, fhi, passages = job.extract()
        ev = self.evidence
        ev.update(fkey=fkey, flo=flo, fhi=fhi, fans=None, free_intervals=int(fkey.shape[0]),
                  fan_passages=passages)  # fmt: skip
        self.prepare_ms += (time.perf_counter() - t0) * 1e3
