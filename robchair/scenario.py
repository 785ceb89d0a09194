"""The scenario harness behind ``robchair sim``: scene + simulated chair + route follower + perception +
observers, then the one drive loop (:class:`robchair.runtime.Runtime`), then the run folder.

One run:

1. loads the scenario (scene, start, route, sensor, duration, seed) and builds the simulated chair
   behind the hardware interfaces (:func:`sim.backend.backend_from_chair`), its motor controller's
   watchdog set from the loop period;
2. drives the runtime at :data:`CONTROL_HZ` (physics at 240 Hz underneath): the route follower
   (:class:`robchair.route.PurePursuit`) on the odometry pose, the safety layer on by default, the
   Kinect every other cycle (30 Hz) and both sonar arrays as fast as their ranging time allows (SRF08:
   15 Hz) or at ``sonar_hz``; every frame goes through the perception stage into the odometry map
   (and, for the evaluation, a map placed with the physics' poses);
3. observers: the run recorder (MCAP bag), the ground-truth evaluation (odometry drift, maps against
   the scene, collisions), a progress bar;
4. writes the run folder atomically (:mod:`robchair.outdir`): ``metrics.json`` (the schema of every
   run), ``maps.npz`` (each map's structures and its three-valued 2D occupancy of the height band,
   ``nav_msgs/OccupancyGrid`` codes), the map exports and pictures of :mod:`mapping.export`
   (``map/``), a rendered ``scene.png`` and the bag.

A failure inside the loop (e.g. the physics diverging) stops the chair; what was recorded so far is
written (``status`` = ``"error"`` in the metrics) and the error is raised afterwards. Same scenario +
same seed -> the same maps, paths and frame data bit for bit, threaded or not (wall-clock metrics
aside).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from robchair.loop_types import LoopView, Observer, RunResult
from robchair.perception import MAP_KINDS
from robchair.platform.errors import ConfigError
from robchair.platform.kinematics import DiffDrive, Pose2D
from robchair.platform.safety import Footprint, SafetyLayer, SafetyLimits
from robchair.platform.spec import RobChairSpec, load_spec
from robchair.route import PurePursuit, Route
from robchair.run_output import _json_default
from robchair.runtime import LoopAborted, Runtime
from robchair.runtime_config import RuntimeConfig, check_duration_s

CONTROL_HZ = 60.0
KINECT_EVERY = 2  # cycles: 30 Hz at 60 Hz
CELL_SIZE = 0.05
MAP_TOLERANCE = 0.05
GRID_MARGIN = 1.0
GOAL_TOLERANCE_M = 0.15
POSE_DEFAULT = "matched"  # the pose the run's map is built with (see robchair.perception.POSE_SOURCES)
ZOOM_HALF_WIDTH_M = 1.0  # a 2 m x 2 m fine region around the chair ...
ZOOM_FACTOR = 5  # ... at 1 cm (5 cm / 5)
# The evaluation maps (odometry beside the matched map, ground truth) take every 3rd Kinect frame (10 Hz)
# and the matching registers every 2nd (15 Hz, odometry between): tests/robchair/test_perception_rates.py
# bounds both against the every-frame path (2D map IoU, matched pose within a map cell).
EVALUATION_EVERY = 3
MATCH_EVERY = 2


def grid_covering(xy_min: tuple[float, float], xy_max: tuple[float, float], cell_size: float = CELL_SIZE,
                  margin: float = GRID_MARGIN) -> Any:  # fmt: skip
    """A :class:`mapping.grid.GridSpec` covering the box ``xy_min``-``xy_max`` plus ``margin`` m each side,
    a whole even number of cells each way (as the grid requires)."""
    from mapping.grid import GridSpec

    x0, y0 = xy_min[0] - margin, xy_min[1] - margin
    x1, y1 = xy_max[0] + margin, xy_max[1] + margin
    nx, ny = (2 * math.ceil((b - a) / (2 * cell_size) - 1e-9) for a, b in ((x0, x1), (y0, y1)))
    return GridSpec(cell_size=cell_size, size_x=nx * cell_size, size_y=ny * cell_size,
                    centre=((x0 + x1) / 2, (y0 + y1) / 2))  # fmt: skip


def scenario_grid(scenario: Any) -> Any:
    """The map grid of a scenario: its scene's bounds and its route, plus :data:`GRID_MARGIN`."""
    x0, y0, x1, y1 = scenario.scene.bounds_xy()
    pts = np.array([*scenario.route.waypoints, scenario.start[:2]], dtype=float)
    lo = (min(x0, pts[:, 0].min()), min(y0, pts[:, 1].min()))
    hi = (max(x1, pts[:, 0].max()), max(y1, pts[:, 1].max()))
    return grid_covering(lo, hi)


