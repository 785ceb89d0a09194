"""Compiled (numba, cached on disk) kernels of :mod:`sim.kinect_render`'s ray-cast path and HD splat.

The camera's ray buffer for Embree (Open3D's ``RaycastingScene``), Embree's raw hits turned into the
depth, normal, body and link images, and the z-buffer splat of the depth points into the colour camera.
Split from :mod:`sim._kinect_kernels` (the noise and the fused raster capture) along the caster seam:
these kernels read Embree's output or write images, the noise kernels read images or the z-buffer.
Defined at module level (not as closures) so numba can cache them between runs.
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


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


# first run after an install or a change here: say why the first frame takes longer
announce_compilation(sys.modules[__name__], "Kinect ray-cast kernels")
