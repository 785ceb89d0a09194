"""The in-place store update (``mapping._store_update.update_store``) gives the pool of the reference
kernels of ``mapping._store_kernels`` (the sweep into temporaries, the relocation count, the dynamic
bookkeeping, the write-back) bit for bit: lists, stamps, starts, reserved room, fill, garbage and the
dynamic-cell list, with stamps and decay on and off."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from mapping.grid import GridSpec
from mapping.probabilistic import EvidenceParams, ProbabilisticVHV
from tests.mapping.test_probabilistic_prepared import _assert_same, _frames, _insert


def _reference_update(self, okey, olo, ohi, fkey, flo, fhi):  # type: ignore[no-untyped-def]
    """``IntervalStore._update`` as the four reference kernels do it."""
    from mapping import _store_kernels as E

    tkey, toff, tlo, thi, tl, tt = E.update_cells(
        self._cstart, self._ccount, self._plo, self._phi, self._pl, self._pt,
        okey, olo, ohi, fkey, flo, fhi,
        self._l_hit, self._l_miss, self._l_min, self._l_max, np.float32(1e-4),
        self._track, self._now, self._l_void, self._l_occ,
    )  # fmt: skip
    extra = int(E.relocation_slots(tkey, toff, self._ccap))
    if self._used + extra > self._plo.shape[0]:
        self._grow(self._used + extra)
    if self._track:
        if self._n_dyn + tkey.shape[0] > self._dyn_cells.shape[0]:
            grown = np.empty(2 * (self._n_dyn + tkey.shape[0]), np.int64)
            grown[: self._n_dyn] = self._dyn_cells[: self._n_dyn]
            self._dyn_cells = grown
        n_dyn = E.track_dynamic(
            tkey, toff, tl, tt, self._max_dwell(), self._l_occ,
            self._dyn_flag, self._dyn_due, self._dyn_cells, self._n_dyn,
        )  # fmt: skip
        self._n_dyn = int(n_dyn)
    used, freed, delta = E.write_back(
        tkey, toff, tlo, thi, tl, tt, self._cstart, self._ccount, self._ccap,
        self._plo, self._phi, self._pl, self._pt, self._used,
    )  # fmt: skip
    self._used = int(used)
    self._garbage += int(freed)
    self._n_intervals += int(delta)
    if self._garbage > 2 * self._n_intervals + (1 << 16):
        self._compact()
    return int(tkey.shape[0])


def _reference(m: ProbabilisticVHV) -> ProbabilisticVHV:
    m._update = _reference_update.__get__(m)  # type: ignore[method-assign]
    return m


def _random_frame(rng: np.random.Generator, n_cells: int, top: int) -> tuple[np.ndarray, ...]:
    """Occupied slabs and free intervals of random cells: per cell sorted, disjoint, touching often
    (the bounds come from a coarse lattice), on lattice heights ``[0, top)``."""
    cells = np.sort(rng.choice(n_cells, size=rng.integers(1, min(n_cells, 40)), replace=False))
    ok, ol, oh, fk, fl, fh = ([] for _ in range(6))
    for c in cells:
        bounds = np.unique(rng.integers(0, top // 3, size=rng.integers(2, 9))) * 3
        for lo, hi in itertools.pairwise(bounds):
            kind = rng.random()
            if kind < 0.25:
                ok.append(c)
                ol.append(lo)
                oh.append(hi)
            elif kind < 0.8:
                fk.append(c)
                fl.append(lo)
                fh.append(hi)
    return (np.array(ok, np.int64), np.array(ol, np.int32), np.array(oh, np.int32),
            np.array(fk, np.int64), np.array(fl, np.int32), np.array(fh, np.int32))  # fmt: skip


def _store_state(m: ProbabilisticVHV) -> dict[str, np.ndarray]:
    runs = [np.arange(s, s + c) for s, c in zip(m._cstart, m._ccount) if c]
    live = np.concatenate(runs or [np.empty(0, np.int64)])
    return {
        "cstart": m._cstart, "ccount": m._ccount, "ccap": m._ccap,
        "plo": m._plo[live], "phi": m._phi[live], "pl": m._pl[live], "pt": m._pt[live],
        "dyn_cells": m._dyn_cells[: m._n_dyn], "dyn_flag": m._dyn_flag, "dyn_due": m._dyn_due,
        "scalars": np.array([m._used, m._garbage, m._n_intervals, m._n_dyn]),
    }  # fmt: skip


@pytest.mark.parametrize("decay", [0.05, None])
def test_random_frames_give_the_reference_pool_bit_for_bit(decay):
    """Random evidence on a few cells (slabs over free space, free over slabs, gaps, bounds that
    touch), frame after frame at 20 Hz with the decay on (stamps, drops) and off, from a pool so small
    that cells relocate past its end (the update stops, the pool grows, it goes on): after every frame
    the pools are equal."""
    rng = np.random.default_rng(11)
    spec = GridSpec(cell_size=0.05, size_x=0.4, size_y=0.4)
    params = EvidenceParams(dynamic_decay_s=decay, dynamic_max_dwell_s=0.3)
    new, ref = ProbabilisticVHV(spec, params=params), _reference(ProbabilisticVHV(spec, params=params))
    for m in (new, ref):  # a tiny pool: relocations run out of room
        m._plo, m._phi, m._pl, m._pt = (
            m._plo[:64].copy(),
            m._phi[:64].copy(),
            m._pl[:64].copy(),
            m._pt[:64].copy(),
        )
    n_cells = spec.shape[0] * spec.shape[1]
    grew = dropped = 0
    for k in range(300):
        frame = _random_frame(rng, n_cells, 60)
        cap = new._plo.shape[0]
        for m in (new, ref):
            m._advance(k / 20.0)
            dropped += m._decay()
            m._update(*frame)
        grew += new._plo.shape[0] > cap
        a, b = _store_state(new), _store_state(ref)
        for name in a:
            np.testing.assert_array_equal(a[name], b[name], err_msg=f"frame {k}: {name}", strict=True)
    assert grew > 0
    assert new._n_intervals > 3 * n_cells  # lists of several pieces
    if decay is not None:
        assert dropped > 0 and np.isfinite(new._pt[: new._used, 0]).any()


@pytest.mark.parametrize("decay", [0.5, None])
def test_rendered_frames_give_the_reference_map_bit_for_bit(decay):
    """A walker crossing a room in rendered depth frames (range limits, no-return ends, a repeated
    stamp): the map equals the map of the reference kernels, also its counters."""
    spec = GridSpec(cell_size=0.05, size_x=8.0, size_y=8.0)
    params = dataclasses.replace(EvidenceParams(dynamic_decay_s=0.5, dynamic_max_dwell_s=2.0),
                                 dynamic_decay_s=decay)  # fmt: skip
    new, ref = ProbabilisticVHV(spec, params=params), _reference(ProbabilisticVHV(spec, params=params))
    for f in _frames():
        got, want = _insert(new, f), _insert(ref, f)
        assert dataclasses.replace(got, build_ms=0.0) == dataclasses.replace(want, build_ms=0.0)
    _assert_same(new, ref)
    assert new._n_intervals > 1000
