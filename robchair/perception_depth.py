"""Depth-frame geometry for the perception stage: the pixel rays of a camera, fitted to its own frames.

:func:`pinhole_rays` gives :meth:`robchair.perception.Perception` the unit ray of every
``stride``-th pixel, so that pixels without a return can clear free space along their rays
(:func:`no_return_points`).
"""

from __future__ import annotations

import hashlib
import threading
from typing import Any

import numpy as np

#: Fits of :func:`pinhole_rays` by frame content: the perception stage and the recorder each fit the
#: first frame of a camera, the same frame (an HD frame's fit is ~0.3 s of CPU).
_FITS: dict[tuple[Any, ...], np.ndarray | None] = {}
_MAX_FITS = 4
_FITS_LOCK = threading.Lock()


def pinhole_rays(pts: np.ndarray, stride: int) -> np.ndarray | None:
    """Unit rays (H', W', 3) in the camera frame of every ``stride``-th pixel of an organized frame.

    A pinhole model is fitted to the frame's own returns ``pts`` (H, W, 3), camera x forward:
    ``y/x`` linear in the column, ``z/x`` in the row. A frame fitted before in this process (the same
    shape, dtype, ``stride`` and bytes) gives the earlier fit's rays again (read-only) without a new fit.

    Returns:
        The rays; an empty (0, 0, 3) array when the frame does not fit a pinhole (residual over 1 %,
        so no free space comes from its no-return pixels); None when it has under 100 returns to fit.
    """
    data = np.ascontiguousarray(pts)
    key = (data.shape, data.dtype.str, stride, hashlib.sha256(data.data).digest())
    with _FITS_LOCK:  # the two fit the same frame from two threads at once: the second waits for it
        if key in _FITS:
            return _FITS[key]
        rays = _fit_pinhole_rays(data, stride)
        if rays is not None:
            rays.flags.writeable = False
        if len(_FITS) >= _MAX_FITS:
            del _FITS[next(iter(_FITS))]
        _FITS[key] = rays
        return rays


def _fit_pinhole_rays(pts: np.ndarray, stride: int) -> np.ndarray | None:
    """:func:`pinhole_rays` without the memo."""
    h, w = pts.shape[:2]
    x = pts[..., 0]
    ok = np.isfinite(pts).all(axis=2) & (x > 1e-3)
    if ok.sum() < 100:
        return None
    v, u = np.nonzero(ok)
    a, b = pts[v, u, 1] / x[v, u], pts[v, u, 2] / x[v, u]
    cu, cv = np.polyfit(u, a, 1), np.polyfit(v, b, 1)
    if max(np.abs(np.polyval(cu, u) - a).max(), np.abs(np.polyval(cv, v) - b).max()) > 0.01:
        return np.zeros((0, 0, 3))
    uu, vv = np.meshgrid(np.arange(w)[::stride], np.arange(h)[::stride])
    d = np.stack([np.ones(uu.shape), np.polyval(cu, uu), np.polyval(cv, vv)], axis=-1)
    return np.asarray(d / np.linalg.norm(d, axis=-1, keepdims=True))


def no_return_points(
    frame: Any, range_m: float, stride: int, rays_cache: dict[Any, np.ndarray]
) -> np.ndarray | None:
    """Points (M, 3) in the camera frame at depth ``range_m`` along the rays of no-return pixels.

    The pixel rays come from a pinhole model fitted once per (frame_id, H, W) of ``frame`` (a
    :class:`hw.interfaces.DepthFrame`) to the frame's own returns (:func:`pinhole_rays`, kept in
    ``rays_cache``); a frame that does not fit a pinhole (residual over 1 %) gives none. Every
    ``stride``-th pixel each way is used: the free space is built per cell, not per ray.
    """
    pts = np.asarray(frame.points)
    if pts.ndim != 3:
        return None
    h, w = pts.shape[:2]
    key = (frame.frame_id, h, w)
    rays = rays_cache.get(key)
    if rays is None:
        rays = pinhole_rays(pts, stride)
        if rays is None:
            return None
        rays_cache[key] = rays
    if rays.size == 0:
        return None
    nan = ~np.isfinite(pts[::stride, ::stride]).all(axis=2)
    d = rays[nan]
    return np.asarray(d * (range_m / d[:, :1]))  # the range is a depth (x), not a distance
