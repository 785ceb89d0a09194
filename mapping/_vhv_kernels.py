"""Compiled (numba, one thread, cached) kernels of the VHV build; see :mod:`mapping.vhv` for the method.

Every kernel takes the point array in its own dtype (float32 or float64) and converts each coordinate
to float64 before indexing, so the cell of a point is exactly ``GridSpec.world_to_index`` of it.
Structures leave the kernels as three parallel arrays: cell key ``i * ny + j`` (int64), bottom and top
(float64), sorted by key then bottom.
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


@numba.jit(**_JIT)
def scan(pts, cu, cv, ch, step):  # type: ignore[no-untyped-def]
    """Coordinate ranges of the finite points among every ``step``-th point; count of non-finite ones.

    Returns:
        (n_nonfinite, u_min, u_max, v_min, v_max, h_min, h_max) over the visited points; ranges are
        (inf, -inf) when none of them is finite.
    """
    n = pts.shape[0]
    n_nonfinite = 0
    u_min = np.inf
    u_max = -np.inf
    v_min = np.inf
    v_max = -np.inf
    h_min = np.inf
    h_max = -np.inf
    for k in range(0, n, step):
        u = np.float64(pts[k, cu])
        v = np.float64(pts[k, cv])
        h = np.float64(pts[k, ch])
        s = u + v + h
        if s - s != 0.0:  # NaN or inf in any coordinate
            n_nonfinite += 1
            continue
        u_min = min(u_min, u)
        u_max = max(u_max, u)
        v_min = min(v_min, v)
        v_max = max(v_max, v)
        h_min = min(h_min, h)
        h_max = max(h_max, h)
    return n_nonfinite, u_min, u_max, v_min, v_max, h_min, h_max


@intrinsic
def _minmax_pair(typingctx, mm, i, h):  # type: ignore[no-untyped-def]
    """``mm[i] = min(mm[i], h)`` and ``mm[i + 1] = max(mm[i + 1], h)`` through one 2-lane load, compare,
    select and store (``mm`` a 1-D float array, ``i`` in bounds).

    Two scalar updates cost two loads and two stores; a bin's (min, max) pair is adjacent, so one 8-byte
    (float32) or 16-byte (float64) access serves both: the scatter's memory operations per point drop
    from six to four (HD frame: the whole build 3-5 % less CPU). Lane 1 is a minimum of sign-flipped values
    (``max(y, h) = -min(-y, -h)``), so that one vector minimum serves both lanes. The result is numba's
    ``min`` and ``max`` bit for bit: lane 0 takes ``h`` when ``h < mm[i]``, lane 1 when ``h > mm[i + 1]``
    (ties, signed zeros included, keep the stored value; a NaN height changes nothing)."""
    sig = types.void(mm, i, h)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        aty = signature.args[0]
        ary = context.make_array(aty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(
            context, builder, aty, ary, [args[1]], wraparound=False, boundscheck=False
        )
        vt = ir.VectorType(context.get_data_type(aty.dtype), 2)
        i32 = ir.IntType(32)
        hv = context.cast(builder, args[2], signature.args[2], aty.dtype)
        a = builder.insert_element(ir.Constant(vt, ir.Undefined), hv, ir.Constant(i32, 0))
        a = builder.shuffle_vector(a, a, ir.Constant(ir.VectorType(i32, 2), [0, 0]))
        vp = builder.bitcast(ptr, vt.as_pointer())
        align = aty.dtype.bitwidth // 8
        x = builder.load(vp, align=align)
        # lane 1 as a minimum of negated values: max(y, h) = -min(-y, -h), ties keep y
        neg = ir.Constant(vt, [0.0, -0.0])
        it = ir.VectorType(ir.IntType(aty.dtype.bitwidth), 2)
        sign = builder.bitcast(neg, it)

        def flip(v):  # type: ignore[no-untyped-def]
            return builder.bitcast(builder.xor(builder.bitcast(v, it), sign), vt)

        a, x = flip(a), flip(x)
        builder.store(flip(builder.select(builder.fcmp_ordered("<", a, x), a, x)), vp, align=align)
        return context.get_dummy_value()

    return sig, codegen


# Points per chunk of the binning pass: its slot buffer (int32) and the chunk's points stay in the L1/L2
# cache between the two passes over them.
_CHUNK = 4096
# Interleaved streams of the scatter: consecutive points often share a (cell, bin) slot, and updating
# it again before the previous store retired chains the updates through memory; walking four far-apart
# parts of the chunk side by side keeps four independent chains in flight.
_STREAMS = 4


@numba.jit(**_JIT)
def _slot_chunk(pc, m, xu, xv, xh, ics, fi0, fj0, fni, fnj, iw, fb0, fnb, trash, buf):  # type: ignore[no-untyped-def]
    """Table slot (``2 * entry``, or ``trash``) of each of the ``m`` points of the flat chunk ``pc``.

    Branch-free and in float64 only (the slot is an exact integer below 2**31 in float64), so that the
    compiler vectorises it (the columns ``xu, xv, xh`` are constants after inlining). Same float64
    operations as ``GridSpec.world_to_index``, so the cells are exact. Only what every point needs is
    computed here (its box test and whether it is finite); the points that are finite but outside
    the box are classified by :func:`_box_misses` in the chunks that have any.

    Returns:
        (points with a non-finite coordinate, points in the box).
    """
    n_nonfinite = np.int64(0)
    n_ok = np.int64(0)
    for q in range(m):
        u = np.float64(pc[3 * q + xu])
        v = np.float64(pc[3 * q + xv])
        h = np.float64(pc[3 * q + xh])
        di = np.floor(u * ics) - fi0
        dj = np.floor(v * ics) - fj0
        db = np.floor(h * iw) - fb0
        # x - x is 0 for a finite x and NaN otherwise; the sum of three is 0 only when all are finite
        finite = (u - u) + (v - v) + (h - h) == 0.0
        # NaN fails every comparison: non-finite points are never in the box
        ok = (di >= 0.0) & (dj >= 0.0) & (db >= 0.0) & (di < fni) & (dj < fnj) & (db < fnb)
        n_nonfinite += np.int64(not finite)
        n_ok += np.int64(ok)
        slot = ((di * fnj + dj) * fnb + db) * 2.0
        buf[q] = np.int32(slot if ok else trash)
    return n_nonfinite, n_ok


@numba.jit(**_JIT)
def _box_misses(pc, m, cu, cv, ch, ics, fou, fov, fnx, fny, trash, buf, base, overflow, n_over):  # type: ignore[no-untyped-def]
    """Finite points of a chunk that are not in the box: off the grid (counted) or in it (to overflow).

    ``buf`` holds the chunk's slots from :func:`_slot_chunk`; the indices (``base + q``) of in-grid
    misses are appended to ``overflow`` from position ``n_over`` while they fit.

    Returns:
        (finite points off the grid, the new n_over).
    """
    cap = overflow.shape[0]
    n_outside = 0
    for q in range(m):
        if buf[q] != trash:
            continue
        u = np.float64(pc[3 * q + cu])
        v = np.float64(pc[3 * q + cv])
        h = np.float64(pc[3 * q + ch])
        if (u - u) + (v - v) + (h - h) != 0.0:  # non-finite: counted by the slot pass, dropped
            continue
        fi = np.floor(u * ics) - fou
        fj = np.floor(v * ics) - fov
        if fi >= 0.0 and fj >= 0.0 and fi < fnx and fj < fny:
            if n_over < cap:
                overflow[n_over] = base + q
            n_over += 1
        else:
            n_outside += 1
    return n_outside, n_over


@numba.jit(**_JIT)
def _scatter_chunk(pc, m, xh, buf, mm):  # type: ignore[no-untyped-def]
    """``mm[slot] = min(mm[slot], h)``, ``mm[slot + 1] = max(mm[slot + 1], h)`` for the chunk's points
    (one paired access each, :func:`_minmax_pair`).

    Branch-free (which point is extreme in its bin is unpredictable) and in :data:`_STREAMS`
    interleaved streams; the order of the updates does not matter, min and max are exact.
    """
    ms = m // _STREAMS
    for q in range(ms):
        for k in range(_STREAMS):
            r = q + k * ms
            # unsigned: no negative-index wraparound in the address
            _minmax_pair(mm, np.uint32(buf[r]), pc[3 * r + xh])  # type: ignore[call-arg]
    for r in range(_STREAMS * ms, m):
        _minmax_pair(mm, np.uint32(buf[r]), pc[3 * r + xh])  # type: ignore[call-arg]


@numba.jit(**_JIT)
def _bin_chunk(pc, m, xu, xv, xh, ics, fi0, fj0, fni, fnj, iw, fb0, fnb, trash, buf, mm):  # type: ignore[no-untyped-def]
    """Slots then scatter of one chunk; returns the counts of :func:`_slot_chunk`."""
    counts = _slot_chunk(pc, m, xu, xv, xh, ics, fi0, fj0, fni, fnj, iw, fb0, fnb, trash, buf)
    _scatter_chunk(pc, m, xh, buf, mm)
    return counts


@numba.jit(**_JIT)
def bin_minmax(pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, ni, nj, iw, b0, nb, mm, overflow):  # type: ignore[no-untyped-def]
    """Min and max height per (cell, height bin of width ``1 / iw``) inside a box of cells and bins.

    ``mm`` is a flat dense table of ``2 * ni * nj * nb + 2`` entries, (min, max) side by side so that
    one access updates both (:func:`_minmax_pair`), pre-filled with (+inf, -inf), for the box
    ``[i0, i0 + ni) x [j0, j0 + nj) x [b0, b0 + nb)`` (grid indices, bin indices); the last two entries
    are scratch (points that are not binned write there, so that the scatter has no branch).
    ``2 * ni * nj * nb + 2`` must fit an int32, and the box must lie inside the grid. ``pts`` is
    C-contiguous ``(N, 3)``. Points with a non-finite coordinate are counted and dropped; finite in-grid
    points whose cell or bin falls outside the box are not binned: their indices go to ``overflow`` (as
    many as fit, in increasing order) for the exact slow path.

    Per chunk of points: a vectorised pass computes every point's slot, then a scalar pass updates
    the table; a chunk with finite points outside the box is walked once more to classify them.

    Returns:
        (n_nonfinite, n_outside_grid, n_overflow); n_overflow may exceed ``overflow.shape[0]``.
    """
    n = pts.shape[0]
    p = pts.reshape(-1)
    trash = np.float64(mm.shape[0] - 2)
    fou = np.float64(ou)
    fov = np.float64(ov)
    # Box offsets as floats: floor() values minus these are exact whenever the result is inside the box
    # (integers below 2**53, or Sterbenz subtraction), so the box test can stay in float64.
    fi0 = np.float64(ou + i0)
    fj0 = np.float64(ov + j0)
    fb0 = np.float64(b0)
    fnx = np.float64(nx)
    fny = np.float64(ny)
    fni = np.float64(ni)
    fnj = np.float64(nj)
    fnb = np.float64(nb)
    buf = np.empty(_CHUNK, np.int32)
    n_nonfinite = 0
    n_outside = 0
    n_over = 0
    for s in range(0, n, _CHUNK):
        m = min(_CHUNK, n - s)
        pc = p[3 * s : 3 * (s + m)]
        # literal columns for the common axes: contiguous loads the compiler can vectorise
        if ch == 2:
            nf, n_ok = _bin_chunk(pc, m, 0, 1, 2, ics, fi0, fj0, fni, fnj, iw, fb0, fnb, trash, buf, mm)
        elif ch == 0:
            nf, n_ok = _bin_chunk(pc, m, 1, 2, 0, ics, fi0, fj0, fni, fnj, iw, fb0, fnb, trash, buf, mm)
        else:
            nf, n_ok = _bin_chunk(pc, m, cu, cv, ch, ics, fi0, fj0, fni, fnj, iw, fb0, fnb, trash, buf, mm)
        n_nonfinite += nf
        if m - nf - n_ok:  # finite points outside the box: off the grid, or a poor box guess
            off, n_over = _box_misses(
                pc, m, cu, cv, ch, ics, fou, fov, fnx, fny, trash, buf, s, overflow, n_over
            )
            n_outside += off
    return n_nonfinite, n_outside, n_over


@numba.jit(**_JIT)
def extract_bins(mm, nb, i0, j0, nj, ny, tol, out_key, out_b, out_t):  # type: ignore[no-untyped-def]
    """Merge consecutive non-empty bins of each cell into structures (gap <= tol joins).

    Writes into ``out_*`` (capacity: at least the number of non-empty bins; pages never written are
    never touched) and returns the number of structures. Every bin read is emptied again (+inf, -inf),
    so that the table can serve the next frame without a refill.
    """
    n_cells = mm.shape[0] // (2 * nb)
    n_out = 0
    for c in range(n_cells):
        base = 2 * c * nb
        # most cells of the box are empty: a branch-free count (vectorised) skips them
        filled = np.int64(0)
        for b in range(nb):
            filled += np.int64(mm[base + 2 * b] != np.inf)
        if filled == 0:
            continue
        open_ = False
        key = (i0 + c // nj) * ny + (j0 + c % nj)
        for b in range(nb):
            lo = np.float64(mm[base + 2 * b])
            if lo == np.inf:
                continue
            hi = np.float64(mm[base + 2 * b + 1])
            mm[base + 2 * b] = np.inf
            mm[base + 2 * b + 1] = -np.inf
            filled -= 1
            if open_ and lo - out_t[n_out - 1] <= tol:
                out_t[n_out - 1] = hi
            else:
                out_key[n_out] = key
                out_b[n_out] = lo
                out_t[n_out] = hi
                n_out += 1
                open_ = True
            if filled == 0:  # the cell's last non-empty bin
                break
    return n_out


@numba.jit(**_JIT)
def count_bin_structures(mm, nb, tol):  # type: ignore[no-untyped-def]
    """Number of structures :func:`extract_bins` will write (to size its output exactly)."""
    n_cells = mm.shape[0] // (2 * nb)
    n_out = 0
    for c in range(n_cells):
        base = 2 * c * nb
        have = False
        last_top = 0.0
        for b in range(nb):
            lo = np.float64(mm[base + 2 * b])
            if lo == np.inf:
                continue
            if not (have and lo - last_top <= tol):
                n_out += 1
            have = True
            last_top = np.float64(mm[base + 2 * b + 1])
    return n_out


@numba.jit(inline="always", **_JIT)
def append_joined(ok, ob, ot, o, joinable, key, lo, hi, tol):  # type: ignore[no-untyped-def]  # pragma: no cover
    """The VHV join rule at the end of an output ``(ok, ob, ot)`` of length ``o``: ``[lo, hi]`` of cell
    ``key`` (taken in bottom order) joins the last structure when ``joinable`` (it is of the same cell)
    and ``lo - last.top <= tol``, raising its top to ``hi`` if higher; else it is appended. The new
    length."""
    if joinable and lo - ot[o - 1] <= tol:
        if hi > ot[o - 1]:
            ot[o - 1] = hi
        return o
    ok[o] = key
    ob[o] = lo
    ot[o] = hi
    return o + 1


@numba.jit(**_JIT)
def merge_structures(k1, b1, t1, k2, b2, t2, tol):  # type: ignore[no-untyped-def]
    """Merge two structure lists (each sorted by key then bottom, disjoint per cell) into one.

    Intervals of one cell are swept in bottom order; the next joins the current one while
    ``next.bottom - running_top <= tol``. This equals clustering the union of the points (see
    :mod:`mapping.vhv`).
    """
    n1 = k1.shape[0]
    n2 = k2.shape[0]
    out_key = np.empty(n1 + n2, np.int64)
    out_b = np.empty(n1 + n2, np.float64)
    out_t = np.empty(n1 + n2, np.float64)
    p = 0
    q = 0
    n_out = 0
    while p < n1 or q < n2:
        if q >= n2 or (p < n1 and (k1[p] < k2[q] or (k1[p] == k2[q] and b1[p] <= b2[q]))):
            key = k1[p]
            lo = b1[p]
            hi = t1[p]
            p += 1
        else:
            key = k2[q]
            lo = b2[q]
            hi = t2[q]
            q += 1
        joinable = n_out > 0 and out_key[n_out - 1] == key
        n_out = append_joined(out_key, out_b, out_t, n_out, joinable, key, lo, hi, tol)
    return out_key[:n_out].copy(), out_b[:n_out].copy(), out_t[:n_out].copy()


@numba.jit(**_JIT)
def cell_counts(pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, ni, nj, counts):  # type: ignore[no-untyped-def]
    """Points per cell of the box ``[i0, i0 + ni) x [j0, j0 + nj)`` (which must hold every kept point).

    ``counts`` has ``ni * nj + 1`` zeros; cell ``c`` is counted in ``counts[c + 1]`` so that a cumulative
    sum gives the start offsets. Returns (n_nonfinite, n_outside_grid).
    """
    n_nonfinite = 0
    n_outside = 0
    for k in range(pts.shape[0]):
        u = np.float64(pts[k, cu])
        v = np.float64(pts[k, cv])
        h = np.float64(pts[k, ch])
        s = u + v + h
        if s - s != 0.0:
            n_nonfinite += 1
            continue
        fi = np.floor(u * ics) - ou
        fj = np.floor(v * ics) - ov
        if not (fi >= 0.0 and fj >= 0.0 and fi < nx and fj < ny):
            n_outside += 1
            continue
        counts[(np.int64(fi) - i0) * nj + (np.int64(fj) - j0) + 1] += 1
    return n_nonfinite, n_outside


@numba.jit(**_JIT)
def scatter_heights(pts, ics, ou, ov, nx, ny, cu, cv, ch, i0, j0, nj, fill, out):  # type: ignore[no-untyped-def]
    """Counting sort: write each kept point's height at ``out[fill[cell]]`` and advance ``fill[cell]``."""
    for k in range(pts.shape[0]):
        u = np.float64(pts[k, cu])
        v = np.float64(pts[k, cv])
        h = np.float64(pts[k, ch])
        s = u + v + h
        if s - s != 0.0:
            continue
        fi = np.floor(u * ics) - ou
        fj = np.floor(v * ics) - ov
        if not (fi >= 0.0 and fj >= 0.0 and fi < nx and fj < ny):
            continue
        c = (np.int64(fi) - i0) * nj + (np.int64(fj) - j0)
        out[fill[c]] = pts[k, ch]
        fill[c] += 1


