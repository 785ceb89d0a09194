"""A probabilistic variable-height map: occupied and free evidence over vertical intervals per cell.

The thesis's VHV map (:class:`mapping.vhv.VHVMap`) only accumulates: whatever was seen once stays, and
a cell nobody saw reads like a free one. Its future work (section 6.2) asks for merged free structures
(Fig. 5.14) and a probability of occupation per cell. :class:`ProbabilisticVHV` does both, in the
spirit of MVOG (Dryanovski et al., IROS 2010: positive and negative vertical volumes per 2D cell) with
OctoMap's clamped log-odds update (Hornung et al., 2013).

Per frame (:meth:`ProbabilisticVHV.insert`)
-------------------------------------------
1. **Occupied structures**: the frame's VHV structures (the thesis build of :mod:`mapping.vhv`,
   unchanged). Each is a sample of a surface: its evidence is the slab ``[bottom - t, top + t]`` with
   ``t = surface_half_thickness`` (default half a cell, what a voxel of the cell size gives a hit).
2. **Free intervals per structure** (Fig. 5.14): two lines from the sensor to the structure's bottom
   and top (aimed at its cell centre); every cell the segment passes through *before* the structure's
   cell gets one free interval, the heights the fan spans in that cell. Computed per structure, never
   per point (a 2.07M-point frame has a few thousand structures).
3. **Merging**: free intervals are united per cell on a bit table of height bins, so they never
   overlap each other; runs closer than ``gap_fill`` (2 cm: sampling holes between neighbouring
   fans) are joined; each run is then shrunk by ``surface_margin`` at both ends (the near-surface
   rule, below) and the frame's own occupied slabs are cut out of it, so free evidence never overlaps
   the frame's occupied evidence.
4. **Update**: per touched cell, the stored intervals and the frame's evidence are swept together;
   each elementary piece gets ``clamp(L + l_hit)`` under an occupied slab, ``clamp(L + l_miss)`` under
   a free interval, and keeps ``L`` elsewhere (``L = 0``, p = 0.5, where nothing was known). Intervals
   split where evidence starts or stops inside them and neighbours with equal log-odds merge again.
   Nothing is created where no evidence came: **unknown is what no evidence has touched**, and free
   space is remembered (MVOG's negative volumes).

Thresholds and defaults (:class:`EvidenceParams`, OctoMap's defaults): ``prob_hit = 0.7`` (log-odds
+0.847), ``prob_miss = 0.4`` (-0.405), clamping to ``[0.1192, 0.971]`` (log-odds [-2.0, +3.5]); an
interval is **occupied** when ``p >= occupied_threshold = 0.5`` and **free** when ``p <
free_threshold = 0.5``. A walker seen for a long time (clamped at 0.971) reads free after 9 frames of
free evidence (0.3 s at 30 Hz); a structure seen once reads free after 3.

Near-surface rule (why surfaces do not flicker and tables are not erased)
-------------------------------------------------------------------------
* A fan stops before the cell of its own structure: a ray that ends *on* a surface never clears it.
* In every cell, the frame's own occupied slabs are cut out of its free intervals: a surface hit by a
  frame gets only occupied evidence from that frame, so a surface hit by every frame is never lowered.
* Each per-cell run of free bins is shrunk by ``surface_margin`` (default one cell size) at both ends.
  A fan is a hull over the cell's width and aimed at cell centres, so near the end of a run it may dip
  a few centimetres into a surface the real rays only grazed: e.g. rays passing over a table top to
  the floor behind. The shrink keeps that graze off the table; space is cleared only where the fans
  cover it with this margin to spare. A moving obstacle is cleared because fans pass *through* its
  former place, far from the run's ends.
* Clamping gives hysteresis: a surface at the upper bound needs 9 consecutive frames of free evidence
  before it reads free.

Dynamic decay (people who walk out of view)
-------------------------------------------
A cell is cleared only by rays that pass through it again; a person who walks out of the sensor's
view leaves a trail nobody clears. With :attr:`EvidenceParams.dynamic_decay_s` and insertion stamps,
an occupied slab of a frame that lands on space the map knew free (probability below
``dynamic_void_probability``, DUFOMap's "void") or on a dynamic interval is *dynamic*: every piece
under it keeps the stamp of its last hit. Before each update, dynamic occupied intervals whose last
hit is older than ``dynamic_decay_s`` are dropped (when they were hit for at most
``dynamic_max_dwell_s``: a person passes a cell within a second or two): they become unknown, not free
(the spatio-temporal voxel layer's decay, restricted to what moved). Static surfaces are not seen free
before they are hit, or keep being hit longer, so they stay however long they are out of view; a person
standing still keeps being hit.

Storage (structure of arrays)
-----------------------------
Heights are integers on a lattice of ``height_resolution`` (1 cm by default): noisy observations of a
surface then give identical bounds and merge instead of fragmenting. Per grid cell a dense table holds
the start, count and reserved room of the cell's list in a pool of ``(lo, hi, log_odds, stamp)``
arrays (int32, int32, float32, float64; stamp -inf unless dynamic), sorted and disjoint; a frame
rewrites only the cells it touches, in place when the list fits, else appended at the pool's end (the
pool is compacted when half of it is dead).

The pure thesis method stays available as :class:`mapping.vhv.VHVMap` (accumulate only, no free
space); :func:`make_map` chooses by name.
"""

