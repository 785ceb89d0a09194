"""Compiled sonar arc of one array reading (:func:`robchair.perception_sonar.explained_arc_fast`).

The arc of a fusion, clipped to the known surfaces that explain its echo, and its distance ahead
in the corridor: ~40 small numpy calls per reading in :mod:`robchair.perception_sonar`, one compiled
call here. Every value is computed with the operations the numpy path applies, in its order (IEEE
float64, no fused multiply-add: numba contracts nothing without ``fastmath``), and the functions
``cos``, ``sin``, ``atan2`` and ``hypot`` come from the C library numpy calls for them on float64
(``np.angle(np.exp(1j * x))`` is ``atan2(sin x, cos x)``): a test drives this and the numpy path
side by side and asks for the same bits. ``near_range`` is the compiled pre-filter of the numpy path.
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np

from mapping._deps import announce_compilation


@numba.njit(cache=True, nogil=True)
def near_range(xy, r00, r01, r10, r11, tx, ty, d, band):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """Indices (ascending, int64) of the points ``xy`` (M, 2) whose ``R p + t`` is within ``band`` of ``d``
    from the origin (``R = [[r00, r01], [r10, r11]]``, ``t = (tx, ty)``): ``| |R p + t| - d | <= band``."""
    n = xy.shape[0]
    out = np.empty(n, np.int64)
    m = 0
    lo = d - band
    hi = d + band
    lo2 = lo * lo if lo > 0.0 else 0.0
    hi2 = hi * hi
    for k in range(n):
        x = np.float64(xy[k, 0])
        y = np.float64(xy[k, 1])
        u = r00 * x + r01 * y + tx
        v = r10 * x + r11 * y + ty
        r2 = u * u + v * v
        if r2 <= hi2 and r2 >= lo2:
            out[m] = k
            m += 1
    return out[:m].copy()


@numba.njit(cache=True, nogil=True)
def _wrapped(x):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    # np.angle(np.exp(1j * x)): exp(+-0 + i x) = cos x + i sin x, its angle atan2(sin x, cos x)
    return math.atan2(math.sin(x), math.cos(x))


@numba.njit(cache=True, nogil=True)
def sonar_arc(prm, n_arc, scan, zoom):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """The explained arc (N, 2) in ``base_link`` and the smallest x of it inside the corridor (NaN: none).

    ``prm`` (20,) float64: ``alpha, theta, dist, x0, y0, yaw0, ox, oy, px, py, c, s, c0, s0, dzx, dzy,
    tol, front_x, half_width, beside`` (one array: a numba call types each argument). ``alpha``,
    ``theta`` deg, ``dist`` m: the fusion; ``(x0, y0)``, ``yaw0``: the array's origin and
    heading; ``(ox, oy)``: the sonar origin of the explanation (the mount's xy). ``scan`` (M, 2): laser
    returns in ``odom`` with ``(px, py)``, ``(c, s)`` the pose's position and heading's cos/sin;
    ``zoom`` (K, 2): cells in ``base_link`` at the zoom's pose (``(c0, s0)`` its heading, ``(dzx, dzy)``
    its position less the pose's); empty arrays for none. ``front_x``, ``half_width``, ``beside``: the
    corridor (:class:`robchair.perception_queries.Corridor`).
    """
    alpha, theta, dist, x0, y0, yaw0, ox, oy = prm[0], prm[1], prm[2], prm[3], prm[4], prm[5], prm[6], prm[7]
    px, py, c, s, c0, s0, dzx, dzy = prm[8], prm[9], prm[10], prm[11], prm[12], prm[13], prm[14], prm[15]
    tol, front_x, half_width, beside = prm[16], prm[17], prm[18], prm[19]
    # np.linspace(alpha, alpha + theta, n_arc) as linspace computes it, then radians + yaw0
    stop = alpha + theta
    div = n_arc - 1
    deg = np.empty(n_arc)
    for i in range(n_arc):
        deg[i] = float(i)
    if div > 0:
        delta = stop - alpha
        step = delta / div
        for i in range(n_arc):
            deg[i] = (deg[i] / div) * delta if step == 0 else deg[i] * step
    else:
        for i in range(n_arc):
            deg[i] = deg[i] * (stop - alpha)
    for i in range(n_arc):
        deg[i] = deg[i] + alpha
    if n_arc > 1:
        deg[n_arc - 1] = stop
    arc = np.empty((n_arc, 2))
    for i in range(n_arc):
        b = math.radians(deg[i]) + yaw0
        arc[i, 0] = dist * math.cos(b) + x0
        arc[i, 1] = dist * math.sin(b) + y0
    out = arc
    if n_arc >= 2 and (scan.shape[0] + zoom.shape[0]) > 0:
        d = math.hypot(arc[0, 0] - ox, arc[0, 1] - oy)
        mid = math.atan2(arc[n_arc // 2, 1] - oy, arc[n_arc // 2, 0] - ox)
        rmin = np.inf
        rmax = -np.inf
        for i in range(n_arc):
            r = _wrapped(math.atan2(arc[i, 1] - oy, arc[i, 0] - ox) - mid)
            rmin = min(rmin, r)
            rmax = max(rmax, r)
        kept = np.empty((scan.shape[0] + zoom.shape[0], 2))
        m = 0
        for k in range(scan.shape[0] + zoom.shape[0]):
            if k < scan.shape[0]:  # odom -> base_link at the pose
                qx = scan[k, 0] - px
                qy = scan[k, 1] - py
            else:  # base_link at the zoom's pose -> odom, less the pose
                zx = zoom[k - scan.shape[0], 0]
                zy = zoom[k - scan.shape[0], 1]
                qx = c0 * zx - s0 * zy + dzx
                qy = s0 * zx + c0 * zy + dzy
            kx = c * qx + s * qy
            ky = c * qy - s * qx
            ux = kx - ox
            uy = ky - oy
            if not abs(math.hypot(ux, uy) - d) <= tol:
                continue
            qb = _wrapped(math.atan2(uy, ux) - mid)
            if qb >= rmin and qb <= rmax:
                kept[m, 0] = kx
                kept[m, 1] = ky
                m += 1
        if m > 0:
            out = kept[:m].copy()
    x_min = np.nan
    for i in range(out.shape[0]):
        x = out[i, 0]
        ay = abs(out[i, 1])
        if (ay <= half_width and x > front_x) or (ay <= beside and x > 0.0):
            if not x_min <= x:  # NaN at first
                x_min = x
    return out, x_min


# first run after an install or a change here: say what is being compiled
announce_compilation(sys.modules[__name__], "sonar arc kernels")
