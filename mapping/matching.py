"""Local-to-global map matching: register each new frame against the map before inserting it.

The thesis's conclusion (section 6.2) asks for "a map matching from local to global map" so that the map
is not built from raw odometry alone. A wheelchair moves on a floor, so the correction is planar: x, y
and yaw. :class:`ScanMatcher` keeps the ``map -> odom`` transform (REP-105): wheel odometry stays
``odom -> base_link``; each frame, already placed by odometry, is registered against the map and the
correction is folded into ``map -> odom``.

Method. The frame and the map are both reduced to their occupied 2D cells in a height band above the
floor (the floor constrains only z, roll and pitch, which a planar pose does not have): the frame to the
centroid of its points in each cell, the map to its cell centres. The frame's centroids are registered to
the lines through the map's cells (each cell's line fitted to the occupied cells of the 5 x 5 block around
it) by a planar point-to-line ICP: Gauss-Newton on (x, y, yaw) about the frame's centroid, Huber weights.
Point-to-point ICP (Open3D's ``registration_icp``) on the same cells was measured first and stopped short
of the answer (1.3 deg of a 2 deg offset): the map's cells lie on a 5 cm lattice, and point-to-point pulls
towards the lattice's own offsets, while point-to-line lets the frame slide along walls. Matching cells
rather than raw points makes the cost independent of the camera resolution.

Correspondences. The map cells near the frame are rastered once per frame and scipy's exact Euclidean
distance transform (``ndimage.distance_transform_edt`` with ``return_indices``) gives every raster cell
its nearest map cell, so a correspondence is an array look-up; the iterations are compiled (numba).
Measured on a 512x424 synthetic room frame, CPU time of one match on one core (median): nearest
neighbours from scipy's ``cKDTree`` queried every iteration and numpy iterations 35 ms; the distance
transform with numpy iterations 15.5 ms; the distance transform with compiled iterations 4.1 ms (the
raster and transform about 0.8 ms of it). The map changes with every inserted frame, so the raster is
rebuilt per frame; it covers only the frame's cells plus ``map_radius``.

Weighting. Each accepted match is a measurement of the ``map -> odom`` error with a standard deviation
from the geometry (:attr:`MatchResult.sd`): the 5 cm lattice's error, spread by the inverse of the ICP's
information matrix per inlier. A scalar Kalman filter per axis (translation, heading about the frame's
centroid) weighs it against the error's own growth (``drift_sd`` a frame): a frame that sees only a few
small objects far away, whose heading is poorly fixed, moves the heading little, and the noise of
consecutive matches averages out instead of adding up.

A match is rejected, and odometry kept, when: the frame has too few cells (empty, all NaN, a featureless
floor); its cells lie along one line (a single straight wall fixes only the offset across it); the map
has too few cells near it; the ICP fitness is below ``min_fitness`` or its inlier RMSE above
``max_rmse``; the geometry is degenerate (parallel walls of a corridor: the smallest eigenvalue of the
translation part of the information matrix below ``min_information``); or the correction exceeds the
per-frame bounds (an outlier). Rejections are counted by reason.
"""

from __future__ import annotations

