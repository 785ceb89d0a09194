"""The convex hull of points in the plane, in numpy alone.

A scenario's load checks its waypoints against the footprints of the scene's objects; computing those
hulls with ``scipy.spatial.ConvexHull`` made every ``robchair sim`` / ``robchair run`` process import
``scipy.spatial`` (about 0.3 s of CPU, a tenth of a short run), for a few hulls of a few hundred points.
Andrew's monotone chain gives the same hull in O(n log n).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def convex_hull_2d(points: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Indices into ``points`` (N, 2) of the convex hull's corners, counter-clockwise.

    Points on an edge between two corners (collinear) and repeated points are not corners. The hull
    starts at the corner of least x (least y among those).

    Returns:
        (K,) int64 indices; K < 3 when the points have no area (fewer than three distinct points, or all
        on one line): then the hull is not a polygon.

    Raises:
        ValueError: ``points`` is not (N, 2) or holds a non-finite value.
    """
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"points must be (N, 2), got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("points must be finite")
    order = np.lexsort((p[:, 1], p[:, 0]))
    xs, ys = p[order, 0].tolist(), p[order, 1].tolist()

    def chain(idx: range) -> list[int]:
        out: list[int] = []
        for k in idx:
            while len(out) >= 2:
                a, b = out[-2], out[-1]
                cross = (xs[b] - xs[a]) * (ys[k] - ys[a]) - (ys[b] - ys[a]) * (xs[k] - xs[a])
                if cross > 0.0:  # a left turn: b stays a corner
                    break
                out.pop()
            out.append(k)
        return out

    n = len(xs)
    lower = chain(range(n))
    upper = chain(range(n - 1, -1, -1))
    corners = lower[:-1] + upper[:-1]
    return np.asarray(order[corners], dtype=np.int64)


def inside_by(
    points: npt.ArrayLike, hull: npt.NDArray[np.int64], query: npt.ArrayLike, margin: float
) -> bool:
    """True when ``query`` (2,) lies inside the polygon ``points[hull]`` (CCW, from
    :func:`convex_hull_2d`) by more than ``margin`` (m) from every edge line; False for a hull of
    fewer than three corners."""
    if len(hull) < 3:
        return False
    c = np.asarray(points, dtype=float)[hull]
    e = np.roll(c, -1, axis=0) - c
    inward = np.stack([-e[:, 1], e[:, 0]], axis=1) / np.linalg.norm(e, axis=1, keepdims=True)
    depth = np.einsum("ij,ij->i", inward, np.asarray(query, dtype=float) - c)
    return bool(np.all(depth > margin))
