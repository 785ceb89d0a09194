"""A planar world of wall segments: a laser-like scan and footprint contact, for fast kinematic checks.

The walls are line segments in the ``odom`` plane; :meth:`PlanarWorld.scan` casts rays from a pose
(vectorised ray-segment intersection) and returns the nearest returns as points, the way the chair's
laser sees a room in its height band; :meth:`PlanarWorld.contact` tells whether a rectangle footprint
at a pose overlaps a wall. :func:`doorway` builds a wall with one door, the scene of a doorway passage.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


class PlanarWorld:
    """Wall segments ``(K, 4)`` rows ``x0, y0, x1, y1`` in m."""

    def __init__(self, segments: np.ndarray) -> None:
        self.segments = np.asarray(segments, dtype=float).reshape(-1, 4)
        self._points: np.ndarray | None = None

    def points(self, step: float = 0.01) -> np.ndarray:
        """The walls sampled every ``step`` m, (P, 2) (cached for the first ``step``)."""
        if self._points is None:
            pts = [np.linspace(s[:2], s[2:], max(2, int(math.hypot(s[2] - s[0], s[3] - s[1]) / step) + 1))
                   for s in self.segments]  # fmt: skip
            self._points = np.vstack(pts)
        return self._points

    def scan(
        self, x: float, y: float, theta: float, angles: np.ndarray, max_range: float = 5.6
    ) -> np.ndarray:
        """Returns (M, 2) in ``odom``: rays from ``(x, y)`` at ``theta + angles`` rad, to ``max_range`` m."""
        a = theta + np.asarray(angles, dtype=float)
        d = np.stack([np.cos(a), np.sin(a)], axis=1)  # (R, 2)
        p0, p1 = self.segments[:, :2], self.segments[:, 2:]
        e = p1 - p0  # (K, 2)
        q = p0 - (x, y)  # (K, 2)
        den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (R, K)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (q[None, :, 0] * e[None, :, 1] - q[None, :, 1] * e[None, :, 0]) / den
            u = (q[None, :, 0] * d[:, None, 1] - q[None, :, 1] * d[:, None, 0]) / den
        hit = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
        t = np.where(hit, t, np.inf).min(axis=1)
        ok = t <= max_range
        return np.stack([x + t[ok] * d[ok, 0], y + t[ok] * d[ok, 1]], axis=1)

    def contact(
        self, x: float, y: float, theta: float, centre_x: float, half_depth: float, half_width: float
    ) -> bool:
        """True when the rectangle (``base_link`` footprint, m) at the pose overlaps a wall (1 cm samples)."""
        return self.clearance(x, y, theta, centre_x, half_depth, half_width) <= 0.0

    def clearance(
        self, x: float, y: float, theta: float, centre_x: float, half_depth: float, half_width: float
    ) -> float:
        """Distance (m) from the rectangle footprint at the pose to the nearest wall sample (0 in contact)."""
        p = self.points() - (x, y)
        near = np.einsum("ij,ij->i", p, p) <= (abs(centre_x) + half_depth + half_width + 1.0) ** 2
        p = p[near]
        if len(p) == 0:
            return math.inf
        c, s = math.cos(theta), math.sin(theta)
        bx, by = c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]
        dx = np.maximum(np.abs(bx - centre_x) - half_depth, 0.0)
        dy = np.maximum(np.abs(by) - half_width, 0.0)
        return float(np.sqrt(dx * dx + dy * dy).min())


def from_scene(scene: Any, band: tuple[float, float] = (0.1, 1.632)) -> PlanarWorld:
    """The outlines, in the plane, of a scene's boxes and cylinders that reach into the height band
    ``(z_min, z_max)`` m (a :class:`sim.scene.Scene`; meshes and moving objects are left out)."""
    segs: list[tuple[float, float, float, float]] = []
    for o in scene.objects:
        if o.motion is not None or o.shape not in ("box", "cylinder"):
            continue
        half_h = 0.5 * (o.size[2] if o.shape == "box" else o.length)
        if o.xyz[2] + half_h < band[0] or o.xyz[2] - half_h > band[1]:
            continue
        if o.shape == "box":
            hx, hy = 0.5 * o.size[0], 0.5 * o.size[1]
            corners = np.array([(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)])
        else:
            a = np.linspace(0.0, 2 * math.pi, 13)[:-1]
            corners = o.radius * np.stack([np.cos(a), np.sin(a)], axis=1)
        yaw = o.rpy[2]
        c, s = math.cos(yaw), math.sin(yaw)
        w = corners @ np.array([[c, s], [-s, c]]) + o.xyz[:2]
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
