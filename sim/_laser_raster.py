"""Compiled (numba, cached on disk) first hits of a planar laser fan among the scene's triangles.

The exact geometric answer of casting each beam of a scan plane against the triangles of
:class:`sim.raycast.MeshMirror` (the same as Embree's up to its float32 rounding), without Embree: a
beam lies in the scan plane, so it can only meet a triangle on the segment where the triangle crosses
that plane. Each triangle is cut once by the plane; the cut segment covers an arc of beam angles, and
only the beams of that arc (one beam of margin on each side) are tested against the segment. A scan
costs about the beams the crossing segments cover instead of a BVH walk per beam.

Triangles lying in the scan plane (every vertex at zero height) are skipped: a beam grazing a surface
along its plane has no defined first hit (Embree reports such rays as it happens to round them).

The chair's caster skips whole chunks of triangles (those of :func:`sim._sonar_raster.mesh_chunks`)
whose bounding sphere lies on one side of the scan plane or beyond the range before reading their
vertices. Measured (``time.process_time`` medians, the office scene's 6,746 triangles in 220 chunks,
682 beams, 200 poses along the corridor and the room, the three in the same process): Embree
through :meth:`sim.laser.LaserSim.true_ranges` 164 us, every triangle cut 68 us, the chunked cut 37 us
per scan; tests/sim/test_laser_raster.py compares them with Embree.
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


@numba.njit(cache=True, nogil=True, inline="always")
def _beam_span(lo, width, amin, inc, n):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """First and last beam index of the arc [lo, lo + width] (rad) with a beam of margin, clipped to
    the fan [0, n) (a second call covers the part of an arc that wraps past 2 pi)."""
    rel = (lo - amin) % (2.0 * math.pi)
    k0 = max(math.floor(rel / inc) - 1, 0)
    k1 = min(math.ceil((rel + width) / inc) + 1, n - 1)
    w0 = 0
    w1 = -1
    over = rel + width + inc - 2.0 * math.pi
    if over > 0.0:
        w1 = min(math.ceil(over / inc) + 1, n - 1)
    return k0, k1, w0, w1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def planar_first_hits(verts, faces, rot, origin, amin, inc, cosb, sinb, rmax):  # type: ignore[no-untyped-def]  # pragma: no cover
    """(n,) distance (m) along each beam of a planar fan to the first triangle it meets (inf: none).

    Beam ``k`` of the fan points along ``rot @ (cosb[k], sinb[k], 0)`` from ``origin``, where
    ``cosb[k], sinb[k]`` are the cosine and sine of ``a_k = amin + k * inc`` (the sensor frame's x axis
    forward, z the scan plane's normal). Every triangle is cut; :func:`planar_first_hits_chunked`
    skips whole chunks first.

    Args:
        verts: (M, 3) float64 world vertices; faces: (T, 3) int64 vertex indices.
        rot: (3, 3) world <- sensor rotation; origin: (3,) world position of the sensor, m.
        amin, inc: the first beam's angle and the angle between beams, rad.
        cosb, sinb: (n,) cosine and sine of each beam's angle.
        rmax: hits farther than this are misses, m.
    """
    chunks = np.array([0, faces.shape[0]], dtype=np.int64)
    bounds = np.zeros((1, 12))
    bounds[0, 3] = np.inf  # a sphere holding everything: never culled
    bounds[0, 4], bounds[0, 5] = 0, verts.shape[0] - 1
    return planar_first_hits_chunked(verts, faces, chunks, bounds, rot, origin, amin, inc, cosb, sinb, rmax)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def planar_first_hits_chunked(verts, faces, chunks, bounds, rot, origin, amin, inc, cosb, sinb, rmax):  # type: ignore[no-untyped-def]  # pragma: no cover
    """:func:`planar_first_hits` over the chunks of :func:`sim._sonar_raster.mesh_chunks`: a chunk whose
    bounding sphere lies wholly on one side of the scan plane, or wholly beyond ``rmax``, has no
    triangle a beam can meet and is skipped before its vertices are read (the same answer: only the
    cut of a triangle that crosses the plane within the range can give a hit).

    Args:
        chunks: (K + 1,) face offsets; bounds: (K, >= 6) sphere centre (x, y, z), radius (m), then the
            first and last vertex index of the chunk's faces; the rest as in :func:`planar_first_hits`.
    """
    m = verts.shape[0]
    pc = np.empty((m, 3))
    ox, oy, oz = origin[0], origin[1], origin[2]
    nx, ny, nz = rot[0, 2], rot[1, 2], rot[2, 2]  # the scan plane's normal
    n = cosb.shape[0]
    best = np.full(n, np.inf)
    px = np.empty(2)
    py = np.empty(2)
    for ch in range(chunks.shape[0] - 1):
        dx, dy, dz = bounds[ch, 0] - ox, bounds[ch, 1] - oy, bounds[ch, 2] - oz
        rad = bounds[ch, 3]
        if abs(dx * nx + dy * ny + dz * nz) > rad:
            continue  # every vertex on one side of the plane
        reach = rmax + rad
        if dx * dx + dy * dy + dz * dz > reach * reach:
            continue  # every vertex beyond the range
        for i in range(int(bounds[ch, 4]), int(bounds[ch, 5]) + 1):
            ex = verts[i, 0] - ox
            ey = verts[i, 1] - oy
            ez = verts[i, 2] - oz
            for j in range(3):
                pc[i, j] = rot[0, j] * ex + rot[1, j] * ey + rot[2, j] * ez
        _cut_faces(pc, faces, chunks[ch], chunks[ch + 1], amin, inc, cosb, sinb, rmax, best, px, py)
    return best


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _cut_faces(pc, faces, f0, f1, amin, inc, cosb, sinb, rmax, best, px, py):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Cut faces [f0, f1) (sensor-frame vertices ``pc``) by the plane z = 0; keep each beam's nearest hit."""
    n = cosb.shape[0]
    for f in range(f0, f1):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        z0, z1, z2 = pc[i0, 2], pc[i1, 2], pc[i2, 2]
        if (z0 > 0.0 and z1 > 0.0 and z2 > 0.0) or (z0 < 0.0 and z1 < 0.0 and z2 < 0.0):
            continue  # wholly above or below the scan plane
        if z0 == 0.0 and z1 == 0.0 and z2 == 0.0:
            continue  # in the plane: no defined first hit
        # the cut: vertices on the plane and strict crossings of the edges (two points at most)
        c = 0
        for e in range(3):
            if e == 0:
                ia, ib = i0, i1
            elif e == 1:
                ia, ib = i1, i2
            else:
                ia, ib = i2, i0
            za, zb = pc[ia, 2], pc[ib, 2]
            if za == 0.0:
                if c < 2:
                    px[c], py[c] = pc[ia, 0], pc[ia, 1]
                c += 1
            elif (za < 0.0) != (zb < 0.0) and zb != 0.0:
                s = za / (za - zb)
                if c < 2:
                    px[c] = pc[ia, 0] + s * (pc[ib, 0] - pc[ia, 0])
                    py[c] = pc[ia, 1] + s * (pc[ib, 1] - pc[ia, 1])
                c += 1
        if c < 2:
            continue  # touches the plane at one vertex only
        ax, ay, bx, by = px[0], py[0], px[1], py[1]
        ex, ey = bx - ax, by - ay
        if ex == 0.0 and ey == 0.0:
            continue
        # the segment's nearest point to the sensor: its foot on the line when inside, else an end
        ee = ex * ex + ey * ey
        u = -(ax * ex + ay * ey) / ee
        u = min(max(u, 0.0), 1.0)
        nx, ny = ax + u * ex, ay + u * ey
        if nx * nx + ny * ny > rmax * rmax * (1.0 + 1e-9):
            continue  # wholly beyond the range
        aa = math.atan2(ay, ax)
        ab = math.atan2(by, bx)
        span = ab - aa
        if span > math.pi:
            span -= 2.0 * math.pi
        elif span <= -math.pi:
            span += 2.0 * math.pi
        lo, width = (aa, span) if span >= 0.0 else (ab, -span)
        k0, k1, w0, w1 = _beam_span(lo, width, amin, inc, n)
        cross_pe = ax * ey - ay * ex
        for part in range(2):
            ka, kb = (k0, k1) if part == 0 else (w0, w1)
            for k in range(ka, kb + 1):
                dx, dy = cosb[k], sinb[k]
                den = dx * ey - dy * ex
                if den == 0.0:
                    continue  # the beam runs along the segment
                t = cross_pe / den
                s = (ax * dy - ay * dx) / den
                if s >= 0.0 and s <= 1.0 and t > 0.0 and t <= rmax and t < best[k]:
                    best[k] = t


# first run after an install or a change here: say why the first scan takes seconds
announce_compilation(sys.modules[__name__], "laser kernels")
