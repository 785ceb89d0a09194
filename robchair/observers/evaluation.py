"""Ground-truth evaluation of a simulated run: paths, odometry drift, maps against the scene, collisions.

Uses only domain-named powers of the simulated chair (:class:`sim.backend.SimChair`):
``ground_truth_pose``, ``ground_truth_transform`` and ``contacts``. It adds a map placed with the
physics' poses to the perception stage (a :class:`robchair.perception.MapLayer`), so the odometry map
and the ground-truth-pose map see the same frames, and writes into the run's metrics:

* ``route.distance_travelled_m`` (ground truth), ``odometry_drift`` (final / max position error, final
  heading error, error per metre travelled);
* with scan-to-map matching, ``odometry_drift.matched`` (the same errors for the matched pose,
  ``T_map_odom x`` odometry) and ``paths["matched"]``;
* ``map.odometry_map_vs_scene``, ``map.matched_map_vs_scene`` and ``map.ground_truth_pose_map_vs_scene``:
  precision and recall of
  the 2D occupancy in the chair's height band against the static scene rasterised
  (:func:`sim.truth.scene_occupancy`), with one cell of tolerance both ways;
* ``collisions``: distinct contact events between the chair and scene bodies (a body that starts
  touching the chair; walking people count when they overlap it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.ndimage import binary_dilation

from robchair.frames import wrap_angle
from robchair.observers import Observer

if TYPE_CHECKING:
    from robchair.runtime import CycleResult, RunResult, Runtime


def precision_recall(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Precision and recall of a boolean raster against the truth, one cell of tolerance both ways."""
    ring = np.ones((3, 3), dtype=bool)
    tp_p = int(np.sum(pred & binary_dilation(truth, ring)))
    tp_r = int(np.sum(truth & binary_dilation(pred, ring)))
    return {"precision": tp_p / max(int(pred.sum()), 1), "recall": tp_r / max(int(truth.sum()), 1)}


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

    def episode_start(self, runtime: Runtime) -> None:
        if self.ground_truth_map:
            from mapping.vhv import VHVMap

            p = runtime.perception
            if "ground-truth" in getattr(p, "pose_maps", {}):  # the run's own map is placed so already
                self.gt_map = p.pose_maps["ground-truth"]
                return
            self.gt_map = VHVMap(p.grid, getattr(p.map, "tolerance", 0.05))
            p.add_layer("ground_truth", self.gt_map, self.chair.ground_truth_transform)

    def after_cycle(self, runtime: Runtime, cycle: CycleResult) -> None:
        gt = self.chair.ground_truth_pose()  # raises SimulationDivergedError on a non-finite pose
        self.paths["t"].append(cycle.stamp_ns)
        self.paths["odometry"].append((cycle.pose.x, cycle.pose.y, cycle.pose.theta))
        self.paths["ground_truth"].append((gt.x, gt.y, gt.theta))
        if getattr(runtime.perception, "matcher", None) is not None:
            from robchair.frames import se3_planar

            t = runtime.perception.t_map_odom @ se3_planar(cycle.pose.x, cycle.pose.y, cycle.pose.theta)
            self.paths["matched"].append((t[0, 3], t[1, 3], float(np.arctan2(t[1, 0], t[0, 0]))))
        touching = self.chair.contacts()
        for name in sorted(touching - self._touching):
            self.collisions += 1
            self.contact_events.append(((cycle.stamp_ns - runtime.t0_ns) / 1e9, name))
        self._touching = touching

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v, dtype=np.int64 if k == "t" else np.float64) for k, v in self.paths.items()}

    def episode_end(self, runtime: Runtime, result: RunResult) -> None:
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
        for k, v in extra.items():
            if isinstance(v, dict) and isinstance(result.extra.get(k), dict):
                result.extra[k].update(v)
            else:
                result.extra[k] = v

    def _map_metrics(self, runtime: Runtime) -> dict[str, Any]:
        from sim.truth import scene_occupancy

        p = runtime.perception
        grid = p.grid
        truth = scene_occupancy(self.scene, grid, p.band)
        maps = getattr(p, "pose_maps", {"odometry": p.map})
        occ = {"odometry": p.occupancy_2d(maps["odometry"])}
        if "matched" in maps:
            occ["matched"] = p.occupancy_2d(maps["matched"])
        if self.gt_map is not None:
            occ["ground_truth"] = p.occupancy_2d(self.gt_map)
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
            "notes": "occupancy = a structure overlapping the band; precision/recall with one-cell tolerance "
            "against the static scene rasterised from its meshes (moving people are not in the scene truth; "
            "recall counts every static surface, seen or not, so it measures coverage)",
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
