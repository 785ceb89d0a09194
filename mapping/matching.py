"""Local-to-global map matching: register each new frame against the map before inserting it.

The thesis's conclusion (section 6.2) asks for "a map matching from local to global map" so that the map
is not built from raw odometry alone. A wheelchair moves on a floor, so the correction is planar: x, y
and yaw. :class:`ScanMatcher` keeps the ``map -> odom`` transform (REP-105): wheel odometry stays
``odom -> base_link``; each frame, already placed by odometry, is registered against the map and the
correction is folded into ``map -> odom``.

Method. The frame and the map are both reduced to their occupied 2D cells in a height band above the
floor (the floor constrains only z, roll and pitch, which a planar pose does not have): the frame to the
centroid of its points in each cell, the map to its cell centres. The frame's centroids are registered to
the lines through the map's cells (each cell's normal from its nearest neighbours) by a planar
point-to-line ICP: Gauss-Newton on (x, y, yaw) with Huber weights, nearest neighbours from scipy's
``cKDTree``. Point-to-point ICP (Open3D's ``registration_icp``) on the same cells was measured first and
stopped short of the answer (1.3 deg of a 2 deg offset): the map's cells lie on a 5 cm lattice, and
point-to-point pulls towards the lattice's own offsets, while point-to-line lets the frame slide along
walls. Matching cells rather than raw points makes the cost independent of the camera resolution.

A match is rejected, and odometry kept, when: the frame has too few cells (empty, all NaN, a featureless
floor); its cells lie along one line (a single straight wall fixes only the offset across it); the map
has too few cells near it; the ICP fitness is below ``min_fitness`` or its inlier RMSE above
``max_rmse``; or the correction exceeds the per-frame bounds. Rejections are counted by reason.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.errors import MappingError
from mapping.vhv import VHVMap, as_points


@dataclass(frozen=True)
class MatchParams:
    """Parameters of :class:`ScanMatcher` (metres, radians).

    Attributes:
        band: Height band ``(z_min, z_max)`` of the cells that are matched (above the floor).
        max_correspondence: ICP correspondence distance.
        max_iterations: ICP iterations.
        min_cells: Fewest occupied frame cells (and map cells near them) for a match.
        min_spread_ratio: Smallest ratio of the minor to the major standard deviation of the frame's
            cells; below it they lie along one line and the match is degenerate.
        min_fitness: Smallest fraction of frame cells with a map cell within ``max_correspondence``.
        max_rmse: Largest inlier RMSE.
        max_translation: Largest accepted correction per frame.
        max_rotation: Largest accepted heading correction per frame.
        map_radius: Map cells within this distance of the frame's cells are the target.
        max_source: Most frame cells registered (an even subset beyond it), which bounds the cost.
        max_points: Most frame points reduced to cells (an even subset beyond it): a 512x424 frame has
            ten to a hundred points per 5 cm cell, so a subset gives the same cell centroids cheaper.
    """

    band: tuple[float, float] = (0.15, 1.8)
    max_correspondence: float = 0.3
    max_iterations: int = 60
    min_cells: int = 60
    min_spread_ratio: float = 0.15
    min_fitness: float = 0.6
    max_rmse: float = 0.05
    max_translation: float = 0.2
    max_rotation: float = math.radians(4.0)
    map_radius: float = 0.5
    max_source: int = 800
    max_points: int = 60000

    def __post_init__(self) -> None:
        lo, hi = self.band
        checks = {
            "band": lo < hi,
            "max_correspondence": self.max_correspondence > 0,
            "max_iterations": self.max_iterations >= 1,
            "min_cells": self.min_cells >= 3,
            "min_spread_ratio": 0 <= self.min_spread_ratio <= 1,
            "min_fitness": 0 <= self.min_fitness <= 1,
            "max_rmse": self.max_rmse > 0,
            "max_translation": self.max_translation > 0,
            "max_rotation": self.max_rotation > 0,
            "map_radius": self.map_radius >= 0,
            "max_source": self.max_source >= self.min_cells,
            "max_points": self.max_points >= self.min_cells,
        }
        for name, ok in checks.items():
            if not ok:
                raise MappingError(f"MatchParams.{name}={getattr(self, name)!r} is out of range")


@dataclass(frozen=True)
class MatchResult:
    """Outcome of one frame's registration.

    Attributes:
        accepted: The correction was applied.
        reason: Why it was rejected (``""`` when accepted).
        dx, dy, dyaw: The planar correction found (m, m, rad), in the map frame, applied on the left of
            the frame's pose (zero when ICP did not run).
        fitness: ICP fitness (fraction of frame cells with a correspondence).
        rmse: ICP inlier RMSE, m.
        n_source, n_target: Frame cells and map cells used.
        ms: Wall time of the match, ms.
    """

    accepted: bool
    reason: str
    dx: float = 0.0
    dy: float = 0.0
    dyaw: float = 0.0
    fitness: float = 0.0
    rmse: float = math.nan
    n_source: int = 0
    n_target: int = 0
    ms: float = 0.0


def occupied_cell_centroids(
    points: ArrayLike, cell_size: float, band: tuple[float, float]
) -> NDArray[np.float64]:
    """Mean ``(x, y)`` ``(K, 2)`` of the points in ``band`` of each occupied cell of pitch ``cell_size``.

    Centroids, not cell centres: a frame reduced to cell centres would match the map's lattice best at
    the lattice's own offsets and pull every correction towards them.

    Args:
        points: ``(N, 3)`` or ``(H, W, 3)`` xyz, m.
        cell_size: Cell side, m (the map's).
        band: ``(z_min, z_max)``, m.
    """
    pts = as_points(points)
    return _centroids(pts[_in_band(pts, band), :2].astype(np.float64), cell_size)


def _in_band(pts: NDArray[np.floating], band: tuple[float, float]) -> NDArray[np.bool_]:
    z = pts[:, 2]
    with np.errstate(invalid="ignore"):
        return (z >= band[0]) & (z <= band[1]) & np.isfinite(pts[:, 0]) & np.isfinite(pts[:, 1])


def _centroids(xy: NDArray[np.float64], cell_size: float) -> NDArray[np.float64]:
    if xy.shape[0] == 0:
        return np.empty((0, 2))
    ij = np.floor(xy * (1.0 / cell_size)).astype(np.int64)
    i0, j0 = ij.min(axis=0)
    span = int(ij[:, 1].max() - j0 + 1)
    key = (ij[:, 0] - i0) * span + (ij[:, 1] - j0)
    n = int(key.max()) + 1
    counts = np.bincount(key, minlength=n)
    hit = counts > 0
    sx = np.bincount(key, weights=xy[:, 0], minlength=n)[hit]
    sy = np.bincount(key, weights=xy[:, 1], minlength=n)[hit]
    return np.column_stack([sx, sy]) / counts[hit, None]


def map_cell_centres(
    vhv: VHVMap, band: tuple[float, float], window: tuple[float, float, float, float] | None = None
) -> NDArray[np.float64]:
    """Centres ``(K, 2)`` (world x, y) of the map's cells holding a structure that overlaps ``band``.

    Args:
        vhv: The map.
        band: ``(z_min, z_max)``, m.
        window: ``(x_min, y_min, x_max, y_max)`` world box, m: only cells in it (None: every cell).
    """
    ny = vhv.spec.shape[1]
    keys = vhv.cell_keys
    s = vhv.structures()
    lo, hi = 0, len(keys)
    if window is not None and len(keys):
        # the keys are sorted by i, then j: the window's rows are one slice
        (i0, j0), (i1, j1) = (np.asarray(vhv.spec.world_to_index(u, v), np.int64) for u, v in
                              ((window[0], window[1]), (window[2], window[3])))  # fmt: skip
        lo, hi = np.searchsorted(keys, [int(i0) * ny, (int(i1) + 1) * ny])
    i, j = s.i[lo:hi], s.j[lo:hi]
    hit = (s.top[lo:hi] >= band[0]) & (s.bottom[lo:hi] <= band[1])
    if window is not None and len(keys):
        hit &= (j >= j0) & (j <= j1)
    if not hit.any():
        return np.empty((0, 2))
    key = np.unique(i[hit].astype(np.int64) * ny + j[hit])
    u, v = vhv.spec.index_to_world(key // ny, key % ny)
    return np.column_stack([u, v])


def _se2(dx: float, dy: float, dyaw: float) -> NDArray[np.float64]:
    c, s = math.cos(dyaw), math.sin(dyaw)
    return np.array([[c, -s, 0.0, dx], [s, c, 0.0, dy], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@dataclass
class ScanMatcher:
    """Keeps ``map -> odom`` by registering each frame's occupied cells against the map's.

    Args:
        params: :class:`MatchParams`.

    Attributes:
        t_map_odom: (4, 4) current ``map -> odom`` transform (planar; identity at the start).
        results: Every frame's :class:`MatchResult`, in order.
        rejections: Count of rejected frames by reason.
    """

    params: MatchParams = field(default_factory=MatchParams)
    t_map_odom: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    results: list[MatchResult] = field(default_factory=list)
    rejections: Counter[str] = field(default_factory=Counter)

    def match(self, points_odom: ArrayLike, vhv: VHVMap) -> MatchResult:
        """Register one frame (points in the ``odom`` frame) against the map; update ``t_map_odom``.

        The caller then inserts ``t_map_odom @ points`` into the map (accepted or not).

        Args:
            points_odom: ``(N, 3)`` or ``(H, W, 3)`` xyz in ``odom``, m (NaN rows ignored).
            vhv: The map (world = ``map`` frame).

        Raises:
            MappingError: the points array is malformed.
        """
        t0 = time.perf_counter()
        res = self._match(points_odom, vhv)
        res = MatchResult(**{**res.__dict__, "ms": (time.perf_counter() - t0) * 1e3})
        self.results.append(res)
        if res.accepted:
            self.t_map_odom = _se2(res.dx, res.dy, res.dyaw) @ self.t_map_odom
        else:
            self.rejections[res.reason] += 1
        return res

    def _match(self, points_odom: ArrayLike, vhv: VHVMap) -> MatchResult:
        p = self.params
        cs = vhv.spec.cell_size
        pts = as_points(points_odom)
        if pts.shape[0] > p.max_points:  # an even subset: the cell centroids barely change
            pts = pts[:: math.ceil(pts.shape[0] / p.max_points)]
        # the map -> odom transform is planar: the height band can be cut before it is applied
        xy = pts[_in_band(pts, p.band), :2].astype(np.float64)
        xy = xy @ self.t_map_odom[:2, :2].T + self.t_map_odom[:2, 3]
        src = _centroids(xy, cs)
        if len(src) < p.min_cells:
            return MatchResult(False, "too few frame cells", n_source=len(src))
        sd = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(src.T)), 0.0, None))
        if sd[0] < p.min_spread_ratio * sd[1]:
            return MatchResult(False, "frame cells along one line", n_source=len(src))
        lo, hi = src.min(axis=0) - p.map_radius, src.max(axis=0) + p.map_radius
        tgt = map_cell_centres(vhv, p.band, (lo[0], lo[1], hi[0], hi[1]))
        if len(tgt):
            tgt = tgt[np.all((tgt >= lo) & (tgt <= hi), axis=1)]
        if len(tgt) < p.min_cells:
            return MatchResult(False, "too few map cells", n_source=len(src), n_target=len(tgt))
        if len(src) > p.max_source:  # an even subset of the cells (they come sorted along x, then y)
            src = src[:: math.ceil(len(src) / p.max_source)]
        reg = _point_to_line_icp(src, tgt, p)
        # the correction rotates about the map origin: express it as a planar transform
        dx, dy, dyaw = reg.dx, reg.dy, reg.dyaw
        fit, rmse = reg.fitness, reg.rmse

        def result(accepted: bool, reason: str) -> MatchResult:
            return MatchResult(accepted, reason, dx, dy, dyaw, fit, rmse, len(src), len(tgt))

        if fit < p.min_fitness:
            return result(False, "low fitness")
        if rmse > p.max_rmse:
            return result(False, "high rmse")
        if math.hypot(dx, dy) > p.max_translation or abs(dyaw) > p.max_rotation:
            return result(False, "correction too large")
        return result(True, "")


@dataclass(frozen=True)
class _Icp:
    dx: float
    dy: float
    dyaw: float
    fitness: float
    rmse: float
    min_information: float


def _local_lines(
    tgt: NDArray[np.float64], tree: Any, k: int = 7
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The line through each map cell's k nearest neighbours: their centroid (K, 2) and unit normal (K, 2).

    The centroid, not the cell centre: a wall lying on a cell border fills the cells on both sides, and
    lines through the cell centres would sit half a cell to either side of it; a frame pulled onto one
    of them and inserted there would move the wall by half a cell, frame after frame.
    """
    _, nn = tree.query(tgt, k=min(k, len(tgt)))
    mean = tgt[nn].mean(axis=1)
    nb = tgt[nn] - mean[:, None, :]
    cov = np.einsum("kni,knj->kij", nb, nb)
    _, vec = np.linalg.eigh(cov)
    return mean, vec[:, :, 0]


def _point_to_line_icp(src: NDArray[np.float64], tgt: NDArray[np.float64], p: MatchParams) -> _Icp:
    """Planar point-to-line ICP (Gauss-Newton on x, y, yaw) of ``src`` onto the lines through ``tgt``."""
    from scipy.spatial import cKDTree

    tree = cKDTree(tgt)
    anchors, normals = _local_lines(tgt, tree)
    x = np.zeros(3)
    info = np.zeros((3, 3))
    inl = np.zeros(len(src), bool)
    res = np.zeros(len(src))
    # coarse to fine: wide correspondences first to capture the offset, then narrow ones to refine it
    half = p.max_iterations // 2
    fine = False
    for it in range(p.max_iterations):
        fine = fine or it >= half
        reach = p.max_correspondence * (0.4 if fine else 1.0)
        c, s_ = math.cos(x[2]), math.sin(x[2])
        moved = src @ np.array([[c, s_], [-s_, c]]) + x[:2]
        dist, idx = tree.query(moved, distance_upper_bound=reach)
        inl = np.isfinite(dist)
        if inl.sum() < 3:
            break
        n = normals[idx[inl]]
        q = anchors[idx[inl]]
        m = moved[inl]
        res = np.einsum("ki,ki->k", n, m - q)
        # d(moved)/d(yaw) = perpendicular of the rotated source point (before translation)
        rot = m - x[:2]
        jac = np.column_stack([n[:, 0], n[:, 1], n[:, 1] * rot[:, 0] - n[:, 0] * rot[:, 1]])
        w = 1.0 / np.maximum(1.0, np.abs(res) / 0.02)  # Huber weights beyond 2 cm
        info = jac.T @ (jac * w[:, None])
        try:
            step = np.linalg.solve(info, -(jac.T @ (w * res)))
        except np.linalg.LinAlgError:  # singular: the least-squares step
            step = np.linalg.lstsq(info, -(jac.T @ (w * res)), rcond=None)[0]
        x += step
        if np.hypot(step[0], step[1]) < 1e-4 and abs(step[2]) < 1e-5:
            if fine:
                break
            fine = True
    rmse = float(np.sqrt(np.mean(res**2))) if inl.any() else math.nan
    min_info = float(np.linalg.eigvalsh(info)[0] / max(len(src), 1)) if inl.any() else 0.0
    return _Icp(float(x[0]), float(x[1]), float(x[2]), float(inl.mean()), rmse, min_info)