def scenario_route(scenario: Any) -> Route:
    """The scenario's route as a :class:`Route` from the start position (in ``map``)."""
    x, y, _ = scenario.start
    waypoints = [(float(w[0]), float(w[1])) for w in scenario.route.waypoints]
    return Route(((float(x), float(y)), *waypoints),
                 speed=scenario.route.speed, lookahead_m=scenario.route.lookahead,
                 goal_tolerance_m=GOAL_TOLERANCE_M)  # fmt: skip


def default_out_dir(scenario: Any) -> Path:
    """``runs/<scenario>-<UTC time>``, a folder no earlier run wrote (see :func:`timestamped_dir`)."""
    from robchair.outdir import timestamped_dir

    return timestamped_dir(scenario.name)


class ProgressBar(Observer):
    """A tqdm bar of simulated seconds with the real-time factor."""

    def __init__(self, name: str, duration_s: float) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=round(duration_s, 3), unit="sim s", desc=f"sim {name}",
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} sim s "
                        "[{elapsed} wall, {rate_fmt}{postfix}]")  # fmt: skip
        self._shown = 0.0
        self._wall0 = time.perf_counter()

    def after_cycle(self, runtime: LoopView, cycle: Any) -> None:
        t = (cycle.stamp_ns - runtime.t0_ns) / 1e9
        if t - self._shown >= 1.0:
            self.bar.set_postfix_str(f"RTF {t / max(time.perf_counter() - self._wall0, 1e-9):.2f}")
            self.bar.update(t - self._shown)
            self._shown = t

    def episode_end(self, runtime: LoopView, result: RunResult) -> None:
        self.bar.close()


def sonar_every(chair: Any, sonar_hz: float | None, rate_hz: float = CONTROL_HZ) -> int:
    """Cycles between sonar readings: ``sonar_hz``, or the ranging time (SRF08: 65 ms -> every 4th)."""
    if sonar_hz is not None:
        if not (math.isfinite(sonar_hz) and 0 < sonar_hz <= rate_hz):
            raise ConfigError(f"sonar_hz = {sonar_hz!r}: expected a rate in (0, {rate_hz:g}] Hz")
        return max(1, round(rate_hz / sonar_hz))
    if not chair.sonars:
        return 0
    ranging = max(arr.model.ranging_time_s for arr in chair.sonars.values())
    return max(1, math.ceil(ranging * rate_hz - 1e-9))


