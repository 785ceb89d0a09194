"""A planar world of wall segments: a laser-like scan and footprint clearance, for fast kinematic checks.

The walls are line segments in the ``odom`` plane; :meth:`PlanarWorld.scan` casts rays from a pose
(vectorised ray-segment intersection over the segments within range) and returns the nearest returns
as points, the way the chair's laser sees a room in its height band; :meth:`PlanarWorld.clearance`
is the exact distance from a rectangle footprint at a pose to the nearest wall (0 when they overlap).
:func:`doorway` builds a wall with one door, the scene of a doorway passage; :func:`from_scene` the
outlines of a scene's solids in the chair's height band.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` (..., 2) to segments ``a``-``b`` (..., 2) (broadcast), m."""
    e = b - a
    ee = np.einsum("...i,...i->...", e, e)
    t = np.clip(np.einsum("...i,...i->...", p - a, e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
    d = p - (a + t[..., None] * e)
    return np.sqrt(np.einsum("...i,...i->...", d, d))


class PlanarWorld:
    """Wall segments ``(K, 4)`` rows ``x0, y0, x1, y1`` in m."""

    def __init__(self, segments: np.ndarray) -> None:
        self.segments = np.asarray(segments, dtype=float).reshape(-1, 4)

    def distance(self, x: float, y: float) -> np.ndarray:
        """Distance (K,) from the point ``(x, y)`` to each segment, m."""
        return _point_segment_distance(np.array([x, y]), self.segments[:, :2], self.segments[:, 2:])

    def scan(
        self, x: float, y: float, theta: float, angles: np.ndarray, max_range: float = 5.6
    ) -> np.ndarray:
        """Returns (M, 2) in ``odom``: rays from ``(x, y)`` at ``theta + angles`` rad, to ``max_range`` m."""
        seg = self.segments[self.distance(x, y) <= max_range]
        a = theta + np.asarray(angles, dtype=float)
        d = np.stack([np.cos(a), np.sin(a)], axis=1)  # (R, 2)
        p0, p1 = seg[:, :2], seg[:, 2:]
        e = p1 - p0  # (K, 2)
        q = p0 - (x, y)  # (K, 2)
        den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (R, K)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (q[None, :, 0] * e[None, :, 1] - q[None, :, 1] * e[None, :, 0]) / den
            u = (q[None, :, 0] * d[:, None, 1] - q[None, :, 1] * d[:, None, 0]) / den
        hit = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
        t = np.where(hit, t, np.inf).min(axis=1) if len(seg) else np.full(len(a), np.inf)
        ok = t <= max_range
        return np.stack([x + t[ok] * d[ok, 0], y + t[ok] * d[ok, 1]], axis=1)

    def contact(
        self, x: float, y: float, theta: float, centre_x: float, half_depth: float, half_width: float
    ) -> bool:
        """True when the rectangle (``base_link`` footprint, m) at the pose touches or overlaps a wall."""
        return self.clearance(x, y, theta, centre_x, half_depth, half_width) <= 0.0

    def clearance(
        self, x: float, y: float, theta: float, centre_x: float, half_depth: float, half_width: float
    ) -> float:
        """Distance (m) from the rectangle footprint at the pose to the nearest wall (0 when they meet).

        The rectangle spans ``[centre_x - half_depth, centre_x + half_depth] x [-half_width, half_width]``
        in ``base_link``. Exact: a segment that crosses the rectangle is at 0; otherwise the distance is
        the smallest of its end points' distances to the rectangle and the rectangle's corners'
        distances to it.
        """
        if len(self.segments) == 0:
            return math.inf
        c, s = math.cos(theta), math.sin(theta)
        rot = np.array([[c, s], [-s, c]])
        a = (self.segments[:, :2] - (x, y)) @ rot.T - (centre_x, 0.0)  # end points in the rectangle's frame
        b = (self.segments[:, 2:] - (x, y)) @ rot.T - (centre_x, 0.0)
        half = np.array([half_depth, half_width])

        def rect(p: np.ndarray) -> np.ndarray:
            q = np.maximum(np.abs(p) - half, 0.0)
            return np.hypot(q[:, 0], q[:, 1])

        corners = np.array([(-1, -1), (1, -1), (1, 1), (-1, 1)], dtype=float) * half
        d_corner = _point_segment_distance(corners[:, None, :], a[None], b[None]).min(axis=0)
        dist = np.minimum(np.minimum(rect(a), rect(b)), d_corner)
        # a segment crossing the rectangle with both ends outside cuts one of its diagonals
        for i, j in ((0, 2), (1, 3)):
            dist = np.where(_crosses(a, b, corners[i], corners[j]), 0.0, dist)
        return float(dist.min())


def _crosses(a: np.ndarray, b: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Whether segments ``a``-``b`` (K, 2) properly cross the segment ``p``-``q``."""

    def side(o: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.asarray((u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1])
                          - (u[..., 1] - o[..., 1]) * (v[..., 0] - o[..., 0]))  # fmt: skip

    d1, d2 = side(p, q, a), side(p, q, b)
    d3, d4 = side(a, b, p), side(a, b, q)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


def _outline(o: Any, band: tuple[float, float]) -> np.ndarray | None:
    """The object's outline (V, 2) in the plane, closed polygon order, or None outside the band."""
    if o.shape == "box":
        half_h = 0.5 * o.size[2]
        if o.xyz[2] + half_h < band[0] or o.xyz[2] - half_h > band[1]:
            return None
        hx, hy = 0.5 * o.size[0], 0.5 * o.size[1]
        corners = np.array([(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)])
    elif o.shape == "cylinder":
        half_h = 0.5 * o.length
        if o.xyz[2] + half_h < band[0] or o.xyz[2] - half_h > band[1]:
            return None
        a = np.linspace(0.0, 2 * math.pi, 13)[:-1]
        corners = o.radius * np.stack([np.cos(a), np.sin(a)], axis=1)
    else:  # a mesh (or another shape): the convex hull of its vertices in the band
        from scipy.spatial import ConvexHull

        v = o.world_mesh().vertices
        v = v[(v[:, 2] >= band[0]) & (v[:, 2] <= band[1])][:, :2]
        if len(v) < 3:
            return None
        return np.asarray(v[ConvexHull(v).vertices])
    yaw = o.rpy[2]
    c, s = math.cos(yaw), math.sin(yaw)
    return np.asarray(corners @ np.array([[c, s], [-s, c]]) + o.xyz[:2])


def from_scene(scene: Any, band: tuple[float, float] = (0.1, 1.632)) -> PlanarWorld:
    """The outlines, in the plane, of a scene's solids that reach into the height band
    ``(z_min, z_max)`` m (a :class:`sim.scene.Scene`): boxes and cylinders exactly, meshes (tables,
    plants, furniture) as the convex hull of their vertices in the band; moving objects are left out."""
    segs: list[tuple[float, float, float, float]] = []
    for o in scene.objects:
        if o.motion is not None:
            continue
        w = _outline(o, band)
        if w is not None:
            segs += [(*w[k], *w[(k + 1) % len(w)]) for k in range(len(w))]
    return PlanarWorld(np.array(segs))


def doorway(width: float, wall_x: float = 0.0, half_length: float = 3.0, room_depth: float = 3.0,
            thickness: float = 0.1) -> PlanarWorld:  # fmt: skip
    """A wall across ``x = wall_x`` (``thickness`` m thick) with a door of ``width`` m centred on ``y = 0``,
    and a back wall ``room_depth`` m beyond it."""
    h = 0.5 * width
    x0, x1 = wall_x, wall_x + thickness
    segs = []
    for sgn in (1.0, -1.0):
        segs += [
            (x0, sgn * h, x0, sgn * half_length),
            (x1, sgn * h, x1, sgn * half_length),
            (x0, sgn * h, x1, sgn * h),  # the jamb's face
        ]
    segs.append((x1 + room_depth, -half_length, x1 + room_depth, half_length))
    return PlanarWorld(np.array(segs))
