"""The free-space kernels of the probabilistic map against the kernels they replaced, bit for bit.

``fan_bits`` (per-structure bit masks without a per-passage call or a branch on the run's width) and
``extract_free`` (output sized by a counting pass instead of grown inside the loop) are faster
rewrites of the previous kernels, which are kept here verbatim as the reference: on random structure
sets, sensor positions and bin coarsenings and on real frames of the synthetic scene, the bit table,
the passage count and the extracted free intervals must be identical.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import pytest

from mapping import _evidence_kernels as E
from mapping.grid import GridSpec
from mapping.probabilistic import EvidenceParams, ProbabilisticVHV
from mapping.synthetic import kinect_hd_like_cloud

_J: dict[str, Any] = {"nopython": True, "error_model": "numpy", "boundscheck": False}
_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)


# ---------------------------------------------------------------- the previous kernels (reference)
@numba.jit(**_J)
def _ref_set_bits(bits, base, b0, b1):  # type: ignore[no-untyped-def]
    w0 = b0 >> 6
    w1 = b1 >> 6
    if w0 == w1:
        width = b1 - b0 + 1
        if width == 64:
            bits[base + w0] = _ALL
        else:
            bits[base + w0] |= ((np.uint64(1) << np.uint64(width)) - np.uint64(1)) << np.uint64(b0 & 63)
        return
    for w in range(w0, w1 + 1):
        lo = b0 - (w << 6) if w == w0 else 0
        hi = b1 - (w << 6) if w == w1 else 63
        width = hi - lo + 1
        if width == 64:
            mask = _ALL
        else:
            mask = ((np.uint64(1) << np.uint64(width)) - np.uint64(1)) << np.uint64(lo)
        bits[base + w] |= mask


@numba.jit(**_J)
def _ref_fan_bits(  # type: ignore[no-untyped-def]
    key, bottom, top, ny, cs, ou, ov, su, sv, sh, i0, j0, ni, nj, nw, inv_r, b0, m, nbins, bits
):
    n = key.shape[0]
    ics = 1.0 / cs
    li0 = np.int64(np.floor(su * ics))
    lj0 = np.int64(np.floor(sv * ics))
    fb0 = np.float64(b0)
    passages = 0
    g0 = 0
    while g0 < n:
        g1 = g0 + 1
        while g1 < n and key[g1] == key[g0]:
            g1 += 1
        ti = key[g0] // ny + ou
        tj = key[g0] % ny + ov
        cu = (ti + 0.5) * cs
        cv = (tj + 0.5) * cs
        du = cu - su
        dv = cv - sv
        ci = li0
        cj = lj0
        if du > 0.0:
            stu = 1
            tmu = ((ci + 1) * cs - su) / du
            tdu = cs / du
        elif du < 0.0:
            stu = -1
            tmu = (ci * cs - su) / du
            tdu = -cs / du
        else:
            stu = 0
            tmu = 1e300
            tdu = 0.0
        if dv > 0.0:
            stv = 1
            tmv = ((cj + 1) * cs - sv) / dv
            tdv = cs / dv
        elif dv < 0.0:
            stv = -1
            tmv = (cj * cs - sv) / dv
            tdv = -cs / dv
        else:
            stv = 0
            tmv = 1e300
            tdv = 0.0
        s_in = 0.0
        steps = abs(ti - ci) + abs(tj - cj)
        for _ in range(steps):
            s_out = min(tmu, tmv)
            if s_out > s_in:
                gi = ci - ou - i0
                gj = cj - ov - j0
                if gi >= 0 and gj >= 0 and gi < ni and gj < nj:
                    base = (gi * nj + gj) * nw
                    for k in range(g0, g1):
                        bl = bottom[k] - sh
                        tl = top[k] - sh
                        lo = sh + min(s_in * bl, s_out * bl)
                        hi = sh + max(s_in * tl, s_out * tl)
                        bb0 = np.int64(lo * inv_r - fb0)
                        bb1 = np.int64(hi * inv_r - fb0)
                        if m != 1:
                            bb0 //= m
                            bb1 //= m
                        bb0 = min(max(bb0, np.int64(0)), nbins - 1)
                        bb1 = min(max(bb1, np.int64(0)), nbins - 1)
                        _ref_set_bits(bits, base, bb0, bb1)
                        passages += 1
            s_in = s_out
            fu = np.int64(tmu <= tmv)
            ci += stu * fu
            cj += stv * (1 - fu)
            tmu += tdu * fu
            tmv += tdv * (1 - fu)
        g0 = g1
    return passages


def _ref_extract_free(bits, i0, j0, ni, nj, nw, nbins, ny, b0, m, gap, erode, okey, olo, ohi):  # type: ignore[no-untyped-def]
    """The previous extraction's rule, written over bins in Python (slow, plain)."""
    out: list[tuple[int, int, int]] = []
    rows = np.unpackbits(bits.view(np.uint8).reshape(ni * nj, nw * 8), axis=1, bitorder="little")
    occ_of: dict[int, list[tuple[int, int]]] = {}
    for k, lo, hi in zip(okey.tolist(), olo.tolist(), ohi.tolist(), strict=True):
        occ_of.setdefault(k, []).append((lo, hi))
    for c in np.flatnonzero(rows[:, :nbins].any(axis=1)).tolist():
        row = rows[c, :nbins].astype(bool).tolist()
        key = (i0 + c // nj) * ny + (j0 + c % nj)
        runs: list[list[int]] = []
        b = 0
        while b < nbins:
            if not row[b]:
                b += 1
                continue
            r0 = b
            while b < nbins and row[b]:
                b += 1
            if runs and r0 - runs[-1][1] <= gap:
                runs[-1][1] = b
            else:
                runs.append([r0, b])
        occ = occ_of.get(key, [])
        for r0, r1 in runs:
            lo, hi = b0 + (r0 + erode) * m, b0 + (r1 - erode) * m
            cur = lo
            for olo_, ohi_ in occ:
                if ohi_ <= cur or olo_ >= hi:
                    continue
                if olo_ > cur:
                    out.append((key, cur, olo_))
                cur = max(cur, ohi_)
            if cur < hi:
                out.append((key, cur, hi))
    return out


# ---------------------------------------------------------------- cases
def _random_case(rng: np.random.Generator) -> tuple[Any, ...]:
    """Structures in random cells of a small grid, a random sensor (inside or outside the box), a
    random coarsening ``m`` and table depth, like ``ProbabilisticVHV._fan_job`` lays them out."""
    cs = float(rng.choice([0.05, 0.1, 0.13]))
    nx, ny = int(rng.integers(8, 60)), int(rng.integers(8, 60))
    ou, ov = -(nx // 2), -(ny // 2)
    n_cells = int(rng.integers(1, 80))
    cells = rng.integers(0, nx * ny, n_cells)
    per = rng.integers(1, 4, n_cells)
    key = np.sort(np.repeat(cells, per)).astype(np.int64)
    bottom = rng.uniform(-0.5, 2.5, key.size)
    top = bottom + rng.uniform(0.0, 1.0, key.size)
    # a few sensors on cell borders and corners (zero-length passages), the rest anywhere
    su = float(rng.integers(ou, ou + nx) * cs) if rng.random() < 0.3 else float(rng.uniform(ou, ou + nx) * cs)
    sv = float(rng.integers(ov, ov + ny) * cs) if rng.random() < 0.3 else float(rng.uniform(ov, ov + ny) * cs)
    sh = float(rng.uniform(0.0, 2.0))
    i0, j0 = 0, 0
    ni, nj = nx, ny
    r = 0.01
    inv_r = 1.0 / r
    b0 = int(np.floor(min(sh, bottom.min()) * inv_r))
    b1 = int(np.floor(max(sh, top.max()) * inv_r))
    span = b1 - b0 + 1
    m = int(rng.choice([1, 1, 2, 3, 7]))
    nbins = -(-span // m)
    nw = (nbins + 63) // 64 + int(rng.integers(0, 2))
    return key, bottom, top, ny, cs, ou, ov, su, sv, sh, i0, j0, ni, nj, nw, inv_r, b0, m, nbins


def _both(args: tuple[Any, ...]) -> tuple[np.ndarray, int, np.ndarray, int]:
    ni, nj, nw = args[12], args[13], args[14]
    new = np.zeros(ni * nj * nw, np.uint64)
    ref = np.zeros(ni * nj * nw, np.uint64)
    p_new = E.fan_bits(*args, new)
    p_ref = _ref_fan_bits(*args, ref)
    return new, int(p_new), ref, int(p_ref)


@pytest.mark.parametrize("seed", range(40))
def test_fan_bits_equal_the_previous_kernel_on_random_structures(seed: int) -> None:
    args = _random_case(np.random.default_rng(seed))
    new, p_new, ref, p_ref = _both(args)
    assert p_new == p_ref
    assert np.array_equal(new, ref)


@pytest.mark.parametrize("seed", range(20))
def test_extract_free_equals_the_previous_rule_on_random_tables(seed: int) -> None:
    rng = np.random.default_rng(1000 + seed)
    ni, nj, nw = int(rng.integers(1, 12)), int(rng.integers(1, 12)), int(rng.integers(1, 4))
    nbins = int(rng.integers(1, 64 * nw + 1))
    # sparse and dense rows, runs across word borders
    bits = (rng.integers(0, 2**63, ni * nj * nw, dtype=np.uint64) * np.uint64(2)) | rng.integers(
        0, 2, ni * nj * nw, dtype=np.uint64
    )
    bits[rng.random(bits.size) < 0.3] = 0
    bits[rng.random(bits.size) < 0.2] = _ALL
    ny, i0, j0, b0, m = nj + 3, 2, 1, int(rng.integers(-50, 50)), int(rng.choice([1, 2]))
    keys = np.array([(i0 + c // nj) * ny + (j0 + c % nj) for c in range(ni * nj)], np.int64)
    occ = []
    for k in keys[rng.random(keys.size) < 0.5]:
        edges = np.sort(rng.choice(np.arange(b0 - 5, b0 + nbins * m + 5), 2 * int(rng.integers(1, 4)), False))
        occ += [(k, edges[q], edges[q + 1]) for q in range(0, edges.size, 2)]
    okey = np.array([o[0] for o in occ], np.int64)
    olo = np.array([o[1] for o in occ], np.int32)
    ohi = np.array([o[2] for o in occ], np.int32)
    gap, erode = int(rng.integers(0, 4)), int(rng.integers(0, 3))
    fk, flo, fhi = E.extract_free(bits, i0, j0, ni, nj, nw, nbins, ny, b0, m, gap, erode, okey, olo, ohi)
    ref = _ref_extract_free(bits, i0, j0, ni, nj, nw, nbins, ny, b0, m, gap, erode, okey, olo, ohi)
    assert list(zip(fk.tolist(), flo.tolist(), fhi.tolist(), strict=True)) == ref


@pytest.mark.parametrize(("height", "width", "seed"), [(144, 256, 0), (212, 256, 1), (424, 512, 2)])
def test_free_kernels_equal_the_previous_ones_on_real_frames(
    height: int, width: int, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Frames of the synthetic room (and their cut-back max-range targets) inserted into a map holding
    earlier frames: every call's table, passage count and free intervals as the previous kernels."""
    calls: list[tuple[Any, ...]] = []
    fan, extract = E.fan_bits, E.extract_free

    def fan_rec(*a: Any) -> Any:
        calls.append(("fan", a[:-1], a[-1].copy()))
        return fan(*a)

    def extract_rec(*a: Any) -> Any:
        out = extract(*a)
        calls.append(("extract", a, out))
        return out

    monkeypatch.setattr(E, "fan_bits", fan_rec)
    monkeypatch.setattr(E, "extract_free", extract_rec)
    rng = np.random.default_rng(seed)
    m = ProbabilisticVHV(GridSpec(cell_size=0.05, size_x=20.0, size_y=20.0), 0.05, EvidenceParams())
    origin = np.array([0.0, 0.0, 1.0])
    for k in range(3):
        m.insert(kinect_hd_like_cloud(rng, height, width), sensor_origin=origin + 0.07 * k, max_range=4.0)
    fans = [c for c in calls if c[0] == "fan"]
    assert len(fans) == 3
    for (_, args, before), (_, eargs, out) in zip(fans, [c for c in calls if c[0] == "extract"], strict=True):
        assert not before.any()
        ref = before.copy()
        p_ref = _ref_fan_bits(*args, ref)
        new = np.zeros_like(ref)
        assert E.fan_bits(*args, new) == p_ref > 10_000
        assert np.array_equal(new, ref)
        assert np.array_equal(eargs[0], ref)  # the table the map extracted from
        expected = _ref_extract_free(*eargs)
        assert len(expected) > 500
        assert list(zip(*(o.tolist() for o in out), strict=True)) == expected


def test_ctz_finds_the_lowest_set_bit() -> None:
    rng = np.random.default_rng(7)
    words = [1 << p for p in range(64)] + [
        int(w) | (1 << 63) for w in rng.integers(1, 2**63, 500, dtype=np.uint64)
    ]
    words += [
        int(w) & ~((1 << int(s)) - 1) or 1 << 63
        for w, s in zip(rng.integers(1, 2**63, 500), rng.integers(0, 64, 500), strict=True)
    ]
    for w in words:
        assert E._ctz(np.uint64(w)) == (w & -w).bit_length() - 1, hex(w)
