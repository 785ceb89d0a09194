"""The headless scenario runner behind ``robchair sim``: drive a route, map every frame, write a run folder.

One run:

1. loads the scenario (scene, start, route, sensor, duration, seed) and builds the simulated chair
   (:class:`sim.backend.SimChair`) behind the hardware interfaces (:func:`sim.backend.backend_from_chair`);
2. steps the physics at 240 Hz; at 60 Hz reads the encoders through ``MotorController.read_state``,
   integrates odometry (:class:`robchair.kinematics.Odometry`) and runs a pure-pursuit follower on the
   odometry pose, whose (v, w) goes through :class:`robchair.kinematics.DiffDrive` to motor RPM set
   points (``MotorController.set_speeds_rpm``); at 30 Hz captures a Kinect frame at the camera's
   physics pose (the call ``DepthCamera.read`` makes, keeping the pose for the ground-truth map); at
   15 Hz (the SRF08's 65 ms ranging time) reads both sonar arrays (``SonarArray.read``) and turns
   their servos toward the nearest echo (:func:`mapping.sonar.servo_command_deg`);
3. inserts every Kinect frame into two :class:`mapping.vhv.VHVMap` global maps: one placed with the
   chair's odometry (what the real chair would build) and one with the physics' ground-truth camera
   pose (for comparison); sonar readings go through the five-zone fusion and the cone -> points
   algorithm (:mod:`mapping.sonar`) into a third map (odometry);
4. writes the run folder atomically (:func:`robchair.outdir.staged_output_dir`): ``metrics.json``,
   the maps (``maps.npz`` always; M2's exports when :mod:`mapping.export` provides them), pictures and
   a ROS 2 bag of the sensor data.

A diverging simulation (non-finite pose) stops the run: everything recorded so far is written, the
metrics say ``"diverged"``, and the :class:`sim.errors.SimulationDivergedError` is raised afterwards.

Same scenario + same seed -> the same maps, paths and frame data bit for bit (wall-clock metrics
aside): the physics is deterministic, every noise generator is seeded from the scenario seed, and
nothing reads the wall clock to make a decision.
"""

from __future__ import annotations

import json
import logging
import math
import shutil
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from robchair.kinematics import DiffDrive, Odometry, Pose2D, wrap_angle
from robchair.spec import RobChairSpec, load_spec
from sim.errors import SimError, SimulationDivergedError
from sim.scene import Scenario, ground_truth_points, load_scenario

log = logging.getLogger(__name__)

CONTROL_HZ = 60
KINECT_HZ = 30
SONAR_HZ: float | None = None  # None: as fast as the sonar model's ranging time allows (SRF08: 15 Hz)
CELL_SIZE = 0.05
MAP_TOLERANCE = 0.05
OCC_BAND = (0.10, None)  # occupancy band: above the floor's noise, up to the chair's height (spec)
BAG_CLOUD_HZ = 10  # the bag keeps every third Kinect frame ...
BAG_CLOUD_STRIDE = 4  # ... decimated 4x4 (a full-rate full-size bag would be ~1 GB per minute)
GRID_MARGIN = 1.0


# ------------------------------------------------------------------------------------------------
# pure pursuit
# ------------------------------------------------------------------------------------------------


class PurePursuit:
    """Pure-pursuit path follower (Coulter 1992) on a polyline.

    The look-ahead point is the point ``lookahead`` metres further along the path than the path point
    closest to the robot (searching forward only, so the follower never goes back to an earlier leg).
    Curvature ``k = 2 y_l / L^2`` with (x_l, y_l) the look-ahead point in the robot frame and L its
    distance; ``w = v k``. The speed is reduced in tight turns and near the goal, and (v, w) is scaled
    by :meth:`robchair.kinematics.DiffDrive.limit` so no motor exceeds its maximum RPM. A look-ahead
    point behind the chair makes it turn on the spot.

    Args:
        path: (N, 2) points, the first being the start position.
        speed: Cruise speed, m/s.
        lookahead: Look-ahead distance, m.
        drive: Kinematics (for the speed limits).
        goal_tolerance: Stop within this distance of the last point, m.
    """

    def __init__(
        self, path: np.ndarray, speed: float, lookahead: float, drive: DiffDrive, goal_tolerance: float = 0.15
    ) -> None:
        self.path = np.asarray(path, dtype=float).reshape(-1, 2)
        if len(self.path) < 2:
            raise SimError("pure pursuit needs at least two path points")
        seg = np.diff(self.path, axis=0)
        self.seg_len = np.hypot(seg[:, 0], seg[:, 1])
        self.cum = np.concatenate([[0.0], np.cumsum(self.seg_len)])
        self.speed, self.lookahead, self.drive, self.goal_tolerance = speed, lookahead, drive, goal_tolerance
        self.s = 0.0  # arc length of the closest path point found so far
        self.done = False

    def point_at(self, s: float) -> np.ndarray:
        s = min(max(s, 0.0), float(self.cum[-1]))
        k = min(int(np.searchsorted(self.cum, s, side="right")) - 1, len(self.seg_len) - 1)
        frac = 0.0 if self.seg_len[k] == 0 else (s - self.cum[k]) / self.seg_len[k]
        return self.path[k] + frac * (self.path[k + 1] - self.path[k])

    def _closest_s(self, p: np.ndarray) -> float:
        a, b = self.path[:-1], self.path[1:]
        ab = b - a
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(self.seg_len**2, 1e-12), 0.0, 1.0)
        proj = a + t[:, None] * ab
        d = np.hypot(*(proj - p).T)
        s_all = self.cum[:-1] + t * self.seg_len
        # forward only, and not further than one look-ahead beyond the current progress
        ok = (s_all >= self.s - 1e-9) & (s_all <= self.s + 2 * self.lookahead)
        if not ok.any():
            return self.s
        k = int(np.argmin(np.where(ok, d, np.inf)))
        return float(s_all[k])

    def command(self, pose: Pose2D) -> tuple[float, float]:
        """(v m/s, w rad/s) for the current pose estimate."""
        p = np.array([pose.x, pose.y])
        goal = self.path[-1]
        dist_goal = float(np.hypot(*(goal - p)))
        if self.done or (dist_goal < self.goal_tolerance and self.s > self.cum[-1] - 2 * self.lookahead):
            self.done = True
            return 0.0, 0.0
        self.s = max(self.s, self._closest_s(p))
        target = self.point_at(self.s + self.lookahead)
        dx, dy = target - p
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        xl, yl = c * dx + s * dy, -s * dx + c * dy
        l2 = xl * xl + yl * yl
        if l2 < 1e-12:
            return 0.0, 0.0
        if xl < 0.0 and abs(yl) < abs(xl):  # target behind: turn on the spot toward it
            return self.drive.limit(0.0, math.copysign(0.6, yl))
        k = 2.0 * yl / l2
        v = self.speed / (1.0 + 0.6 * abs(k))
        v = min(v, max(0.12, 0.8 * dist_goal))
        return self.drive.limit(v, v * k)


