"""Ground-truth evaluation of a simulated run: paths, odometry drift, maps against the scene, collisions.

Uses only domain-named powers of the simulated chair (:class:`sim.backend.SimChair`):
``ground_truth_pose``, ``ground_truth_transform`` and ``contacts``. It adds a map placed with the
physics' poses to the perception stage (a :class:`robchair.perception_layers.MapLayer`), so the odometry map
and the ground-truth-pose map see the same frames, and writes into the run's metrics:

* ``route.distance_travelled_m`` (ground truth), ``odometry_drift`` (final / max position error, final
  heading error, error per metre travelled);
* with scan-to-map matching, ``odometry_drift.matched`` (the same errors for the matched pose,
  ``T_map_odom x`` odometry) and ``paths["matched"]``;
* ``map.odometry_map_vs_scene``, ``map.matched_map_vs_scene`` and ``map.ground_truth_pose_map_vs_scene``:
  precision and recall of the occupied cells of the 2D map in the chair's height band (for the
  probabilistic map: occupied = at or above its occupancy threshold; unknown is not occupied) against the
  static scene rasterised
  (:func:`sim.truth.scene_occupancy`), with one cell of tolerance both ways;
* ``collisions``: distinct contact events between the chair and scene bodies (a body that starts
  touching the chair; walking people count when they overlap it);
* ``map.walker_clearing`` (scenes with scripted people, ground-truth-pose map): how long a cell a
  walker left stays occupied in the map (:class:`WalkerClearing`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.ndimage import binary_dilation

from robchair.loop_types import CycleResult, LoopView, Observer, RunResult
from robchair.platform.frames import wrap_angle


def precision_recall(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Precision and recall of a boolean raster against the truth, one cell of tolerance both ways."""
    ring = np.ones((3, 3), dtype=bool)
    tp_p = int(np.sum(pred & binary_dilation(truth, ring)))
    tp_r = int(np.sum(truth & binary_dilation(pred, ring)))
    return {"precision": tp_p / max(int(pred.sum()), 1), "recall": tp_r / max(int(truth.sum()), 1)}


class WalkerClearing:
    """Clearing time of the cells scripted people leave, measured on a map every ``every_s`` seconds.

    The scene knows each walker's trajectory (:meth:`sim.scene.Motion.pose_at`, or where the simulation
    placed it when it stepped aside for the chair: ``poses``), so at each sample the walkers'
    footprints in the height band are rasterised (surface samples of their meshes, widened by one
    cell: the map's tolerance). A cell a walker covered and no longer covers has been *left* at
    that sample; if the map reads it occupied then, its clearing time is the simulated time until the
    map first reads it not occupied (unknown is not occupied). A walker coming back cancels the wait.
    Cells of the static scene (widened by one cell) are left out. Resolution: ``every_s``.

    Args:
        scene: the :class:`sim.scene.Scene` (its moving objects are the walkers).
        grid: the map's :class:`mapping.grid.GridSpec`.
        band: (z_min, z_max) m of the 2D occupancy.
        static: (grid shape) bool cells of the static scene in the band.
        every_s: sampling period, simulated seconds.
        poses: where each walker stands now, (x, y, yaw) by name (e.g. :attr:`sim.scene.SceneBodies.poses`);
            a walker it does not name is placed by its script.
    """

    def __init__(self, scene: Any, grid: Any, band: tuple[float, float], static: np.ndarray,
                 every_s: float = 0.1,
                 poses: dict[str, tuple[float, float, float]] | None = None) -> None:  # fmt: skip
        import dataclasses
        from types import SimpleNamespace

        from sim.scene import ground_truth_points

        self.grid, self.band, self.every_s = grid, band, float(every_s)
        self.poses = poses if poses is not None else {}
        self.walkers: list[tuple[str, Any, np.ndarray]] = []
        for obj in scene.objects:
            if obj.motion is None:
                continue
            at_origin = dataclasses.replace(obj, motion=None, xyz=(0.0, 0.0, obj.xyz[2]))
            one = SimpleNamespace(objects=(at_origin,))  # ground_truth_points reads only .objects
            pts = ground_truth_points(one, grid.cell_size / 2, np.random.default_rng(0))  # type: ignore[arg-type]
            pts = pts[(pts[:, 2] >= band[0]) & (pts[:, 2] <= band[1])]
            self.walkers.append((obj.name, obj.motion, pts[:, :2]))
        self.excluded = binary_dilation(static, np.ones((3, 3), dtype=bool))
        shape = grid.shape
        self.under = np.zeros(shape, dtype=bool)  # a walker covers the cell now
        self.left_at = np.full(shape, np.nan)  # when a walker left a cell that was occupied then
        self.times: list[float] = []
        self.cells_left_occupied = 0
        self._next_t = 0.0

    def footprint(self, t: float) -> np.ndarray:
        """Cells (grid shape, bool) the walkers cover at scene time ``t`` s, widened by one cell."""
        g = self.grid
        out = np.zeros(g.shape, dtype=bool)
        for name, motion, xy in self.walkers:
            x, y, yaw = self.poses[name] if name in self.poses else motion.pose_at(t)
            c, s = np.cos(yaw), np.sin(yaw)
            wx = x + c * xy[:, 0] - s * xy[:, 1]
            wy = y + s * xy[:, 0] + c * xy[:, 1]
            i, j = g.world_to_index(wx, wy)
            ok = (i >= 0) & (i < g.shape[0]) & (j >= 0) & (j < g.shape[1])
            out[i[ok], j[ok]] = True
        return binary_dilation(out, np.ones((3, 3), dtype=bool))

    def due(self, t: float) -> bool:
        return bool(self.walkers) and t >= self._next_t - 1e-9

    def sample(self, t: float, occupied: np.ndarray) -> None:
        """One sample at scene time ``t`` s with the map's occupied cells (grid shape, bool)."""
        self._next_t = t + self.every_s
        now = self.footprint(t) & ~self.excluded
        left = self.under & ~now
        self.left_at[now] = np.nan  # back again: no wait
        start = left & occupied
        self.left_at[start] = t
        self.cells_left_occupied += int(start.sum())
        waiting = np.isfinite(self.left_at)
        cleared = waiting & ~occupied
        self.times.extend((t - self.left_at[cleared]).tolist())
        self.left_at[cleared] = np.nan
        self.under = now

    def summary(self, t_end: float) -> dict[str, Any]:
        """``{median_s, p90_s, max_s, cells_cleared, cells_left_occupied, cells_not_cleared, ...}``."""
        ts = np.asarray(self.times)
        waiting = np.isfinite(self.left_at)
        return {
            "median_s": float(np.median(ts)) if ts.size else None,
            "p90_s": float(np.percentile(ts, 90)) if ts.size else None,
            "max_s": float(ts.max()) if ts.size else None,
            "cells_cleared": int(ts.size),
            "cells_cleared_within_1s": int(np.sum(ts <= 1.0 + 1e-9)),
            "cells_left_occupied": self.cells_left_occupied,
            "cells_not_cleared": int(waiting.sum()),
            "not_cleared_median_age_s": float(np.median(t_end - self.left_at[waiting]))
            if waiting.any()
            else None,
            "sample_period_s": self.every_s,
            "walkers": len(self.walkers),
            "notes": "ground-truth-pose map; a cell a walker (footprint in the band, widened by one cell) "
            "left while the map read it occupied, until the map reads it not occupied; cells the chair "
            "no longer sees cannot clear and stay in cells_not_cleared",
        }