import math
import sys
import time
from collections import Counter
from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping._deps import announce_compilation
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
        min_information: Smallest eigenvalue of the translation part of the ICP's information matrix per
            inlier (unit normals: 0.5 when the walls face every way, 0 along a corridor, whose parallel
            walls fix the offset across it and nothing along it); below it the match is degenerate.
        max_translation: Largest accepted correction per frame (larger ones are rejected as outliers).
        max_rotation: Largest accepted heading correction per frame.
        match_sd: Standard deviations ``(m, rad)`` of one accepted match's translation and heading: its
            error on a 5 cm lattice (frame cells' centroids against map cells), not the ICP's own
            fit, which is far smaller.
        drift_sd: Standard deviations ``(m, rad)`` that the odometry's error may grow by from one frame
            to the next (when the caller gives no odometry pose).
        drift_step: Odometry motion ``(m, rad)`` that ``drift_sd`` belongs to, when the caller gives the
            odometry pose: the error's variance grows with the larger of the distance and the turn since
            the last frame over these (a chair standing still adds none, so matching the same view over
            and over cannot walk the map away).
        initial_sd: Standard deviations ``(m, rad)`` of ``map -> odom`` before the first match: infinite
            (the default) when nothing is known, so the first accepted match is applied in full; zero when
            the map is defined by the odometry's start (a run that builds its map from its first frame),
            so the corrections follow the odometry's error as it grows.
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
    min_information: float = 0.05
    max_translation: float = 0.2
    max_rotation: float = math.radians(4.0)
    match_sd: tuple[float, float] = (0.01, math.radians(0.25))
    drift_sd: tuple[float, float] = (0.002, math.radians(0.05))
    drift_step: tuple[float, float] = (0.02, math.radians(1.0))
    initial_sd: tuple[float, float] = (math.inf, math.inf)
    map_radius: float = 0.5
    max_source: int = 800
    max_points: int = 20000
    tolerance: float = 5e-4

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
            "min_information": 0 <= self.min_information <= 0.5,
            "max_translation": self.max_translation > 0,
            "max_rotation": self.max_rotation > 0,
            "map_radius": self.map_radius >= 0,
            "match_sd": min(self.match_sd) > 0,
            "drift_sd": min(self.drift_sd) >= 0,
            "drift_step": min(self.drift_step) > 0,
            "initial_sd": min(self.initial_sd) >= 0,
            "max_source": self.max_source >= self.min_cells,
            "max_points": self.max_points >= self.min_cells,
            "tolerance": self.tolerance > 0,
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
        pivot: World ``(x, y)`` of the frame cells' centroid, m, about which ``sd`` is given.
        sd: Standard deviations of the correction's translation (its worse axis) and heading about
            ``pivot`` (m, rad): ``match_sd``'s lattice error spread by the geometry (the inverse of the
            ICP's information matrix per inlier); a heading fixed by a small cluster of objects far away
            gets a large one.
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
    pivot: tuple[float, float] = (0.0, 0.0)
    sd: tuple[float, float] = (math.inf, math.inf)


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
    band_cell_keys = getattr(vhv, "band_cell_keys", None)
    if window is not None and band_cell_keys is not None:
        # a probabilistic map reads the window's cells only (the same cells, without its occupied view)
        (i0, j0), (i1, j1) = (np.asarray(vhv.spec.world_to_index(u, v), np.int64) for u, v in
                              ((window[0], window[1]), (window[2], window[3])))  # fmt: skip
        key = band_cell_keys(band, (int(i0), int(i1)), (int(j0), int(j1)))
        if key.shape[0] == 0:
            return np.empty((0, 2))
        u, v = vhv.spec.index_to_world(key // ny, key % ny)
        return np.column_stack([u, v])
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
    _var: NDArray[np.float64] = field(default_factory=lambda: np.full(2, np.nan), repr=False)

    _last_pose: NDArray[np.float64] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self._var = np.square(np.asarray(self.params.initial_sd, np.float64))

    def match(self, points_odom: ArrayLike, vhv: VHVMap, odom_pose: ArrayLike | None = None) -> MatchResult:
        """Register one frame (points in the ``odom`` frame) against the map; update ``t_map_odom``.

        The caller then inserts ``t_map_odom @ points`` into the map (accepted or not).

        Args:
            points_odom: ``(N, 3)`` or ``(H, W, 3)`` xyz in ``odom``, m (NaN rows ignored).
            vhv: The map (world = ``map`` frame).
            odom_pose: (4, 4) pose of the sensor (or base) in ``odom``: the error's growth then follows
                the motion since the previous frame (``drift_step``); None: ``drift_sd`` every frame.

        Raises:
            MappingError: the points array is malformed.
        """
        t0 = time.perf_counter()
        res = self._match(points_odom, vhv)
        res = MatchResult(**{**res.__dict__, "ms": (time.perf_counter() - t0) * 1e3})
        self.results.append(res)
        # the map -> odom error is a random walk between matches: its variance grows by drift_sd^2 a frame
        self._var = self._var + np.square(self.params.drift_sd) * self._motion(odom_pose)
        if res.accepted:
            # each accepted match measures it (translation and heading about the pivot): a scalar Kalman
            # update per axis, so a match whose geometry fixes the heading poorly moves it little
            r = np.maximum(np.square(res.sd), np.square(self.params.match_sd))
            finite = np.isfinite(self._var)
            with np.errstate(invalid="ignore"):
                gain = np.where(finite, self._var / (self._var + r), 1.0)
                self._var = np.where(finite, self._var * (1.0 - gain), r)
            # the correction about the pivot: translation t = d - (I - R) c, scaled, back about the origin
            c = np.asarray(res.pivot)
            rot = _se2(0.0, 0.0, res.dyaw)[:2, :2]
            t = np.array([res.dx, res.dy]) - (c - rot @ c)
            yaw = float(gain[1]) * res.dyaw
            rot = _se2(0.0, 0.0, yaw)[:2, :2]
            d = float(gain[0]) * t + (c - rot @ c)
            self.t_map_odom = _se2(float(d[0]), float(d[1]), yaw) @ self.t_map_odom
        else:
            self.rejections[res.reason] += 1
        return res

    def _motion(self, odom_pose: ArrayLike | None) -> float:
        """Odometry motion since the previous frame in units of ``drift_step`` (1 without a pose)."""
        if odom_pose is None:
            return 1.0
        t = np.asarray(odom_pose, np.float64)
        if t.shape != (4, 4) or not np.isfinite(t).all():
            raise MappingError(
                f"ScanMatcher.match odom_pose: expected a finite (4, 4) transform, got {t.shape}"
            )
        last, self._last_pose = self._last_pose, t
        if last is None:
            return 0.0
        d = math.hypot(*(t[:2, 3] - last[:2, 3]))
        turn = abs(
            math.remainder(math.atan2(t[1, 0], t[0, 0]) - math.atan2(last[1, 0], last[0, 0]), math.tau)
        )
        return max(d / self.params.drift_step[0], turn / self.params.drift_step[1])

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
        reg = _point_to_line_icp(src, tgt, p, cs)
        # the correction rotates about the map origin: express it as a planar transform
        dx, dy, dyaw = reg.dx, reg.dy, reg.dyaw
        fit, rmse = reg.fitness, reg.rmse

        def result(accepted: bool, reason: str) -> MatchResult:
            return MatchResult(accepted, reason, dx, dy, dyaw, fit, rmse, len(src), len(tgt), 0.0,
                               reg.pivot, reg.sd)  # fmt: skip

        if fit < p.min_fitness:
            return result(False, "low fitness")
        if rmse > p.max_rmse:
            return result(False, "high rmse")
        if reg.min_information < p.min_information:
            return result(False, "degenerate geometry")
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
    iterations: int
    pivot: tuple[float, float]
    sd: tuple[float, float]


@dataclass(frozen=True)
class _LineField:
    """The map cells near a frame as a raster: for every raster cell, the line through its nearest map cell.

    Attributes:
        origin: World ``(x, y)`` of raster cell ``(0, 0)``'s centre, m.
        cell_size: Raster pitch (the map's), m.
        near: ``(H, W)`` flat index of each cell's nearest map cell (a Euclidean distance transform).
        anchor: ``(H * W, 2)`` world point of the line through each map cell (its neighbours' centroid), m.
        normal: ``(H * W, 2)`` unit normal of that line.
    """

    origin: NDArray[np.float64]
    cell_size: float
    near: NDArray[np.intp]
    anchor: NDArray[np.float64]
    normal: NDArray[np.float64]

    @classmethod
    def build(cls, tgt: NDArray[np.float64], cell_size: float, margin: float, window: int = 5) -> _LineField:
        """Raster ``tgt`` (map cell centres, ``(K, 2)``), its distance transform and local lines.

        The line of a map cell is fitted to the occupied cells in the ``window`` x ``window`` block around
        it (their centroid and the minor axis of their scatter), only at the map cells (compiled).
        The centroid, not the cell centre: a wall lying on a cell border fills the cells on both sides, and
        lines through the cell centres would sit half a cell to either side of it; a frame pulled onto one
        of them and inserted there would move the wall by half a cell, frame after frame.
        """
        from scipy import ndimage

        pad = math.ceil(margin / cell_size) + 1
        origin = tgt.min(axis=0) - pad * cell_size  # on the map's lattice: cell centres land on integers
        ij = np.floor((tgt - origin) / cell_size + 0.5).astype(np.int64)
        shape = tuple(int(v) for v in ij.max(axis=0) + pad + 1)
        occ = np.zeros(shape, np.bool_)
        occ[ij[:, 0], ij[:, 1]] = True
        # nearest occupied cell of every cell (exact Euclidean distance transform, scipy's EDT)
        ni, nj = ndimage.distance_transform_edt(~occ, return_distances=False, return_indices=True)
        near = ni * shape[1] + nj
        anchor = np.zeros((occ.size, 2))
        normal = np.zeros((occ.size, 2))
        _block_lines(occ, ij, window // 2, anchor, normal)
        anchor = anchor * cell_size + origin
        return cls(origin, cell_size, near, anchor, normal)

    def lookup(self, xy: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Flat index of the nearest map cell of each point (-1 outside the raster) and its distance, m."""
        h, w = self.near.shape
        ij = np.floor((xy - self.origin) / self.cell_size + 0.5).astype(np.intp)
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < h) & (ij[:, 1] >= 0) & (ij[:, 1] < w)
        idx = np.full(len(xy), -1, np.intp)
        idx[ok] = self.near[ij[ok, 0], ij[ok, 1]]
        centre = self.origin + self.cell_size * np.column_stack([idx // w, idx % w])
        dist = np.where(ok, np.hypot(*(xy - centre).T), np.inf)
        return idx, dist


def _point_to_line_icp(
    src: NDArray[np.float64], tgt: NDArray[np.float64], p: MatchParams, cell_size: float
) -> _Icp:
    """Planar point-to-line ICP (Gauss-Newton on x, y, yaw) of ``src`` onto the lines through ``tgt``.

    Correspondences come from a distance transform of the map cells (:class:`_LineField`), built once per
    frame, so each iteration is array indexing (compiled: :func:`_gauss_newton`). The rotation is about
    the frame cells' centroid, which keeps the information matrix well conditioned; ``min_information``
    is the smallest eigenvalue of its translation part (Schur complement of the heading) per inlier: about
    0.5 when walls face every way, near 0 along a corridor whose walls fix only the offset across them.
    """
    field = _LineField.build(tgt, cell_size, p.max_correspondence)
    centre = src.mean(axis=0)
    local = np.ascontiguousarray(src - centre)
    x = np.zeros(3)
    info = np.zeros((3, 3))
    stats = np.zeros(3)  # inliers, sum of squared residuals, iterations
    _gauss_newton(local, centre, field.near, field.anchor, field.normal, field.origin, field.cell_size,
                  p.max_correspondence, p.max_iterations, p.tolerance, x, info, stats)  # fmt: skip
    n_in, sq, it = int(stats[0]), float(stats[1]), int(stats[2])
    rmse = math.sqrt(sq / n_in) if n_in else math.nan
    min_info, sd = 0.0, (math.inf, math.inf)
    if n_in and info[2, 2] > 0:
        trans = info[:2, :2] - np.outer(info[:2, 2], info[2, :2]) / info[2, 2]
        min_info = float(np.linalg.eigvalsh(trans)[0] / n_in)
        try:
            cov = np.linalg.inv(info / n_in)
            lattice = p.match_sd[0]  # one cell centroid's error: correlated, so not divided by sqrt(n)
            sd = (lattice * math.sqrt(max(cov[0, 0], cov[1, 1])), lattice * math.sqrt(max(cov[2, 2], 0.0)))
        except np.linalg.LinAlgError:
            pass
    # the correction about the centroid as one about the map origin: t' = centre + t - R centre
    c, s_ = math.cos(x[2]), math.sin(x[2])
    dx = centre[0] + x[0] - (c * centre[0] - s_ * centre[1])
    dy = centre[1] + x[1] - (s_ * centre[0] + c * centre[1])
    return _Icp(float(dx), float(dy), float(x[2]), n_in / max(len(src), 1), rmse, min_info, it,
                (float(centre[0]), float(centre[1])), sd)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _block_lines(occ, ij, r, anchor, normal):  # type: ignore[no-untyped-def]
    """For each occupied cell ``ij[k]``: centroid (cell units) and unit normal of the occupied cells in
    the ``(2r+1) x (2r+1)`` block around it (the minor axis of their scatter), at its flat index."""
    h, w = occ.shape
    for k in range(ij.shape[0]):
        i0, j0 = ij[k, 0], ij[k, 1]
        n = 0
        si = 0.0
        sj = 0.0
        sii = 0.0
        sjj = 0.0
        sij = 0.0
        for i in range(max(i0 - r, 0), min(i0 + r + 1, h)):
            for j in range(max(j0 - r, 0), min(j0 + r + 1, w)):
                if occ[i, j]:
                    di = i - i0
                    dj = j - j0
                    n += 1
                    si += di
                    sj += dj
                    sii += di * di
                    sjj += dj * dj
                    sij += di * dj
        mi = si / n
        mj = sj / n
        cii = sii / n - mi * mi
        cjj = sjj / n - mj * mj
        cij = sij / n - mi * mj
        theta = 0.5 * np.arctan2(2.0 * cij, cii - cjj)  # the major axis
        q = i0 * w + j0
        anchor[q, 0] = i0 + mi
        anchor[q, 1] = j0 + mj
        normal[q, 0] = -np.sin(theta)
        normal[q, 1] = np.cos(theta)


@numba.njit(cache=True, nogil=True)
def _gauss_newton(local, centre, near, anchor, normal, origin, cs, reach, max_it, tol, x, info, stats):  # type: ignore[no-untyped-def]
    """Gauss-Newton iterations of the point-to-line ICP; writes ``x`` (dx, dy, dyaw about ``centre``),
    ``info`` (the last weighted information matrix) and ``stats`` (inliers, squared residuals, iterations).

    Coarse to fine: correspondences within ``reach`` until the steps fall below ``tol`` (or half the
    iterations are spent), then within ``0.4 * reach`` until they fall below it again. Huber weights
    beyond 2 cm.
    """
    h, w = near.shape
    n = local.shape[0]
    half = max_it // 2
    fine = False
    it = 0
    n_in = 0
    sq = 0.0
    while it < max_it:
        it += 1
        if it > half:
            fine = True
        r2 = (reach * (0.4 if fine else 1.0)) ** 2
        c = np.cos(x[2])
        s = np.sin(x[2])
        a = np.zeros((3, 3))
        b = np.zeros(3)
        n_in = 0
        sq = 0.0
        for k in range(n):
            rx = c * local[k, 0] - s * local[k, 1]
            ry = s * local[k, 0] + c * local[k, 1]
            mx = rx + centre[0] + x[0]
            my = ry + centre[1] + x[1]
            gi = int(np.floor((mx - origin[0]) / cs + 0.5))
            gj = int(np.floor((my - origin[1]) / cs + 0.5))
            if gi < 0 or gi >= h or gj < 0 or gj >= w:
                continue
            q = near[gi, gj]
            qi = q // w
            qj = q - qi * w
            ex = mx - (origin[0] + qi * cs)
            ey = my - (origin[1] + qj * cs)
            if ex * ex + ey * ey > r2:
                continue
            nx = normal[q, 0]
            ny = normal[q, 1]
            res = nx * (mx - anchor[q, 0]) + ny * (my - anchor[q, 1])
            j2 = ny * rx - nx * ry
            wt = 1.0 / max(1.0, abs(res) / 0.02)
            jac = (nx, ny, j2)
            for u in range(3):
                b[u] += wt * jac[u] * res
                for v in range(3):
                    a[u, v] += wt * jac[u] * jac[v]
            n_in += 1
            sq += res * res
        if n_in < 3:
            break
        info[:, :] = a
        step = -np.linalg.lstsq(a, b)[0]
        x += step
        if np.hypot(step[0], step[1]) < tol and abs(step[2]) < tol / 10.0:
            if fine:
                break
            fine = True
    stats[0] = n_in
    stats[1] = sq
    stats[2] = it


announce_compilation(sys.modules[__name__], "scan matching kernels")