# ------------------------------------------------------------------------------------------------
# geometry helpers
# ------------------------------------------------------------------------------------------------


def planar_transform(x: float, y: float, yaw: float) -> np.ndarray:
    """4x4 world <- base_link for a pose on the floor."""
    t = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:2, 3] = (x, y)
    return t


def transform_points(t: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (..., 3) points (float32 in, float32 out; NaN stays NaN)."""
    from sim._kinect_kernels import transform_points as kernel

    p = np.ascontiguousarray(pts, dtype=np.float32)
    return kernel(np.ascontiguousarray(t, dtype=np.float64), p)  # type: ignore[no-any-return]


def occupancy(structures: Any, shape: tuple[int, int], z_min: float, z_max: float) -> np.ndarray:
    """Cells holding a structure that overlaps the height band [z_min, z_max] (bool, (nx, ny))."""
    occ = np.zeros(shape, dtype=bool)
    sel = (np.asarray(structures.top) >= z_min) & (np.asarray(structures.bottom) <= z_max)
    occ[np.asarray(structures.i)[sel], np.asarray(structures.j)[sel]] = True
    return occ


def elevation(structures: Any, shape: tuple[int, int]) -> np.ndarray:
    """Highest structure top per cell (NaN where empty)."""
    top = np.full(shape, -np.inf)
    np.maximum.at(top, (np.asarray(structures.i), np.asarray(structures.j)), np.asarray(structures.top))
    top[~np.isfinite(top)] = np.nan
    return top


def dilate(mask: np.ndarray, r: int = 1) -> np.ndarray:
    """Binary dilation by a (2r+1)^2 square (no scipy needed for this)."""
    out = mask.copy()
    p = np.pad(mask, r)
    n0, n1 = mask.shape
    for di in range(-r, r + 1):
        for dj in range(-r, r + 1):
            out |= p[r + di : r + di + n0, r + dj : r + dj + n1]
    return out


# ------------------------------------------------------------------------------------------------
# the run
# ------------------------------------------------------------------------------------------------


@dataclass
class RunResult:
    """What a run produced (the folder, the metrics and the maps)."""

    out_dir: Path | None
    metrics: dict[str, Any]
    maps: dict[str, Any] = field(default_factory=dict)
    paths: dict[str, np.ndarray] = field(default_factory=dict)
    error: BaseException | None = None
    sonar_ranges: list[tuple[int, str, tuple[float, float, float]]] = field(default_factory=list)


def default_out_dir(scenario: Scenario) -> Path:
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    return Path("runs") / f"{scenario.name}-{stamp}"


def run_scenario(
    scenario: Scenario | str | Path = "office_corridor",
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
    raycast_threads: int = 0,
    ground_truth_map: bool = True,
    pipeline: bool = True,
    sonar_hz: float | None = SONAR_HZ,
) -> RunResult:
    """Run a scenario headlessly and (with ``write``) write its run folder.

    Args:
        scenario: A :class:`Scenario`, or a scenario name / file.
        out_dir: Run folder (default ``runs/<scenario>-<UTC timestamp>``).
        duration, sensor, seed: Override the scenario's values.
        spec: Platform spec (default ``assets/robchair.toml``).
        progress: Show a tqdm progress bar (simulated vs wall time) on stderr.
        write_bag, pictures: Write the ROS 2 bag / the PNG pictures.
        camera_backend: ``"raycast"`` or ``"pybullet"``.
        write: Write the run folder at all (False: return the metrics and maps only).
        sensors: Simulate the Kinect and sonars (False: physics, motors and route following only).
        mapping_thread: Map Kinect frames on a second thread (overlapping the physics and sensors).
        raycast_threads: Embree threads of the ray caster (0 = all cores).
        ground_truth_map: Also build the map placed with ground-truth poses (for the comparison metrics).
        pipeline: Capture Kinect frames on background threads (two frames in flight with the ray
            caster) while the physics and sonars go on.
        sonar_hz: Sonar reading rate; None = as fast as the model's ranging time allows (SRF08: 15 Hz).

    Raises:
        ScenarioError: The scenario is invalid.
        SimulationDivergedError: The physics diverged (after the partial run folder was written).
    """
    from robchair.outdir import staged_output_dir
    from sim.backend import robot_radius

    spec = spec if spec is not None else load_spec()
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario, robot_radius=robot_radius(spec))
    duration = scenario.duration if duration is None else float(duration)
    if not (math.isfinite(duration) and duration > 0):
        raise SimError(f"duration must be a positive number of seconds, got {duration!r}")
    sensor = scenario.sensor if sensor is None else sensor
    seed = scenario.seed if seed is None else int(seed)
    if seed < 0:
        raise SimError(f"seed must be >= 0, got {seed}")
    if not write:
        res = _simulate(
            scenario,
            spec,
            duration,
            sensor,
            seed,
            None,
            progress,
            False,
            camera_backend,
            sensors,
            mapping_thread,
            raycast_threads,
            ground_truth_map,
            pipeline,
            sonar_hz,
        )
        if res.error is not None:
            raise res.error
        return res
    target = Path(out_dir) if out_dir is not None else default_out_dir(scenario)
    with staged_output_dir(target) as staging:
        res = _simulate(
            scenario,
            spec,
            duration,
            sensor,
            seed,
            staging,
            progress,
            write_bag,
            camera_backend,
            sensors,
            mapping_thread,
            raycast_threads,
            ground_truth_map,
            pipeline,
            sonar_hz,
        )
        _write_outputs(res, scenario, spec, staging, pictures)
    res.out_dir = target.resolve()
    if res.error is not None:
        raise res.error
    return res


def _grid_for(scenario: Scenario) -> Any:
    from mapping.grid import GridSpec

    x0, y0, x1, y1 = scenario.scene.bounds_xy()
    pts = np.array([*scenario.route.waypoints, scenario.start[:2]], dtype=float)
    x0, y0 = min(x0, pts[:, 0].min()), min(y0, pts[:, 1].min())
    x1, y1 = max(x1, pts[:, 0].max()), max(y1, pts[:, 1].max())
    x0, y0, x1, y1 = x0 - GRID_MARGIN, y0 - GRID_MARGIN, x1 + GRID_MARGIN, y1 + GRID_MARGIN
    # a whole (even) number of cells each way, as GridSpec requires
    nx, ny = (2 * math.ceil((b - a) / (2 * CELL_SIZE) - 1e-9) for a, b in ((x0, x1), (y0, y1)))
    return GridSpec(
        cell_size=CELL_SIZE,
        size_x=nx * CELL_SIZE,
        size_y=ny * CELL_SIZE,
        centre=((x0 + x1) / 2, (y0 + y1) / 2),
    )


def _simulate(
    scenario: Scenario,
    spec: RobChairSpec,
    duration: float,
    sensor: str,
    seed: int,
    out: Path | None,
    progress: bool,
    write_bag: bool,
    camera_backend: str,
    sensors: bool = True,
    mapping_thread: bool = True,
    raycast_threads: int = 0,
    ground_truth_map: bool = True,
    pipeline: bool = True,
    sonar_hz: float | None = SONAR_HZ,
) -> RunResult:
    from mapping.sonar import array_points, servo_command_deg
    from mapping.vhv import VHVMap
    from sim.backend import SimChair, SimSonarArray, backend_from_chair

    retain_freed_memory()  # per-frame arrays: reuse heap blocks instead of faulting in new pages
    wall0 = time.perf_counter()
    chair = SimChair(
        spec,
        scenario.scene,
        scenario.start,
        sensor=sensor if sensors else None,
        sonars=scenario.sonars and sensors,
        seed=seed,
        camera_backend=camera_backend,
        raycast_threads=raycast_threads,
    )
    world, robot = chair.world, chair.robot
    backend = backend_from_chair(chair)
    backend.open()
    grid = _grid_for(scenario)
    maps = {
        "odometry": VHVMap(grid, MAP_TOLERANCE),
        "ground_truth": VHVMap(grid, MAP_TOLERANCE),
        "sonar": VHVMap(grid, MAP_TOLERANCE),
    }
    drive = DiffDrive(spec)
    odom = Odometry(spec, Pose2D(*scenario.start))
    path = np.array([scenario.start[:2], *scenario.route.waypoints], dtype=float)
    follower = PurePursuit(path, scenario.route.speed, scenario.route.lookahead, drive)
    hz = world.physics_hz
    n_steps = round(duration * hz)
    every = {
        "control": hz // CONTROL_HZ,
        "kinect": hz // KINECT_HZ,
        "sonar": _sonar_every(chair, hz, sonar_hz),
    }
    cam = chair.kinect
    t_base_cam = spec.mounts["kinect_link"].transform()  # the chair's belief of where its Kinect sits
    t_cam_out = cam.output_pose(np.eye(4)) if cam is not None else np.eye(4)
    arrays: list[SimSonarArray] = [a for a in backend.sonar_arrays if isinstance(a, SimSonarArray)]
    servo_cmd = {a.mount: 90.0 for a in arrays}
    rec = None
    if write_bag and out is not None:
        from sim.recorder import BagRecorder

        rec = BagRecorder(out / "bag")
        statics_cam = [("base_link", "kinect_link", t_base_cam)]
        if cam is not None and cam.frame_id != "kinect_link":  # HD/qHD clouds are in the colour camera
            statics_cam.append(("kinect_link", cam.frame_id, t_cam_out))
        rec.tf(1, statics_cam, static=True)
        if chair.sonars:
            statics = []
            for mount, arr in chair.sonars.items():
                for k, t in enumerate(arr.sonar_poses(np.eye(4), 0.0), 1):
                    statics.append((mount, f"{mount}_{k}", t))
            rec.tf(1, statics, static=True)
    paths: dict[str, list[Any]] = {"t": [], "odometry": [], "ground_truth": []}
    frame_stats = {
        "kinect_frames": 0,
        "sonar_readings": 0,
        "points_in": 0,
        "points_dropped_nonfinite": 0,
        "points_outside_grid": 0,
        "sonar_points": 0,
        "sonar_fusions_with_obstacle": 0,
    }
    mapper = _Mapper(maps, frame_stats, threaded=mapping_thread, ground_truth=ground_truth_map)
    timing = {"physics": 0.0, "kinect_capture": 0.0, "sonar": 0.0}
    sonar_ranges: list[tuple[int, str, tuple[float, float, float]]] = []
    error: BaseException | None = None
    v_cmd = w_cmd = 0.0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(
            total=round(duration, 3),
            unit="sim s",
            desc=f"sim {scenario.name}",
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} sim s "
            "[{elapsed} wall, {rate_fmt}{postfix}]",
        )
    camera = _Camera(chair, mapper, rec, threaded=pipeline, timing=timing) if cam is not None else None
    loop0 = time.perf_counter()
    setup_wall = loop0 - wall0
    try:
        for step in range(n_steps + 1):
            stamp = world.now_ns()
            if step % every["control"] == 0:
                st = backend.motors.read_state()
                pose = odom.update(*st.encoder_counts)
                gt = robot.pose2d()  # raises SimulationDivergedError on a non-finite pose
                paths["t"].append(stamp)
                paths["odometry"].append((pose.x, pose.y, pose.theta))
                paths["ground_truth"].append((gt.x, gt.y, gt.theta))
                if rec is not None and step % (2 * every["control"]) == 0:
                    rec.odometry(
                        "/odom", stamp, "odom", "base_link", pose.x, pose.y, pose.theta, v_cmd, w_cmd
                    )
                    rec.odometry("/ground_truth/odom", stamp, "map", "base_link_gt", gt.x, gt.y, gt.theta)
                    rec.tf(stamp, [("odom", "base_link", planar_transform(pose.x, pose.y, pose.theta))])
                v_cmd, w_cmd = follower.command(pose)
                backend.motors.set_speeds_rpm(*drive.motor_rpm(v_cmd, w_cmd))
            if camera is not None and step % every["kinect"] == 0:
                t_world_cam_gt = chair.kinect_pose()
                pose = odom.pose
                t_odom = planar_transform(pose.x, pose.y, pose.theta) @ t_base_cam @ t_cam_out
                camera.submit(
                    t_world_cam_gt,
                    t_odom,
                    t_world_cam_gt @ t_cam_out,
                    stamp,
                    rec is not None and step % (hz // BAG_CLOUD_HZ) == 0,
                )
            if arrays and step % every["sonar"] == 0:
                ts = time.perf_counter()
                pose = odom.pose
                for arr in arrays:
                    reading = arr.read()
                    frame_stats["sonar_readings"] += 1
                    sonar_ranges.append((stamp, arr.mount, reading.ranges_m))
                    fusion, spts = array_points(reading.ranges_m)
                    if fusion.has_obstacle:
                        frame_stats["sonar_fusions_with_obstacle"] += 1
                    if len(spts):
                        joint_rad = math.radians(reading.servo_angle_deg - 90.0)
                        t_arr = planar_transform(pose.x, pose.y, pose.theta) @ spec.mounts[
                            arr.mount
                        ].transform(joint_rad)
                        maps["sonar"].insert(
                            spts @ t_arr[:3, :3].T + t_arr[:3, 3], sensor_origin=t_arr[:3, 3]
                        )
                        frame_stats["sonar_points"] += len(spts)
                    servo_cmd[arr.mount] = servo_command_deg(
                        fusion, servo_cmd[arr.mount], gain=0.5, max_step_deg=15.0
                    )
                    arr.set_servo_deg(servo_cmd[arr.mount])
                    if rec is not None:
                        model = chair.sonars[arr.mount].model
                        for k, r in enumerate(reading.ranges_m, 1):
                            rec.range(
                                f"/sonar/{arr.mount}_{k}",
                                stamp,
                                f"{arr.mount}_{k}",
                                r,
                                model.min_range_m,
                                model.max_range_m,
                                model.field_of_view_rad,
                            )
                        rec.tf(
                            stamp,
                            [
                                (
                                    "base_link",
                                    arr.mount,
                                    spec.mounts[arr.mount].transform(
                                        math.radians(reading.servo_angle_deg - 90)
                                    ),
                                )
                            ],
                        )
                timing["sonar"] += time.perf_counter() - ts
            if step < n_steps:
                if camera is not None and chair.bodies.moving:
                    camera.collect()  # people must not move while a frame is being captured
                tp = time.perf_counter()
                chair.step(1)
                timing["physics"] += time.perf_counter() - tp
            if bar is not None and step % hz == 0 and step:
                wall = time.perf_counter() - loop0
                bar.set_postfix_str(f"RTF {world.time / max(wall, 1e-9):.2f}")
                bar.update(1.0)
    except SimulationDivergedError as exc:
        error = exc
        log.error("%s; writing what was recorded so far", exc)
    finally:
        if bar is not None:
            bar.close()
        try:
            if camera is not None:
                camera.close()  # the frame in flight goes to the map and the bag too
        finally:
            mapper.close()  # waits for the frames in flight; re-raises a mapping error
        if rec is not None:
            rec.close()
        backend.close()
    loop_wall = time.perf_counter() - loop0
    sim_time = world.time
    chair.close()
    arr_paths = {k: np.asarray(v, dtype=np.float64 if k != "t" else np.int64) for k, v in paths.items()}
    metrics = _metrics(
        scenario,
        spec,
        sensor,
        seed,
        duration,
        sim_time,
        loop_wall,
        time.perf_counter() - wall0,
        mapper.map_ms,
        frame_stats,
        arr_paths,
        maps,
        odom,
        follower,
        error,
    )
    metrics["camera_backend"] = camera_backend
    metrics["tyre_radius_scale"] = list(chair.wheel_radius_scale)
    metrics["odometry_drift"]["source"] = (
        "the simulated tyres' true radii differ from the spec's by tyre_radius_scale (seeded, 0.2 % sd); "
        "the odometry assumes the spec's radius, plus wheel slip from the physics"
    )
    metrics["wall_time_s"]["setup"] = setup_wall
    metrics["wall_time_s"]["components"] = timing  # summed per component, whichever thread ran it
    res = RunResult(None, metrics, maps, arr_paths, error, sonar_ranges)
    if rec is not None:
        metrics["bag"] = {
            "path": "bag",
            "messages": dict(sorted(rec.counts.items())),
            "cloud_rate_hz": BAG_CLOUD_HZ,
            "cloud_stride": BAG_CLOUD_STRIDE,
        }
    return res


def retain_freed_memory(limit_bytes: int = 1 << 30) -> bool:
    """Ask glibc's allocator to keep freed blocks up to ``limit_bytes`` for reuse; True if it agreed.

    Every sensor frame allocates a few multi-megabyte arrays and frees them a frame later. By
    default glibc serves such blocks with fresh ``mmap`` pages and returns them on ``free``, so
    each frame pays a page fault per 4 KiB it touches: measured here, a Kinect v2 capture took
    49 ms that way and 28 ms with the blocks kept. Raising the mmap and trim thresholds keeps them
    in the heap. Process-wide and harmless (memory use is bounded by the peak); a no-op where the
    C library is not glibc.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    limit = min(int(limit_bytes), 2**31 - 1)
    # older glibc caps the mmap threshold at 32 MiB (64-bit): fall back to that
    ok = bool(mallopt(m_mmap_threshold, ctypes.c_int(limit))) or bool(
        mallopt(m_mmap_threshold, ctypes.c_int(min(limit, 32 << 20)))
    )
    return ok and bool(mallopt(m_trim_threshold, ctypes.c_int(limit)))


def _sonar_every(chair: Any, hz: int, sonar_hz: float | None) -> int:
    """Physics steps between sonar readings: ``sonar_hz``, or the ranging time (SRF08: 65 ms, 15 Hz)."""
    if sonar_hz is not None:
        if not (math.isfinite(sonar_hz) and 0 < sonar_hz <= hz):
            raise SimError(f"sonar_hz must be in (0, {hz}], got {sonar_hz!r}")
        return max(1, round(hz / sonar_hz))
    if not chair.sonars:
        return hz
    ranging = max(arr.model.ranging_time_s for arr in chair.sonars.values())
    return max(1, math.ceil(ranging * hz - 1e-9))


class _Camera:
    """Captures Kinect frames on background threads, up to two frames in flight, delivered in order.

    Frames k and k + 1 are captured (on two threads, so on both cores) while the simulation thread
    steps the physics and reads the sonars; each is handed to the mapper (and the bag, whose sqlite
    connection belongs to the simulation thread) in frame order once a third frame is submitted.
    Determinism: the ray-casting mirror is synced on the simulation thread before each capture, the
    chair itself is not in the mirror, scripted people are never moved while a capture is in flight
    (:meth:`collect` first), and each frame's random words are drawn on the simulation thread in
    frame order (:meth:`sim.kinect.KinectSim.noise_bits`), so every frame is the one a serial run
    captures. PyBullet's renderer is not thread-safe: with that backend one frame at a time.
    """

    def __init__(
        self, chair: Any, mapper: _Mapper, rec: Any, threaded: bool, timing: dict[str, float]
    ) -> None:
        import threading
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor

        self.chair, self.cam, self.mapper, self.rec, self.timing = chair, chair.kinect, mapper, rec, timing
        self.max_inflight = 2 if self.cam.backend == "raycast" else 1
        self.pool = (
            ThreadPoolExecutor(max_workers=self.max_inflight, thread_name_prefix="kinect")
            if threaded
            else None
        )
        self.inflight: deque[tuple[Any, np.ndarray, np.ndarray, bool]] = deque()
        self._lock = threading.Lock()

    def _capture(self, pose: np.ndarray, stamp: int, bits: Any = None) -> Any:
        t0 = time.perf_counter()
        frame = self.cam.capture(pose, stamp_ns=stamp, noise_bits=bits)
        with self._lock:  # two capture threads add to the same total
            self.timing["kinect_capture"] += time.perf_counter() - t0
        return frame

    def _deliver(self, frame: Any, t_odom: np.ndarray, t_gt: np.ndarray, record: bool) -> None:
        self.mapper.submit(frame, t_odom, t_gt)
        if record:
            self.rec.cloud(
                "/kinect/points",
                frame.stamp_ns,
                frame.frame_id,
                frame.points[::BAG_CLOUD_STRIDE, ::BAG_CLOUD_STRIDE],
            )

    def submit(
        self, pose: np.ndarray, t_odom: np.ndarray, t_gt: np.ndarray, stamp: int, record: bool
    ) -> None:
        """Capture at the camera's world ``pose``; map with ``t_odom`` / ``t_gt`` (world <- cloud frame)."""
        if self.pool is None:
            self._deliver(self._capture(pose, stamp), t_odom, t_gt, record)
            return
        while len(self.inflight) >= self.max_inflight:
            self._deliver_oldest()
        if self.chair.mirror is not None:
            self.chair.mirror.sync()  # here, so the capture thread's own sync finds nothing to do
        bits = self.cam.noise_bits()  # in frame order, on this thread
        self.inflight.append((self.pool.submit(self._capture, pose, stamp, bits), t_odom, t_gt, record))

    def _deliver_oldest(self) -> None:
        fut, t_odom, t_gt, record = self.inflight.popleft()
        self._deliver(fut.result(), t_odom, t_gt, record)

    def collect(self) -> None:
        """Wait for the frames in flight (if any) and hand them on, oldest first."""
        while self.inflight:
            self._deliver_oldest()

    def close(self) -> None:
        try:
            self.collect()
        finally:
            if self.pool is not None:
                self.pool.shutdown(wait=True)


class _Mapper:
    """Maps Kinect frames on one background thread, in submission order (so the maps are deterministic).

    The simulation thread captures a frame and hands it over; transforming and inserting it into the
    odometry and ground-truth maps (numpy and numba kernels that release the GIL) then overlaps with
    the next physics steps and sensor reads on the second core. At most ``max_pending`` frames wait.
    """

    def __init__(
        self,
        maps: dict[str, Any],
        stats: dict[str, int],
        max_pending: int = 3,
        threaded: bool = True,
        ground_truth: bool = True,
    ) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.maps, self.stats = maps, stats
        self.ground_truth = ground_truth
        self.map_ms: list[float] = []
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vhv-mapper") if threaded else None
        self.pending: list[Any] = []
        self.max_pending = max_pending

    def _job(self, frame: Any, t_odom: np.ndarray, t_gt: np.ndarray) -> None:
        pts = frame.points
        s = self.maps["odometry"].insert(transform_points(t_odom, pts), sensor_origin=t_odom[:3, 3])
        if self.ground_truth:
            self.maps["ground_truth"].insert(transform_points(t_gt, pts), sensor_origin=t_gt[:3, 3])
        self.map_ms.append(s.build_ms)
        st = self.stats
        st["kinect_frames"] += 1
        st["points_in"] += s.points_in
        st["points_dropped_nonfinite"] += s.points_dropped_nonfinite
        st["points_outside_grid"] += s.points_outside_grid

    def submit(self, frame: Any, t_odom: np.ndarray, t_gt: np.ndarray) -> None:
        if self.pool is None:
            self._job(frame, t_odom, t_gt)
            return
        still = []
        for f in self.pending:
            if f.done():
                f.result()  # re-raise a mapping error now rather than at the end
            else:
                still.append(f)
        self.pending = still
        while len(self.pending) >= self.max_pending:
            self.pending.pop(0).result()
        self.pending.append(self.pool.submit(self._job, frame, t_odom, t_gt))

    def close(self) -> None:
        try:
            for f in self.pending:
                f.result()
        finally:
            if self.pool is not None:
                self.pool.shutdown(wait=True)
            self.pending = []


def _metrics(
    scenario: Scenario,
    spec: RobChairSpec,
    sensor: str,
    seed: int,
    duration: float,
    sim_time: float,
    loop_wall: float,
    total_wall: float,
    map_ms: list[float],
    stats: dict[str, int],
    paths: dict[str, np.ndarray],
    maps: dict[str, Any],
    odom: Odometry,
    follower: PurePursuit,
    error: BaseException | None,
) -> dict[str, Any]:
    grid = maps["odometry"].spec
    shape = grid.shape
    band = (OCC_BAND[0], spec.body.height)
    occ = {k: occupancy(maps[k].structures(), shape, *band) for k in ("odometry", "ground_truth")}
    gt_scene = scene_occupancy(scenario, grid, band)
    od, gp = paths["odometry"], paths["ground_truth"]
    if len(od):
        err = np.hypot(od[:, 0] - gp[:, 0], od[:, 1] - gp[:, 1])
        heading = np.abs([wrap_angle(a - b) for a, b in zip(od[:, 2], gp[:, 2])])
        travelled = float(np.sum(np.hypot(*np.diff(gp[:, :2], axis=0).T))) if len(gp) > 1 else 0.0
    else:
        err = heading = np.zeros(1)
        travelled = 0.0

    def prf(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
        # one-cell tolerance both ways: a cell counts as right when the other map has one next to it
        tp_p = int(np.sum(pred & dilate(truth)))
        tp_r = int(np.sum(truth & dilate(pred)))
        return {"precision": tp_p / max(int(pred.sum()), 1), "recall": tp_r / max(int(truth.sum()), 1)}

    inter = int(np.sum(occ["odometry"] & occ["ground_truth"]))
    union = int(np.sum(occ["odometry"] | occ["ground_truth"]))
    ms = np.asarray(map_ms) if map_ms else np.array([np.nan])
    return {
        "scenario": scenario.name,
        "scene": scenario.scene.name,
        "sensor": sensor,
        "seed": seed,
        "duration_s": duration,
        "sim_time_s": sim_time,
        "status": "diverged" if error is not None else "ok",
        "error": str(error) if error is not None else None,
        "frames": {k: int(v) for k, v in stats.items()},
        "mapping_ms_per_frame_median": float(np.median(ms)),
        "mapping_ms_per_frame_p90": float(np.percentile(ms, 90)),
        "mapping_ms_total": float(np.sum(map_ms)) if map_ms else 0.0,
        "wall_time_s": {"loop": loop_wall, "total_simulation": total_wall},
        "real_time_factor": sim_time / loop_wall if loop_wall > 0 else None,
        "route": {"goal_reached": follower.done, "distance_travelled_m": travelled},
        "odometry_drift": {
            "final_position_error_m": float(err[-1]),
            "max_position_error_m": float(err.max()),
            "final_heading_error_rad": float(heading[-1]),
            "position_error_per_metre": float(err[-1] / travelled) if travelled > 0 else None,
        },
        "map": {
            "grid": {"cell_size": grid.cell_size, "shape": list(shape), "centre": list(grid.centre)},
            "tolerance": MAP_TOLERANCE,
            "occupancy_band_m": list(band),
            "structures": {k: int(m.n_structures) for k, m in maps.items()},
            "occupied_cells": {k: int(v.sum()) for k, v in occ.items()},
            "iou_odometry_vs_ground_truth_pose": inter / union if union else None,
            "odometry_map_vs_scene": prf(occ["odometry"], gt_scene),
            "ground_truth_pose_map_vs_scene": prf(occ["ground_truth"], gt_scene),
            "scene_occupied_cells": int(gt_scene.sum()),
            "notes": "occupancy = a structure overlapping the band; precision/recall with one-cell tolerance "
            "against the static scene rasterised from its meshes (moving people are not in the "
            "scene truth; recall counts every static surface, seen or not, so it measures coverage)",
        },
    }


_truth_cache: dict[tuple[Any, ...], np.ndarray] = {}


def scene_occupancy(scenario: Scenario, grid: Any, band: tuple[float, float]) -> np.ndarray:
    """Ground-truth 2D occupancy of the static scene: surface samples in the height band, rasterised.

    About four samples per cell side (spacing cell/2 over each surface, area-weighted), so even a 5 cm
    table leg marks its cell; cached per (scene file, grid, band).
    """
    key = (str(scenario.scene.path), scenario.scene.objects, grid, band)
    if key in _truth_cache:
        return _truth_cache[key].copy()
    rng = np.random.default_rng(0)  # fixed: the truth must not depend on the run's seed
    pts = ground_truth_points(scenario.scene, grid.cell_size / 2, rng)
    occ = np.zeros(grid.shape, dtype=bool)
    if len(pts) == 0:
        return occ
    pts = pts[(pts[:, 2] >= band[0]) & (pts[:, 2] <= band[1])]
    i, j = grid.world_to_index(pts[:, 0], pts[:, 1])
    ok = (i >= 0) & (i < grid.shape[0]) & (j >= 0) & (j < grid.shape[1])
    occ[i[ok], j[ok]] = True
    _truth_cache[key] = occ
    return occ.copy()


# ------------------------------------------------------------------------------------------------
# outputs
# ------------------------------------------------------------------------------------------------


def _write_outputs(res: RunResult, scenario: Scenario, spec: RobChairSpec, out: Path, pictures: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {}
    for name, m in res.maps.items():
        s = m.structures()
        arrays[f"{name}_i"] = np.asarray(s.i)
        arrays[f"{name}_j"] = np.asarray(s.j)
        arrays[f"{name}_bottom"] = np.asarray(s.bottom)
        arrays[f"{name}_top"] = np.asarray(s.top)
    for name, p in res.paths.items():
        arrays[f"path_{name}"] = p
    np.savez_compressed(out / "maps.npz", **arrays)  # type: ignore[arg-type]
    files = ["metrics.json", "maps.npz"]
    t0 = time.perf_counter()
    exports = _export_maps(res, out, spec.body.height)
    res.metrics["wall_time_s"]["map_exports"] = time.perf_counter() - t0
    files += exports
    if pictures:
        t0 = time.perf_counter()
        files += write_pictures(res, scenario, spec, out)
        res.metrics["wall_time_s"]["pictures"] = time.perf_counter() - t0
    if "bag" in res.metrics:
        files.append("bag")
    res.metrics["files"] = sorted(files)
    (out / "metrics.json").write_text(
        json.dumps(res.metrics, indent=2, allow_nan=False, default=_json_default) + "\n"
    )


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _export_maps(res: RunResult, out: Path, spec_height: float) -> list[str]:
    """M2's map exports (occupancy PGM/YAML, meshes, marker bag) of the odometry map, when available."""
    try:
        from mapping.export import write_map_outputs  # type: ignore[attr-defined]
    except ImportError:
        log.info("mapping.export.write_map_outputs not available: maps.npz only")
        return []
    d = out / "map_odometry"
    d.mkdir()
    try:
        write_map_outputs(
            res.maps["odometry"],
            d,
            band=(OCC_BAND[0], spec_height),
            build_ms=res.metrics["mapping_ms_total"],
            parameters={"scenario": res.metrics["scenario"], "pose_source": "odometry"},
        )
    except ImportError as exc:  # a mapping module it needs is not built yet; keep the run
        log.warning("map exports skipped (%s): maps.npz holds the maps", exc)
        shutil.rmtree(d, ignore_errors=True)
        return []
    return [d.name]


def write_pictures(res: RunResult, scenario: Scenario, spec: RobChairSpec, out: Path) -> list[str]:
    """scene.png (rendered view), map_2d.png, elevation.png, structures_3d.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    img = render_scene(scenario, spec, res.paths.get("ground_truth"))
    plt.imsave(out / "scene.png", img)
    files.append("scene.png")

    m = res.maps["odometry"]
    grid = m.spec
    shape = grid.shape
    band = (OCC_BAND[0], spec.body.height)
    x0, y0 = grid.index_to_world(np.array([0]), np.array([0]))
    h = grid.cell_size / 2
    extent = (
        float(x0[0]) - h,
        float(x0[0]) - h + shape[0] * grid.cell_size,
        float(y0[0]) - h,
        float(y0[0]) - h + shape[1] * grid.cell_size,
    )
    occ = occupancy(m.structures(), shape, *band)
    truth = scene_occupancy(scenario, grid, band)
    fig, ax = plt.subplots(figsize=(9, 9 * shape[1] / max(shape[0], 1) + 1), dpi=110)
    rgb = np.ones((*shape, 3))
    rgb[truth] = (1.0, 0.8, 0.8)
    rgb[occ] = (0.15, 0.15, 0.15)
    ax.imshow(np.transpose(rgb, (1, 0, 2)), origin="lower", extent=extent, interpolation="nearest")
    for key, col, lab in (
        ("ground_truth", "tab:green", "ground truth"),
        ("odometry", "tab:blue", "odometry"),
    ):
        p = res.paths.get(key)
        if p is not None and len(p):
            ax.plot(p[:, 0], p[:, 1], color=col, lw=1.6, label=f"path ({lab})")
    wp = np.asarray(scenario.route.waypoints)
    ax.plot(wp[:, 0], wp[:, 1], "x", color="tab:orange", label="route waypoints")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        f"{scenario.name}: 2D occupancy {band[0]:.2f}-{band[1]:.2f} m from the odometry map\n"
        "(black: mapped, pink: scene truth)"
    )
    ax.legend(loc="upper right", fontsize=8)
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out / "map_2d.png")
    plt.close(fig)
    files.append("map_2d.png")

    elev = elevation(m.structures(), shape)
    fig, ax = plt.subplots(figsize=(9, 9 * shape[1] / max(shape[0], 1) + 1), dpi=110)
    im = ax.imshow(elev.T, origin="lower", extent=extent, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=ax, label="highest point (m)", shrink=0.8)
    ax.set_title(f"{scenario.name}: 2.5D elevation map (odometry)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out / "elevation.png")
    plt.close(fig)
    files.append("elevation.png")

    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    s = m.structures()
    fig = plt.figure(figsize=(10, 7), dpi=110)
    ax3 = fig.add_subplot(projection="3d")
    if len(s) and np.any(np.asarray(s.top) >= OCC_BAND[0]):
        cx, cy = grid.index_to_world(np.asarray(s.i), np.asarray(s.j))
        # the floor is most of the structures and hides everything else; draw what stands on it
        keep = np.flatnonzero(np.asarray(s.top) >= OCC_BAND[0])
        if len(keep) > 40000:  # the picture cannot show more; the choice is deterministic
            keep = keep[:: math.ceil(len(keep) / 40000)]
        segs = np.stack(
            [
                np.stack([cx[keep], cy[keep], np.asarray(s.bottom)[keep]], -1),
                np.stack([cx[keep], cy[keep], np.asarray(s.top)[keep] + 0.01], -1),
            ],
            axis=1,
        )
        cmap = plt.get_cmap("viridis")
        top = np.asarray(s.top)[keep]
        cols = cmap(np.clip(top / max(float(top.max()), 1e-6), 0, 1))
        ax3.add_collection3d(Line3DCollection(segs, colors=cols, linewidths=2.0))
        ax3.set_xlim(extent[0], extent[1])
        ax3.set_ylim(extent[2], extent[3])
        ax3.set_zlim(0, max(2.5, float(top.max())))
        span = (extent[1] - extent[0], extent[3] - extent[2], 3.0)
        ax3.set_box_aspect(span)
    ax3.set_title(
        f"{scenario.name}: variable-height voxel structures above {OCC_BAND[0]:.2f} m (map total {len(s)})"
    )
    ax3.view_init(elev=40, azim=-65)
    fig.tight_layout()
    fig.savefig(out / "structures_3d.png")
    plt.close(fig)
    files.append("structures_3d.png")
    return files


def render_scene(
    scenario: Scenario,
    spec: RobChairSpec,
    path: np.ndarray | None = None,
    width: int = 960,
    height: int = 600,
) -> np.ndarray:
    """A rendered overview of the scene (PyBullet's TinyRenderer), with the chair at its start pose."""
    import pybullet as p

    from sim.backend import SimChair

    chair = SimChair(spec, scenario.scene, scenario.start, sensor=None, sonars=False)
    try:
        x0, y0, x1, y1 = scenario.scene.bounds_xy()
        target = ((x0 + x1) / 2, (y0 + y1) / 2, 0.0)
        dist = 0.75 * max(x1 - x0, y1 - y0) + 2.0
        view = p.computeViewMatrixFromYawPitchRoll(target, dist, yaw=-30, pitch=-50, roll=0, upAxisIndex=2)
        proj = p.computeProjectionMatrixFOV(fov=50, aspect=width / height, nearVal=0.1, farVal=200)
        img = p.getCameraImage(
            width,
            height,
            view,
            proj,
            renderer=p.ER_TINY_RENDERER,
            lightDirection=(0.4, -0.3, 1.0),
            shadow=1,
            physicsClientId=chair.world.client,
        )
        rgba = np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))
        return rgba[..., :3].copy()
    finally:
        chair.close()
