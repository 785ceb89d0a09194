"""Compiled (numba, cached on disk) per-pixel kernels of :mod:`sim.kinect`: noise, fused raster capture.

The raster (the first hit of every pixel) lives in :mod:`sim._raster_kernels`; :func:`raster_capture`
runs it and the noise in one call. The ray-cast path's kernels and the HD splat live in
:mod:`sim._ray_kernels`.

Kept in their own module so that importing :mod:`sim.kinect` does not import numba, and defined at
module level (not as closures) so numba can cache them between runs. The noise formulas are the same
as the documented pure functions in :mod:`sim.kinect` (the tests compare the two).
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np

from mapping._deps import announce_compilation
from sim._raster_kernels import draw, triangle_normals
from sim.kinect_params import (
    KINECT1_BASELINE_M,
    KINECT1_FOCAL_PX,
    KINECT1_SUBPIXEL,
    NGUYEN2012,
    QUANT_DISPARITY,
    QUANT_MM,
    THETA_MAX,
)

HALF_PI = math.pi / 2
COS_THETA_MAX = math.cos(THETA_MAX)
#: Kinect v1 disparity constant f * b * subpixels (580 px, 7.5 cm, 1/8 px).
K_DISPARITY = KINECT1_FOCAL_PX * KINECT1_BASELINE_M * KINECT1_SUBPIXEL


# Acklam's rational approximation of the standard normal quantile (relative error < 1.15e-9)
_A = (
    -3.969683028665376e01,
    2.209460984245205e02,
    -2.759285104469687e02,
    1.383577518672690e02,
    -3.066479806614716e01,
    2.506628277459239e00,
)
_B = (
    -5.447609879822406e01,
    1.615858368580409e02,
    -1.556989798598866e02,
    6.680131188771972e01,
    -1.328068155288572e01,
)
_C = (
    -7.784894002430293e-03,
    -3.223964580411365e-01,
    -2.400758277161838e00,
    -2.549732539343734e00,
    4.374664141464968e00,
    2.938163982698783e00,
)
_D = (7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e00, 3.754408661907416e00)
_P_LOW = 0.02425


@numba.njit(cache=True, nogil=True, inline="always")
def _normal_quantile(p):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    if p < _P_LOW:
        q = math.sqrt(-2.0 * math.log(p))
        return (((((_C[0] * q + _C[1]) * q + _C[2]) * q + _C[3]) * q + _C[4]) * q + _C[5]) / (
            (((_D[0] * q + _D[1]) * q + _D[2]) * q + _D[3]) * q + 1.0
        )
    if p > 1.0 - _P_LOW:
        q = math.sqrt(-2.0 * math.log(1.0 - p))
        return -(((((_C[0] * q + _C[1]) * q + _C[2]) * q + _C[3]) * q + _C[4]) * q + _C[5]) / (
            (((_D[0] * q + _D[1]) * q + _D[2]) * q + _D[3]) * q + 1.0
        )
    q = p - 0.5
    r = q * q
    return (
        (((((_A[0] * r + _A[1]) * r + _A[2]) * r + _A[3]) * r + _A[4]) * r + _A[5])
        * q
        / (((((_B[0] * r + _B[1]) * r + _B[2]) * r + _B[3]) * r + _B[4]) * r + 1.0)
    )


#: Abramowitz & Stegun 4.4.46: acos(x) = sqrt(1 - x) * sum(a_k x^k) for 0 <= x <= 1, |error| <= 2e-8 rad
_ACOS = (
    1.5707963050,
    -0.2145988016,
    0.0889789874,
    -0.0501743046,
    0.0308918810,
    -0.0170881256,
    0.0066700901,
    -0.0012624911,
)


@numba.njit(cache=True, nogil=True, inline="always")
def _acos01(x):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """acos(x) for 0 <= x <= 1 to 2e-8 rad (A&S 4.4.46), ~5x cheaper than libm's acos."""
    poly = _ACOS[7]
    for k in range(6, -1, -1):
        poly = poly * x + _ACOS[k]
    return math.sqrt(1.0 - x) * poly


