"""Compiled (numba, cached on disk) z-buffer raster of :mod:`sim.kinect`: the first hit of every pixel ray.

The exact answer of casting one ray per pixel against the scene's triangles (the same as Embree's up
to floating point rounding), found by image-space culling. Split from :mod:`sim._kinect_kernels`
(the noise) along the raster / noise seam; :func:`sim._kinect_kernels.raster_capture` fuses the two.

Work saved per frame, all of it without changing a single output bit (the result is that of testing
every triangle, in index order, against every pixel of its projected box; a test compares the two):

* the triangles are drawn in chunks (each geometry's faces, at most :data:`CHUNK_FACES` at a time);
  a chunk that lies behind the camera, beyond the range or outside the image is skipped whole;
* occlusion culling: a coarse buffer keeps, per tile of :data:`TILE_V` x :data:`TILE_U` pixels, an
  upper bound of the depths drawn there (refreshed after each chunk); a chunk or triangle whose
  nearest possible depth lies beyond that bound on every tile it covers cannot show and is skipped;
* the pixel loop of a triangle's row is branch-free, so it runs on SIMD lanes;
* a triangle whose box is narrower than :data:`_NARROW_PX` pixels tests its whole box row by row
  (the exact test decides) instead of computing each row's span with three divisions;
* the boxes hold the pixels within :data:`_BOX_MARGIN_PX` of the projection, not a whole pixel more.

Measured on the office route (120 frames, ``time.process_time`` medians, same run, loaded machine):
4.5-4.7 ms -> 3.4-3.5 ms CPU per 512x424 frame (1.33x against the index-order raster). Of that, the
narrow boxes give 1.25x -> 1.33x; with the occlusion test disabled the rest is 0.96x, so the culling
carries it. Drawing the chunks nearest first culls more, but then an exact depth tie needs the lowest
index to win, and that test in the pixel loop cost more than it saved (0.91x). A branch-free lateral
gather (no branch on a missing return) measured the same as the branchy one (1.45 vs 1.47 ms).
The box margin of a twentieth of a pixel instead of one (201 frames of ``NavigationKinect-v1``, 128 x
106, same run): 1.81 -> 1.07 ms per draw on average, median 2.14 -> 1.22, p90 2.83 -> 1.70; of
205k pixel tests per frame, 66k lay inside a triangle.
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np

from mapping._deps import announce_compilation

#: Faces per chunk at most (a geometry with more is drawn in several chunks, culled one by one).
CHUNK_FACES = 128
#: Occlusion tile: rows and columns of pixels (powers of two: the tile of a pixel is a shift).
_SHIFT_V, _SHIFT_U = 3, 4
TILE_V, TILE_U = 1 << _SHIFT_V, 1 << _SHIFT_U
#: A chunk or triangle is culled only when its nearest possible depth, shrunk by this relative
#: margin, lies beyond a tile's bound: the computed depth of a hit, ``d / (n . r)``, is within about
#: 1e-15 / cos(incidence) of the exact one (relative), far inside the margin once the plane passes at
#: least :data:`_MIN_PLANE_DIST_M` from the camera.
_CULL_MARGIN = 1e-6
#: Triangles whose plane passes closer than this to the camera (seen almost edge-on) are never culled.
_MIN_PLANE_DIST_M = 1e-6
_EPS_X = 1e-9
#: Boxes narrower than this (pixels) skip the span computation of each row and test every pixel.
_NARROW_PX = 16
#: A triangle's (and a chunk's) pixel box holds the pixels whose ray lies within this many pixels of
#: its projected vertices' extremes. The box's bounds are computed within ~1e-13 px; a ray outside the
#: projection by 0.05 px fails an edge test in floating point too unless the triangle's projection is a
#: sliver (seen edge-on, or collinear vertices), so the z-buffer is that of a whole pixel of margin
#: (tested: the reference draws each box one pixel wider). Slivers (:func:`_well_shaped`), triangles
#: whose plane passes within :data:`_MIN_PLANE_DIST_M` of the camera, and the chunks holding either,
#: keep the whole pixel: there the edge tests' rounding passes rays off the projection. A pixel of
#: margin made the boxes of the small triangles of the office's meshes five times larger than their
#: pixels in the decimated frame.
_BOX_MARGIN_PX = 0.05
#: A projected triangle is a sliver (keeps the whole pixel) below these: see :func:`_well_shaped`.
_MIN_SHAPE = 1e-6
_MIN_EDGE = 1e-6


@numba.njit(cache=True, nogil=True)
def _chunks(tri_geom, n_faces):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """(K + 1,) face offsets of the chunks: a new chunk at each change of geometry and every
    :data:`CHUNK_FACES` faces (without ``tri_geom``, i.e. an empty one: every CHUNK_FACES faces)."""
    out = np.empty(n_faces + 2, dtype=np.int64)
    k = 0
    out[0] = 0
    start = 0
    labelled = tri_geom.shape[0] == n_faces
    for f in range(1, n_faces):
        if f - start >= CHUNK_FACES or (labelled and tri_geom[f] != tri_geom[f - 1]):
            k += 1
            out[k] = f
            start = f
    if n_faces > 0:
        k += 1
        out[k] = n_faces
    return out[: k + 1]


@numba.njit(cache=True, nogil=True, inline="always")
def _occluded(tmax, u0, u1, v0, v1, zmin):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """True when every tile over pixels [u0, u1] x [v0, v1] has its depth bound below ``zmin``."""
    for tv in range(v0 >> _SHIFT_V, (v1 >> _SHIFT_V) + 1):
        for tu in range(u0 >> _SHIFT_U, (u1 >> _SHIFT_U) + 1):
            if not tmax[tv, tu] < zmin:
                return False
    return True


@numba.njit(cache=True, nogil=True)
def _refresh_tiles(zbuf, tmax, dirty):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Recompute the depth bound (the largest depth, inf when a pixel is empty) of the dirty tiles."""
    h, w = zbuf.shape
    for tv in range(tmax.shape[0]):
        for tu in range(tmax.shape[1]):
            if not dirty[tv, tu]:
                continue
            dirty[tv, tu] = False
            m = 0.0
            for v in range(tv * TILE_V, min((tv + 1) * TILE_V, h)):
                for u in range(tu * TILE_U, min((tu + 1) * TILE_U, w)):
                    m = max(m, zbuf[v, u])
            tmax[tv, tu] = m


