"""A planar world of wall segments: a laser-like scan and footprint contact, for fast kinematic checks.

The walls are line segments in the ``odom`` plane; :meth:`PlanarWorld.scan` casts rays from a pose
(vectorised ray-segment intersection) and returns the nearest returns as points, the way the chair's
laser sees a room in its height band; :meth:`PlanarWorld.contact` tells whether a rectangle footprint
at a pose overlaps a wall. :func:`doorway` builds a wall with one door, the scene of a doorway passage.
"""

from __future__ import annotations

import math

import numpy as np


class PlanarWorld:
    """Wall segments ``(K, 4)`` rows ``x0, y0, x1, y1`` in m."""

    def __init__(self, segments: np.ndarray) -> None:
        self.segments = np.asarray(segments, dtype=float).reshape(-1, 4)

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

    def contact(self, x: float, y: float, theta: float, centre_x: float, half_depth: float, half_width: float,
                step: float = 0.005) -> bool:  # fmt: skip
        """True when the rectangle (``base_link`` footprint, m) at the pose overlaps a wall."""
        pts = [np.linspace(s[:2], s[2:], max(2, int(math.hypot(s[2] - s[0], s[3] - s[1]) / step) + 1))
               for s in self.segments]  # fmt: skip
        p = np.vstack(pts) - (x, y)
        c, s = math.cos(theta), math.sin(theta)
        bx, by = c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]
        return bool(np.any((np.abs(bx - centre_x) <= half_depth) & (np.abs(by) <= half_width)))


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
