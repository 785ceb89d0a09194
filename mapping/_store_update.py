"""The compiled (numba, one thread, cached, no GIL) update of the interval store with one frame's
evidence, in place in the pool.

One pass per touched cell does what the reference kernels of :mod:`mapping._store_kernels` do in four
(``update_cells`` into temporaries, ``relocation_slots``, ``track_dynamic``, ``write_back``) and gives
the same pool bit for bit (same lists, starts, reserved room, fill, dynamic-cell list and dues): only
the stored pieces the frame's evidence can change are swept, and the new list is written back into the
cell's room (or relocated at the pool's end with twice the room, as ``write_back`` does).

Why the unchanged pieces can be skipped: every stored list is *normal*, two touching neighbours never
pass the merge test (|log-odds difference| <= ``merge_eps`` and equal stamps), because the sweep starts
a new piece exactly when that test fails against the previous piece's value, and a decay pass only
removes pieces (which leaves a gap, not a touch). So the reference sweep copies a stored piece that ends
at or below the lowest evidence bound unchanged, and after the last evidence interval it copies whole
stored pieces unchanged from the first one that does not merge with the piece before it.
"""

from __future__ import annotations

import sys

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from mapping._deps import announce_compilation
from mapping._evidence_kernels import _JIT

_AHEAD = 3  # evidence rows ahead (about a cell each for the slabs, half a cell for the free intervals)


@intrinsic
def _prefetch(typingctx, arr, idx):  # type: ignore[no-untyped-def]
    """Hint the CPU to load the cache line of ``arr[idx]`` (1-D array, in bounds or not: a hint never
    faults); numba has no such intrinsic, LLVM's ``llvm.prefetch`` (read, keep, data) is called."""
    sig = types.void(arr, idx)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        aty = signature.args[0]
        ary = context.make_array(aty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(
            context, builder, aty, ary, [args[1]], wraparound=False, boundscheck=False
        )
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), "llvm.prefetch.p0i8"
        )
        builder.call(
            fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)]
        )
        return context.get_dummy_value()

    return sig, codegen


@numba.jit(inline="always", **_JIT)
def _prefetch_cell(key, cstart, ccount, plo, phi, pl, ptf):  # type: ignore[no-untyped-def]
    """Prefetch the pool lines of cell ``key``'s list (``ptf``: the stamps' flat view)."""
    s = cstart[key]
    _prefetch(plo, s)  # type: ignore[call-arg]
    _prefetch(phi, s)  # type: ignore[call-arg]
    _prefetch(pl, s)  # type: ignore[call-arg]
    n = 2 * np.int64(ccount[key])
    for k in range(0, n, 8):
        _prefetch(ptf, 2 * s + k)  # type: ignore[call-arg]


@numba.jit(inline="always", **_JIT)
def _emit(xlo, xhi, xl, xt, n, lo, hi, v, vt, vf, merge_eps):  # type: ignore[no-untyped-def]
    """Append segment ``[lo, hi)`` (log-odds ``v``, stamps ``vt``, ``vf``) to the run ``[:n]``: it extends
    the last piece when it touches it with (nearly) the same log-odds and the same stamps. Returns the
    run's new length."""
    if (
        n > 0
        and np.int64(xhi[n - 1]) == lo
        and abs(xl[n - 1] - v) <= merge_eps
        and xt[n - 1, 0] == vt
        and xt[n - 1, 1] == vf
    ):
        xhi[n - 1] = hi
        return n
    xlo[n] = lo
    xhi[n] = hi
    xl[n] = v
    xt[n, 0] = vt
    xt[n, 1] = vf
    return n + 1


@numba.jit(inline="always", **_JIT)
def _copy_pieces(plo, phi, pl, pt, dst, src, n, backwards):  # type: ignore[no-untyped-def]
    """Copy ``n`` pool pieces from slot ``src`` to slot ``dst`` (``backwards``: last first, for a move to
    higher slots that overlaps its source)."""
    for i in range(n):
        k = n - 1 - i if backwards else i
        plo[dst + k] = plo[src + k]
        phi[dst + k] = phi[src + k]
        pl[dst + k] = pl[src + k]
        pt[dst + k, 0] = pt[src + k, 0]
        pt[dst + k, 1] = pt[src + k, 1]