@numba.njit(cache=True, nogil=True, inline="always")
def clipped_box(x0, y0, z0, x1, y1, z1, x2, y2, z2, eps, cx, cy, cz):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """A camera-frame triangle clipped against the plane x = ``eps`` (Sutherland-Hodgman, one plane)
    and the box of its projection: ``(nc, amin, amax, bmin, bmax)``, ``nc`` the clipped polygon's
    vertices (written to ``cx, cy, cz``, (4,) each) and the extremes of ``y / x`` and ``z / x`` over
    them (an empty polygon: an empty box, inf / -inf). Shared by the Kinect raster and the sonar
    beam's (:mod:`sim._sonar_raster`)."""
    nc = 0
    for e in range(3):
        if e == 0:
            px, py, pz, qx, qy, qz = x0, y0, z0, x1, y1, z1
        elif e == 1:
            px, py, pz, qx, qy, qz = x1, y1, z1, x2, y2, z2
        else:
            px, py, pz, qx, qy, qz = x2, y2, z2, x0, y0, z0
        if px > eps:
            cx[nc], cy[nc], cz[nc] = px, py, pz
            nc += 1
        if (px > eps) != (qx > eps):
            s = (eps - px) / (qx - px)
            cx[nc], cy[nc], cz[nc] = eps, py + s * (qy - py), pz + s * (qz - pz)
            nc += 1
    amin, amax, bmin, bmax = np.inf, -np.inf, np.inf, -np.inf
    for k in range(nc):
        a = cy[k] / cx[k]
        b = cz[k] / cx[k]
        amin, amax = min(amin, a), max(amax, a)
        bmin, bmax = min(bmin, b), max(bmax, b)
    return nc, amin, amax, bmin, bmax


