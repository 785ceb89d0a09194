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
def _angle(normals, rays, inv_norm, v, u):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    c = abs(
        normals[v, u, 0] * rays[v, u, 0] + normals[v, u, 1] * rays[v, u, 1] + normals[v, u, 2] * rays[v, u, 2]
    )
    c *= inv_norm[v, u]
    if not c == c:  # NaN normal (unknown): treat the surface as facing the camera
        return 0.0
    if c > 1.0:
        c = 1.0
    th = math.acos(c)
    return th if th < THETA_MAX else THETA_MAX


@numba.njit(cache=True)
def finish(depth, normals, rays, inv_norm, rnd, noise, model, quant, zmin, zmax):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Noisy (or clean) depth with the range cut, and the flat index of the pixel each value came from.

    ``rnd`` holds three standard-normal draws per pixel: lateral u, lateral v, axial.
    """
    h, w = depth.shape
    z_out = np.empty((h, w))
    src = np.empty((h, w), dtype=np.int64)
    for v in range(h):
        for u in range(w):
            if noise:
                th = _angle(normals, rays, inv_norm, v, u)
                sl = 0.8 + 0.035 * th / (HALF_PI - th) if model == NGUYEN2012 else 1.6
                su = int(np.rint(u + rnd[0, v, u] * sl))
                sv = int(np.rint(v + rnd[1, v, u] * sl))
                su = min(max(su, 0), w - 1)
                sv = min(max(sv, 0), h - 1)
                z = depth[sv, su]
                ts = _angle(normals, rays, inv_norm, sv, su)
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
                s = sv * w + su
            else:
                z = depth[v, u]
                s = v * w + u
            if not (z >= zmin and z <= zmax):
                z = np.nan
            z_out[v, u] = z
            src[v, u] = s
    return z_out, src


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