def run_scenario(
    scenario: Any = "office_corridor",
    *,
    out_dir: Path | str | None = None,
    duration: float | None = None,
    sensor: str | None = None,
    seed: int | None = None,
    spec: RobChairSpec | None = None,
    progress: bool = True,
    write_bag: bool = True,
    pictures: bool = True,
    camera_backend: str = "raycast",
    write: bool = True,
    sensors: bool = True,
    mapping_thread: bool = True,
    raycast_threads: int = 1,
    ground_truth_map: bool = True,
    pipeline: bool = True,
    sonar_hz: float | None = None,
    safety: bool = True,
    safety_limits: SafetyLimits | None = None,
    bag_storage: str = "mcap",
    bag_clouds: str = "voxel",
    pose: str = POSE_DEFAULT,
    matching: bool = True,
    zoom: bool = True,
    map_kind: str = "probabilistic",
    observers: Sequence[Observer] = (),
    evaluation_every: int = EVALUATION_EVERY,
    match_every: int = MATCH_EVERY,
) -> RunResult:
    """Run a scenario through the runtime and (with ``write``) write its run folder.

    Args:
        scenario: a :class:`sim.scene.Scenario`, or a scenario name / file.
        out_dir: run folder (default ``runs/<scenario>-<UTC timestamp>``).
        duration, sensor, seed: override the scenario's values.
        spec: platform spec (default ``assets/robchair.toml``).
        progress: show a progress bar (simulated vs wall time) on stderr.
        write_bag, pictures: write the bag / the pictures and map exports.
        camera_backend: ``"raycast"`` or ``"pybullet"``.
        write: write the run folder at all (False: return the result only).
        sensors: simulate the Kinect and sonars (False: physics, motors and route following only).
        mapping_thread: insert frames into the maps on a second thread.
        raycast_threads: Embree threads of the ray caster (0 = all cores; default 1: on 2 cores the
            capture threads overlap frames, and TBB's spinning workers cost more than they gain).
        ground_truth_map: also build the map placed with ground-truth poses.
        pipeline: capture Kinect frames on background threads.
        sonar_hz: sonar reading rate; None = as fast as the model's ranging time allows.
        safety: the safety layer on (default) or off (recorded in the metrics).
        safety_limits: limits of the safety layer (default: from the spec).
        bag_storage: ``"mcap"`` or ``"sqlite3"``.
        bag_clouds: depth clouds in the bag, a key of :data:`robchair.observers.recorder.BAG_CLOUDS`.
        pose: the pose the run's map (and its safety stops) is built with: ``"matched"`` (the default,
            :data:`POSE_DEFAULT`: scan-to-map matching, :mod:`mapping.matching`), ``"odometry"`` or
            ``"ground-truth"``.
        matching: run the scan-to-map matching (its map and drift beside the others); forced by
            ``pose="matched"``.
        zoom: map a 2 m x 2 m region around the chair at 1 cm (:mod:`mapping.zoom`).
        map_kind: the maps (odometry and ground-truth pose): ``"probabilistic"`` (free space and
            unknown, moving people cleared) or ``"thesis"`` (accumulate only); ``map.kind`` in the metrics.
        observers: more observers of the loop, called after the run's own (e.g. the live view).
        evaluation_every, match_every: the evaluation maps (the ground-truth pose map and extra
            layers; the odometry map takes every frame) take every k-th depth frame, the matching
            registers every k-th frame (:class:`robchair.perception.Perception`; default
            :data:`EVALUATION_EVERY`, :data:`MATCH_EVERY`; 1: every frame).

    Raises:
        ScenarioError: the scenario is invalid (nothing is written).
        LoopAborted: the loop failed (e.g. the physics diverged) after the partial run folder was written.
    """
    from robchair.backends import default_watchdog_ms
    from robchair.outdir import staged_output_dir
    from sim.backend import SimChair, backend_from_chair, robot_radius
    from sim.scene import Scenario, load_scenario

    spec = spec if spec is not None else load_spec()
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario, robot_radius=robot_radius(spec))
    duration = check_duration_s(scenario.duration if duration is None else duration, "duration")
    sensor = scenario.sensor if sensor is None else sensor
    camera = None if not sensors or sensor in (None, "none") else sensor
    seed = scenario.seed if seed is None else int(seed)
    if seed < 0:
        raise ConfigError(f"seed = {seed}: expected >= 0")
    if map_kind not in MAP_KINDS:
        raise ConfigError(f"map kind {map_kind!r}: expected one of {', '.join(MAP_KINDS)}")
    wall0 = time.perf_counter()
    chair = SimChair(spec, scenario.scene, scenario.start, sensor=camera,
                     sonars=scenario.sonars and sensors, seed=seed, camera_backend=camera_backend,
                     raycast_threads=raycast_threads)  # fmt: skip
    backend = backend_from_chair(chair, default_watchdog_ms(CONTROL_HZ), threaded=pipeline)
    config = RuntimeConfig(rate_hz=CONTROL_HZ, camera_every=KINECT_EVERY,
                           sonar_every=sonar_every(chair, sonar_hz), map_kind=map_kind)  # fmt: skip
    target = None
    if write:
        target = Path(out_dir) if out_dir is not None else default_out_dir(scenario)
    opts = _options(progress, write_bag, mapping_thread, ground_truth_map, safety, safety_limits,
                    bag_storage, pictures, sensor, seed, camera_backend, wall0, pose, matching, zoom,
                    bag_clouds)  # fmt: skip
    opts.update(evaluation_every=evaluation_every, match_every=match_every)
    try:
        if target is None:
            return _drive(scenario, spec, chair, backend, config, duration, None, opts, observers)
        with staged_output_dir(target) as stage:
            res = _drive(scenario, spec, chair, backend, config, duration, stage, opts, observers)
        res.out_dir = target.resolve()
        if res.error is not None and res.exception is not None:
            raise res.exception
        return res
    finally:
        backend.close()


