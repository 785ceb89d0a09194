"""Compiled (numba, cached on disk) per-pixel kernels of :mod:`sim.kinect`: noise and HD splatting.

Kept in their own module so that importing :mod:`sim.kinect` does not import numba, and defined at
module level (not as closures) so numba can cache them between runs. The noise formulas are the same
as the documented pure functions in :mod:`sim.kinect` (the tests compare the two).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim.kinect import _THETA_MAX, KINECT1_BASELINE_M, KINECT1_FOCAL_PX, KINECT1_SUBPIXEL

#: Noise model codes (``sim.kinect._NOISE_CODES``) and quantisation codes (``_QUANT_CODES``).
NGUYEN2012, FANKHAUSER2015 = 0, 1
QUANT_NONE, QUANT_MM, QUANT_DISPARITY = 0, 1, 2

HALF_PI = math.pi / 2
#: The angle the noise models are held at (``sim.kinect._THETA_MAX``).
THETA_MAX = _THETA_MAX
#: Kinect v1 disparity constant f * b * subpixels (580 px, 7.5 cm, 1/8 px).
K_DISPARITY = KINECT1_FOCAL_PX * KINECT1_BASELINE_M * KINECT1_SUBPIXEL


@numba.njit(cache=True, nogil=True)
def _angles(normals, rays, inv_norm):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Angle (rad) between surface normal and viewing ray per pixel, held at THETA_MAX; 0 if unknown."""
    h, w = inv_norm.shape
    out = np.empty((h, w))
    for v in range(h):
        for u in range(w):
            c = abs(
                normals[v, u, 0] * rays[v, u, 0]
                + normals[v, u, 1] * rays[v, u, 1]
                + normals[v, u, 2] * rays[v, u, 2]
            )
            c *= inv_norm[v, u]
            if not c == c:  # NaN normal (unknown): treat the surface as facing the camera
                out[v, u] = 0.0
                continue
            th = math.acos(min(c, 1.0))
            out[v, u] = th if th < THETA_MAX else THETA_MAX
    return out


@numba.njit(cache=True, nogil=True)
def finish(depth, normals, body, link, rays, inv_norm, rnd, noise, model, quant, zmin, zmax):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Noise, quantisation and range cut in one pass; the organized cloud and labels of the result.

    ``rnd`` holds three standard-normal draws per pixel: lateral u, lateral v, axial.

    Returns:
        ``(z, src, points, body, link)``: depth (NaN invalid), flat index of the pixel each value came
        from, float32 points ``z * ray``, and the (body, link) labels of the source pixel (-1 invalid).
    """
    h, w = depth.shape
    z_out = np.empty((h, w))
    src = np.empty((h, w), dtype=np.int64)
    pts = np.empty((h, w, 3), dtype=np.float32)
    body_out = np.empty((h, w), dtype=np.int64)
    link_out = np.empty((h, w), dtype=np.int64)
    nguyen = model == NGUYEN2012
    # per pixel (once, not once per pixel that samples it): the angle term of the axial model at
    # the surface seen there, and the lateral sigma of the pixel (constant 1.6 px for the v2 model)
    if noise:
        theta = _angles(normals, rays, inv_norm)
        aterm = np.empty((h, w))
        lat = np.empty((h, w)) if nguyen else np.empty((1, 1))
        for v in range(h):
            for u in range(w):
                th = theta[v, u]
                aterm[v, u] = th * th / ((HALF_PI - th) * (HALF_PI - th))
                if nguyen:
                    lat[v, u] = 0.8 + 0.035 * th / (HALF_PI - th)
    else:
        aterm = np.empty((1, 1))
        lat = np.empty((1, 1))
    for v in range(h):
        for u in range(w):
            if noise:
                sl = lat[v, u] if nguyen else 1.6
                su = int(np.rint(u + rnd[0, v, u] * sl))
                sv = int(np.rint(v + rnd[1, v, u] * sl))
                su = min(max(su, 0), w - 1)
                sv = min(max(sv, 0), h - 1)
                z = depth[sv, su]
                if z == z:  # a return at the source pixel (NaN: none, nothing to perturb)
                    a = aterm[sv, su]
                    if nguyen:
                        sz = 0.0012 + 0.0019 * (z - 0.4) ** 2 + 0.0001 / math.sqrt(z) * a
                    else:
                        sz = 1e-3 * (1.5 - 0.5 * z + 0.3 * z * z + 0.1 * (z * math.sqrt(z)) * a)
                    z = z + rnd[2, v, u] * sz
                    if quant == QUANT_MM:
                        z = np.rint(z * 1000.0) / 1000.0
                    elif quant == QUANT_DISPARITY:
                        steps = np.rint(K_DISPARITY / z) if z != 0.0 else 0.0
                        z = K_DISPARITY / steps if steps > 0 else np.nan
            else:
                sv, su = v, u
                z = depth[v, u]
            s = sv * w + su
            src[v, u] = s
            if z >= zmin and z <= zmax:
                z_out[v, u] = z
                for c in range(3):
                    pts[v, u, c] = z * rays[v, u, c]
                body_out[v, u] = body[sv, su]
                link_out[v, u] = link[sv, su]
            else:
                z_out[v, u] = np.nan
                pts[v, u, 0] = pts[v, u, 1] = pts[v, u, 2] = np.nan
                body_out[v, u] = -1
                link_out[v, u] = -1
    return z_out, src, pts, body_out, link_out


@numba.njit(cache=True, nogil=True)
def splat(uc, vc, zc, half_w, width, height):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Z-buffer splat: per colour pixel, the nearest sample whose footprint covers it (index, or -1)."""
    zbuf = np.full(height * width, np.inf)
    src = np.full(height * width, -1, dtype=np.int64)
    for k in range(uc.shape[0]):
        hw = half_w[k]
        u0 = max(math.ceil(uc[k] - hw - 0.5), 0)
        u1 = min(math.floor(uc[k] + hw - 0.5), width - 1)
        v0 = max(math.ceil(vc[k] - hw - 0.5), 0)
        v1 = min(math.floor(vc[k] + hw - 0.5), height - 1)
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                i = v * width + u
                if zc[k] < zbuf[i]:
                    zbuf[i] = zc[k]
                    src[i] = k
    return src


