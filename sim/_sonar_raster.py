"""Compiled (numba, cached on disk) image-space cast of the sonar beams: the first hit of every ray, exact.

The sonar's counterpart of :mod:`sim._raster_kernels` (the Kinect's z-buffer). A sonar's rays are
fixed in its frame (x forward, y left, z up; :func:`sim.sonar.beam_rays`) and all lie well inside 90
deg of the axis, so each has pinhole coordinates ``a = y / x``, ``c = z / x``. :func:`beam_layout`
sorts them once into a uniform grid of bins over (a, c), row by row, so that the rays of a run of
bins along a row are contiguous. Per sonar, each triangle of the scene is taken into the sonar's
frame, its pinhole box bounded (clipped at x = 1e-9 as the raster does), and only the rays of the
bins the box covers are tested, exactly: a ray ``r`` from the origin crosses the triangle (p0, p1,
p2) iff the three triple products ``r . (p_i x p_j)`` share the sign of ``d = n . p0`` (n the
triangle's normal), at the distance ``d / (n . r)`` (metres: the rays are unit vectors). The
nearest hit of each ray is kept (a tie keeps the lower triangle index), then the echo rule of
:func:`sim._kinect_kernels.sonar_first_echo` picks each sonar's first echo.

Whole chunks of triangles (each geometry's faces, at most :data:`CHUNK_FACES` at a time, bounded by a
sphere computed once per mirror rebuild) are skipped when they lie beyond the range, behind the sonar
or outside the cone that holds every ray. The answer is Embree's up to its float32 rounding (Embree
casts float32 rays; here the geometry is the mirror's float32 vertices in float64, the rays float64).
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np
import numpy.typing as npt

from mapping._deps import announce_compilation
from sim._kinect_kernels import _interp_uniform

#: Faces per chunk at most (a geometry with more is culled in several chunks).
CHUNK_FACES = 32
#: Bins of the (a, c) grid along a (columns) and c (rows).
GRID_A, GRID_C = 40, 24
_EPS_X = 1e-9
#: Margin (in a and c) added to a triangle's box before it is mapped to bins: covers the rounding of
#: the box itself (relative ~1e-16), far below a bin.
_BOX_MARGIN = 1e-9
#: Boxes at least this many bins wide get a span per row (narrower ones test their whole box).
_SPAN_BINS = 1 << 30


def beam_layout(
    dirs: npt.NDArray[np.float64], grid_a: int = GRID_A, grid_c: int = GRID_C
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Sort a beam's rays into a (grid_c, grid_a) grid of bins over their pinhole coordinates.

    Args:
        dirs: (N, 3) unit ray directions in the sonar frame, every one with x >= 0.2 (within ~78 deg
            of the axis).
        grid_a, grid_c: bins along a = y / x and c = z / x.

    Returns:
        ``(order, rays, grid, bin_start)``: (N,) ray indices in bin order (row by row, then column),
        (3, N) the rays in that order (x, y, z rows), (6,) ``(a0, da, c0, dc, grid_a, grid_c)`` and
        (grid_a * grid_c + 1,) offsets of each bin's rays in the order.

    Raises:
        ValueError: a ray too far off the axis, or a grid of less than one bin.
    """
    d = np.ascontiguousarray(dirs, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3 or len(d) == 0 or not np.all(d[:, 0] >= 0.2):
        raise ValueError(f"beam_layout: {d.shape} rays: expected (N > 0, 3), each with x >= 0.2")
    if grid_a < 1 or grid_c < 1:
        raise ValueError(f"beam_layout: a grid of {grid_a} x {grid_c} bins")
    a, c = d[:, 1] / d[:, 0], d[:, 2] / d[:, 0]
    a0, c0 = float(a.min()), float(c.min())
    # widened a little so that the largest coordinate falls inside the last bin
    da = max(float(a.max()) - a0, 1e-9) * (1.0 + 1e-9) / grid_a
    dc = max(float(c.max()) - c0, 1e-9) * (1.0 + 1e-9) / grid_c
    ia = np.minimum(np.floor((a - a0) / da).astype(np.int64), grid_a - 1)
    ic = np.minimum(np.floor((c - c0) / dc).astype(np.int64), grid_c - 1)
    b = ic * grid_a + ia
    order = np.argsort(b, kind="stable").astype(np.int64)
    bin_start = np.searchsorted(b[order], np.arange(grid_a * grid_c + 1)).astype(np.int64)
    grid = np.array([a0, da, c0, dc, grid_a, grid_c], dtype=np.float64)
    return order, np.ascontiguousarray(d[order].T), grid, bin_start


@numba.njit(cache=True, nogil=True)
def mesh_chunks(verts, faces, tri_geom):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Chunks of the mirror's triangles and their bounding spheres, once per mirror rebuild.

    A new chunk starts at each change of geometry and every :data:`CHUNK_FACES` faces.

    Returns:
        ``(chunks, bounds)``: (K + 1,) face offsets and (K, 4) sphere (world centre x, y, z, radius m).
    """
    nf = faces.shape[0]
    off = np.empty(nf + 2, dtype=np.int64)
    k = 0
    off[0] = 0
    start = 0
    for f in range(1, nf):
        if f - start >= CHUNK_FACES or tri_geom[f] != tri_geom[f - 1]:
            k += 1
            off[k] = f
            start = f
    if nf > 0:
        k += 1
        off[k] = nf
    chunks = off[: k + 1].copy()
    bounds = np.empty((k, 4))
    for c in range(k):
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for f in range(chunks[c], chunks[c + 1]):
            for j in range(3):
                for q in range(3):
                    v = verts[faces[f, j], q]
                    lo[q] = min(lo[q], v)
                    hi[q] = max(hi[q], v)
        r2 = 0.0
        for q in range(3):
            bounds[c, q] = 0.5 * (lo[q] + hi[q])
        for f in range(chunks[c], chunks[c + 1]):
            for j in range(3):
                s = 0.0
                for q in range(3):
                    e = verts[faces[f, j], q] - bounds[c, q]
                    s += e * e
                r2 = max(r2, s)
        # a hair larger than the farthest vertex: the sphere holds every vertex despite rounding
        bounds[c, 3] = math.sqrt(r2) * (1.0 + 1e-12) + 1e-12
    return chunks, bounds


@numba.njit(cache=True, nogil=True, inline="always")
def _bin_range(lo, hi, x0, dx, n):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """First and last bin (of ``n``) a coordinate interval [lo, hi] reaches (first > last: none)."""
    # clamped as floats first: a vertex just in front of the sonar projects near infinity
    i0 = math.floor(min(max((lo - x0) / dx, -1.0), n + 1.0))
    i1 = math.floor(min(max((hi - x0) / dx, -1.0), n + 1.0))
    return max(i0, 0), min(i1, n - 1)


# error_model="numpy": a division by zero gives inf instead of raising (the ray loop relies on it)
@numba.njit(cache=True, nogil=True, error_model="numpy")
def _cast_one(verts, faces, chunks, bounds, pose, rays, grid, bin_start, cos_cone, far, zbuf, tri):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Nearest hit (distance into ``zbuf``, face into ``tri``) of each ray of one sonar.

    ``pose``: (4, 4) the sonar's world pose; ``rays``: (3, N) sonar-frame unit rays in bin order;
    ``cos_cone``: cosine of the widest ray's angle off the axis. ``zbuf`` (inf) and ``tri`` (-1) come
    in filled with "no hit"; hits beyond ``far`` are misses.
    """
    a0, da, c0, dc = grid[0], grid[1], grid[2], grid[3]
    ga, gc = int(grid[4]), int(grid[5])
    # planes just outside the grid (every ray lies strictly inside them): y = alo x, y = ahi x, ...
    alo, ahi = a0 - 1e-6, a0 + ga * da + 1e-6
    clo, chi = c0 - 1e-6, c0 + gc * dc + 1e-6
    eps = _EPS_X
    cone = math.acos(cos_cone)
    # the pose as scalars (world <- sonar rotation r.., origin o.)
    r00, r01, r02 = pose[0, 0], pose[0, 1], pose[0, 2]
    r10, r11, r12 = pose[1, 0], pose[1, 1], pose[1, 2]
    r20, r21, r22 = pose[2, 0], pose[2, 1], pose[2, 2]
    ox, oy, oz = pose[0, 3], pose[1, 3], pose[2, 3]
    rx, ry, rz = rays[0], rays[1], rays[2]
    cx = np.empty(4)
    cy = np.empty(4)
    cz = np.empty(4)
    pa = np.empty(5)  # the polygon's pinhole coordinates, closed (the first vertex again at the end)
    pc = np.empty(5)
    slope = np.empty(4)  # da / dc along each edge of the polygon
    for ch in range(chunks.shape[0] - 1):
        # the chunk's sphere in the sonar frame
        dx, dy, dz = bounds[ch, 0] - ox, bounds[ch, 1] - oy, bounds[ch, 2] - oz
        qx = r00 * dx + r10 * dy + r20 * dz
        qy = r01 * dx + r11 * dy + r21 * dz
        qz = r02 * dx + r12 * dy + r22 * dz
        rad = bounds[ch, 3]
        dist = math.sqrt(qx * qx + qy * qy + qz * qz)
        if dist - rad > far or qx + rad <= eps:
            continue  # every point of it beyond the range, or behind the sonar
        # wholly outside the cone that holds every ray: the centre's angle off the axis, less the
        # sphere's angular radius, beyond the widest ray's (with a margin for rounding)
        if dist > rad and math.acos(min(1.0, max(-1.0, qx / dist))) - math.asin(rad / dist) > cone + 1e-9:
            continue
        for f in range(chunks[ch], chunks[ch + 1]):
            i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
            dx, dy, dz = verts[i0, 0] - ox, verts[i0, 1] - oy, verts[i0, 2] - oz
            x0 = r00 * dx + r10 * dy + r20 * dz
            y0 = r01 * dx + r11 * dy + r21 * dz
            z0 = r02 * dx + r12 * dy + r22 * dz
            dx, dy, dz = verts[i1, 0] - ox, verts[i1, 1] - oy, verts[i1, 2] - oz
            x1 = r00 * dx + r10 * dy + r20 * dz
            y1 = r01 * dx + r11 * dy + r21 * dz
            z1 = r02 * dx + r12 * dy + r22 * dz
            dx, dy, dz = verts[i2, 0] - ox, verts[i2, 1] - oy, verts[i2, 2] - oz
            x2 = r00 * dx + r10 * dy + r20 * dz
            y2 = r01 * dx + r11 * dy + r21 * dz
            z2 = r02 * dx + r12 * dy + r22 * dz
            if x0 > far and x1 > far and x2 > far:
                continue  # every point of it farther than the range (a distance is at least its x)
            # wholly on the outer side of one of the four planes that bound the beam (no division;
            # this also drops what lies behind the sonar)
            if (
                (y0 < alo * x0 and y1 < alo * x1 and y2 < alo * x2)
                or (y0 > ahi * x0 and y1 > ahi * x1 and y2 > ahi * x2)
                or (z0 < clo * x0 and z1 < clo * x1 and z2 < clo * x2)
                or (z0 > chi * x0 and z1 > chi * x1 and z2 > chi * x2)
            ):
                continue
            if x0 <= eps and x1 <= eps and x2 <= eps:
                continue  # wholly behind the sonar
            if x0 > eps and x1 > eps and x2 > eps:
                nc = 3
                cx[0], cy[0], cz[0] = x0, y0, z0
                cx[1], cy[1], cz[1] = x1, y1, z1
                cx[2], cy[2], cz[2] = x2, y2, z2
            else:
                # clip against x = eps (Sutherland-Hodgman, one plane) to bound the projection
                nc = 0
                for e in range(3):
                    if e == 0:
                        px, py, pz, sx, sy, sz = x0, y0, z0, x1, y1, z1
                    elif e == 1:
                        px, py, pz, sx, sy, sz = x1, y1, z1, x2, y2, z2
                    else:
                        px, py, pz, sx, sy, sz = x2, y2, z2, x0, y0, z0
                    if px > eps:
                        cx[nc], cy[nc], cz[nc] = px, py, pz
                        nc += 1
                    if (px > eps) != (sx > eps):
                        s = (eps - px) / (sx - px)
                        cx[nc], cy[nc], cz[nc] = eps, py + s * (sy - py), pz + s * (sz - pz)
                        nc += 1
            # the (clipped) polygon in pinhole coordinates and its box
            amin, amax, cmin, cmax = np.inf, -np.inf, np.inf, -np.inf
            for k in range(nc):
                pa[k] = cy[k] / cx[k]
                pc[k] = cz[k] / cx[k]
                amin, amax = min(amin, pa[k]), max(amax, pa[k])
                cmin, cmax = min(cmin, pc[k]), max(cmax, pc[k])
            pa[nc], pc[nc] = pa[0], pc[0]
            scale = max(-amin, amax, -cmin, cmax)
            margin = _BOX_MARGIN * (1.0 + scale)
            ia0, ia1 = _bin_range(amin - margin, amax + margin, a0, da, ga)
            ic0, ic1 = _bin_range(cmin - margin, cmax + margin, c0, dc, gc)
            if ia0 > ia1 or ic0 > ic1:
                continue  # outside the beam
            # rows get their own span (the polygon's extent in a over the row's band of c) unless the
            # polygon reaches far out (a vertex just in front of the sonar), where rounding grows
            spans = scale < 1e4 and ia1 - ia0 >= _SPAN_BINS
            if spans:
                for k in range(nc):
                    slope[k] = (pa[k + 1] - pa[k]) / (pc[k + 1] - pc[k]) if pc[k + 1] != pc[k] else 0.0
            # edge vectors p_i x p_j, the normal (their sum) and the plane's n . p0
            e00, e01, e02 = y0 * z1 - z0 * y1, z0 * x1 - x0 * z1, x0 * y1 - y0 * x1
            e10, e11, e12 = y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2
            e20, e21, e22 = y2 * z0 - z2 * y0, z2 * x0 - x2 * z0, x2 * y0 - y2 * x0
            n0, n1, n2 = e00 + e10 + e20, e01 + e11 + e21, e02 + e12 + e22
            d = n0 * x0 + n1 * y0 + n2 * z0
            if d == 0.0:
                continue  # the plane passes through the sonar: seen edge-on, no area
            # a ray crosses the triangle in front of the sonar iff every triple product has the sign
            # of d (their sum is n . r, and the distance d / (n . r) must be positive)
            if d < 0.0:
                e00, e01, e02, e10, e11, e12 = -e00, -e01, -e02, -e10, -e11, -e12
                e20, e21, e22 = -e20, -e21, -e22
            for ic in range(ic0, ic1 + 1):
                ja0, ja1 = ia0, ia1
                if spans:
                    bl, bh = c0 + ic * dc - margin, c0 + (ic + 1) * dc + margin
                    lo_a, hi_a = np.inf, -np.inf
                    for k in range(nc):
                        # edge k's part within the band: its c range clipped, then a along it
                        ca, cb = pc[k], pc[k + 1]
                        lo_c, hi_c = max(bl, min(ca, cb)), min(bh, max(ca, cb))
                        if lo_c > hi_c:
                            continue
                        if ca == cb:
                            u0, u1 = pa[k], pa[k + 1]
                        else:
                            u0, u1 = pa[k] + (lo_c - ca) * slope[k], pa[k] + (hi_c - ca) * slope[k]
                        lo_a, hi_a = min(lo_a, u0, u1), max(hi_a, u0, u1)
                    if lo_a > hi_a:
                        continue
                    ja0, ja1 = _bin_range(lo_a - margin, hi_a + margin, a0, da, ga)
                    if ja0 > ja1:
                        continue
                lo, hi = bin_start[ic * ga + ja0], bin_start[ic * ga + ja1 + 1]
                # branch-free over the row's rays (contiguous), so that it runs on SIMD lanes (the
                # slices give indices LLVM knows are >= 0: no wraparound test per ray); a ray in the
                # triangle's plane gives an infinite distance, which fails t <= far
                sx, sy, sz, zr, tr = rx[lo:hi], ry[lo:hi], rz[lo:hi], zbuf[lo:hi], tri[lo:hi]
                for j in range(hi - lo):
                    ux, uy, uz = sx[j], sy[j], sz[j]
                    t = d / (n0 * ux + n1 * uy + n2 * uz)
                    zj = zr[j]
                    ok = (
                        (e00 * ux + e01 * uy + e02 * uz >= 0.0)
                        & (e10 * ux + e11 * uy + e12 * uz >= 0.0)
                        & (e20 * ux + e21 * uy + e22 * uz >= 0.0)
                        & (t > 0.0)
                        & (t <= far)
                        & (t < zj)
                    )
                    zr[j] = t if ok else zj
                    tr[j] = f if ok else tr[j]


@numba.njit(cache=True, nogil=True)
def beam_hits(verts, faces, chunks, bounds, stack, rays, grid, bin_start, cos_cone, far):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Nearest hit of every ray of ``k`` sonars: ``(distance (k, N), face (k, N))``, rays in bin order.

    ``stack``: (k, 4, 4) world poses of the sonars; the other arguments as :func:`first_echoes`.
    A ray without a hit within ``far`` (m) has distance inf and face -1.
    """
    k, n = stack.shape[0], rays.shape[1]
    zbuf = np.full((k, n), np.inf)
    tri = np.full((k, n), -1, dtype=np.int64)
    for s in range(k):
        _cast_one(
verts, faces, chunks, bounds, stack[s], rays, grid, bin_start, cos_cone, far, zbuf[s], tri[s])
    return zbuf, tri


@numba.njit(cache=True, nogil=True)
def first_echoes(  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    verts,
    faces,
    chunks,
    bounds,
    stack,
    rays,
    grid,
    bin_start,
    cos_cone,
    max_range,
    cos_incidence,
    bearing,
    elevation,
    table_m,
    table_left,
    table_right,
):
    """First echo (m, unquantised; NaN = none) of each of ``k`` sonars, cast and echo rule in one call.

    Args:
        verts, faces: (M, 3) float64 world vertices and (T, 3) int64 faces of the mirror
            (:attr:`sim.raycast.MeshMirror.tri_vertices`, ``tri_faces``).
        chunks, bounds: :func:`mesh_chunks` of them.
        stack: (k, 4, 4) world poses of the sonars (x = axis).
        rays, grid, bin_start: :func:`beam_layout` of the beam; ``bearing``, ``elevation``: (N,) deg of
            each ray, in the same (bin) order.
        cos_cone: cosine of the widest ray's angle off the axis.
        max_range: m; cos_incidence: the echo rule's limit; table_*: the tabulated half-apertures
            (as :func:`sim._kinect_kernels.sonar_first_echo`).

    Returns:
        (k,) float64 first echoes: per sonar the smallest distance of a ray whose nearest hit lies
        within ``max_range``, faces it (``|normal . ray| >= cos_incidence``) and lies inside the beam's
        ellipse at that distance.
    """
    zbuf, tri = beam_hits(verts, faces, chunks, bounds, stack, rays, grid, bin_start, cos_cone, max_range)
    k, n = zbuf.shape
    out = np.full(k, np.nan)
    for s in range(k):
        best = np.inf
        rot = stack[s, :3, :3]
        for i in range(n):
            r = zbuf[s, i]
            f = tri[s, i]
            if f < 0 or not r < best:
                continue
            # the triangle's world normal and the ray's world direction
            i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
            ux, uy, uz = verts[i1, 0] - verts[i0, 0], verts[i1, 1] - verts[i0, 1], verts[i1, 2] - verts[i0, 2]
            wx, wy, wz = verts[i2, 0] - verts[i0, 0], verts[i2, 1] - verts[i0, 1], verts[i2, 2] - verts[i0, 2]
            nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
            rx, ry, rz = rays[0, i], rays[1, i], rays[2, i]
            dx = rot[0, 0] * rx + rot[0, 1] * ry + rot[0, 2] * rz
            dy = rot[1, 0] * rx + rot[1, 1] * ry + rot[1, 2] * rz
            dz = rot[2, 0] * rx + rot[2, 1] * ry + rot[2, 2] * rz
            ln = math.sqrt(nx * nx + ny * ny + nz * nz)
            if not abs(nx * dx + ny * dy + nz * dz) >= cos_incidence * ln:
                continue
            left = _interp_uniform(r, table_m, table_left)
            right = _interp_uniform(r, table_m, table_right)
            vert = 0.5 * (left + right)
            h = left if bearing[i] >= 0 else right
            if (bearing[i] / h) ** 2 + (elevation[i] / vert) ** 2 <= 1.0:
                best = r
        if best < np.inf:
            out[s] = best
    return out


# first run after an install or a change here: say why the first sonar reading takes seconds
announce_compilation(sys.modules[__name__], "sonar raster kernels")
