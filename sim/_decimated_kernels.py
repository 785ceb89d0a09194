"""Compiled (numba, cached on disk) axial noise of a reduced-resolution Kinect's clean cloud.

One pass over the image for :func:`sim.envs.geometry.decimated_depth_noise`: the surface normal by
central differences (:func:`sim.kinect_render.organized_normals`), the angle between it and the
pixel's ray, the model's axial sigma at that depth and angle
(:func:`sim.kinect_models.fankhauser2015_axial_sigma_m`,
:func:`sim.kinect_models.nguyen2012_axial_sigma_m`), the draw and the device's quantisation
(:func:`sim.kinect_models.quantize_depth`): the same formulas as those numpy functions, a few ulp apart
where the kernel saves work (one square root for the normal's angle, ``z * sqrt(z)`` for ``z**1.5``,
no-return pixels skipped), which moves a depth across a rounding edge in well under 0.1 % of the
pixels (the tests compare the two). The angle's acos is the full-resolution path's
(:func:`sim._kinect_kernels._acos01`, A&S 4.4.46, within 2e-8 rad; not evaluated beyond THETA_MAX,
where the angle is held): libm's acos was about a quarter of the pass (405 -> 308 us of CPU for a
128x106 frame). The sigma moves by at most 1e-8 m (at 75 deg and 8 m), so a noisy depth crosses a 1 mm
rounding edge for about one pixel in 10^4 at worst.
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np

from mapping._deps import announce_compilation
from sim._kinect_kernels import COS_THETA_MAX, HALF_PI, K_DISPARITY, _acos01
from sim.kinect_params import NGUYEN2012, QUANT_DISPARITY, QUANT_MM, THETA_MAX


# error_model="numpy": a zero normal (three collinear neighbours) gives NaN, as numpy does, not an error
@numba.njit(cache=True, nogil=True, error_model="numpy")
def axial_noise(p, noise, model, quant):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """``p`` (H, W, 3) float64 clean camera-frame cloud (NaN = no return), ``noise`` (H, W) scaled
    standard normal draws; the noisy, quantised cloud (H, W, 3): each point moved along its own ray.

    ``model``: :data:`sim.kinect_params.NGUYEN2012` or ``FANKHAUSER2015``; ``quant``: ``QUANT_NONE``,
    ``QUANT_MM`` or ``QUANT_DISPARITY``. The normal is undefined (angle 0) on the border and where a
    neighbour has no return.
    """
    h, w = p.shape[0], p.shape[1]
    out = np.empty((h, w, 3))
    for v in range(h):
        for u in range(w):
            x0, x1, x2 = p[v, u, 0], p[v, u, 1], p[v, u, 2]
            if not math.isfinite(x0):  # no return: NaN stays NaN (what the formulas below give)
                out[v, u, 0] = out[v, u, 1] = out[v, u, 2] = np.nan
                continue
            theta = 0.0
            if 0 < u < w - 1 and 0 < v < h - 1:
                a0 = p[v, u + 1, 0] - p[v, u - 1, 0]
                a1 = p[v, u + 1, 1] - p[v, u - 1, 1]
                a2 = p[v, u + 1, 2] - p[v, u - 1, 2]
                b0 = p[v + 1, u, 0] - p[v - 1, u, 0]
                b1 = p[v + 1, u, 1] - p[v - 1, u, 1]
                b2 = p[v + 1, u, 2] - p[v - 1, u, 2]
                n0 = a1 * b2 - a2 * b1
                n1 = a2 * b0 - a0 * b2
                n2 = a0 * b1 - a1 * b0
                # |n . p| / (|n| |p|): the facing flip of the normal does not change the absolute value
                # (one square root and one division: equal to the reference's to a few ulp)
                c = abs(n0 * x0 + n1 * x1 + n2 * x2) / math.sqrt(
                    (n0 * n0 + n1 * n1 + n2 * n2) * (x0 * x0 + x1 * x1 + x2 * x2)
                )
                if math.isfinite(c):  # c >= 0: beyond THETA_MAX the angle is held there, acos or not
                    c = min(c, 1.0)
                    theta = THETA_MAX if c <= COS_THETA_MAX else _acos01(c)
            z = zs = x0
            th = min(max(theta, 0.0), THETA_MAX)
            rest = HALF_PI - th
            term = (th * th) / (rest * rest)
            if model == NGUYEN2012:
                sigma = 0.0012 + 0.0019 * (zs - 0.4) ** 2 + 0.0001 / math.sqrt(zs) * term
            else:  # zs**1.5 as zs * sqrt(zs): no pow call, equal to an ulp
                sigma = 1e-3 * (1.5 - 0.5 * zs + 0.3 * (zs * zs) + 0.1 * (zs * math.sqrt(zs)) * term)
            zn = z + sigma * noise[v, u]
            if quant == QUANT_MM:
                zn = np.rint(zn * 1000.0) / 1000.0
            elif quant == QUANT_DISPARITY:
                steps = np.rint(K_DISPARITY / zn) if zn != 0.0 else math.inf
                zn = K_DISPARITY / steps if steps > 0 else np.nan
            f = zn / z
            out[v, u, 0] = x0 * f
            out[v, u, 1] = x1 * f
            out[v, u, 2] = x2 * f
    return out


announce_compilation(sys.modules[__name__], "Kinect noise kernel")
