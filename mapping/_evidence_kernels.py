"""Compiled (numba, one thread, cached) kernels of one frame's evidence in the probabilistic map.

The frame's occupied slabs, its fans of free space and their merge (:mod:`mapping.probabilistic`); the
kernels that update the stored intervals with that evidence are in :mod:`mapping._store_kernels`.

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

import sys
from typing import Any

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from mapping._deps import announce_compilation

_JIT: dict[str, Any] = {
    "cache": True,
    "nogil": True,
    "nopython": True,
    "error_model": "numpy",
    "boundscheck": False,
}

_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)


@intrinsic
def _or_run4(typingctx, bits, at, lo, hi):  # type: ignore[no-untyped-def]
    """Set bins ``lo .. hi`` (inclusive, counted from word ``at``) in the four uint64 words
    ``bits[at : at + 4]`` with one 4-lane load, OR and store; bins outside those words are ignored
    (``lo``, ``hi`` may be any int64: below 0 or past 255).

    Word ``w`` gets ``(ALL << clamp(lo - 64 w)) & (ALL >> clamp(64 w + 63 - hi))``, a shift by 64 or more
    giving 0 and one by 0 or less keeping ALL (clamped before the shift: LLVM's shifts by the width are
    undefined), which is exactly the bins of ``[lo, hi]`` in that word. Branch-free, so that a run of
    unpredictable width costs one access instead of one to four read-modify-writes behind branches."""
    sig = types.void(bits, at, lo, hi)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        aty = signature.args[0]
        ary = context.make_array(aty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(
            context, builder, aty, ary, [args[1]], wraparound=False, boundscheck=False
        )
        vt = ir.VectorType(ir.IntType(64), 4)
        i32 = ir.IntType(32)

        def splat(x):  # type: ignore[no-untyped-def]
            v = builder.insert_element(ir.Constant(vt, ir.Undefined), x, ir.Constant(i32, 0))
            return builder.shuffle_vector(v, v, ir.Constant(ir.VectorType(i32, 4), [0, 0, 0, 0]))

        lo = splat(context.cast(builder, args[2], signature.args[2], types.int64))
        hi = splat(context.cast(builder, args[3], signature.args[3], types.int64))
        zero = ir.Constant(vt, [0] * 4)
        c63 = ir.Constant(vt, [63] * 4)
        ones = ir.Constant(vt, [-1] * 4)

        def shifted(count, left):  # type: ignore[no-untyped-def]
            c = builder.select(builder.icmp_signed("<", count, zero), zero, count)
            past = builder.icmp_signed(">", c, c63)
            c = builder.select(past, c63, c)
            v = builder.shl(ones, c) if left else builder.lshr(ones, c)
            return builder.select(past, zero, v)

        from_lo = shifted(builder.sub(lo, ir.Constant(vt, [0, 64, 128, 192])), True)
        to_hi = shifted(builder.sub(ir.Constant(vt, [63, 127, 191, 255]), hi), False)
        vp = builder.bitcast(ptr, vt.as_pointer())
        x = builder.load(vp, align=8)
        builder.store(builder.or_(x, builder.and_(from_lo, to_hi)), vp, align=8)
        return context.get_dummy_value()

    return sig, codegen


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
    Structures come sorted by key (those of one cell consecutive: their cell's segment is walked once).
    Rows of 4 or 8 words (``FanJob`` pads 5 to 7 to 8) set each run with one or two branch-free 4-word
    accesses (:func:`_or_run4`; about 20 % less CPU on the HD and the Kinect frames), other widths word by
    word; the bits are the same.

    Returns:
        Number of (structure, cell) passages marked.
    """
    n = key.shape[0]
    ics = 1.0 / cs
    li0 = np.int64(np.floor(su * ics))
    lj0 = np.int64(np.floor(sv * ics))
    fb0 = np.float64(b0)
    # the fan's lines relative to the sensor's height, once per structure
    rel_b = np.empty(n, np.float64)
    rel_t = np.empty(n, np.float64)
    for k in range(n):
        rel_b[k] = bottom[k] - sh
        rel_t[k] = top[k] - sh
    last_bin = np.int64(nbins - 1)
    zero = np.int64(0)
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
                        bl = rel_b[k]
                        tl = rel_t[k]
                        lo = sh + min(s_in * bl, s_out * bl)
                        hi = sh + max(s_in * tl, s_out * tl)
                        # heights of a fan lie within the table (>= b0): truncation is floor here
                        # (a rounding step below 0 truncates to bin 0, where it belongs)
                        bb0 = np.int64(lo * inv_r - fb0)
                        bb1 = np.int64(hi * inv_r - fb0)
                        if m != 1:  # an integer division costs more than the rest of a passage
                            bb0 //= m
                            bb1 //= m
                        bb0 = min(max(bb0, zero), last_bin)
                        bb1 = min(max(bb1, zero), last_bin)
                        # bins bb0 .. bb1 (inclusive)
                        w0 = bb0 >> 6
                        w1 = bb1 >> 6
                        if nw == 4:
                            _or_run4(bits, base, bb0, bb1)  # type: ignore[call-arg]
                        elif nw == 8:
                            if w0 < 4:
                                _or_run4(bits, base, bb0, bb1)  # type: ignore[call-arg]
                            if w1 >= 4:
                                _or_run4(bits, base + 4, bb0 - 256, bb1 - 256)  # type: ignore[call-arg]
                        else:
                            # ones from bb0 up in its word, up to bb1 in its word, whole words between
                            # (no branch on the width: 64 is not special)
                            from_lo = _ALL << np.uint64(bb0 & 63)
                            to_hi = _ALL >> np.uint64(63 - (bb1 & 63))
                            if w0 == w1:
                                bits[base + w0] |= from_lo & to_hi
                            else:
                                bits[base + w0] |= from_lo
                                for w in range(w0 + 1, w1):
                                    bits[base + w] = _ALL
                                bits[base + w1] |= to_hi
                    passages += g1 - g0
            s_in = s_out
            # branch-free step (which axis comes next is unpredictable): selects, so that the walk's
            # chain is a compare and a blend per step, not a compare, a conversion, a multiply and an add
            # (a skipped update adds nothing: the old ``tmu + tdu * 0`` only turned a -0.0 into +0.0,
            # which no comparison, product or truncation below can tell apart)
            go_u = tmu <= tmv
            nu = tmu + tdu
            nv = tmv + tdv
            ci = ci + stu if go_u else ci
            cj = cj if go_u else cj + stv
            tmu = nu if go_u else tmu
            tmv = tmv if go_u else nv
        g0 = g1
    return passages