class GroundTruthEvaluation(Observer):
    """Evaluate a simulated run against the physics and the scene.

    Args:
        chair: the :class:`sim.backend.SimChair` being driven.
        scene: its :class:`sim.scene.Scene` (None: no map comparison).
        ground_truth_map: also build the map placed with ground-truth poses.
    """

    def __init__(self, chair: Any, scene: Any, ground_truth_map: bool = True) -> None:
        self.chair, self.scene = chair, scene
        self.ground_truth_map = ground_truth_map
        self.paths: dict[str, list[Any]] = {"t": [], "odometry": [], "ground_truth": [], "matched": []}
        self.gt_map: Any = None
        self.collisions = 0
        self.contact_events: list[tuple[float, str]] = []
        self._touching: set[str] = set()
        self.clearing: WalkerClearing | None = None

    def episode_start(self, runtime: LoopView) -> None:
        if self.ground_truth_map:
            p = runtime.perception
            if "ground-truth" in getattr(p, "pose_maps", {}):  # the run's own map is placed so already
                self.gt_map = p.pose_maps["ground-truth"]
                return
            self.gt_map = p.new_map()  # the same kind as the perception's maps
            p.add_layer("ground_truth", self.gt_map, self.chair.ground_truth_transform)
            if self.scene is not None and any(o.motion is not None for o in self.scene.objects):
                from sim.truth import scene_occupancy

                static = scene_occupancy(self.scene, p.grid, p.band)
                poses = getattr(getattr(self.chair, "bodies", None), "poses", None)
                self.clearing = WalkerClearing(self.scene, p.grid, p.band, static, poses=poses)

    def after_cycle(self, runtime: LoopView, cycle: CycleResult) -> None:
        gt = self.chair.ground_truth_pose()  # raises SimulationDivergedError on a non-finite pose
        self.paths["t"].append(cycle.stamp_ns)
        self.paths["odometry"].append((cycle.pose.x, cycle.pose.y, cycle.pose.theta))
        self.paths["ground_truth"].append((gt.x, gt.y, gt.theta))
        if getattr(runtime.perception, "matcher", None) is not None:
            from robchair.platform.frames import se3_planar

            tm = runtime.perception.t_map_odom @ se3_planar(cycle.pose.x, cycle.pose.y, cycle.pose.theta)
            self.paths["matched"].append((tm[0, 3], tm[1, 3], float(np.arctan2(tm[1, 0], tm[0, 0]))))
        touching = self.chair.contacts()
        for name in sorted(touching - self._touching):
            self.collisions += 1
            self.contact_events.append(((cycle.stamp_ns - runtime.t0_ns) / 1e9, name))
        self._touching = touching
        t = cycle.stamp_ns / 1e9  # the scene's clock (the walkers are placed by simulated time)
        if self.clearing is not None and self.clearing.due(t):
            from mapping.derived import occupancy_codes

            runtime.perception.wait_for_maps()  # not flush(): frames in flight stay in flight
            codes = occupancy_codes(self.gt_map, runtime.perception.band)
            self.clearing.sample(t, np.asarray(codes == 100))

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v, dtype=np.int64 if k == "t" else np.float64) for k, v in self.paths.items()}

    def episode_end(self, runtime: LoopView, result: RunResult) -> None:
        paths = self.arrays()
        if not len(paths["matched"]):
            del paths["matched"]
        result.paths.update(paths)
        gp = paths["ground_truth"]
        travelled = float(np.sum(np.hypot(*np.diff(gp[:, :2], axis=0).T))) if len(gp) > 1 else 0.0
        drift = _drift(paths["odometry"], gp, travelled)
        if "matched" in paths:
            drift["matched"] = _drift(paths["matched"], gp, travelled)
            m = result.extra.get("matching") or {}
            drift["matched"]["matching_ms_per_frame_median"] = m.get("ms_per_frame_median")
            drift["matched"]["rejections"] = m.get("rejected")
        extra: dict[str, Any] = {
            "route": {"distance_travelled_m": travelled},
            "odometry_drift": drift,
            "collisions": self.collisions,
            "contact_events": [{"t_s": t, "body": n} for t, n in self.contact_events],
        }
        if self.gt_map is not None:
            result.maps["ground_truth"] = self.gt_map
        if self.scene is not None:
            extra["map"] = self._map_metrics(runtime)
            if self.clearing is not None:
                extra["map"]["walker_clearing"] = self.clearing.summary(
                    self.paths["t"][-1] / 1e9 if self.paths["t"] else 0.0
                )
        for k, v in extra.items():
            if isinstance(v, dict) and isinstance(result.extra.get(k), dict):
                result.extra[k].update(v)
            else:
                result.extra[k] = v

    def _map_metrics(self, runtime: LoopView) -> dict[str, Any]:
        from sim.truth import scene_occupancy

        p = runtime.perception
        grid = p.grid
        truth = scene_occupancy(self.scene, grid, p.band)
        maps = getattr(p, "pose_maps", {"odometry": p.map})
        occ = {"odometry": p.occupied_2d(maps["odometry"])}
        if "matched" in maps:
            occ["matched"] = p.occupied_2d(maps["matched"])
        if self.gt_map is not None:
            occ["ground_truth"] = p.occupied_2d(self.gt_map)
        out: dict[str, Any] = {
            "grid": {"cell_size": grid.cell_size, "shape": list(grid.shape), "centre": list(grid.centre)},
            "occupancy_band_m": list(p.band),
            "occupied_cells": {k: int(v.sum()) for k, v in occ.items()},
            "scene_occupied_cells": int(truth.sum()),
            "odometry_map_vs_scene": precision_recall(occ["odometry"], truth),
            "ground_truth_pose_map_vs_scene": (
                precision_recall(occ["ground_truth"], truth) if "ground_truth" in occ else None
            ),
            "matched_map_vs_scene": precision_recall(occ["matched"], truth) if "matched" in occ else None,
            "iou_odometry_vs_ground_truth_pose": None,
            "iou_matched_vs_ground_truth_pose": None,
            "notes": "occupied = a structure overlapping the band (probabilistic map: an interval at or "
            "above its occupancy threshold; unknown and free are not occupied); precision/recall with "
            "one-cell tolerance against the static scene rasterised from its meshes (moving people are not "
            "in the scene truth; recall counts every static surface, seen or not, so it measures coverage)",
        }
        if "ground_truth" in occ:
            for name in ("odometry", "matched"):
                if name in occ:
                    union = int(np.sum(occ[name] | occ["ground_truth"]))
                    inter = int(np.sum(occ[name] & occ["ground_truth"]))
                    out[f"iou_{name}_vs_ground_truth_pose"] = inter / union if union else None
        return out


def _drift(path: np.ndarray, truth: np.ndarray, travelled: float) -> dict[str, Any]:
    """Final / max position error, final heading error and error per metre of a pose path (N, 3)."""
    if len(path):
        err = np.hypot(path[:, 0] - truth[:, 0], path[:, 1] - truth[:, 1])
        heading = np.abs([wrap_angle(a - b) for a, b in zip(path[:, 2], truth[:, 2])])
    else:
        err = heading = np.zeros(1)
    return {
        "final_position_error_m": float(err[-1]),
        "max_position_error_m": float(err.max()),
        "final_heading_error_rad": float(heading[-1]),
        "max_heading_error_rad": float(np.max(heading)),
        "position_error_per_metre": float(err[-1] / travelled) if travelled > 0 else None,
    }