def _options(progress: bool, write_bag: bool, mapping_thread: bool, ground_truth_map: bool, safety: bool,
            safety_limits: SafetyLimits | None, bag_storage: str, pictures: bool, sensor: str, seed: int,
            camera_backend: str, wall0: float, pose: str = POSE_DEFAULT, matching: bool = True,
            zoom: bool = True, bag_clouds: str = "voxel") -> dict[str, Any]:  # fmt: skip
    return dict(progress=progress, write_bag=write_bag, mapping_thread=mapping_thread,
                ground_truth_map=ground_truth_map, safety=safety, safety_limits=safety_limits,
                bag_storage=bag_storage, pictures=pictures, sensor=sensor, seed=seed,
                camera_backend=camera_backend, wall0=wall0, pose=pose, matching=matching,
                zoom=zoom, bag_clouds=bag_clouds)  # fmt: skip


def _drive(scenario: Any, spec: RobChairSpec, chair: Any, backend: Any, config: RuntimeConfig,
           duration: float, stage: Path | None, o: dict[str, Any],
           extra_observers: Sequence[Observer] = ()) -> RunResult:  # fmt: skip
    from robchair.observers.evaluation import GroundTruthEvaluation
    from robchair.observers.recorder import DEFAULT_BAG_CLOUDS, RunRecorder
    from robchair.perception import Perception

    frames = {}
    cam = backend.depth_camera
    if cam is not None and cam.frame_id not in spec.mounts:  # HD/qHD clouds are in the colour camera
        frames[cam.frame_id] = spec.mounts["kinect_link"].transform() @ cam.link_to_frame()
    matcher = None
    if o.get("matching", True) or o.get("pose") == "matched":
        from mapping.matching import MatchParams, ScanMatcher

        # the run's map starts empty and its first frame goes in at the odometry's pose: map = odom then
        matcher = ScanMatcher(MatchParams(initial_sd=(0.0, 0.0)))
    depth_range = chair.kinect.model.max_range_m if chair.kinect is not None else None
    perception = Perception(spec, grid=scenario_grid(scenario), threaded=o["mapping_thread"], frames=frames,
                            tolerance=MAP_TOLERANCE, matcher=matcher, pose=o.get("pose", POSE_DEFAULT),
                            ground_truth=chair.ground_truth_transform,
                            zoom_half_width=ZOOM_HALF_WIDTH_M if o.get("zoom", True) else None,
                            zoom_factor=ZOOM_FACTOR, map_kind=config.map_kind,
                            depth_max_range_m=depth_range, evaluation_every=o.get("evaluation_every", 1),
                            match_every=o.get("match_every", 1))  # fmt: skip
    evaluation = GroundTruthEvaluation(chair, scenario.scene, o["ground_truth_map"])
    observers: list[Observer] = [evaluation]
    recorder = None
    if stage is not None and o["write_bag"]:
        recorder = RunRecorder(stage / "bag", o["bag_storage"], o.get("bag_clouds", DEFAULT_BAG_CLOUDS))
        observers.append(recorder)
    if stage is not None:
        from robchair.observers.timeseries import TimeseriesWriter

        observers.append(TimeseriesWriter(stage / "timeseries.csv"))
    from robchair.observers.diagnostics import DiagnosticsObserver

    observers.append(DiagnosticsObserver(recorder=recorder))
    if o["progress"]:
        observers.append(ProgressBar(scenario.name, duration))
    observers.extend(extra_observers)
    follower = PurePursuit(scenario_route(scenario), DiffDrive(spec))
    safety = SafetyLayer(
        o["safety_limits"] or SafetyLimits.from_spec(spec), spec.wheel_separation, Footprint.from_spec(spec)
    )
    backend.open()
    rt = Runtime(backend, follower, spec=spec, config=config, safety=safety,
                 perception=perception, observers=observers, start_pose=Pose2D(*scenario.start),
                 safety_enabled=o["safety"])  # fmt: skip
    setup_s = time.perf_counter() - o["wall0"]
    try:
        res = rt.run(duration)
        res.exception = None
    except LoopAborted as exc:
        res = rt.result
        res.exception = exc
    res.extra.update(
        scenario=scenario.name,
        scene=scenario.scene.name,
        sensor=o["sensor"],
        seed=o["seed"],
        duration_s=duration,
        camera_backend=o["camera_backend"],
        tyre_radius_scale=list(chair.wheel_radius_scale),
        wall_time_s={"setup": setup_s, "components": dict(chair.timing)},
    )
    res.extra["odometry_drift"] = {
        **(res.extra.get("odometry_drift") or {}),
        "source": "the simulated tyres' true radii differ from the spec's by tyre_radius_scale (seeded, "
        "0.2 % sd); the odometry assumes the spec's radius, plus wheel slip from the physics",
    }
    if stage is not None:
        write_run_folder(res, scenario, spec, stage, o["pictures"])
    return res


