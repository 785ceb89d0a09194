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


@numba.njit(cache=True)
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


@numba.njit(cache=True)
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
    theta = _angles(normals, rays, inv_norm) if noise else np.zeros((1, 1))
    for v in range(h):
        for u in range(w):
            if noise:
                th = theta[v, u]
                sl = 0.8 + 0.035 * th / (HALF_PI - th) if model == NGUYEN2012 else 1.6
                su = int(np.rint(u + rnd[0, v, u] * sl))
                sv = int(np.rint(v + rnd[1, v, u] * sl))
                su = min(max(su, 0), w - 1)
                sv = min(max(sv, 0), h - 1)
                z = depth[sv, su]
                ts = theta[sv, su]
                a = ts * ts / ((HALF_PI - ts) * (HALF_PI - ts))
                if model == NGUYEN2012:
                    sz = 0.0012 + 0.0019 * (z - 0.4) ** 2 + 0.0001 / math.sqrt(z) * a
                else:
                    sz = 1e-3 * (1.5 - 0.5 * z + 0.3 * z * z + 0.1 * z**1.5 * a)
                z = z + rnd[2, v, u] * sz
                if quant == QUANT_MM:
                    z = np.rint(z * 1000.0) / 1000.0
                elif quant == QUANT_DISPARITY:
                    steps = np.rint(K_DISPARITY / z)
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


@numba.njit(cache=True)
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
