"""Compiled (numba, one thread, cached) kernels of the probabilistic map (:mod:`mapping.probabilistic`).

Heights along the kept axis are integers on the map's height lattice (multiples of ``height_resolution``), so
that interval bounds from different frames are equal exactly and intervals merge instead of splitting
into slivers. Intervals are half-open ``[lo, hi)`` in lattice units.

Layout of the map (structure of arrays):

* a dense table over the grid's cells: ``cstart`` (int64, first slot in the pool), ``ccount`` (int32,
  intervals of the cell), ``ccap`` (int32, slots reserved for the cell);
* a pool: ``plo``, ``phi`` (int32 lattice bounds) and ``pl`` (float32 log-odds), cell lists stored
  contiguously, sorted by ``lo`` and disjoint.

A frame touches few cells; only those are rewritten (in place when the new list fits the reserved
slots, else appended at the pool's end).
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

_JIT: dict[str, Any] = {
    "cache": True,
    "nogil": True,
    "nopython": True,
    "error_model": "numpy",
    "boundscheck": False,
}

_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)


@numba.jit(**_JIT)
def occupied_evidence(key, bottom, top, inv_r, half, lat_min, lat_max):  # type: ignore[no-untyped-def]
    """The frame's occupied intervals on the lattice: ``[floor((b - half) / r), ceil((t + half) / r))``.

    Structures come sorted by key then bottom; slabs of one cell that overlap or touch after widening
    are joined, so the output is sorted and disjoint per cell. Bounds are clipped to
    ``[lat_min, lat_max]``.
    """
    n = key.shape[0]
    ok = np.empty(n, np.int64)
    olo = np.empty(n, np.int32)
    ohi = np.empty(n, np.int32)
    m = 0
    for k in range(n):
        lo = np.floor((bottom[k] - half) * inv_r)
        hi = np.ceil((top[k] + half) * inv_r)
        lo = min(max(lo, lat_min), lat_max - 1.0)
        hi = min(max(hi, lo + 1.0), lat_max)
        ilo = np.int32(lo)
        ihi = np.int32(hi)
        if m > 0 and ok[m - 1] == key[k] and ilo <= ohi[m - 1]:
            if ihi > ohi[m - 1]:
                ohi[m - 1] = ihi
            continue
        ok[m] = key[k]
        olo[m] = ilo
        ohi[m] = ihi
        m += 1
    return ok[:m].copy(), olo[:m].copy(), ohi[:m].copy()


@numba.jit(**_JIT)
def _set_bits(bits, base, b0, b1):  # type: ignore[no-untyped-def]
    """Set bins ``b0 .. b1`` (inclusive) of the bit row starting at word ``base``."""
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


@numba.jit(**_JIT)
def fan_bits(  # type: ignore[no-untyped-def]
    key, bottom, top, ny, cs, ou, ov, su, sv, sh, i0, j0, ni, nj, nw, inv_r, b0, m, nbins, bits
):
    """Mark the free fan of every target structure in a (cell, height bin) bit table (thesis Fig. 5.14).

    From the sensor ``(su, sv, sh)`` (grid-frame metres) two lines go to the bottom and the top of each
    structure, both aimed at the centre of its cell. The segment is walked cell by cell in the grid
    plane (Amanatides-Woo); every cell it passes through before the structure's own cell gets the
    heights the fan spans there: from the lower of the bottom line's heights at the entry and exit of
    the passage to the higher of the top line's. Passages of zero length (a corner) are skipped, and so
    are cells outside the table's box ``[i0, i0 + ni) x [j0, j0 + nj)``.

    The table has ``nw`` uint64 words per cell; bin ``k`` is lattice ``[b0 + k m, b0 + (k + 1) m)``.

    Returns:
        Number of (structure, cell) passages marked.
    """
    n = key.shape[0]
    ics = 1.0 / cs
    li0 = np.int64(np.floor(su * ics))
    lj0 = np.int64(np.floor(sv * ics))
    fb0 = np.float64(b0)
    passages = 0
    g0 = 0
    while g0 < n:
        # structures of one cell are consecutive: walk the segment to that cell once for all of them
        g1 = g0 + 1
        while g1 < n and key[g1] == key[g0]:
            g1 += 1
        ti = key[g0] // ny + ou  # lattice cell of the target
        tj = key[g0] % ny + ov
        cu = (ti + 0.5) * cs
        cv = (tj + 0.5) * cs
        du = cu - su
        dv = cv - sv
        ci = li0
        cj = lj0
        # Large finite stand-ins for "never": a step times 0 must stay 0 (inf * 0 is NaN).
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
        # A 4-connected walk reaches the target's cell in exactly this many steps; the cells before
        # each step are the ones the fan passes through.
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
                        # heights of a fan lie within the table (>= b0): truncation is floor here
                        # (a rounding step below 0 truncates to bin 0, where it belongs)
                        bb0 = np.int64(lo * inv_r - fb0)
                        bb1 = np.int64(hi * inv_r - fb0)
                        if m != 1:  # an integer division costs more than the rest of a passage
                            bb0 //= m
                            bb1 //= m
                        bb0 = min(max(bb0, np.int64(0)), nbins - 1)
                        bb1 = min(max(bb1, np.int64(0)), nbins - 1)
                        _set_bits(bits, base, bb0, bb1)
                        passages += 1
            s_in = s_out
            # branch-free step (which axis comes next is unpredictable)
            fu = np.int64(tmu <= tmv)
            ci += stu * fu
            cj += stv * (1 - fu)
            tmu += tdu * fu
            tmv += tdv * (1 - fu)
        g0 = g1
    return passages


@numba.jit(**_JIT)
def _ctz(x):  # type: ignore[no-untyped-def]
    """Trailing zero bits of a non-zero uint64 (binary search: numba has no portable intrinsic)."""
    n = 0
    if (x & np.uint64(0xFFFFFFFF)) == np.uint64(0):
        n += 32
        x >>= np.uint64(32)
    if (x & np.uint64(0xFFFF)) == np.uint64(0):
        n += 16
        x >>= np.uint64(16)
    if (x & np.uint64(0xFF)) == np.uint64(0):
        n += 8
        x >>= np.uint64(8)
    if (x & np.uint64(0xF)) == np.uint64(0):
        n += 4
        x >>= np.uint64(4)
    if (x & np.uint64(0x3)) == np.uint64(0):
        n += 2
        x >>= np.uint64(2)
    if (x & np.uint64(0x1)) == np.uint64(0):
        n += 1
    return n


@numba.jit(**_JIT)
def _next_bit(bits, base, nw, b, zero):  # type: ignore[no-untyped-def]
    """First bin ``>= b`` whose bit is set (or clear, with ``zero``) in a row of ``nw`` words;
    ``64 * nw`` when there is none."""
    w = b >> 6
    if w >= nw:
        return nw << 6
    x = bits[base + w]
    if zero:
        x = ~x
    x = (x >> np.uint64(b & 63)) << np.uint64(b & 63)
    while x == np.uint64(0):
        w += 1
        if w >= nw:
            return nw << 6
        x = bits[base + w]
        if zero:
            x = ~x
    return (w << 6) + _ctz(x)


@numba.jit(**_JIT)
def extract_free(  # type: ignore[no-untyped-def]
    bits, i0, j0, ni, nj, nw, nbins, ny, b0, m, gap, erode, okey, olo, ohi
):
    """Free intervals of the frame from the bit table: runs of marked bins per cell (runs separated by
    at most ``gap`` empty bins joined), each shrunk by ``erode`` bins at both ends (the near-surface
    rule), minus the frame's occupied intervals of the cell (``okey``/``olo``/``ohi``, sorted by key
    then lo, disjoint).

    Returns:
        (key, lo, hi) sorted by key then lo; disjoint per cell and disjoint from the occupied ones.
    """
    cap = 1024
    fk = np.empty(cap, np.int64)
    flo = np.empty(cap, np.int32)
    fhi = np.empty(cap, np.int32)
    n = 0
    po = 0
    n_occ = okey.shape[0]
    for gi in range(ni):
        for gj in range(nj):
            base = (gi * nj + gj) * nw
            anyset = False
            for w in range(nw):
                if bits[base + w] != 0:
                    anyset = True
                    break
            if not anyset:
                continue
            key = (i0 + gi) * ny + (j0 + gj)
            while po < n_occ and okey[po] < key:
                po += 1
            pe = po
            while pe < n_occ and okey[pe] == key:
                pe += 1
            b = 0
            while b < nbins:
                r0 = _next_bit(bits, base, nw, b, False)
                if r0 >= nbins:
                    break
                b = min(_next_bit(bits, base, nw, r0, True), nbins)
                while b < nbins:  # join runs separated by at most ``gap`` empty bins
                    nxt = _next_bit(bits, base, nw, b, False)
                    if nxt >= nbins or nxt - b > gap:
                        break
                    b = min(_next_bit(bits, base, nw, nxt, True), nbins)
                r1 = b  # run = bins [r0, r1)
                lo = b0 + (r0 + erode) * m
                hi = b0 + (r1 - erode) * m
                if hi <= lo:
                    continue
                # subtract the occupied intervals of the cell
                q = po
                while q < pe and ohi[q] <= lo:
                    q += 1
                cur = lo
                while cur < hi:
                    if q < pe and olo[q] < hi:
                        seg_hi = max(cur, min(hi, np.int64(olo[q])))
                        if seg_hi > cur:
                            if n == cap:
                                cap *= 2
                                fk2 = np.empty(cap, np.int64)
                                fk2[:n] = fk[:n]
                                fk = fk2
                                fl2 = np.empty(cap, np.int32)
                                fl2[:n] = flo[:n]
                                flo = fl2
                                fh2 = np.empty(cap, np.int32)
                                fh2[:n] = fhi[:n]
                                fhi = fh2
                            fk[n] = key
                            flo[n] = cur
                            fhi[n] = seg_hi
                            n += 1
                        cur = max(cur, np.int64(ohi[q]))
                        q += 1
                    else:
                        if n == cap:
                            cap *= 2
                            fk2 = np.empty(cap, np.int64)
                            fk2[:n] = fk[:n]
                            fk = fk2
                            fl2 = np.empty(cap, np.int32)
                            fl2[:n] = flo[:n]
                            flo = fl2
                            fh2 = np.empty(cap, np.int32)
                            fh2[:n] = fhi[:n]
                            fhi = fh2
                        fk[n] = key
                        flo[n] = cur
                        fhi[n] = hi
                        n += 1
                        cur = hi
    return fk[:n].copy(), flo[:n].copy(), fhi[:n].copy()


@numba.jit(**_JIT)
def update_cells(  # type: ignore[no-untyped-def]
    cstart,
    ccount,
    plo,
    phi,
    pl,
    pt,
    okey,
    olo,
    ohi,
    fkey,
    flo,
    fhi,
    l_hit,
    l_miss,
    l_min,
    l_max,
    merge_eps,
    track,
    now,
    l_void,
    l_occ,
):
    """Apply one frame's evidence to the cells it touches.

    Per touched cell the stored intervals and the frame's evidence (occupied slabs: ``+l_hit``; free
    intervals: ``+l_miss``; disjoint) are swept together: every elementary segment between their
    bounds gets ``clamp(stored + delta, l_min, l_max)`` (``stored = 0``, i.e. p = 0.5, where the map knew
    nothing), untouched stored segments keep their value, and neighbours that touch with (nearly) equal
    log-odds merge. Nothing is created where neither stored nor frame evidence exists (unknown stays
    unknown).

    With ``track``, ``pt`` (``(cap, 2)``) holds per interval the stamps of its last hit and of its first
    dynamic hit when it is *dynamic* (``-inf`` both otherwise): an occupied slab that overlaps a stored
    piece known free (``stored < l_void``) or already dynamic is a dynamic slab, and every piece under
    it becomes dynamic with last stamp ``now`` and first stamp the earliest of the dynamic pieces still
    occupied (``stored >= l_occ``) it overlaps (``now`` if none: a new passage). The whole body that
    moved in becomes dynamic, also its parts over space nobody saw before. Other pieces keep their
    stamps, and only pieces with equal stamps merge.

    Returns:
        (tkey, toff, tlo, thi, tl, tt): the new lists of the touched cells (CSR by cell, keys ascending).
    """
    no = okey.shape[0]
    nf = fkey.shape[0]
    cap = 2 * (no + nf) + 1024
    tkey = np.empty(no + nf, np.int64)
    toff = np.empty(no + nf + 1, np.int64)
    tlo = np.empty(cap, np.int32)
    thi = np.empty(cap, np.int32)
    tl = np.empty(cap, np.float32)
    tt = np.empty((cap, 2), np.float64)
    dyn = np.zeros(no if track else 0, np.bool_)
    first = np.empty(no if track else 0, np.float64)
    ninf = -np.inf
    nt = 0
    n = 0
    a = 0
    b = 0
    big = np.int64(1) << 40
    toff[0] = 0
    while a < no or b < nf:
        if b >= nf or (a < no and okey[a] <= fkey[b]):
            key = okey[a]
        else:
            key = fkey[b]
        ae = a
        while ae < no and okey[ae] == key:
            ae += 1
        be = b
        while be < nf and fkey[be] == key:
            be += 1
        s0 = cstart[key]
        ns = np.int64(ccount[key])
        # room for the worst case of this cell
        need = n + 2 * (ns + (ae - a) + (be - b)) + 2
        if need > cap:
            cap = max(2 * cap, need)
            t2 = np.empty(cap, np.int32)
            t2[:n] = tlo[:n]
            tlo = t2
            t3 = np.empty(cap, np.int32)
            t3[:n] = thi[:n]
            thi = t3
            t4 = np.empty(cap, np.float32)
            t4[:n] = tl[:n]
            tl = t4
            t5 = np.empty((cap, 2), np.float64)
            t5[:n] = tt[:n]
            tt = t5
        cell0 = n
        if track:
            q = 0
            for k in range(a, ae):
                dyn[k] = False
                first[k] = now
                while q < ns and phi[s0 + q] <= olo[k]:
                    q += 1
                q2 = q
                while q2 < ns and plo[s0 + q2] < ohi[k]:
                    if pt[s0 + q2, 0] > ninf and pl[s0 + q2] >= l_occ:
                        dyn[k] = True  # still the same body: it keeps its first stamp
                        first[k] = min(first[k], pt[s0 + q2, 1])
                    elif pl[s0 + q2] < l_void or pt[s0 + q2, 0] > ninf:
                        dyn[k] = True
                    q2 += 1
        p = 0
        x = -big
        while True:
            # next evidence interval: the lower of the occupied and free streams
            e_lo = big
            e_hi = big
            e_d = np.float32(0.0)
            if a < ae and (b >= be or olo[a] <= flo[b]):
                e_lo = np.int64(olo[a])
                e_hi = np.int64(ohi[a])
                e_d = l_hit
                e_occ = True
            elif b < be:
                e_lo = np.int64(flo[b])
                e_hi = np.int64(fhi[b])
                e_d = l_miss
                e_occ = False
            else:
                e_occ = False
            s_lo = big
            s_hi = big
            s_l = np.float32(0.0)
            s_t = ninf
            s_f = ninf
            if p < ns:
                s_lo = np.int64(plo[s0 + p])
                s_hi = np.int64(phi[s0 + p])
                s_l = pl[s0 + p]
                s_t = pt[s0 + p, 0]
                s_f = pt[s0 + p, 1]
            if s_lo == big and e_lo == big:
                break
            start = max(x, min(s_lo, e_lo))
            in_s = s_lo <= start
            in_e = e_lo <= start
            end = big
            if in_s:
                end = min(end, s_hi)
            elif s_lo < end:
                end = min(end, s_lo)
            if in_e:
                end = min(end, e_hi)
            elif e_lo < end:
                end = min(end, e_lo)
            if end > start:
                v = np.float32(0.0)
                vt = ninf
                vf = ninf
                if in_s:
                    v = s_l
                    vt = s_t
                    vf = s_f
                if in_e:
                    if track and e_occ and dyn[a]:
                        vt = now
                        vf = first[a]
                    v = v + e_d
                    v = min(max(v, l_min), l_max)
                if (
                    n > cell0
                    and np.int64(thi[n - 1]) == start
                    and abs(tl[n - 1] - v) <= merge_eps
                    and tt[n - 1, 0] == vt
                    and tt[n - 1, 1] == vf
                ):
                    thi[n - 1] = end
                else:
                    tlo[n] = start
                    thi[n] = end
                    tl[n] = v
                    tt[n, 0] = vt
                    tt[n, 1] = vf
                    n += 1
            x = end
            if in_s and s_hi <= end:
                p += 1
            if in_e and e_hi <= end:
                if e_occ:
                    a += 1
                else:
                    b += 1
        a = ae
        b = be
        tkey[nt] = key
        nt += 1
        toff[nt] = n
    return (
        tkey[:nt].copy(),
        toff[: nt + 1].copy(),
        tlo[:n].copy(),
        thi[:n].copy(),
        tl[:n].copy(),
        tt[:n].copy(),
    )


@numba.jit(**_JIT)
def relocation_slots(tkey, toff, ccap):  # type: ignore[no-untyped-def]
    """Pool slots the write-back will append (cells whose new list outgrows their reserved slots)."""
    extra = 0
    for c in range(tkey.shape[0]):
        cnt = toff[c + 1] - toff[c]
        if cnt > ccap[tkey[c]]:
            extra += 2 * cnt
    return extra


@numba.jit(**_JIT)
def write_back(tkey, toff, tlo, thi, tl, tt, cstart, ccount, ccap, plo, phi, pl, pt, used):  # type: ignore[no-untyped-def]
    """Store the new lists: in place when they fit, else at the pool's end with twice the room.

    Returns:
        (new pool fill, slots freed by relocated cells, net change of the number of intervals).
    """
    freed = 0
    delta = 0
    for c in range(tkey.shape[0]):
        key = tkey[c]
        a = toff[c]
        cnt = toff[c + 1] - a
        delta += cnt - ccount[key]
        if cnt > ccap[key]:
            freed += ccap[key]
            cstart[key] = used
            ccap[key] = 2 * cnt
            used += 2 * cnt
        s = cstart[key]
        for k in range(cnt):
            plo[s + k] = tlo[a + k]
            phi[s + k] = thi[a + k]
            pl[s + k] = tl[a + k]
            pt[s + k, 0] = tt[a + k, 0]
            pt[s + k, 1] = tt[a + k, 1]
        ccount[key] = cnt
    return used, freed, delta


@numba.jit(**_JIT)
def gather(cstart, ccount, plo, phi, pl, pt, total):  # type: ignore[no-untyped-def]
    """All intervals as flat arrays sorted by cell key then lo: (key, lo, hi, log-odds, stamp)."""
    key = np.empty(total, np.int64)
    lo = np.empty(total, np.int32)
    hi = np.empty(total, np.int32)
    lv = np.empty(total, np.float32)
    lt = np.empty((total, 2), np.float64)
    n = 0
    for c in range(ccount.shape[0]):
        cnt = ccount[c]
        if cnt == 0:
            continue
        s = cstart[c]
        for k in range(cnt):
            key[n] = c
            lo[n] = plo[s + k]
            hi[n] = phi[s + k]
            lv[n] = pl[s + k]
            lt[n, 0] = pt[s + k, 0]
            lt[n, 1] = pt[s + k, 1]
            n += 1
    return key[:n], lo[:n], hi[:n], lv[:n], lt[:n]


@numba.jit(**_JIT)
def compact(cstart, ccount, ccap, plo, phi, pl, pt, new_lo, new_hi, new_l, new_t, slack):  # type: ignore[no-untyped-def]
    """Copy every cell's list into fresh pool arrays, contiguous, each with ``slack`` spare slots.

    Returns:
        The new pool fill.
    """
    used = 0
    for c in range(ccount.shape[0]):
        cnt = ccount[c]
        if cnt == 0 and ccap[c] == 0:
            continue
        s = cstart[c]
        for k in range(cnt):
            new_lo[used + k] = plo[s + k]
            new_hi[used + k] = phi[s + k]
            new_l[used + k] = pl[s + k]
            new_t[used + k, 0] = pt[s + k, 0]
            new_t[used + k, 1] = pt[s + k, 1]
        cstart[c] = used
        ccap[c] = cnt + slack
        used += cnt + slack
    return used


@numba.jit(**_JIT)
def decay(ccount, cstart, plo, phi, pl, pt, now, age, max_dwell, l_occ):  # type: ignore[no-untyped-def]
    """Forget dynamic occupied intervals whose last hit is older than ``age``: they become unknown.

    An interval is dropped when it is dynamic (finite stamps), ``now - last > age``, it was hit for
    ``last - first <= max_dwell`` and its log-odds is at least ``l_occ``; each cell's list is compacted
    in place (order kept).

    Returns:
        Number of intervals dropped.
    """
    dropped = 0
    for c in range(ccount.shape[0]):
        cnt = ccount[c]
        if cnt == 0:
            continue
        s = cstart[c]
        w = 0
        for k in range(cnt):
            t = pt[s + k, 0]
            if t > -np.inf and now - t > age and t - pt[s + k, 1] <= max_dwell and pl[s + k] >= l_occ:
                continue
            if w != k:
                plo[s + w] = plo[s + k]
                phi[s + w] = phi[s + k]
                pl[s + w] = pl[s + k]
                pt[s + w, 0] = t
                pt[s + w, 1] = pt[s + k, 1]
            w += 1
        if w != cnt:
            dropped += cnt - w
            ccount[c] = w
    return dropped


@numba.jit(**_JIT)
def count_beyond(pts, ox, oy, oz, max_range):  # type: ignore[no-untyped-def]
    """Finite points farther than ``max_range`` from ``(ox, oy, oz)``."""
    r2 = max_range * max_range
    n = 0
    for k in range(pts.shape[0]):
        dx = np.float64(pts[k, 0]) - ox
        dy = np.float64(pts[k, 1]) - oy
        dz = np.float64(pts[k, 2]) - oz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > r2 and d2 - d2 == 0.0:
            n += 1
    return n


@numba.jit(**_JIT)
def split_beyond(pts, ox, oy, oz, max_range, kept, ends):  # type: ignore[no-untyped-def]
    """Copy ``pts`` into ``kept`` with the points beyond ``max_range`` set to NaN, and write those
    points cut back to ``max_range`` along their ray into ``ends`` (sized by :func:`count_beyond`)."""
    r2 = max_range * max_range
    n = 0
    for k in range(pts.shape[0]):
        x = np.float64(pts[k, 0])
        y = np.float64(pts[k, 1])
        z = np.float64(pts[k, 2])
        dx = x - ox
        dy = y - oy
        dz = z - oz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > r2 and d2 - d2 == 0.0:
            f = max_range / np.sqrt(d2)
            ends[n, 0] = ox + f * dx
            ends[n, 1] = oy + f * dy
            ends[n, 2] = oz + f * dz
            n += 1
            kept[k, 0] = np.nan
            kept[k, 1] = np.nan
            kept[k, 2] = np.nan
        else:
            kept[k, 0] = pts[k, 0]
            kept[k, 1] = pts[k, 1]
            kept[k, 2] = pts[k, 2]
    return n