def write_zoom_picture(res: RunResult, band: tuple[float, float], path: Path) -> bool:
    """``zoom_2d.png``: the run's map with the zoom region outlined, beside the region at its fine cells.

    Occupancy in the height ``band`` (m); the region is where it was at the end of the run (around the
    chair). A region without an occupied cell in the band would draw an empty picture: then nothing is
    written, and ``metrics.json`` ``zoom.picture`` says why.

    Returns:
        True if the picture was written.
    """
    from mapping.derived import occupancy_2d

    fine = res.maps["zoom"]
    fine_occ = occupancy_2d(fine, *band)
    if not np.any(fine_occ):
        x0, x1, y0, y1 = fine.spec.extent
        res.extra.setdefault("zoom", {})["picture"] = (
            f"not drawn: the zoom region x {x0:.2f}..{x1:.2f} m, y {y0:.2f}..{y1:.2f} m (around the chair at "
            f"the end of the run) holds no occupied cell in the band {band[0]:g}-{band[1]:g} m"
        )
        return False
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    main = res.maps.get(res.extra.get("matching", {}).get("pose", "odometry").replace("-", "_"))
    main = main if main is not None else res.maps["odometry"]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 5.5), gridspec_kw={"width_ratios": [2, 1]})
    for ax, m, title in ((ax0, main, "map"), (ax1, fine, "zoom")):
        x0, x1, y0, y1 = m.spec.extent
        ax.imshow(occupancy_2d(m, *band).T, origin="lower", extent=(x0, x1, y0, y1), cmap="Greys",
                  interpolation="nearest")  # fmt: skip
        ax.set_title(f"{title}: {m.spec.cell_size * 100:g} cm cells")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    x0, x1, y0, y1 = fine.spec.extent
    ax0.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, edgecolor="tab:red", linewidth=1.5))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    res.extra.setdefault("zoom", {})["picture"] = path.name
    return True


def write_run_folder(res: RunResult, scenario: Any, spec: RobChairSpec, out: Path, pictures: bool) -> None:
    """``maps.npz``, the map exports and pictures (``map/``), ``scene.png`` and ``metrics.json``."""
    from robchair.run_output import default_band, write_maps

    band = default_band(res, spec)
    files = ["metrics.json", *write_maps(out, res, band)]
    timing = res.extra.setdefault("wall_time_s", {})
    if pictures:
        from mapping.export import write_map_outputs
        from sim.render import render_scene

        t0 = time.perf_counter()
        (out / "map").mkdir()
        write_map_outputs(res.maps["odometry"], out / "map", band=band,
                          build_ms=res.extra.get("mapping_ms_total"),
                          parameters={"scenario": scenario.name, "pose_source": "odometry"})  # fmt: skip
        if "zoom" in res.maps:
            write_zoom_picture(res, band, out / "map" / "zoom_2d.png")
        from robchair.viz.map_picture import MAP_2D_NAME, write_map_2d

        main = res.extra.get("matching", {}).get("pose", "odometry").replace("-", "_")
        write_map_2d(res, scenario, band, out / MAP_2D_NAME,
                     map_name=main if main in res.maps else "odometry")  # fmt: skip
        import matplotlib.pyplot as plt

        plt.imsave(out / "scene.png", render_scene(scenario, spec, path=res.paths.get("ground_truth")))
        files += ["map", "scene.png", MAP_2D_NAME]
        timing["pictures"] = time.perf_counter() - t0
    if "bag" in res.extra:
        files.append("bag")
    if (out / "timeseries.csv").exists():
        files.append("timeseries.csv")
    looks = pictures and res.exception is None  # the report and the recording of a complete run
    if looks:
        from robchair.viz.rerun_recording import rerun_available

        files += ["report.html", *(["recording.rrd"] if rerun_available() else [])]
    res.extra["files"] = sorted(files)
    (out / "metrics.json").write_text(
        json.dumps(res.metrics(), indent=2, allow_nan=False, default=_json_default) + "\n"
    )
    if looks:
        from robchair.report import build_report

        build_report(out, name=scenario.name)
        if "recording.rrd" in files:
            from robchair.viz.rerun_recording import write_recording

            write_recording(out, name=scenario.name)
