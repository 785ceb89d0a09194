"""Compiled (numba, one thread, cached) kernels of the probabilistic map's interval store.

The update of the stored intervals with one frame's evidence, the pool's bookkeeping (write-back,
compaction, gather) and the dynamic decay (:mod:`mapping._interval_store`); the frame's evidence
itself comes from :mod:`mapping._evidence_kernels`, whose module docstring gives the layout and units.

``update_cells``, ``relocation_slots``, ``track_dynamic`` and ``write_back`` are the reference form of the
update (every touched cell swept into temporaries, then copied back): the store runs the one-pass,
in-place :func:`mapping._store_update.update_store`, which tests check against them bit for bit.
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from mapping._deps import announce_compilation
from mapping._evidence_kernels import _JIT


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
    # room for the worst case of every touched cell, counted first: growing (and copying) the outputs
    # inside the sweep cost more than this pass over the touched cells' counts
    cap = 2 * (no + nf) + 1024
    a = 0
    b = 0
    while a < no or b < nf:
        if b >= nf or (a < no and okey[a] <= fkey[b]):
            key = okey[a]
        else:
            key = fkey[b]
        while a < no and okey[a] == key:
            a += 1
        while b < nf and fkey[b] == key:
            b += 1
        cap += 2 * np.int64(ccount[key]) + 2
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
    # views, not copies: the caller writes them back and drops them
    return tkey[:nt], toff[: nt + 1], tlo[:n], thi[:n], tl[:n], tt[:n]


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
def _decay_cell(c, ccount, cstart, plo, phi, pl, pt, now, age, max_dwell, l_occ):  # type: ignore[no-untyped-def]
    """:func:`decay` of cell ``c``: (intervals dropped, whether the cell still holds a dynamic one, the
    earliest last hit of the ones it keeps that a later pass could drop, ``inf`` when none: see
    :func:`track_dynamic`)."""
    cnt = ccount[c]
    s = cstart[c]
    w = 0
    still = False
    due = np.inf
    for k in range(cnt):
        t = pt[s + k, 0]
        droppable = t > -np.inf and t - pt[s + k, 1] <= max_dwell and pl[s + k] >= l_occ
        if droppable and now - t > age:
            continue
        if t > -np.inf:
            still = True
        if droppable:
            due = min(due, t)
        if w != k:
            plo[s + w] = plo[s + k]
            phi[s + w] = phi[s + k]
            pl[s + w] = pl[s + k]
            pt[s + w, 0] = t
            pt[s + w, 1] = pt[s + k, 1]
        w += 1
    ccount[c] = w
    return cnt - w, still, due


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
        if ccount[c] != 0:
            dropped += _decay_cell(c, ccount, cstart, plo, phi, pl, pt, now, age, max_dwell, l_occ)[0]
    return dropped


@numba.jit(**_JIT)
def track_dynamic(tkey, toff, tl, tt, max_dwell, l_occ, flag, due, cells, n):  # type: ignore[no-untyped-def]
    """Keep the list of the cells the decay pass must visit after an update.

    A dynamic interval can be dropped by a later pass only while it is occupied (``log-odds >= l_occ``)
    and was hit for at most ``max_dwell`` (its stamps and log-odds change only in an update, or when a
    pass drops it). For every touched cell (``tkey``, its new list ``toff`` CSR into ``tl``/``tt``):
    ``due[key]`` becomes the earliest last hit of such intervals (``inf`` when it holds none), and a cell
    with one that is not yet listed (``flag[key] == 0``) is appended to ``cells[:n]`` (room for
    ``tkey.shape[0]`` more is the caller's) and flagged. Cells listed before stay listed (the pass
    removes those with nothing left to drop).

    Returns:
        The new length of the list.
    """
    for c in range(tkey.shape[0]):
        key = tkey[c]
        d = np.inf
        for k in range(toff[c], toff[c + 1]):
            t = tt[k, 0]
            if t > -np.inf and t - tt[k, 1] <= max_dwell and tl[k] >= l_occ:
                d = min(d, t)
        due[key] = d
        if d < np.inf and flag[key] == 0:
            flag[key] = 1
            cells[n] = key
            n += 1
    return n


@numba.jit(**_JIT)
def decay_listed(cells, n, flag, due, ccount, cstart, plo, phi, pl, pt, now, age, max_dwell, l_occ):  # type: ignore[no-untyped-def]
    """:func:`decay` over the listed ``cells[:n]`` only (every cell holding an interval a pass could
    drop is listed, see :func:`track_dynamic`); the list is compacted in place to the cells that still
    hold one (the others are unflagged). A cell whose earliest such last hit ``due[c]`` is not older
    than ``age`` is skipped: nothing in it is due, and a pass over it would change nothing.

    Returns:
        (number of intervals dropped, the new length of the list).
    """
    dropped = 0
    nk = 0
    for q in range(n):
        c = cells[q]
        if ccount[c] != 0 and due[c] < np.inf and not (now - due[c] > age):
            cells[nk] = c  # nothing due yet: unchanged
            nk += 1
            continue
        d, first_due = 0, np.inf
        if ccount[c] != 0:
            d, _, first_due = _decay_cell(c, ccount, cstart, plo, phi, pl, pt, now, age, max_dwell, l_occ)
        dropped += d
        due[c] = first_due
        if first_due < np.inf:
            cells[nk] = c
            nk += 1
        else:
            flag[c] = 0
    return dropped, nk


@numba.jit(**_JIT)
def band_cells(cstart, ccount, plo, phi, pl, l_occ, r, z0, z1, i0, i1, j0, j1, ny):  # type: ignore[no-untyped-def]
    """Keys (ascending) of the cells of rows ``[i0, i1]`` x columns ``[j0, j1]`` with an occupied interval
    (log-odds >= ``l_occ``) whose bounds in metres (lattice x ``r``) meet ``[z0, z1]``."""
    out = np.empty((i1 - i0 + 1) * (j1 - j0 + 1), np.int64)
    n = 0
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            c = i * ny + j
            s = cstart[c]
            for k in range(ccount[c]):
                if (
                    pl[s + k] >= l_occ
                    and np.float64(phi[s + k]) * r >= z0
                    and np.float64(plo[s + k]) * r <= z1
                ):
                    out[n] = c
                    n += 1
                    break
    return out[:n].copy()


# first run after an install or a change here: say why the first frame takes tens of seconds
announce_compilation(sys.modules[__name__], "mapping kernels (interval store)")