@numba.njit(cache=True, nogil=True)
def camera_ray_buffer(rays, rot, origin, out):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Fill ``out`` ((h*w, 6) float32, Open3D's ray layout) with ``origin`` and the world directions
    ``rot @ ray`` of the (h, w, 3) camera-frame ``rays`` (computed in float64, stored as float32)."""
    h, w = rays.shape[0], rays.shape[1]
    for v in range(h):
        for u in range(w):
            k = v * w + u
            out[k, 0] = origin[0]
            out[k, 1] = origin[1]
            out[k, 2] = origin[2]
            for i in range(3):
                out[k, 3 + i] = (
                    rays[v, u, 0] * rot[i, 0] + rays[v, u, 1] * rot[i, 1] + rays[v, u, 2] * rot[i, 2]
                )
    return out


@numba.njit(cache=True, nogil=True)
def hits_to_image(t_hit, gid, nrm, invalid_id, keys, rot, max_range, h, w, normals):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Raw Embree hits of a camera's rays -> (depth, camera-frame normals, body, link) images.

    A ray misses when it hit no geometry or farther than ``max_range``: NaN depth and normal,
    body and link -1. Normals (float32, world -> camera by ``rot.T``) are NaN everywhere when
    ``normals`` is False. ``keys`` maps a geometry id to its (body, link).
    """
    depth = np.empty((h, w))
    nc = np.empty((h, w, 3), dtype=np.float32)
    body = np.empty((h, w), dtype=np.int64)
    link = np.empty((h, w), dtype=np.int64)
    for v in range(h):
        for u in range(w):
            k = v * w + u
            g = gid[k]
            t = t_hit[k]
            if g == invalid_id or not t <= max_range:
                depth[v, u] = np.nan
                nc[v, u, 0] = nc[v, u, 1] = nc[v, u, 2] = np.nan
                body[v, u] = -1
                link[v, u] = -1
                continue
            depth[v, u] = t
            body[v, u] = keys[g, 0]
            link[v, u] = keys[g, 1]
            if normals:
                for j in range(3):
                    nc[v, u, j] = nrm[k, 0] * rot[0, j] + nrm[k, 1] * rot[1, j] + nrm[k, 2] * rot[2, j]
            else:
                nc[v, u, 0] = nc[v, u, 1] = nc[v, u, 2] = np.nan
    return depth, nc, body, link


@numba.njit(cache=True, nogil=True)
def raster_depth(verts, faces, tri_geom, keys, rot, origin, ax, by, far, normals):  # type: ignore[no-untyped-def]  # pragma: no cover
    """First hit of every pixel ray of a pinhole camera among triangles, by image-space culling.

    The exact geometric answer of casting one ray per pixel (the same as Embree's, up to floating
    point rounding), but each triangle is only tested against the pixels of its projected bounding
    box, so a frame costs about the pixels the triangles cover instead of a BVH walk per pixel.

    Pixel (u, v) has the camera-frame ray ``(1, ax[u], by[v])`` (x forward, y left, z up; see
    :meth:`sim.kinect.Intrinsics.rays`), so its ray parameter is the depth. A ray through the camera
    origin crosses the triangle (p0, p1, p2) iff the three triple products ``ray . (p_i x p_j)``
    share a sign; each is affine in (ax, by), and so is the plane's ``n . ray``, which gives the
    depth ``(n . p0) / (n . ray)``. Triangles partly behind the camera are clipped against the plane
    x = 1e-9 only to bound their pixels; the hit test itself needs no clipping.

    Args:
        verts: (M, 3) world vertices; faces: (T, 3) vertex indices; tri_geom: (T,) geometry index of
            each triangle; keys: (G, 2) (body, link) of each geometry.
        rot, origin: camera rotation (world <- camera) and position.
        ax, by: (W,) and (H,) ray components of the pixel columns and rows.
        far: hits beyond this depth are misses.
        normals: fill the camera-frame unit normals of the hit triangles (else NaN).

    Returns:
        ``(depth, normals, body, link)``: (H, W) depth (NaN: no hit), (H, W, 3) float32 normals,
        (H, W) body and link (-1: no hit).
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
        u0, u1, v0, v1 = max(u0, 0), min(u1, w - 1), max(v0, 0), min(v1, h - 1)
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
        for v in range(v0, v1 + 1):
            b = by[v]
            f0 = e00 + e02 * b
            f1 = e10 + e12 * b
            f2 = e20 + e22 * b
            g = n0 + n2 * b
            for u in range(u0, u1 + 1):
                a = ax[u]
                s0 = f0 + e01 * a
                s1 = f1 + e11 * a
                s2 = f2 + e21 * a
                if (s0 >= 0.0 and s1 >= 0.0 and s2 >= 0.0) or (s0 <= 0.0 and s1 <= 0.0 and s2 <= 0.0):
                    den = g + n1 * a
                    if den == 0.0:
                        continue  # the ray runs in the triangle's plane
                    t = d / den
                    if t > 0.0 and t <= far and t < zbuf[v, u]:
                        zbuf[v, u] = t
                        tri[v, u] = f
    depth = np.empty((h, w))
    nrm = np.empty((h, w, 3), dtype=np.float32)
    body = np.empty((h, w), dtype=np.int64)
    link = np.empty((h, w), dtype=np.int64)
    for v in range(h):
        for u in range(w):
            f = tri[v, u]
            if f < 0:
                depth[v, u] = np.nan
                nrm[v, u, 0] = nrm[v, u, 1] = nrm[v, u, 2] = np.nan
                body[v, u] = link[v, u] = -1
                continue
            depth[v, u] = zbuf[v, u]
            g = tri_geom[f]
            body[v, u] = keys[g, 0]
            link[v, u] = keys[g, 1]
            if normals:
                p0, p1, p2 = faces[f, 0], faces[f, 1], faces[f, 2]
                ux, uy, uz = pc[p1, 0] - pc[p0, 0], pc[p1, 1] - pc[p0, 1], pc[p1, 2] - pc[p0, 2]
                wx, wy, wz = pc[p2, 0] - pc[p0, 0], pc[p2, 1] - pc[p0, 1], pc[p2, 2] - pc[p0, 2]
                nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
                ln = math.sqrt(nx * nx + ny * ny + nz * nz)
                nrm[v, u, 0], nrm[v, u, 1], nrm[v, u, 2] = nx / ln, ny / ln, nz / ln
            else:
                nrm[v, u, 0] = nrm[v, u, 1] = nrm[v, u, 2] = np.nan
    return depth, nrm, body, link