@numba.jit(**_JIT)
def update_store(  # type: ignore[no-untyped-def]
    cstart,
    ccount,
    ccap,
    plo,
    phi,
    pl,
    pt,
    used,
    okey,
    olo,
    ohi,
    fkey,
    flo,
    fhi,
    a,
    b,
    l_hit,
    l_miss,
    l_min,
    l_max,
    merge_eps,
    track,
    now,
    l_void,
    l_occ,
    max_dwell,
    dyn_flag,
    dyn_due,
    dyn_cells,
    n_dyn,
):
    """Apply one frame's evidence to the cells it touches, in the pool, from evidence rows ``a``/``b``.

    The new lists are those of :func:`mapping._store_kernels.update_cells` (whose docstring gives the
    rules: occupied slabs ``+l_hit``, free intervals ``+l_miss``, clamped to ``[l_min, l_max]``, merges,
    dynamic stamps with ``track``), stored as :func:`mapping._store_kernels.write_back` stores them; with
    ``track`` the dynamic-cell list is kept as :func:`mapping._store_kernels.track_dynamic` keeps it
    (``dyn_cells`` needs room for ``okey.shape[0] + fkey.shape[0]`` more entries).

    Args:
        cstart, ccount, ccap: ``(n_cells,)`` int64 / int32 / int32 per-cell start, count, room (updated).
        plo, phi, pl, pt: the pool, ``(cap,)`` int32 / int32 / float32 and ``(cap, 2)`` float64 (updated).
        used: the pool's fill (slots).
        okey, olo, ohi: occupied slabs, ``(No,)`` int64 cell keys ascending, int32 lattice bounds.
        fkey, flo, fhi: free intervals, ``(Nf,)`` alike (disjoint from the slabs).
        a, b: the first rows of ``okey`` / ``fkey`` to apply (0, 0, or where a stopped call left off).
        l_hit, l_miss, l_min, l_max, merge_eps, l_void, l_occ: float32 log-odds.
        track, now, max_dwell: stamps on; the map's clock and ``dynamic_max_dwell_s`` (s, inf: any).
        dyn_flag, dyn_due, dyn_cells, n_dyn: the dynamic-cell bookkeeping (empty when not ``track``).

    Returns:
        ``(a, b, cells, used, freed, delta, n_dyn, need)``: where the call stopped, the cells updated,
        the pool's new fill, slots freed by relocated cells, the change of the number of intervals, the
        dynamic list's length, and ``need``: 0 when every cell was applied, else the slots the next
        cell's relocation needs at ``used`` beyond the pool's capacity (nothing of that cell was
        written: grow the pool and call again from the returned ``a``, ``b``).
    """
    no = okey.shape[0]
    nf = fkey.shape[0]
    pool_cap = plo.shape[0]
    room = 256
    xlo = np.empty(room, np.int32)
    xhi = np.empty(room, np.int32)
    xl = np.empty(room, np.float32)
    xt = np.empty((room, 2), np.float64)
    ninf = -np.inf
    big = np.int64(1) << 40
    cells = 0
    freed = 0
    delta = np.int64(0)
    ptf = pt.reshape(2 * pt.shape[0])
    while a < no or b < nf:
        if b >= nf or (a < no and okey[a] <= fkey[b]):
            key = okey[a]
        else:
            key = fkey[b]
        a0 = a
        b0 = b
        ae = a
        while ae < no and okey[ae] == key:
            ae += 1
        be = b
        while be < nf and fkey[be] == key:
            be += 1
        # the pool is far larger than the caches and the cells are scattered in it: ask for the lines
        # of cells a few rows ahead while this one is swept
        if ae + _AHEAD < no:
            _prefetch_cell(okey[ae + _AHEAD], cstart, ccount, plo, phi, pl, ptf)
        if be + 2 * _AHEAD < nf:
            _prefetch_cell(fkey[be + 2 * _AHEAD], cstart, ccount, plo, phi, pl, ptf)
        s0 = cstart[key]
        ns = np.int64(ccount[key])
        e_min = big
        if a < ae:
            e_min = np.int64(olo[a])
        if b < be:
            e_min = min(e_min, np.int64(flo[b]))
        # the stored pieces below the evidence stay as they are: the last of them is the open piece
        p0 = 0
        while p0 < ns and np.int64(phi[s0 + p0]) <= e_min:
            p0 += 1
        need_room = 2 * ((ns - p0) + (ae - a) + (be - b)) + 2
        if need_room > room:
            room = 2 * need_room
            xlo = np.empty(room, np.int32)
            xhi = np.empty(room, np.int32)
            xl = np.empty(room, np.float32)
            xt = np.empty((room, 2), np.float64)
        # the new run goes to the scratch, from the last piece below the evidence (which the first
        # segment may extend); the scratch's last piece is the open one
        base = p0 - 1 if p0 > 0 else 0
        nout = 0
        if p0 > 0:
            xlo[0] = plo[s0 + base]
            xhi[0] = phi[s0 + base]
            xl[0] = pl[s0 + base]
            xt[0, 0] = pt[s0 + base, 0]
            xt[0, 1] = pt[s0 + base, 1]
            nout = 1
        p = p0
        x = -big
        while a < ae or b < be:
            # the next evidence interval: the lower of the slabs' and the free intervals' streams
            if a < ae and (b >= be or olo[a] <= flo[b]):
                e_lo = np.int64(olo[a])
                e_hi = np.int64(ohi[a])
                e_d = l_hit
                e_occ = True
                a += 1
            else:
                e_lo = np.int64(flo[b])
                e_hi = np.int64(fhi[b])
                e_d = l_miss
                e_occ = False
                b += 1
            # stored pieces (or their rest) below it: as they are
            while p < ns and np.int64(plo[s0 + p]) < e_lo:
                lo = max(x, np.int64(plo[s0 + p]))
                hi = min(np.int64(phi[s0 + p]), e_lo)
                if hi > lo:
                    nout = _emit(
                        xlo, xhi, xl, xt, nout, lo, hi, pl[s0 + p], pt[s0 + p, 0], pt[s0 + p, 1], merge_eps
                    )
                x = hi
                if np.int64(phi[s0 + p]) > e_lo:
                    break
                p += 1
            x = e_lo
            # a slab over a stored piece known free or dynamic is a dynamic slab (p: the first stored
            # piece that ends above the slab's bottom, none of its pieces changed yet)
            e_dyn = False
            e_first = now
            if track and e_occ:
                q = p
                while q < ns and plo[s0 + q] < e_hi:
                    if pt[s0 + q, 0] > ninf and pl[s0 + q] >= l_occ:
                        e_dyn = True  # still the same body: it keeps its first stamp
                        e_first = min(e_first, pt[s0 + q, 1])
                    elif pl[s0 + q] < l_void or pt[s0 + q, 0] > ninf:
                        e_dyn = True
                    q += 1
            # inside it: the stored pieces (or the gaps between them) it covers, each plus its delta
            while x < e_hi:
                if p < ns and np.int64(plo[s0 + p]) <= x:
                    s_hi = np.int64(phi[s0 + p])
                    end = min(s_hi, e_hi)
                    v = min(max(pl[s0 + p] + e_d, l_min), l_max)
                    if e_dyn:
                        nout = _emit(xlo, xhi, xl, xt, nout, x, end, v, now, e_first, merge_eps)
                    else:
                        nout = _emit(
                            xlo, xhi, xl, xt, nout, x, end, v, pt[s0 + p, 0], pt[s0 + p, 1], merge_eps
                        )
                    if s_hi <= e_hi:
                        p += 1
                else:
                    end = e_hi
                    if p < ns:
                        end = min(end, np.int64(plo[s0 + p]))
                    v = min(max(np.float32(0.0) + e_d, l_min), l_max)
                    if e_dyn:
                        nout = _emit(xlo, xhi, xl, xt, nout, x, end, v, now, e_first, merge_eps)
                    else:
                        nout = _emit(xlo, xhi, xl, xt, nout, x, end, v, ninf, ninf, merge_eps)
                x = end
        # past the evidence: the rest of a piece it cut, then whole pieces while they merge with the
        # open one; from the first that does not, they all stay as they are (the list is normal)
        if p < ns and np.int64(plo[s0 + p]) < x:
            nout = _emit(
                xlo,
                xhi,
                xl,
                xt,
                nout,
                x,
                np.int64(phi[s0 + p]),
                pl[s0 + p],
                pt[s0 + p, 0],
                pt[s0 + p, 1],
                merge_eps,
            )
            p += 1
        while (
            p < ns
            and nout > 0
            and np.int64(xhi[nout - 1]) == np.int64(plo[s0 + p])
            and abs(xl[nout - 1] - pl[s0 + p]) <= merge_eps
            and xt[nout - 1, 0] == pt[s0 + p, 0]
            and xt[nout - 1, 1] == pt[s0 + p, 1]
        ):
            xhi[nout - 1] = phi[s0 + p]
            p += 1
        # new list: slots [0, base) as they are, the run's nout pieces, then the stored pieces [p, ns)
        tail = ns - p
        cnt = base + nout + tail
        if cnt > ccap[key]:
            if used + 2 * cnt > pool_cap:
                return a0, b0, cells, used, freed, delta, n_dyn, used + 2 * cnt - pool_cap
            d0 = used
            _copy_pieces(plo, phi, pl, pt, d0, s0, base, False)
            _copy_pieces(plo, phi, pl, pt, d0 + base + nout, s0 + p, tail, False)
            freed += ccap[key]
            cstart[key] = used
            ccap[key] = 2 * cnt
            used += 2 * cnt
            s1 = d0
        else:
            s1 = s0
            shift = base + nout - p
            if shift != 0:  # a move to higher slots overlaps its source from the end: copy last first
                _copy_pieces(plo, phi, pl, pt, s0 + p + shift, s0 + p, tail, shift > 0)
        for k in range(nout):
            plo[s1 + base + k] = xlo[k]
            phi[s1 + base + k] = xhi[k]
            pl[s1 + base + k] = xl[k]
            pt[s1 + base + k, 0] = xt[k, 0]
            pt[s1 + base + k, 1] = xt[k, 1]
        delta += cnt - ns
        ccount[key] = cnt
        if track:
            # the earliest last hit of the pieces a decay pass could drop: over the new run, and over
            # the pieces kept as they were only when the cell held such a piece before (``dyn_due`` is
            # never inf while the list holds one: an update sets it from the whole list, and a decay
            # pass only removes pieces, setting it from what it keeps)
            due = np.inf
            for k in range(nout):
                t = xt[k, 0]
                if t > ninf and t - xt[k, 1] <= max_dwell and xl[k] >= l_occ:
                    due = min(due, t)
            if dyn_due[key] < np.inf:
                for k in range(s1, s1 + base):
                    t = pt[k, 0]
                    if t > ninf and t - pt[k, 1] <= max_dwell and pl[k] >= l_occ:
                        due = min(due, t)
                for k in range(s1 + base + nout, s1 + cnt):
                    t = pt[k, 0]
                    if t > ninf and t - pt[k, 1] <= max_dwell and pl[k] >= l_occ:
                        due = min(due, t)
            dyn_due[key] = due
            if due < np.inf and dyn_flag[key] == 0:
                dyn_flag[key] = 1
                dyn_cells[n_dyn] = key
                n_dyn += 1
        a = ae
        b = be
        cells += 1
    return a, b, cells, used, freed, delta, n_dyn, 0


# first run after an install or a change here: say why the first frame takes tens of seconds
announce_compilation(sys.modules[__name__], "mapping kernels (store update)")