from __future__ import annotations

import math
import time
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping._evidence_views import EvidenceViews, _structures_from
from mapping._frame_evidence import FrameEvidence, PreparedFrame
from mapping._interval_store import IntervalStore
from mapping.errors import MappingError
from mapping.evidence import EvidenceIntervals, EvidenceParams, EvidenceStats
from mapping.grid import GridSpec
from mapping.vhv import Method, Structures, VHVMap, as_points

__all__ = [
    "EvidenceIntervals",
    "EvidenceParams",
    "EvidenceStats",
    "MapKind",
    "PreparedFrame",
    "ProbabilisticVHV",
    "make_map",
]

#: Map kinds of :func:`make_map`.
MapKind = Literal["probabilistic", "thesis"]


class ProbabilisticVHV(IntervalStore, EvidenceViews, FrameEvidence):
    """A variable-height map that keeps occupied and free evidence per vertical interval.

    Accepts the same inputs as :class:`mapping.vhv.VHVMap` (``insert(points, sensor_origin=...)``) and
    answers the same occupied-structure queries (``structures()``, ``n_structures``, ...), so
    :mod:`mapping.derived` and :mod:`mapping.export` take either. It adds free space, log-odds per
    interval and three-valued views (:meth:`occupancy_2d`).

    Args:
        spec: the grid.
        tolerance: VHV clustering tolerance of each frame's occupied structures, metres (> 0).
        params: evidence parameters (default :class:`EvidenceParams`).

    Example:
        >>> import numpy as np
        >>> m = ProbabilisticVHV(GridSpec(cell_size=0.1, size_x=4.0, size_y=4.0))
        >>> wall = np.array([[1.5, y, z] for y in np.arange(-0.5, 0.5, 0.02) for z in np.arange(0, 1, 0.02)])
        >>> _ = m.insert(wall, sensor_origin=(0.0, 0.0, 0.5))
        >>> codes = m.occupancy_2d((0.1, 0.9))
        >>> int(codes[m.spec.world_to_index(1.5, 0.0)]), int(codes[m.spec.world_to_index(1.0, 0.0)])
        (100, 0)
        >>> int(codes[m.spec.world_to_index(-1.0, 0.0)])  # behind the sensor: never seen
        -1
    """

    def __init__(self, spec: GridSpec, tolerance: float = 0.05, params: EvidenceParams | None = None) -> None:
        # VHVMap validates spec and tolerance with the project's messages.
        VHVMap(spec, tolerance)
        self.spec = spec
        self.tolerance = float(tolerance)
        self.params = params if params is not None else EvidenceParams()
        if not isinstance(self.params, EvidenceParams):
            raise MappingError(
                f"ProbabilisticVHV params={params!r}: expected mapping.probabilistic.EvidenceParams"
            )
        p = self.params
        cs = spec.cell_size
        self._r = float(p.height_resolution)
        self._half = float(cs / 2.0 if p.surface_half_thickness is None else p.surface_half_thickness)
        self._margin = float(cs if p.surface_margin is None else p.surface_margin)
        self._gap = float(p.gap_fill)
        lo = p.log_odds
        self._l_hit = np.float32(lo["hit"])
        self._l_miss = np.float32(lo["miss"])
        self._l_min = np.float32(lo["min"])
        self._l_max = np.float32(lo["max"])
        self._l_occ = np.float32(lo["occupied"])
        self._l_free = np.float32(lo["free"])
        self._l_void = np.float32(lo["void"])
        self._init_store(spec.shape[0] * spec.shape[1], p.dynamic_decay_s is not None)
        self.frames = 0
        self.points_inserted = 0
        self.points_dropped_nonfinite = 0
        self.points_outside_grid = 0
        self.sensor_origins: list[tuple[float, float, float]] = []

    # ------------------------------------------------------------------ insertion
    def insert(
        self,
        points: ArrayLike,
        sensor_origin: ArrayLike | None = None,
        method: Method = "auto",
        max_range: float | None = None,
        stamp: float | None = None,
    ) -> EvidenceStats:
        """Insert one cloud (world frame): occupied evidence at its structures, free evidence in front.

        Args:
            points: ``(N, 3)`` or organized ``(H, W, 3)`` xyz in metres (float32/float64; NaN/inf
                dropped and counted), as for :meth:`mapping.vhv.VHVMap.insert`.
            sensor_origin: world xyz of the sensor. Without it the frame gives occupied evidence only.
            method: VHV build path ("auto", "bins", "sort", "numpy").
            max_range: metres; points farther from the sensor give no hit, only free space up to this
                range along their ray (OctoMap's ``maxrange``). None: no limit.
            stamp: capture time of the cloud, seconds (any epoch, non-decreasing); the clock of
                :attr:`EvidenceParams.dynamic_decay_s`. None: the map's clock does not advance.

        Returns:
            :class:`EvidenceStats`.

        Raises:
            PointsError: wrong shape or dtype.
            MappingError: bad method, sensor origin or max_range (max_range needs a sensor origin).
        """
        t0 = time.perf_counter()
        origin = self._check_origin(sensor_origin)
        self._advance(stamp)
        return self._apply(self._prepare(points, origin, method, max_range, t0))

    def prepare_frame(
        self,
        points: ArrayLike,
        sensor_origin: ArrayLike | None = None,
        method: Method = "auto",
        max_range: float | None = None,
        no_return_ends: ArrayLike | None = None,
        defer_fans: bool = False,
    ) -> PreparedFrame:
        """The evidence one frame would add (its VHV structures, occupied slabs and merged free
        intervals), computed without reading or changing the stored map; :meth:`insert_prepared` adds it.

        ``insert(points, sensor_origin, method, max_range, stamp)`` equals ``insert_prepared(
        prepare_frame(points, sensor_origin, method, max_range), stamp)`` bit for bit, and with
        ``no_return_ends`` it equals :meth:`insert_frame`. Frames may be prepared ahead of their insert,
        on another thread (the compiled kernels release the GIL); only the inserts must come in order.

        Args:
            points, sensor_origin, method, max_range: as for :meth:`insert`.
            no_return_ends: ``(M, 3)`` world points, as for :meth:`insert_frame` (needs ``sensor_origin``).
            defer_fans: leave the free intervals (the fans, most of the work) to the frame's
                ``mark_fans`` / ``extract_free`` (or to ``insert_prepared``), e.g. for another thread.

        Returns:
            A :class:`mapping._frame_evidence.PreparedFrame` for this map (or one of the same grid,
            tolerance and params).

        Raises:
            PointsError, MappingError: as :meth:`insert` and :meth:`insert_frame`.
        """
        t0 = time.perf_counter()
        if no_return_ends is None:
            origin = self._check_origin(sensor_origin)
            return self._prepare(points, origin, method, max_range, t0, defer_fans)
        if sensor_origin is None:
            raise MappingError("prepare_frame no_return_ends: the free space needs the sensor_origin")
        o, mr, ends = self._check_ends(sensor_origin, max_range, no_return_ends)
        return self._prepare_with_free(points, o, mr, ends, t0, defer_fans)

    def insert_prepared(self, prepared: PreparedFrame, stamp: float | None = None) -> EvidenceStats:
        """Add a frame prepared by :meth:`prepare_frame`: the dynamic decay at ``stamp``, the update of
        the stored intervals and the map's counters (``build_ms`` covers the preparation too).

        Args:
            prepared: from :meth:`prepare_frame` of this map or of one with the same grid, tolerance
                and params.
            stamp: capture time of the cloud, seconds (see :meth:`insert`).

        Raises:
            MappingError: a frame prepared for another grid, tolerance or params; a bad stamp.
        """
        if not isinstance(prepared, PreparedFrame) or prepared.layout != self._layout():
            raise MappingError(
                "insert_prepared: the frame was prepared for another grid, tolerance or params "
                "(prepare it with this map's prepare_frame)"
            )
        self._advance(stamp)
        prepared.extract_free()
        return self._apply(prepared)

    def _layout(self) -> tuple[Any, ...]:
        return (self.spec, self.tolerance, self.params)

    def _prepare(
        self,
        points: ArrayLike,
        origin: tuple[float, float, float] | None,
        method: str,
        max_range: float | None,
        t0: float,
        defer: bool = False,
    ) -> PreparedFrame:
        """``insert``'s evidence of ``points`` (``origin`` checked), without the map's clock or store."""
        pts = as_points(points)
        n_in = int(pts.shape[0])
        truncated = None
        n_trunc = 0
        if max_range is not None:
            mr = float(max_range)
            if not (math.isfinite(mr) and mr > 0):
                raise MappingError(f"insert max_range={max_range!r}: expected a finite number of metres > 0")
            if origin is None:
                raise MappingError("insert max_range needs a sensor_origin (the range is measured from it)")
            from mapping import _evidence_kernels as E

            # Build first: when every structure (hence every point) lies within the range and no point
            # fell outside the grid, nothing needs cutting and the pass over the points is saved.
            built = self._build(pts, method)
            if built[4] == 0 and self._within(built[0], built[1], built[2], origin, mr):
                return self._prepared(pts, n_in, None, origin, method, t0, 0, built, defer)
            n_trunc = int(E.count_beyond(pts, *origin, mr))
            if n_trunc:
                kept = np.empty_like(pts)
                truncated = np.empty((n_trunc, 3), np.float64)
                E.split_beyond(pts, *origin, mr, kept, truncated)
                pts = kept
            elif built is not None:
                return self._prepared(pts, n_in, None, origin, method, t0, 0, built, defer)
        return self._prepared(pts, n_in, truncated, origin, method, t0, n_trunc, None, defer)

    def _prepare_with_free(
        self,
        points: ArrayLike,
        origin: ArrayLike,
        max_range: float,
        free_targets: NDArray[np.float64],
        t0: float,
        defer: bool = False,
    ) -> PreparedFrame:
        """``insert``'s evidence plus free-only targets (already at the range's end)."""
        stats_origin = self._check_origin(origin)
        pts = as_points(points)
        n_in = int(pts.shape[0])
        from mapping import _evidence_kernels as E

        assert stats_origin is not None
        n_trunc = int(E.count_beyond(pts, *stats_origin, max_range)) if math.isfinite(max_range) else 0
        targets = free_targets
        if n_trunc:
            kept = np.empty_like(pts)
            truncated = np.empty((n_trunc, 3), np.float64)
            E.split_beyond(pts, *stats_origin, max_range, kept, truncated)
            pts = kept
            targets = np.concatenate([truncated, free_targets])
        return self._prepared(pts, n_in, targets, stats_origin, "auto", t0, n_trunc, None, defer)

    def _prepared(
        self,
        pts: NDArray[np.floating],
        n_in: int,
        free_only: NDArray[np.float64] | None,
        origin: tuple[float, float, float] | None,
        method: str,
        t0: float,
        n_free_only: int,
        built: tuple[Any, ...] | None = None,
        defer: bool = False,
    ) -> PreparedFrame:
        ev = self._evidence(pts, free_only, origin, method, built, defer)
        ms = (time.perf_counter() - t0) * 1e3
        return PreparedFrame(self._layout(), ev, n_in, n_free_only, origin, ms)

    def _apply(self, prepared: PreparedFrame) -> EvidenceStats:
        """Decay, update the store with a prepared frame's evidence and count it."""
        t1 = time.perf_counter()
        stats = self._insert(prepared.evidence)
        n_in, n_free_only, origin = prepared.points_in, prepared.free_only, prepared.origin
        n_ins = n_in - stats["n_nonfinite"] - stats["n_outside"] - (n_free_only if n_in else 0)
        self.frames += 1
        self.points_inserted += n_ins
        self.points_dropped_nonfinite += stats["n_nonfinite"]
        self.points_outside_grid += stats["n_outside"]
        if origin is not None:
            self.sensor_origins.append(origin)
        return EvidenceStats(
            points_in=n_in,
            points_dropped_nonfinite=stats["n_nonfinite"],
            points_outside_grid=stats["n_outside"],
            points_inserted=n_ins,
            build_ms=prepared.prepare_ms + (time.perf_counter() - t1) * 1e3,
            frame_structures=stats["frame_structures"],
            method=stats["method"],
            free_intervals=stats["free_intervals"],
            occupied_slabs=stats["occupied_slabs"],
            fan_passages=stats["fan_passages"],
            cells_updated=stats["cells_updated"],
            intervals=self._n_intervals,
            truncated_points=n_free_only,
            decayed=stats["decayed"],
        )

    def insert_frame(
        self,
        points_world: ArrayLike,
        sensor_origin: ArrayLike,
        max_range: float | None = None,
        no_return_ends: ArrayLike | None = None,
        stamp: float | None = None,
    ) -> EvidenceStats:
        """One depth frame, for a perception stage: ``insert`` with a required sensor origin.

        Args:
            points_world: ``(N, 3)`` / ``(H, W, 3)`` world xyz, metres, NaN for no return.
            sensor_origin: world xyz of the sensor's optical centre, metres.
            max_range: metres; farther points clear up to this range and give no hit.
            no_return_ends: optional ``(M, 3)`` world points: for pixels that returned nothing, where
                their ray stops being known free (e.g. the pixel's ray at the camera's maximum depth:
                ``T_world_cam @ (ray_with_unit_depth * max_depth)``). A NaN carries no direction, so
                without them nothing clears behind a walker seen against the sky or beyond the range.
                Use them only where a no-return means "nothing within range": a depth camera also
                misses black or specular surfaces and surfaces seen at grazing incidence.
            stamp: capture time, seconds (see :meth:`insert`).

        Raises:
            MappingError: no sensor origin, or ends of the wrong shape.
        """
        if sensor_origin is None:
            raise MappingError("insert_frame sensor_origin=None: the free space needs the sensor position")
        if no_return_ends is None:
            return self.insert(points_world, sensor_origin=sensor_origin, max_range=max_range, stamp=stamp)
        t0 = time.perf_counter()
        o, mr, ends = self._check_ends(sensor_origin, max_range, no_return_ends)
        self._advance(stamp)
        return self._apply(self._prepare_with_free(points_world, o, mr, ends, t0))

    def _check_ends(
        self, sensor_origin: ArrayLike, max_range: float | None, no_return_ends: ArrayLike
    ) -> tuple[tuple[float, float, float], float, NDArray[np.float64]]:
        """``insert_frame``'s checked origin, range (inf: none) and finite no-return ends."""
        ends = np.asarray(no_return_ends, dtype=np.float64)
        if ends.ndim != 2 or ends.shape[1] != 3:
            raise MappingError(f"insert_frame no_return_ends: expected (M, 3), got shape {ends.shape}")
        ends = ends[np.isfinite(ends).all(axis=1)]
        o = self._check_origin(sensor_origin)
        assert o is not None
        mr = math.inf if max_range is None else float(max_range)
        if not (mr > 0 and not math.isnan(mr)):
            raise MappingError(f"insert_frame max_range={max_range!r}: expected a number of metres > 0")
        return o, mr, ends

    def insert_free(
        self, targets: ArrayLike, sensor_origin: ArrayLike, stamp: float | None = None
    ) -> EvidenceStats:
        """Free evidence only: space from the sensor up to (not into) the cells of ``targets`` is free.

        Used for readings that found nothing within their range (the targets are the range's end).
        ``stamp``: capture time, seconds (see :meth:`insert`).
        """
        t0 = time.perf_counter()
        origin = self._check_origin(sensor_origin)
        self._advance(stamp)
        if origin is None:
            raise MappingError("insert_free sensor_origin=None: free space needs the sensor position")
        tg = as_points(targets, "targets").astype(np.float64)
        tg = tg[np.isfinite(tg).all(axis=1)]
        empty = np.empty((0, 3), np.float64)
        return self._apply(self._prepared(empty, 0, tg, origin, "auto", t0, int(tg.shape[0])))

    def insert_sonar(
        self,
        fusion: Any,
        t_world_array: ArrayLike,
        max_range_m: float = 1.0,
        ppc: int = 40,
    ) -> EvidenceStats:
        """Evidence of one fused sonar-array reading (thesis 5.2, 5.4; :mod:`mapping.sonar`).

        With an echo the zone's cone (Fig. 5.7 points at the fused range, :func:`mapping.sonar.cone_points`)
        is occupied and the zone's solid beam from the array up to that range is free (fans to a
        sampling of the beam's cross-section at the range: the printed Fig. 5.7 rings leave the
        beam's axis unsampled), through the same core as a depth frame. With no echo within range
        (every sonar silent or over 1 m) the array's whole coverage (hull of the three beams, each
        beam's own width as vertical aperture) is free up to ``max_range_m``.

        Args:
            fusion: a :class:`mapping.sonar.FusionResult`.
            t_world_array: ``(4, 4)`` pose of the array frame (x along sonar 2, z up) in the world.
            max_range_m: range trusted free when nothing echoes, metres (the thesis accepts readings
                under 1 m).
            ppc: points per cone circle.

        Raises:
            MappingError: malformed pose or range.
        """
        from mapping.sonar import (
            OUTER_SONAR_DEG,
            beam_points,
            cone_points,
            half_apertures_deg,
            sonar_intervals_deg,
        )

        t0 = time.perf_counter()
        t = np.asarray(t_world_array, dtype=np.float64)
        if t.shape != (4, 4) or not bool(np.all(np.isfinite(t))):
            raise MappingError(
                f"insert_sonar t_world_array: expected a finite (4, 4) pose, got shape {t.shape}"
            )
        if not (math.isfinite(max_range_m) and max_range_m > 0):
            raise MappingError(f"insert_sonar max_range_m={max_range_m!r}: expected metres > 0")
        origin = (float(t[0, 3]), float(t[1, 3]), float(t[2, 3]))
        rot, pos = t[:3, :3], t[:3, 3]
        if fusion.has_obstacle and fusion.theta_deg > 0.0:
            d = float(fusion.distance_m)
            pts = cone_points(d, fusion.theta_deg, fusion.alpha_deg, ppc) @ rot.T + pos
            beam = beam_points(d, fusion.alpha_deg, fusion.theta_deg, fusion.theta_deg / 2.0) @ rot.T + pos
            return self._apply(self._prepared(pts, int(pts.shape[0]), beam, origin, "auto", t0, 0))
        d_cm = min(max_range_m * 100.0, 100.0)  # the detection model's domain
        iv = sonar_intervals_deg(d_cm, OUTER_SONAR_DEG)
        lo, hi = float(iv[:, 0].min()), float(iv[:, 1].max())
        left, right = half_apertures_deg(d_cm)
        half_elev = float(np.asarray(left + right)) / 2.0
        beam = beam_points(max_range_m, lo, hi - lo, half_elev) @ rot.T + pos
        empty = np.empty((0, 3), np.float64)
        return self._apply(self._prepared(empty, 0, beam, origin, "auto", t0, int(beam.shape[0])))

    # ------------------------------------------------------------------ core
    def _check_origin(self, sensor_origin: ArrayLike | None) -> tuple[float, float, float] | None:
        if sensor_origin is None:
            return None
        o = np.asarray(sensor_origin, dtype=np.float64).reshape(-1)
        if o.shape != (3,) or not bool(np.all(np.isfinite(o))):
            raise MappingError(f"sensor_origin={sensor_origin!r}: expected finite (x, y, z) in metres")
        return float(o[0]), float(o[1]), float(o[2])

    def _insert(self, ev: dict[str, Any]) -> dict[str, Any]:
        """Decay, then update the store with one frame's evidence (``_evidence``'s dict, not changed)."""
        out = dict(ev)
        out["decayed"] = self._decay()
        ncells = 0
        if ev["okey"].shape[0] or ev["fkey"].shape[0]:
            ncells = self._update(ev["okey"], ev["olo"], ev["ohi"], ev["fkey"], ev["flo"], ev["fhi"])
        self._cache.clear()
        out["cells_updated"] = ncells
        return out

    def frame_evidence(
        self, points: ArrayLike, sensor_origin: ArrayLike, max_range: float | None = None
    ) -> tuple[Structures, Structures]:
        """What one frame would add, without adding it: ``(occupied slabs, free intervals)``.

        Both are per-cell sorted structure lists in metres; free intervals are disjoint from each other
        and from the occupied slabs (the merge of step 3 in the module docs).
        """
        origin = self._check_origin(sensor_origin)
        if origin is None:
            raise MappingError("frame_evidence sensor_origin=None: free space needs the sensor position")
        pts = as_points(points)
        truncated = None
        if max_range is not None:
            from mapping import _evidence_kernels as E

            mr = float(max_range)
            n_trunc = int(E.count_beyond(pts, *origin, mr))
            if n_trunc:
                kept = np.empty_like(pts)
                truncated = np.empty((n_trunc, 3), np.float64)
                E.split_beyond(pts, *origin, mr, kept, truncated)
                pts = kept
        ev = self._evidence(pts, truncated, origin, "auto")
        ny, r = self.spec.shape[1], self._r
        occ = _structures_from(ev["okey"], ev["olo"] * r, ev["ohi"] * r, ny)
        free = _structures_from(ev["fkey"], ev["flo"] * r, ev["fhi"] * r, ny)
        return occ, free

    def band_cell_keys(self, band: tuple[float, float], rows: tuple[int, int], cols: tuple[int, int]) -> Any:
        """Sorted cell keys ``i * ny + j`` (int64) of the cells in rows ``[i0, i1]`` x columns ``[j0, j1]``
        (clipped to the grid) holding an occupied structure that overlaps ``band`` (m).

        The same cells as selecting on :meth:`structures` (``top >= z_min`` and ``bottom <= z_max``), read
        from the window's cells only, without the whole map's occupied view (a joined structure overlaps
        the band exactly when one of its occupied pieces does).
        """
        from mapping import _store_kernels as K

        nx, ny = self.spec.shape
        i0, i1 = max(int(rows[0]), 0), min(int(rows[1]), nx - 1)
        j0, j1 = max(int(cols[0]), 0), min(int(cols[1]), ny - 1)
        if i0 > i1 or j0 > j1:
            return np.empty(0, np.int64)
        return K.band_cells(self._cstart, self._ccount, self._plo, self._phi, self._pl, self._l_occ, self._r,
                            float(band[0]), float(band[1]), i0, i1, j0, j1, ny)  # fmt: skip

    def __repr__(self) -> str:
        return (
            f"ProbabilisticVHV(cells={self.spec.shape}, cell_size={self.spec.cell_size}, "
            f"tolerance={self.tolerance}, intervals={self._n_intervals}, frames={self.frames})"
        )


def make_map(
    spec: GridSpec,
    tolerance: float = 0.05,
    kind: MapKind = "probabilistic",
    params: EvidenceParams | None = None,
) -> VHVMap | ProbabilisticVHV:
    """The map of ``kind``: "probabilistic" (:class:`ProbabilisticVHV`) or "thesis" (accumulate only,
    :class:`mapping.vhv.VHVMap`, the method of Table 5.2).

    Raises:
        MappingError: unknown kind, or params given for the thesis map.
    """
    if kind == "thesis":
        if params is not None:
            raise MappingError("make_map kind='thesis': the accumulate-only map takes no evidence params")
        return VHVMap(spec, tolerance)
    if kind == "probabilistic":
        return ProbabilisticVHV(spec, tolerance, params)
    raise MappingError(f"make_map kind={kind!r}: expected 'probabilistic' or 'thesis'")