@numba.jit(**_JIT)
def cluster_cells(hs, offsets, i0, j0, nj, ny, tol):  # type: ignore[no-untyped-def]
    """Thesis pipeline per cell on counting-sorted heights: sort each cell in place, then cluster."""
    n_cells = offsets.shape[0] - 1
    n_out = 0
    for c in range(n_cells):
        a = offsets[c]
        b = offsets[c + 1]
        if b == a:
            continue
        if b - a <= 32:
            # insertion sort: a library sort call per cell costs more than the few heights of a fine cell
            for q in range(a + 1, b):
                z = hs[q]
                r = q - 1
                while r >= a and hs[r] > z:
                    hs[r + 1] = hs[r]
                    r -= 1
                hs[r + 1] = z
        else:
            hs[a:b].sort()
        n_out += 1
        for q in range(a + 1, b):
            if np.float64(hs[q]) - np.float64(hs[q - 1]) > tol:
                n_out += 1
    out_key = np.empty(n_out, np.int64)
    out_b = np.empty(n_out, np.float64)
    out_t = np.empty(n_out, np.float64)
    n_out = 0
    for c in range(n_cells):
        a = offsets[c]
        b = offsets[c + 1]
        if b == a:
            continue
        key = (i0 + c // nj) * ny + (j0 + c % nj)
        out_key[n_out] = key
        out_b[n_out] = hs[a]
        out_t[n_out] = hs[a]
        n_out += 1
        for q in range(a + 1, b):
            z = np.float64(hs[q])
            if z - out_t[n_out - 1] <= tol:
                out_t[n_out - 1] = z
            else:
                out_key[n_out] = key
                out_b[n_out] = z
                out_t[n_out] = z
                n_out += 1
    return out_key, out_b, out_t


# first run after an install or a change here: say why the first frame takes tens of seconds
announce_compilation(sys.modules[__name__], "mapping kernels")