@numba.njit(cache=True, nogil=True, inline="always")
def _angle_ratio(normals, ax, by, u, v):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """``theta / (pi/2 - theta)`` at pixel (u, v): the ratio both noise models' angle terms use.

    ``theta`` is the angle between the surface normal and the pixel's viewing ray, held at
    THETA_MAX, and 0 when the normal is unknown (NaN: the surface is taken as facing the camera).
    The acos is A&S 4.4.46 (2e-8 rad), far below anything the noise models resolve.
    """
    a, b = ax[u], by[v]
    c = abs(normals[v, u, 0] + normals[v, u, 1] * a + normals[v, u, 2] * b)
    c /= math.sqrt(1.0 + a * a + b * b)
    if not c == c:
        th = 0.0
    elif c <= COS_THETA_MAX:
        th = THETA_MAX
    else:
        th = min(_acos01(min(c, 1.0)), THETA_MAX)
    return th / (HALF_PI - th)


@numba.njit(cache=True, nogil=True, inline="always")
def _uniform32(k):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """The uniform (k + 0.5) / 2^32 in (0, 1) of a 32-bit integer k."""
    return (float(k) + 0.5) * (1.0 / 4294967296.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _table_offset(p, table):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """The offset o = min{j : p < table[j + J]} (J = len // 2): a rounded normal by its CDF."""
    j0 = table.shape[0] // 2
    i = j0
    if p < table[i]:
        while i > 0 and p < table[i - 1]:
            i -= 1
    else:
        while i < table.shape[0] - 1 and p >= table[i]:
            i += 1
    return i - j0


@numba.njit(cache=True, nogil=True, inline="always")
def _acos01_unrolled(x):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """:func:`_acos01` written out (the same operations in the same order), so loops calling it vectorise."""
    poly = _ACOS[7] * x + _ACOS[6]
    poly = poly * x + _ACOS[5]
    poly = poly * x + _ACOS[4]
    poly = poly * x + _ACOS[3]
    poly = poly * x + _ACOS[2]
    poly = poly * x + _ACOS[1]
    poly = poly * x + _ACOS[0]
    return math.sqrt(1.0 - x) * poly


@numba.njit(cache=True, nogil=True, inline="always")
def _lateral_source(word, u, v, w, h, lat_table, lat_buckets, sigma_l):  # type: ignore[no-untyped-def]  # pragma: no cover
    """The pixel (su, sv) whose depth pixel (u, v) shows under lateral noise, from its 64-bit ``word``.

    ``sigma_l`` is used only without a CDF table (the Kinect v1's per-pixel ``sigma_L``); see :func:`finish`.
    """
    ku = word & np.uint64(0xFFFFFFFF)
    kv = word >> np.uint64(32)
    if lat_table.shape[0] > 0:
        ou = lat_buckets[ku >> np.uint64(16)]
        ov = lat_buckets[kv >> np.uint64(16)]
        su = u + (_table_offset(_uniform32(ku), lat_table) if ou == 127 else ou)
        sv = v + (_table_offset(_uniform32(kv), lat_table) if ov == 127 else ov)
    else:
        su = u + int(np.rint(_normal_quantile(_uniform32(ku)) * sigma_l))
        sv = v + int(np.rint(_normal_quantile(_uniform32(kv)) * sigma_l))
    return min(max(su, 0), w - 1), min(max(sv, 0), h - 1)


@numba.njit(cache=True, nogil=True, inline="always")
def _facing_cos(n0, n1, n2, a, b):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """|cos| of the angle between the normal (n0, n1, n2) and the ray (1, a, b) (NaN: normal unknown)."""
    c = abs(n0 + n1 * a + n2 * b)
    return c / math.sqrt(1.0 + a * a + b * b)


# error_model="numpy": no zero-division checks, so LLVM vectorises the loop (the values are the same)
@numba.njit(cache=True, nogil=True, error_model="numpy")
def _axial_pass(zs, cs, bits, model, quant, out):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Axial noise and quantisation of every pixel, flat: ``out[k]`` from source depth ``zs[k]`` (NaN:
    no return, stays NaN), facing cosine ``cs[k]`` (NaN: unknown normal, angle 0) and the 64-bit word
    ``bits[k]`` (its top 53 bits: the uniform of the axial draw).

    Branch-free so that it runs on SIMD lanes: the normal quantile is Acklam's central branch here;
    :func:`_axial_tails` redoes the pixels whose uniform falls in a tail. The operations are those of
    :func:`_angle_ratio`, the noise models and :func:`_normal_quantile`, in the same order.
    """
    nguyen = model == NGUYEN2012
    for k in range(zs.shape[0]):
        c = cs[k]
        x = min(c, 1.0)
        th = min(_acos01_unrolled(x), THETA_MAX) if c > COS_THETA_MAX else THETA_MAX
        th = th if c == c else 0.0
        q = th / (HALF_PI - th)
        a = q * q
        z = zs[k]
        if nguyen:
            sz = 0.0012 + 0.0019 * (z - 0.4) ** 2 + 0.0001 / math.sqrt(z) * a
        else:
            sz = 1e-3 * (1.5 - 0.5 * z + 0.3 * z * z + 0.1 * (z * math.sqrt(z)) * a)
        p = (float(bits[k] >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
        pc = p - 0.5
        r = pc * pc
        g = (
            (((((_A[0] * r + _A[1]) * r + _A[2]) * r + _A[3]) * r + _A[4]) * r + _A[5])
            * pc
            / (((((_B[0] * r + _B[1]) * r + _B[2]) * r + _B[3]) * r + _B[4]) * r + 1.0)
        )
        out[k] = _quantize(z + g * sz, quant)


@numba.njit(cache=True, nogil=True, inline="always")
def _quantize(z, quant):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    if quant == QUANT_MM:
        return np.rint(z * 1000.0) / 1000.0
    if quant == QUANT_DISPARITY:
        steps = np.rint(K_DISPARITY / z) if z != 0.0 else 0.0
        return K_DISPARITY / steps if steps > 0 else np.nan
    return z


@numba.njit(cache=True, nogil=True)
def _axial_tails(zs, cs, bits, model, quant, out):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """:func:`_axial_pass` for the pixels whose axial uniform lies in a tail of Acklam's quantile
    (about 5 %): the full :func:`_normal_quantile` (a log and a square root) there."""
    nguyen = model == NGUYEN2012
    # 53-bit integers whose uniform is surely central (a margin of 2 for the rounding of + 0.5);
    # the exact test follows, on the uniform itself
    lo = np.uint64(int(_P_LOW * 9007199254740992.0) + 2)
    hi = np.uint64(int((1.0 - _P_LOW) * 9007199254740992.0) - 2)
    for k in range(zs.shape[0]):
        m = bits[k] >> np.uint64(11)
        if lo < m < hi:
            continue
        z = zs[k]
        if not z == z:
            continue
        p = (float(m) + 0.5) * (1.0 / 9007199254740992.0)
        if _P_LOW <= p <= 1.0 - _P_LOW:
            continue
        c = cs[k]
        if not c == c:
            th = 0.0
        elif c <= COS_THETA_MAX:
            th = THETA_MAX
        else:
            th = min(_acos01(min(c, 1.0)), THETA_MAX)
        q = th / (HALF_PI - th)
        a = q * q
        if nguyen:
            sz = 0.0012 + 0.0019 * (z - 0.4) ** 2 + 0.0001 / math.sqrt(z) * a
        else:
            sz = 1e-3 * (1.5 - 0.5 * z + 0.3 * z * z + 0.1 * (z * math.sqrt(z)) * a)
        out[k] = _quantize(z + _normal_quantile(p) * sz, quant)


@numba.njit(cache=True, nogil=True)
def _points(zn, ax, by, zmin, zmax):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """The (H, W, 3) float32 points of :func:`_emit` alone (its ``labels=False`` output), branch-free
    so that each row runs on SIMD lanes: ``z * (1, ax[u], by[v])`` within [zmin, zmax], else NaN."""
    h, w = by.shape[0], ax.shape[0]
    pts = np.empty((h, w, 3), dtype=np.float32)
    for v in range(h):
        b = by[v]
        for u in range(w):
            z = zn[v * w + u]
            ok = (z >= zmin) & (z <= zmax)
            pts[v, u, 0] = z if ok else np.nan
            pts[v, u, 1] = z * ax[u] if ok else np.nan
            pts[v, u, 2] = z * b if ok else np.nan
    return pts


@numba.njit(cache=True, nogil=True)
def _emit(zn, src, body, link, ax, by, zmin, zmax, labels):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Range cut and the organized outputs of :func:`finish` from the flat noisy depth ``zn``."""
    h, w = by.shape[0], ax.shape[0]
    lh, lw = (h, w) if labels else (1, 1)
    z_out = np.empty((lh, lw))
    src_out = np.empty((lh, lw), dtype=np.int64)
    pts = np.empty((h, w, 3), dtype=np.float32)
    body_out = np.empty((lh, lw), dtype=np.int64)
    link_out = np.empty((lh, lw), dtype=np.int64)
    for v in range(h):
        for u in range(w):
            k = v * w + u
            z = zn[k]
            ok = z >= zmin and z <= zmax
            if ok:
                pts[v, u, 0] = z
                pts[v, u, 1] = z * ax[u]
                pts[v, u, 2] = z * by[v]
            else:
                pts[v, u, 0] = pts[v, u, 1] = pts[v, u, 2] = np.nan
            if labels:
                s = src[k]
                src_out[v, u] = s
                sv, su = s // w, s % w
                z_out[v, u] = z if ok else np.nan
                body_out[v, u] = body[sv, su] if ok else -1
                link_out[v, u] = link[sv, su] if ok else -1
    return z_out, src_out, pts, body_out, link_out


@numba.njit(cache=True, nogil=True)
def _gather_image(depth, normals, ax, by, bits, lat_table, lat_buckets, noise, nguyen, labels, zs, cs, src):  # type: ignore[no-untyped-def]  # pragma: no cover
    """The lateral gather of :func:`finish`: per pixel (flat index k) the depth ``zs[k]`` and facing
    cosine ``cs[k]`` at its lateral source pixel, and (``labels``) that pixel's flat index ``src[k]``.

    The table loop is written out by hand: with the quantile branch of :func:`_lateral_source` in the
    same loop (a call to log), it runs several times slower. :func:`raster_capture` repeats it for the
    same reason: the two loops calling one shared inline helper instead made the frame 6.6 -> 8.6 ms
    (`robchair bench sim`, Kinect ms per frame, quiet machine).
    """
    h, w = depth.shape
    if noise and lat_table.shape[0] > 0:
        for v in range(h):
            for u in range(w):
                word = bits[0, v, u]
                ku = word & np.uint64(0xFFFFFFFF)
                kv = word >> np.uint64(32)
                ou = lat_buckets[ku >> np.uint64(16)]
                ov = lat_buckets[kv >> np.uint64(16)]
                su = u + (_table_offset(_uniform32(ku), lat_table) if ou == 127 else ou)
                sv = v + (_table_offset(_uniform32(kv), lat_table) if ov == 127 else ov)
                su = min(max(su, 0), w - 1)
                sv = min(max(sv, 0), h - 1)
                k = v * w + u
                zs[k] = depth[sv, su]
                a, b = ax[su], by[sv]
                c = abs(normals[sv, su, 0] + normals[sv, su, 1] * a + normals[sv, su, 2] * b)
                cs[k] = c / math.sqrt(1.0 + a * a + b * b)
                if labels:
                    src[k] = sv * w + su
        return
    for v in range(h):
        for u in range(w):
            k = v * w + u
            su, sv = u, v
            if noise:
                # (the Kinect v1's sigma_L depends on the angle at this pixel)
                sl = 0.8 + 0.035 * _angle_ratio(normals, ax, by, u, v) if nguyen else 1.6
                su, sv = _lateral_source(bits[0, v, u], u, v, w, h, lat_table, lat_buckets, sl)
                a, b = ax[su], by[sv]
                cs[k] = _facing_cos(normals[sv, su, 0], normals[sv, su, 1], normals[sv, su, 2], a, b)
            zs[k] = depth[sv, su]
            if labels:
                src[k] = sv * w + su


@numba.njit(cache=True, nogil=True)
def finish(
    depth,
    normals,
    body,
    link,
    ax,
    by,
    bits,
    lat_table,
    lat_buckets,
    noise,
    model,
    quant,
    zmin,
    zmax,
    labels=True,
):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Noise, quantisation and range cut; the organized cloud and labels of the result.

    Pixel (u, v) looks along the camera-frame ray ``(1, ax[u], by[v])`` (:meth:`sim.kinect.Intrinsics.rays`);
    a point is ``z`` times its ray.

    Randomness: ``bits`` ((2, h, w) uint64 words of a seeded Generator) per pixel: the two 32-bit
    halves of ``bits[0]`` give the lateral u and v offsets, ``bits[1]`` (53 bits) the axial draw,
    each a uniform in (0, 1) turned into N(0, 1) by the normal quantile (inverse transform
    sampling; Acklam's approximation, relative error < 1.15e-9). A lateral offset is the normal
    draw times ``sigma_L`` rounded to whole pixels; when ``sigma_L`` is constant (the Kinect v2
    model) ``lat_table`` holds the CDF of that rounded offset, ``Phi((j + 0.5) / sigma_L)`` for
    j = -J..J, and the offset is read from it (the same offset the quantile would give, cheaper):
    ``lat_buckets[k >> 16]`` is the offset of every 32-bit ``k`` in that bucket, or 127 for the
    few buckets a CDF step falls in (then the table is searched). An empty table means per-pixel
    ``sigma_L`` (the Kinect v1 model) through the quantile.

    Three passes: the lateral gather (each pixel's source depth and facing cosine), the axial noise
    over the flat image on SIMD lanes (:func:`_axial_pass`, :func:`_axial_tails`), the range cut and
    outputs (:func:`_emit`).

    Returns:
        ``(z, src, points, body, link)``: depth (NaN invalid), flat index of the pixel each value came
        from, float32 points ``z * ray``, and the (body, link) labels of the source pixel (-1 invalid);
        with ``labels=False`` only the points are filled (the others are 1x1 placeholders).
    """
    h, w = depth.shape
    n = h * w
    zs = np.empty(n)
    cs = np.empty(n)
    src = np.empty(n if labels else 1, dtype=np.int64)
    nguyen = model == NGUYEN2012
    _gather_image(depth, normals, ax, by, bits, lat_table, lat_buckets, noise, nguyen, labels, zs, cs, src)
    if noise:
        zn = np.empty(n)
        axial = bits[1].reshape(n)
        _axial_pass(zs, cs, axial, model, quant, zn)
        _axial_tails(zs, cs, axial, model, quant, zn)
    else:
        zn = zs
    return _emit(zn, src, body, link, ax, by, zmin, zmax, labels)


@numba.njit(cache=True, nogil=True)
def raster_capture(  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    verts,
    faces,
    tri_geom,
    rot,
    origin,
    ax,
    by,
    far,
    bits,
    lat_table,
    lat_buckets,
    noise,
    model,
    quant,
    zmin,
    zmax,
):
    """:func:`sim._raster_kernels.raster_depth` then :func:`finish` (``labels=False``), no images between.

    The noisy organized cloud (H, W, 3) float32 of a capture, bit for bit the points of
    ``finish(*raster_depth(...), ...)``, but the lateral gather reads each source pixel's depth from
    the z-buffer and its normal from its triangle, so the depth, normal and label images are never
    written. Only for a constant lateral ``sigma_L`` (a non-empty ``lat_table``: the Kinect v2 models)
    or without noise; the arguments are those of the two kernels.
    """
    h, w = by.shape[0], ax.shape[0]
    n = h * w
    zbuf, tri, pc = draw(verts, faces, tri_geom, rot, origin, ax, by, far)
    zs = np.empty(n)
    if not noise:
        for v in range(h):
            for u in range(w):
                zs[v * w + u] = zbuf[v, u] if tri[v, u] >= 0 else np.nan
        return _points(zs, ax, by, zmin, zmax)
    tn = triangle_normals(pc, faces)
    cs = np.empty(n)
    for v in range(h):
        for u in range(w):
            word = bits[0, v, u]
            ku = word & np.uint64(0xFFFFFFFF)
            kv = word >> np.uint64(32)
            ou = lat_buckets[ku >> np.uint64(16)]
            ov = lat_buckets[kv >> np.uint64(16)]
            su = u + (_table_offset(_uniform32(ku), lat_table) if ou == 127 else ou)
            sv = v + (_table_offset(_uniform32(kv), lat_table) if ov == 127 else ov)
            su = min(max(su, 0), w - 1)
            sv = min(max(sv, 0), h - 1)
            k = v * w + u
            f = tri[sv, su]
            if f < 0:
                zs[k] = cs[k] = np.nan
                continue
            zs[k] = zbuf[sv, su]
            a, b = ax[su], by[sv]
            c = abs(tn[f, 0] + tn[f, 1] * a + tn[f, 2] * b)
            cs[k] = c / math.sqrt(1.0 + a * a + b * b)
    zn = np.empty(n)
    axial = bits[1].reshape(n)
    _axial_pass(zs, cs, axial, model, quant, zn)
    _axial_tails(zs, cs, axial, model, quant, zn)
    return _points(zn, ax, by, zmin, zmax)


@numba.njit(cache=True, nogil=True, inline="always")
def _interp_uniform(x, xp, fp):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """``np.interp(x, xp, fp)`` for increasing ``xp`` (held at the end values outside it)."""
    n = xp.shape[0]
    if x <= xp[0]:
        return fp[0]
    if x >= xp[n - 1]:
        return fp[n - 1]
    lo, hi = 0, n - 1  # xp[lo] <= x < xp[hi]
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if xp[mid] <= x:
            lo = mid
        else:
            hi = mid
    slope = (fp[hi] - fp[lo]) / (xp[hi] - xp[lo])
    return slope * (x - xp[lo]) + fp[lo]


@numba.njit(cache=True, nogil=True)
def sonar_first_echo(
    t_hit,
    gid,
    nrm,
    invalid_id,
    dirs,
    max_range,
    cos_incidence,
    bearing,
    elevation,
    table_m,
    table_left,
    table_right,
):  # type: ignore[no-untyped-def]  # pragma: no cover
    """First echo of each sonar from Embree's raw hits of its beam (see :class:`sim.sonar._Beam`).

    Rays are grouped per sonar (``len(bearing)`` each). A ray echoes when it hit something within
    ``max_range``, the surface faces it (``|normal . dir| >= cos_incidence``) and the hit lies inside
    the beam at that range (ellipse of the tabulated half-apertures). Returns the smallest echoing
    distance per sonar, NaN when none.
    """
    n = bearing.shape[0]
    ns = t_hit.shape[0] // n
    out = np.full(ns, np.nan)
    for s in range(ns):
        best = np.inf
        for i in range(n):
            k = s * n + i
            r = np.float64(t_hit[k])
            if gid[k] == invalid_id or not r <= max_range or not r < best:
                continue
            facing = abs(nrm[k, 0] * dirs[k, 0] + nrm[k, 1] * dirs[k, 1] + nrm[k, 2] * dirs[k, 2])
            if not facing >= cos_incidence:
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


# first run after an install or a change here: say why the first frame takes tens of seconds
announce_compilation(sys.modules[__name__], "Kinect kernels")