@numba.njit(cache=True, nogil=True, inline="always")
def _well_shaped(x0, y0, z0, x1, y1, z1, x2, y2, z2):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """True when the projection of a triangle in front of the camera (every x > 0) is no sliver: twice
    its area is at least :data:`_MIN_SHAPE` times its longest edge squared, that edge at least
    :data:`_MIN_EDGE` (in ray components ``y / x``, ``z / x``). A triangle seen edge-on, or one whose
    vertices are (almost) collinear, is not: the edge tests' rounding may pass rays off its projection."""
    a0, b0 = y0 / x0, z0 / x0
    a1, b1 = y1 / x1, z1 / x1
    a2, b2 = y2 / x2, z2 / x2
    area2 = abs((a1 - a0) * (b2 - b0) - (a2 - a0) * (b1 - b0))
    l2 = max(
        (a1 - a0) ** 2 + (b1 - b0) ** 2,
        (a2 - a1) ** 2 + (b2 - b1) ** 2,
        (a0 - a2) ** 2 + (b0 - b2) ** 2,
    )
    return l2 >= _MIN_EDGE * _MIN_EDGE and area2 >= _MIN_SHAPE * l2


@numba.njit(cache=True, nogil=True, inline="always")
def _pixel_box(amin, amax, bmin, bmax, a0, da, b0, db, w, h, tight):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Unclipped pixel box ``(u0, u1, v0, v1)`` of the ray components [amin, amax] x [bmin, bmax]: within
    :data:`_BOX_MARGIN_PX` of them when ``tight``, else a whole pixel beyond (each bound clamped as a
    float first: a vertex just in front of the camera projects near infinity)."""
    qu0 = min(max((amax - a0) / da, -2.0), w + 2.0)
    qu1 = min(max((amin - a0) / da, -2.0), w + 2.0)
    qv0 = min(max((bmax - b0) / db, -2.0), h + 2.0)
    qv1 = min(max((bmin - b0) / db, -2.0), h + 2.0)
    if tight:
        m = _BOX_MARGIN_PX
        return math.ceil(qu0 - m), math.floor(qu1 + m), math.ceil(qv0 - m), math.floor(qv1 + m)
    return math.floor(qu0) - 1, math.ceil(qu1) + 1, math.floor(qv0) - 1, math.ceil(qv1) + 1


# error_model="numpy": a division by zero gives inf instead of raising (the pixel loop relies on it)
@numba.njit(cache=True, nogil=True, error_model="numpy")
def _draw_rows(pc, faces, chunks, ax, by, far, row0, row1, zbuf, tri):  # type: ignore[no-untyped-def]  # pragma: no cover
    """The triangle loop of :func:`raster_depth`, drawing into the image rows [row0, row1).

    ``chunks``: (K + 1,) face offsets (:func:`_chunks`). The result is that of testing every
    triangle against every pixel of its rows: culling only skips work whose z-test would fail.
    """
    h, w = by.shape[0], ax.shape[0]
    # pixel index of a ray component: ax decreases with u, by with v (uniform steps)
    a0, da = ax[0], ax[1] - ax[0] if w > 1 else -1.0
    b0, db = by[0], by[1] - by[0] if h > 1 else -1.0
    eps = _EPS_X
    cx = np.empty(4)
    cy = np.empty(4)
    cz = np.empty(4)
    nch = chunks.shape[0] - 1
    # per chunk: the nearest depth of its vertices (a lower bound of its hits) and its pixel box
    key = np.full(nch, np.inf)
    box = np.empty((nch, 4), dtype=np.int64)
    cullable = np.zeros(nch, dtype=np.bool_)
    for c in range(nch):
        xmin, xmax = np.inf, -np.inf
        amin, amax, bmin, bmax = np.inf, -np.inf, np.inf, -np.inf
        flat = True  # every plane of the chunk passes far enough from the camera to cull it
        shaped = True  # no face is a sliver in the image (:func:`_well_shaped`)
        for f in range(chunks[c], chunks[c + 1]):
            for j in range(3):
                i = faces[f, j]
                x = pc[i, 0]
                xmin, xmax = min(xmin, x), max(xmax, x)
                if x > eps:
                    a, b = pc[i, 1] / x, pc[i, 2] / x
                    amin, amax = min(amin, a), max(amax, a)
                    bmin, bmax = min(bmin, b), max(bmax, b)
            if flat:
                i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
                ux, uy, uz = pc[i1, 0] - pc[i0, 0], pc[i1, 1] - pc[i0, 1], pc[i1, 2] - pc[i0, 2]
                wx, wy, wz = pc[i2, 0] - pc[i0, 0], pc[i2, 1] - pc[i0, 1], pc[i2, 2] - pc[i0, 2]
                nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
                dist = abs(nx * pc[i0, 0] + ny * pc[i0, 1] + nz * pc[i0, 2])
                flat = dist >= 2.0 * _MIN_PLANE_DIST_M * math.sqrt(nx * nx + ny * ny + nz * nz)
            if shaped:
                i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
                x0, x1, x2 = pc[i0, 0], pc[i1, 0], pc[i2, 0]
                shaped = min(x0, x1, x2) <= eps or _well_shaped(
                    x0, pc[i0, 1], pc[i0, 2], x1, pc[i1, 1], pc[i1, 2], x2, pc[i2, 1], pc[i2, 2]
                )
        cullable[c] = flat
        if xmax <= eps or xmin > far:
            continue  # wholly behind the camera or beyond the range (each triangle is, too)
        if xmin <= eps:  # reaches behind the camera: its projection is unbounded, take the image
            box[c, 0], box[c, 1], box[c, 2], box[c, 3] = 0, w - 1, row0, row1 - 1
            key[c] = eps
            continue
        # (a box holding its triangles' boxes)
        u0, u1, v0, v1 = _pixel_box(amin, amax, bmin, bmax, a0, da, b0, db, w, h, flat and shaped)
        u0, u1, v0, v1 = max(u0, 0), min(u1, w - 1), max(v0, row0), min(v1, row1 - 1)
        if u0 > u1 or v0 > v1:
            continue  # outside the image (every triangle's box lies in the chunk's)
        box[c, 0], box[c, 1], box[c, 2], box[c, 3] = u0, u1, v0, v1
        key[c] = xmin
    th, tw = (h + TILE_V - 1) >> _SHIFT_V, (w + TILE_U - 1) >> _SHIFT_U
    tmax = np.full((th, tw), np.inf)
    dirty = np.zeros((th, tw), dtype=np.bool_)
    for c in range(nch):
        if key[c] == np.inf:
            continue  # culled
        if cullable[c] and _occluded(
            tmax, box[c, 0], box[c, 1], box[c, 2], box[c, 3], key[c] * (1.0 - _CULL_MARGIN)
        ):
            continue
        for f in range(chunks[c], chunks[c + 1]):
            i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
            x0, y0, z0 = pc[i0, 0], pc[i0, 1], pc[i0, 2]
            x1, y1, z1 = pc[i1, 0], pc[i1, 1], pc[i1, 2]
            x2, y2, z2 = pc[i2, 0], pc[i2, 1], pc[i2, 2]
            if x0 <= eps and x1 <= eps and x2 <= eps:
                continue  # wholly behind the camera
            if x0 > far and x1 > far and x2 > far:
                continue  # every point of it is deeper than the range
            nc, amin, amax, bmin, bmax = clipped_box(x0, y0, z0, x1, y1, z1, x2, y2, z2, eps, cx, cy, cz)
            # edge functions r . (p_i x p_j) = e0 + e1 * a + e2 * b, and the plane n . r
            e00, e01, e02 = y0 * z1 - z0 * y1, z0 * x1 - x0 * z1, x0 * y1 - y0 * x1
            e10, e11, e12 = y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2
            e20, e21, e22 = y2 * z0 - z2 * y0, z2 * x0 - x2 * z0, x2 * y0 - y2 * x0
            n0, n1, n2 = e00 + e10 + e20, e01 + e11 + e21, e02 + e12 + e22
            d = n0 * x0 + n1 * y0 + n2 * z0
            if d == 0.0:
                continue  # the plane passes through the camera: seen edge-on, no area
            # seen (almost) edge-on, the edge tests' rounding can pass rays off the projection
            far_plane = abs(d) >= _MIN_PLANE_DIST_M * math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            # columns u with amin <= ax[u] <= amax, within the margin
            # (clamped as floats first: a vertex just in front of the camera projects near infinity)
            tight = far_plane and nc == 3 and _well_shaped(x0, y0, z0, x1, y1, z1, x2, y2, z2)
            u0, u1, v0, v1 = _pixel_box(amin, amax, bmin, bmax, a0, da, b0, db, w, h, tight)
            u0, u1, v0, v1 = max(u0, 0), min(u1, w - 1), max(v0, row0), min(v1, row1 - 1)
            if u0 > u1 or v0 > v1:
                continue
            # occlusion: every hit of the triangle is at least as deep as its nearest (clipped) vertex
            zmin = min(cx[0], cx[1], cx[2]) if nc == 3 else eps
            if zmin > eps and far_plane and _occluded(tmax, u0, u1, v0, v1, zmin * (1.0 - _CULL_MARGIN)):
                continue
            # a ray meets the triangle in front of the camera iff every triple product has the sign of
            # d (their sum is n . r, and the depth d / (n . r) must be positive): flip to ">= 0" tests
            if d < 0.0:
                e00, e01, e02, e10, e11, e12 = -e00, -e01, -e02, -e10, -e11, -e12
                e20, e21, e22 = -e20, -e21, -e22
            for v in range(v0, v1 + 1):
                b = by[v]
                f0 = e00 + e02 * b
                f1 = e10 + e12 * b
                f2 = e20 + e22 * b
                # the columns where each (affine in a) triple product is >= 0, widened by a pixel
                # for rounding; every pixel in the span still gets the exact test below
                lo, hi = u0, u1
                for f_i, e_i in ((f0, e01), (f1, e11), (f2, e21)):
                    if u1 - u0 < _NARROW_PX:
                        break  # a narrow box: testing its pixels costs less than the span's divisions
                    if e_i == 0.0:
                        if f_i < 0.0:
                            hi = -1
                        continue
                    uc = min(max((-f_i / e_i - a0) / da, -2.0), w + 2.0)
                    if e_i > 0.0:  # a >= root: u <= uc (a decreases with u)
                        hi = min(hi, math.ceil(uc) + 1)
                    else:
                        lo = max(lo, math.floor(uc) - 1)
                if lo > hi:
                    continue
                g = n0 + n2 * b
                tv = v >> _SHIFT_V
                for tu in range(lo >> _SHIFT_U, (hi >> _SHIFT_U) + 1):
                    dirty[tv, tu] = True
                # branch-free, so that the span runs on SIMD lanes: a ray in the triangle's plane
                # (n . r = 0) gives an infinite depth, which fails t <= far
                for u in range(lo, hi + 1):
                    a = ax[u]
                    t = d / (g + n1 * a)
                    zb = zbuf[v, u]
                    # nearer than what the pixel holds (drawn in index order: a tie keeps the first)
                    ok = (
                        (f0 + e01 * a >= 0.0)
                        & (f1 + e11 * a >= 0.0)
                        & (f2 + e21 * a >= 0.0)
                        & (t > 0.0)
                        & (t <= far)
                        & (t < zb)
                    )
                    zbuf[v, u] = t if ok else zb
                    tri[v, u] = f if ok else tri[v, u]
        _refresh_tiles(zbuf, tmax, dirty)


@numba.njit(cache=True, nogil=True)
def draw(verts, faces, tri_geom, rot, origin, ax, by, far):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """The vertices in the camera frame and the z-buffer of :func:`raster_depth`: ``(zbuf, tri, pc)``,
    the (H, W) depth of the nearest hit (inf: none), the triangle hit (-1: none) and the (M, 3) vertices.

    ``tri_geom``: (T,) geometry index of each face (chunks never straddle two geometries), or empty.
    """
    h, w = by.shape[0], ax.shape[0]
    m = verts.shape[0]
    pc = np.empty((m, 3))
    for k in range(m):
        dx = verts[k, 0] - origin[0]
        dy = verts[k, 1] - origin[1]
        dz = verts[k, 2] - origin[2]
        for j in range(3):
            pc[k, j] = rot[0, j] * dx + rot[1, j] * dy + rot[2, j] * dz
    zbuf = np.full((h, w), np.inf)
    tri = np.full((h, w), -1, dtype=np.int64)
    _draw_rows(pc, faces, _chunks(tri_geom, faces.shape[0]), ax, by, far, 0, h, zbuf, tri)
    return zbuf, tri, pc


@numba.njit(cache=True, nogil=True)
def triangle_normals(pc, faces):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """(T, 3) float32 unit normal of each triangle of camera-frame vertices ``pc`` (NaN: degenerate)."""
    nt = faces.shape[0]
    tn = np.empty((nt, 3), dtype=np.float32)
    for f in range(nt):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        ux, uy, uz = pc[i1, 0] - pc[i0, 0], pc[i1, 1] - pc[i0, 1], pc[i1, 2] - pc[i0, 2]
        wx, wy, wz = pc[i2, 0] - pc[i0, 0], pc[i2, 1] - pc[i0, 1], pc[i2, 2] - pc[i0, 2]
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        if ln > 0.0:
            tn[f, 0], tn[f, 1], tn[f, 2] = nx / ln, ny / ln, nz / ln
        else:
            tn[f, 0] = tn[f, 1] = tn[f, 2] = np.nan
    return tn


@numba.njit(cache=True, nogil=True)
def raster_depth(verts, faces, tri_geom, keys, rot, origin, ax, by, far, normals, labels=True):  # type: ignore[no-untyped-def]  # pragma: no cover
    """First hit of every pixel ray of a pinhole camera among triangles, by image-space culling.

    The exact geometric answer of casting one ray per pixel (the same as Embree's, up to floating
    point rounding), but each triangle is only tested against the pixels of its projected bounding
    box, so a frame costs about the pixels the triangles cover instead of a BVH walk per pixel.

    Pixel (u, v) has the camera-frame ray ``(1, ax[u], by[v])`` (x forward, y left, z up; see
    :meth:`sim.kinect.Intrinsics.rays`), so its ray parameter is the depth. A ray through the camera
    origin crosses the triangle (p0, p1, p2) iff the three triple products ``ray . (p_i x p_j)``
    share a sign; each is affine in (ax, by), and so is the plane's ``n . ray``, which gives the
    depth ``(n . p0) / (n . ray)``. Triangles partly behind the camera are clipped against the plane
    x = 1e-9 only to bound their pixels; the hit test itself needs no clipping. Where two triangles
    give a pixel the same depth, the lower index wins.

    Args:
        verts: (M, 3) world vertices; faces: (T, 3) vertex indices; tri_geom: (T,) geometry index of
            each triangle; keys: (G, 2) (body, link) of each geometry.
        rot, origin: camera rotation (world <- camera) and position.
        ax, by: (W,) and (H,) ray components of the pixel columns and rows.
        far: hits beyond this depth are misses.
        normals: fill the camera-frame unit normals of the hit triangles (else NaN).
        labels: fill body and link (else they are 1x1 placeholders).

    Returns:
        ``(depth, normals, body, link)``: (H, W) depth (NaN: no hit), (H, W, 3) float32 normals,
        (H, W) body and link (-1: no hit).
    """
    h, w = by.shape[0], ax.shape[0]
    zbuf, tri, pc = draw(verts, faces, tri_geom, rot, origin, ax, by, far)
    tn = triangle_normals(pc, faces if normals else faces[:0])
    depth = np.empty((h, w))
    nrm = np.empty((h, w, 3), dtype=np.float32)
    lh, lw = (h, w) if labels else (1, 1)
    body = np.empty((lh, lw), dtype=np.int64)
    link = np.empty((lh, lw), dtype=np.int64)
    for v in range(h):
        for u in range(w):
            f = tri[v, u]
            if f < 0:
                depth[v, u] = np.nan
                nrm[v, u, 0] = nrm[v, u, 1] = nrm[v, u, 2] = np.nan
                if labels:
                    body[v, u] = link[v, u] = -1
                continue
            depth[v, u] = zbuf[v, u]
            if labels:
                g = tri_geom[f]
                body[v, u] = keys[g, 0]
                link[v, u] = keys[g, 1]
            if normals:
                nrm[v, u, 0], nrm[v, u, 1], nrm[v, u, 2] = tn[f, 0], tn[f, 1], tn[f, 2]
            else:
                nrm[v, u, 0] = nrm[v, u, 1] = nrm[v, u, 2] = np.nan
    return depth, nrm, body, link


# first run after an install or a change here: say why the first frame takes seconds
announce_compilation(sys.modules[__name__], "Kinect raster kernels")
