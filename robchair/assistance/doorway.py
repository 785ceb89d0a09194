"""Doorways ahead of the chair, found in its obstacle points as two jambs with a passable gap.

A doorway seen from in front is a gap in a wall: sweeping the points ahead by bearing, the range jumps
out (the right jamb, then what lies beyond the door, or nothing) and back in (the left jamb). A gap is
a doorway when its width lies between the chair's width plus a margin and about 1.5 m: office doors
are 0.80-0.90 m clear, and accessibility codes ask for at least 0.815 m (ADA Standards for Accessible
Design 2010, 404.2.3; SPEC section 7), so RobChair (0.64 m wide, Table 9.1 of the thesis) keeps about
0.10 m a side in a 0.85 m door.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Doorway:
    """A doorway in some planar frame: its centre (m), unit normal pointing away from the chair, width (m)."""

    cx: float
    cy: float
    nx: float
    ny: float
    width: float

    def transformed(self, x: float, y: float, theta: float) -> Doorway:
        """The same doorway in the parent frame of a frame at ``(x, y, theta)``."""
        c, s = math.cos(theta), math.sin(theta)
        return Doorway(
            x + c * self.cx - s * self.cy, y + s * self.cx + c * self.cy, c * self.nx - s * self.ny,
            s * self.nx + c * self.ny, self.width,
        )  # fmt: skip

    def inverse_transformed(self, x: float, y: float, theta: float) -> Doorway:
        """The same doorway in a frame at ``(x, y, theta)`` of this doorway's frame."""
        c, s = math.cos(theta), math.sin(theta)
        dx, dy = self.cx - x, self.cy - y
        return Doorway(
            c * dx + s * dy,
            -s * dx + c * dy,
            c * self.nx + s * self.ny,
            -s * self.nx + c * self.ny,
            self.width,
        )


@dataclass(frozen=True)
class DoorwayParams:
    """What counts as a doorway (m, rad).

    Attributes:
        min_width_m: narrowest gap (the chair's width plus a margin; 0.64 m + 2 x 0.05 m).
        max_width_m: widest gap still treated as a door (wider is open space).
        max_range_m: jambs farther than this are ignored.
        half_fov_rad: bearings searched either side of straight ahead.
        jump_m: range step that marks a jamb's edge.
        gap_rad: a bearing step without points this large is an opening too (nothing beyond in range).
    """

    min_width_m: float = 0.74
    max_width_m: float = 1.5
    max_range_m: float = 3.5
    half_fov_rad: float = math.radians(75.0)
    jump_m: float = 0.3
    gap_rad: float = math.radians(3.0)


def find_doorways(points: np.ndarray, params: DoorwayParams) -> list[Doorway]:
    """Doorways in obstacle points (N, 2) of ``base_link`` (x forward, y left), nearest first.

    The sweep runs both ways (right to left, and on the points mirrored left to right): a doorway
    seen at an angle shows its near jamb much closer than its far one, and a sweep finds the way
    back in only from the far jamb's side.

    Returns:
        The doorways, in ``base_link``; empty when there is none.
    """
    found = _sweep(points, params)
    for d in _sweep(points * np.array([1.0, -1.0]), params):
        m = Doorway(d.cx, -d.cy, d.nx, -d.ny, d.width)
        if all(math.hypot(m.cx - f.cx, m.cy - f.cy) > 0.2 for f in found):
            found.append(m)
    found.sort(key=lambda d: math.hypot(d.cx, d.cy))
    return found


def _sweep(points: np.ndarray, params: DoorwayParams) -> list[Doorway]:
    """The doorways found sweeping the points by increasing bearing (see :func:`find_doorways`)."""
    if len(points) < 2:
        return []
    r = np.hypot(points[:, 0], points[:, 1])
    b = np.arctan2(points[:, 1], points[:, 0])
    keep = (np.abs(b) <= params.half_fov_rad) & (r > 0.05)
    p, r, b = points[keep], r[keep], b[keep]
    order = np.argsort(b)
    p, r, b = p[order], r[order], b[order]
    if len(p) < 2:
        return []
    dr = np.diff(r)
    db = np.diff(b)
    out_edges = np.flatnonzero((dr > params.jump_m) | (db > params.gap_rad))
    found: list[Doorway] = []
    for i in out_edges:
        if r[i] > params.max_range_m:
            continue
        # the left jamb: the first point after i back near i's range, within the widest door
        cand = np.flatnonzero(
            (r[i + 1 :] < r[i] + params.jump_m) & (np.hypot(*(p[i + 1 :] - p[i]).T) <= params.max_width_m)
        )
        if len(cand) == 0:
            continue
        k = i + 1 + int(cand[0])
        a, c = p[i], p[k]
        width = float(np.hypot(*(c - a)))
        if not params.min_width_m <= width <= params.max_width_m:
            continue
        t = (c - a) / width
        n = np.array([t[1], -t[0]])  # the normal on the far side (a is right of c seen from the chair)
        between = p[i + 1 : k] - a
        if len(between) and np.any(between @ n < 0.05):  # something stands in the gap
            continue
        mid = 0.5 * (a + c)
        if mid @ n < 0:
            n = -n
        found.append(Doorway(float(mid[0]), float(mid[1]), float(n[0]), float(n[1]), width))
    return found