# De Bruijn bit scan (Leiserson, Prokop and Randall, 1998): the lowest set bit times this constant has
# a distinct top 6 bits for each of the 64 positions; the table maps them back to the position.
_DE_BRUIJN = np.uint64(0x03F79D71B4CB0A89)
_DE_BRUIJN_POS = np.zeros(64, np.int64)
for _p in range(64):
    _DE_BRUIJN_POS[((1 << _p) * int(_DE_BRUIJN) % (1 << 64)) >> 58] = _p
del _p


@numba.jit(**_JIT)
def _ctz(x):  # type: ignore[no-untyped-def]
    """Trailing zero bits of a non-zero uint64 (a de Bruijn multiply: numba has no portable intrinsic)."""
    low = x & (~x + np.uint64(1))
    return _DE_BRUIJN_POS[(low * _DE_BRUIJN) >> np.uint64(58)]


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
def _row_set(bits, base, nw):  # type: ignore[no-untyped-def]
    """True when any bin of the row of ``nw`` words at ``base`` is set."""
    for w in range(nw):
        if bits[base + w] != 0:
            return True
    return False


@numba.jit(**_JIT)
def _count_runs(bits, ni, nj, nw, nbins):  # type: ignore[no-untyped-def]
    """Runs of set bins over the whole table (an upper bound of the runs left after joining gaps)."""
    runs = 0
    for c in range(ni * nj):
        base = c * nw
        if not _row_set(bits, base, nw):
            continue
        b = 0
        while b < nbins:
            r0 = _next_bit(bits, base, nw, b, False)
            if r0 >= nbins:
                break
            b = _next_bit(bits, base, nw, r0, True)
            runs += 1
    return runs


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
    n_occ = okey.shape[0]
    # Each run gives at most one interval plus one more per occupied interval cut out of it: sized
    # once, so the output arrays are never reallocated inside the loop.
    cap = _count_runs(bits, ni, nj, nw, nbins) + n_occ
    fk = np.empty(cap, np.int64)
    flo = np.empty(cap, np.int32)
    fhi = np.empty(cap, np.int32)
    n = 0
    po = 0
    for gi in range(ni):
        for gj in range(nj):
            base = (gi * nj + gj) * nw
            if not _row_set(bits, base, nw):
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
                            fk[n] = key
                            flo[n] = cur
                            fhi[n] = seg_hi
                            n += 1
                        cur = max(cur, np.int64(ohi[q]))
                        q += 1
                    else:
                        fk[n] = key
                        flo[n] = cur
                        fhi[n] = hi
                        n += 1
                        cur = hi
    return fk[:n].copy(), flo[:n].copy(), fhi[:n].copy()


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


# first run after an install or a change here: say why the first frame takes tens of seconds
announce_compilation(sys.modules[__name__], "mapping kernels (free space)")
