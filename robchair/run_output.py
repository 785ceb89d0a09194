"""A run of the drive loop into a run folder: the default observers, ``metrics.json``, ``maps.npz`` and
``odometry.csv``.

:func:`run_to_dir` opens the backend, builds the :class:`robchair.runtime.Runtime` with the recording
observers (bag, time series, controller diagnostics) in front of the caller's, runs it and writes the
folder all-or-nothing (:mod:`robchair.outdir`); :func:`write_metrics` writes the one ``metrics.json``
schema of :meth:`robchair.loop_types.RunResult.metrics`, :func:`write_maps` the one ``maps.npz``
(:mod:`robchair.run_folder`) of every backend.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hw.interfaces import Backend
from robchair.loop_types import Observer, RunResult
from robchair.perception import Perception
from robchair.platform.kinematics import Pose2D
from robchair.platform.safety import SafetyLayer
from robchair.platform.spec import RobChairSpec
from robchair.runtime import Runtime
from robchair.runtime_config import RuntimeConfig
from robchair.sources import CommandSource


def run_to_dir(backend: Backend, source: CommandSource | None, duration_s: float, out_dir: Path | None, *,
               spec: RobChairSpec | None = None, config: RuntimeConfig | None = None,
               safety: SafetyLayer | None = None, start_pose: Pose2D | None = None,
               safety_enabled: bool = True, perception: Perception | None = None,
               observers: Sequence[Observer] = (), bag_storage: str = "mcap") -> RunResult:  # fmt: skip
    """Open the backend, run, close it, and (with ``out_dir``) write ``bag/``, ``metrics.json``,
    ``maps.npz``, ``timeseries.csv`` and ``odometry.csv``. The output folder is written all-or-nothing
    (:mod:`robchair.outdir`). Motor-controller diagnostics are polled at 1 Hz where the controller has
    them."""
    from robchair.outdir import staged_output_dir

    def go(stage: Path | None) -> RunResult:
        from robchair.observers.diagnostics import DiagnosticsObserver

        obs = list(observers)
        if stage is not None:  # a recorded run: bag, time series and the controller's diagnostics
            from robchair.observers.recorder import RunRecorder
            from robchair.observers.timeseries import TimeseriesWriter

            recorder = RunRecorder(stage / "bag", storage=bag_storage)
            obs[:0] = [recorder, TimeseriesWriter(stage / "timeseries.csv")]
            obs.append(DiagnosticsObserver(recorder=recorder))
        rt = Runtime(backend, source, spec=spec, config=config, safety=safety, perception=perception,
                     observers=obs, start_pose=start_pose, safety_enabled=safety_enabled)  # fmt: skip
        res = rt.run(duration_s)
        grid, band = rt.perception.grid, rt.perception.band  # where maps.npz's cells are, in metrics.json
        info = res.extra.setdefault("map", {})
        info.setdefault("grid", {"cell_size": grid.cell_size, "shape": list(grid.shape),
                                 "centre": list(grid.centre)})  # fmt: skip
        info.setdefault("occupancy_band_m", [float(band[0]), float(band[1])])
        return res

    with backend:
        if out_dir is None:
            return go(None)
        with staged_output_dir(out_dir) as stage:
            result = go(stage)
            write_maps(stage, result, default_band(result, spec))  # the band of metrics.json
            write_metrics(stage, result)
            np.savetxt(stage / "odometry.csv", np.asarray(result.poses).reshape(-1, 4), delimiter=",",
                       header="t_s,x_m,y_m,theta_rad", comments="")  # fmt: skip
        return result


def default_band(result: RunResult, spec: RobChairSpec | None) -> tuple[float, float]:
    """The 2D band of the run's occupancy: ``metrics.json`` ``map.occupancy_band_m``, else 0.10 m to the
    chair's height (m)."""
    band = result.metrics()["map"].get("occupancy_band_m")
    if not band:
        from robchair.platform.spec import load_spec

        band = [0.10, (spec or load_spec()).body.height]
    return float(band[0]), float(band[1])


def write_maps(folder: Path, result: RunResult, band: tuple[float, float]) -> list[str]:
    """``maps.npz``: per map of the run ``<name>_i``, ``_j``, ``_bottom``, ``_top`` (its structures) and
    ``<name>_occupancy`` (the three-valued 2D map of ``band``, m: nav_msgs/OccupancyGrid codes 100
    occupied, 0 free, -1 unknown), and ``path_<name>`` per path. Returns the file names written."""
    from mapping.derived import occupancy_codes

    arrays: dict[str, np.ndarray] = {}
    for name, m in result.maps.items():
        s = m.structures()
        for field in ("i", "j", "bottom", "top"):
            arrays[f"{name}_{field}"] = np.asarray(getattr(s, field))
        arrays[f"{name}_occupancy"] = occupancy_codes(m, band)
    for name, p in result.paths.items():
        arrays[f"path_{name}"] = p
    np.savez_compressed(folder / "maps.npz", **arrays)  # type: ignore[arg-type]
    return ["maps.npz"]


def write_metrics(folder: Path, result: RunResult) -> dict[str, Any]:
    """Write ``metrics.json`` (the one schema) into ``folder``; returns the document."""
    m = result.metrics()
    (folder / "metrics.json").write_text(json.dumps(m, indent=2, default=_json_default) + "\n")
    return m


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
