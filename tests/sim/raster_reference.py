"""The Kinect raster as it was before culling (every triangle drawn in index order, no occlusion test).

Kept only as the reference the culled raster of :mod:`sim._raster_kernels` must equal bit for bit
(tests/sim/test_raster_culling.py). Not cached: compiled once per test session.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(nogil=True)
def _draw_rows(pc, faces, ax, by, far, row0, row1, zbuf, tri):  # type: ignore[no-untyped-def]
    """Every triangle in index order against every pixel of its projected box (the 2026-11 raster)."""
    h, w = by.shape[0], ax.shape[0]
    # pixel index of a ray component: ax decreases with u, by with v (uniform steps)
    a0, da = ax[0], ax[1] - ax[0] if w > 1 else -1.0
    b0, db = by[0], by[1] - by[0] if h > 1 else -1.0
    eps = 1e-9
    cx = np.empty(4)
    cy = np.empty(4)
    cz = np.empty(4)
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        x0, y0, z0 = pc[i0, 0], pc[i0, 1], pc[i0, 2]
        x1, y1, z1 = pc[i1, 0], pc[i1, 1], pc[i1, 2]
        x2, y2, z2 = pc[i2, 0], pc[i2, 1], pc[i2, 2]
        if x0 <= eps and x1 <= eps and x2 <= eps:
            continue  # wholly behind the camera
        if x0 > far and x1 > far and x2 > far:
            continue  # every point of it is deeper than the range
        # clip against x = eps (Sutherland-Hodgman, one plane) to bound the projection
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
        # columns u with amin <= ax[u] <= amax (one pixel of margin for rounding)
        # (clamped as floats first: a vertex just in front of the camera projects near infinity)
        u0 = math.floor(min(max((amax - a0) / da, -2.0), w + 2.0)) - 1
        u1 = math.ceil(min(max((amin - a0) / da, -2.0), w + 2.0)) + 1
        v0 = math.floor(min(max((bmax - b0) / db, -2.0), h + 2.0)) - 1
        v1 = math.ceil(min(max((bmin - b0) / db, -2.0), h + 2.0)) + 1
        u0, u1, v0, v1 = max(u0, 0), min(u1, w - 1), max(v0, row0), min(v1, row1 - 1)
        if u0 > u1 or v0 > v1:
            continue
        # edge functions r . (p_i x p_j) = e0 + e1 * a + e2 * b, and the plane n . r
        e00, e01, e02 = y0 * z1 - z0 * y1, z0 * x1 - x0 * z1, x0 * y1 - y0 * x1
        e10, e11, e12 = y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2
        e20, e21, e22 = y2 * z0 - z2 * y0, z2 * x0 - x2 * z0, x2 * y0 - y2 * x0
        n0, n1, n2 = e00 + e10 + e20, e01 + e11 + e21, e02 + e12 + e22
        d = n0 * x0 + n1 * y0 + n2 * z0
        if d == 0.0:
            continue  # the plane passes through the camera: seen edge-on, no area
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
                if e_i == 0.0:
                    if f_i < 0.0:
                        hi = -1
                    continue
                uc = min(max((-f_i / e_i - a0) / da, -2.0), w + 2.0)
                if e_i > 0.0:  # a >= root: u <= uc (a decreases with u)
                    hi = min(hi, math.ceil(uc) + 1)
                else:
                    lo = max(lo, math.floor(uc) - 1)
            g = n0 + n2 * b
            for u in range(lo, hi + 1):
                a = ax[u]
                if f0 + e01 * a >= 0.0 and f1 + e11 * a >= 0.0 and f2 + e21 * a >= 0.0:
                    den = g + n1 * a
                    if den == 0.0:
                        continue  # the ray runs in the triangle's plane
                    t = d / den
                    if t > 0.0 and t <= far and t < zbuf[v, u]:
                        zbuf[v, u] = t
                        tri[v, u] = f


@numba.njit(nogil=True)
def draw_reference(verts, faces, rot, origin, ax, by, far):  # type: ignore[no-untyped-def]
    """The vertices in the camera frame and the z-buffer of :func:`raster_depth`: ``(zbuf, tri, pc)``,
    the (H, W) depth of the nearest hit (inf: none), the triangle hit (-1: none) and the (M, 3) vertices."""
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
    _draw_rows(pc, faces, ax, by, far, 0, h, zbuf, tri)
    return zbuf, tri, pc
