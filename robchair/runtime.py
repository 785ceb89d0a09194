"""The runtime: one fixed-rate loop that senses, maps, decides, passes the safety layer, and drives.

The same loop runs the simulated chair, the emulated one and the real one (``hw.registry``); it only
sees :class:`hw.interfaces.Backend`. One cycle, at ``t_k = t_0 + k / rate_hz`` on the backend's clock:

1. **sense**: motor state (encoder counts, speeds, faults) -> odometry; each sonar array -> five-zone
   fusion (:func:`mapping.sonar.fuse_array`) -> distance of the nearest fused obstacle inside the
   corridor ahead; every ``map_every`` cycles, if there is a depth camera, its cloud -> a local
   variable-height-voxel map (:class:`mapping.vhv.VHVMap`) -> 2D occupancy in the chair's height band
   -> distance of the nearest occupied cell in the corridor ahead;
2. **decide**: the command source (scripted route with pure pursuit, joystick with dead-man button,
   or any policy callable) gives a body twist (v, w);
3. **safety**: :class:`robchair.safety.SafetyLayer` limits or stops it (stops logged with reasons);
4. **act**: twist -> motor RPM (:class:`robchair.kinematics.DiffDrive`) -> ``set_speeds_rpm`` (every
   cycle, even when unchanged: only runtime commands feed the Roboteq's watchdog);
5. **record**: odometry, sonar ranges and the odom -> base_link transform into a ROS 2 bag;
6. **wait** for ``t_{k+1}``. A cycle that ends after its period (plus ``deadline_slack``) is a missed
   deadline: the next cycle stops the chair, and the schedule restarts from now (no catch-up burst).

A driver fault (any :class:`hw.errors.HardwareError` from the motors, or fault flags) stops the chair
(the driver has already sent its stop), is latched by the safety layer and ends the run. Sensors that
give nothing new for ``SafetyLimits.stale_after_s`` stop the chair until they recover.
"""

from __future__ import annotations

import json
import logging
import math
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from hw.errors import HardwareError
from hw.interfaces import Backend, MotorState, SonarArrayReading
from robchair.errors import ConfigError
from robchair.kinematics import DiffDrive, Odometry, Pose2D
from robchair.safety import SafetyDecision, SafetyInputs, SafetyLayer, SafetyLimits

log = logging.getLogger(__name__)

SERVO_CENTRE_DEG = 90.0  # hw convention: servo 0..180 deg, 90 = the array faces its mount's x axis
OUTER_SONAR_DEG = 30.0
DEPTH_CAMERA = "depth_camera"


# --- command sources ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Observation:
    """What a command source sees each cycle."""

    stamp_ns: int
    pose: Pose2D
    motor: MotorState | None
    sonars: tuple[SonarArrayReading | None, ...]
    obstacle_distance_m: float | None  # nearest of the sonar and map distances ahead


@dataclass(frozen=True)
class Command:
    v: float
    w: float
    deadman: bool | None = None  # joystick button; None when the source has none
    done: bool = False  # the source has finished (route completed)


class CommandSource(Protocol):
    def command(self, obs: Observation) -> Command: ...


@dataclass(frozen=True)
class Route:
    """A scripted route: waypoints in the odometry frame (m) and how to follow them.

    TOML file::

        waypoints = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.5]]
        speed = 0.3            # cruise speed, m/s
        lookahead_m = 0.6      # pure-pursuit look-ahead distance
        goal_tolerance_m = 0.1 # done when this close to the last waypoint
    """

    waypoints: tuple[tuple[float, float], ...]
    speed: float = 0.3
    lookahead_m: float = 0.6
    goal_tolerance_m: float = 0.1

    def __post_init__(self) -> None:
        if len(self.waypoints) < 2:
            raise ConfigError(f"route.waypoints: expected at least 2 points, got {len(self.waypoints)}")
        for i, p in enumerate(self.waypoints):
            if len(p) != 2 or not all(math.isfinite(c) for c in p):
                raise ConfigError(f"route.waypoints[{i}] = {p!r}: expected finite [x, y]")
        for name in ("speed", "lookahead_m", "goal_tolerance_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"route.{name} = {v!r}: expected a finite number > 0")

    @classmethod
    def load(cls, path: Path | str) -> Route:
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"route file {path}: not valid TOML: {exc}") from exc
        return cls.from_dict(data, str(path))

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "<dict>") -> Route:
        allowed = {"waypoints", "speed", "lookahead_m", "goal_tolerance_m"}
        unknown = set(data) - allowed
        if unknown:
            raise ConfigError(f"route {source}: unknown keys {sorted(unknown)}; allowed {sorted(allowed)}")
        if "waypoints" not in data:
            raise ConfigError(f"route {source}: 'waypoints' is required")
        try:
            wps = tuple((float(p[0]), float(p[1])) if len(p) == 2 else tuple(p) for p in data["waypoints"])
            kw = {k: float(data[k]) for k in ("speed", "lookahead_m", "goal_tolerance_m") if k in data}
        except (TypeError, ValueError, IndexError) as exc:
            raise ConfigError(f"route {source}: waypoints must be [[x, y], ...] numbers: {exc}") from exc
        return cls(wps, **kw)  # type: ignore[arg-type]


class PurePursuit:
    """Follow a :class:`Route` with pure pursuit (Coulter 1992) on the differential drive.

    The goal point is ``lookahead_m`` along the path beyond the closest point of the path (progress
    never goes backwards). Curvature to reach it: ``k = 2 y_r / l^2`` with ``y_r`` its lateral offset
    in the chair's frame and ``l`` its distance; ``w = v k``. The speed is the cruise speed, reduced so
    the chair can stop at the last waypoint (``v <= sqrt(2 a d)``), and the twist is scaled to the
    platform's wheel limits keeping the curvature. A goal point behind the chair turns it in place.
    """

    def __init__(self, route: Route, drive: DiffDrive, decel: float = 0.4) -> None:
        self.route = route
        self.drive = drive
        self.decel = decel
        self._pts = np.asarray(route.waypoints, dtype=float)
        seg = np.diff(self._pts, axis=0)
        self._seg_len = np.hypot(seg[:, 0], seg[:, 1])
        self._cum = np.concatenate([[0.0], np.cumsum(self._seg_len)])
        self.length = float(self._cum[-1])
        self._s = 0.0  # progress along the path, m
        self.done = False

    def _point_at(self, s: float) -> np.ndarray:
        s = min(max(s, 0.0), self.length)
        i = int(np.searchsorted(self._cum, s, side="right") - 1)
        i = min(i, len(self._seg_len) - 1)
        t = (s - self._cum[i]) / self._seg_len[i] if self._seg_len[i] > 0 else 0.0
        return self._pts[i] + t * (self._pts[i + 1] - self._pts[i])

    def _project(self, p: np.ndarray) -> float:
        """Arc length of the closest path point to ``p`` at or after the current progress."""
        best_s, best_d = self._s, math.inf
        for i in range(len(self._seg_len)):
            a, b, ln = self._pts[i], self._pts[i + 1], self._seg_len[i]
            if ln == 0 or self._cum[i + 1] < self._s:
                continue
            t = float(np.clip(np.dot(p - a, b - a) / ln**2, 0.0, 1.0))
            s = max(self._cum[i] + t * ln, self._s)
            d = float(np.hypot(*(p - self._point_at(s))))
            if d < best_d - 1e-12:
                best_s, best_d = s, d
        return best_s

    def cross_track_error(self, pose: Pose2D) -> float:
        p = np.array([pose.x, pose.y])
        return float(np.hypot(*(p - self._point_at(self._project(p)))))

    def command(self, obs: Observation) -> Command:
        pose = obs.pose
        p = np.array([pose.x, pose.y])
        goal = self._pts[-1]
        to_goal = float(np.hypot(*(goal - p)))
        self._s = self._project(p)
        if to_goal <= self.route.goal_tolerance_m and self._s >= self.length - self.route.lookahead_m:
            self.done = True
            return Command(0.0, 0.0, done=True)
        target = self._point_at(self._s + self.route.lookahead_m)
        if self._s + self.route.lookahead_m >= self.length:
            target = goal
        dx, dy = target - p
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        x_r, y_r = c * dx + s * dy, -s * dx + c * dy
        l2 = x_r * x_r + y_r * y_r
        v = min(self.route.speed, math.sqrt(2.0 * self.decel * to_goal))
        if x_r <= 0.0:  # goal point behind: turn in place toward it
            w = math.copysign(0.5 * self.drive.max_yaw_rate, y_r if y_r != 0 else 1.0)
            return Command(0.0, w)
        w = v * 2.0 * y_r / l2 if l2 > 0 else 0.0
        v, w = self.drive.limit(v, w)
        return Command(v, w)


class JoystickSource:
    """Twist from a :class:`hw.interfaces.Joystick`: forward and turn axes scaled to the speed caps."""

    def __init__(self, joystick: Any, max_speed: float, max_yaw_rate: float) -> None:
        self.joystick = joystick
        self.max_speed = max_speed
        self.max_yaw_rate = max_yaw_rate

    def command(self, obs: Observation) -> Command:
        r = self.joystick.read()
        return Command(r.forward * self.max_speed, r.turn * self.max_yaw_rate, deadman=bool(r.deadman))


class PolicySource:
    """Any callable ``policy(observation) -> (v, w)`` (a learned policy, a test script)."""

    def __init__(self, policy: Callable[[Observation], tuple[float, float]]) -> None:
        self.policy = policy

    def command(self, obs: Observation) -> Command:
        v, w = self.policy(obs)
        return Command(float(v), float(w))


# --- perception helpers ------------------------------------------------------------------------


@dataclass(frozen=True)
class Corridor:
    """The strip the chair will sweep driving forward, in ``base_link`` (x forward, y left)."""

    front_x: float  # x of the footprint's front edge, m
    half_width: float  # half of the chair's width plus a lateral margin, m

    @classmethod
    def from_spec(cls, spec: Any, lateral_margin: float = 0.05) -> Corridor:
        b = spec.body
        return cls(b.centre_x + 0.5 * b.depth, 0.5 * b.width + lateral_margin)

    def distance_ahead(self, xy: np.ndarray) -> float | None:
        """Distance from the front edge to the nearest point (N, 2) in the corridor ahead (None: none)."""
        if xy.size == 0:
            return None
        inside = (np.abs(xy[:, 1]) <= self.half_width) & (xy[:, 0] > 0.0)
        if not inside.any():
            return None
        return max(0.0, float(xy[inside, 0].min()) - self.front_x)


def sonar_obstacle_points(reading: SonarArrayReading, mount: Any, n_arc: int = 9) -> np.ndarray:
    """Points (N, 2) in ``base_link`` where the fused obstacle of one array reading may lie.

    Five-zone fusion (thesis 5.2) gives the distance ``d`` and the bearing interval holding the
    obstacle; the obstacle may be anywhere on that arc, so the arc is sampled (conservative).
    """
    from mapping.sonar import fuse_array

    r1, r2, r3 = (float(r) if math.isfinite(r) else math.nan for r in reading.ranges_m)
    res = fuse_array(r1, r2, r3)
    if not res.has_obstacle:
        return np.zeros((0, 2))
    yaw0 = mount.rpy[2] + math.radians(reading.servo_angle_deg - SERVO_CENTRE_DEG)
    bearings = np.radians(np.linspace(res.alpha_deg, res.alpha_deg + res.theta_deg, n_arc)) + yaw0
    x0, y0 = mount.xyz[0], mount.xyz[1]
    return np.stack([x0 + res.distance_m * np.cos(bearings), y0 + res.distance_m * np.sin(bearings)], axis=1)


class LocalMapper:
    """Depth frames -> a local VHV map around the chair -> 2D occupancy -> obstacle distance ahead.

    The map is rebuilt from each frame in ``base_link`` (a local map for safety, not the global one):
    the cloud is moved from the camera mount frame to ``base_link``, inserted into a
    :class:`mapping.vhv.VHVMap`, and the cells holding a structure between ``z_min`` (above the floor
    noise) and the chair's height form the 2D occupancy grid the corridor is checked against.
    """

    def __init__(self, spec: Any, corridor: Corridor, cell_size: float = 0.05, extent_m: float = 6.0,
                 z_min: float = 0.05, stride: int = 4) -> None:  # fmt: skip
        from mapping.grid import GridSpec

        self.spec = spec
        self.corridor = corridor
        self.grid = GridSpec(
            cell_size=cell_size, size_x=extent_m, size_y=extent_m, centre=(extent_m / 2, 0.0)
        )
        self.z_min = z_min
        self.z_max = float(spec.body.height)
        self.stride = stride
        self.last_stats: Any = None
        self.last_map: Any = None

    def distance(self, frame: Any) -> float | None:
        from mapping.vhv import VHVMap

        mount = self.spec.mounts["kinect_link"]
        pts = np.asarray(frame.points, dtype=np.float64)
        if pts.ndim == 3:
            pts = pts[:: self.stride, :: self.stride]
        pts = pts.reshape(-1, 3)
        t = mount.transform()
        pts = pts @ t[:3, :3].T + t[:3, 3]
        m = VHVMap(self.grid)
        self.last_stats = m.insert(pts, sensor_origin=tuple(t[:3, 3]))
        self.last_map = m
        s = m.structures()
        if len(s.i) == 0:
            return None
        band = (s.top >= self.z_min) & (s.bottom <= self.z_max)
        if not band.any():
            return None
        u, v = self.grid.index_to_world(s.i[band], s.j[band])
        half = 0.5 * self.grid.cell_size  # nearest edge of the cell, not its centre
        return self.corridor.distance_ahead(np.stack([np.asarray(u) - half, np.asarray(v)], axis=1))


# --- recording ---------------------------------------------------------------------------------


class BagRecorder:
    """Write the run as a ROS 2 bag (rosbags): /odom (nav_msgs/Odometry), /tf (tf2_msgs/TFMessage),
    one sensor_msgs/Range topic per sonar (/sonar/<array>/<1|2|3>)."""

    def __init__(self, path: Path, sonar_names: Sequence[str], max_range_m: float = 6.0) -> None:
        from rosbags.rosbag2 import Writer
        from rosbags.typesys import Stores, get_typestore

        self.ts = get_typestore(Stores.ROS2_HUMBLE)
        self.writer = Writer(path, version=9)
        self.writer.open()
        self.max_range_m = max_range_m
        self.counts: dict[str, int] = {}
        self._odom = self.writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=self.ts)
        self._tf = self.writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=self.ts)
        self._sonar = {
            (name, k): self.writer.add_connection(
                f"/sonar/{name}/{k + 1}", "sensor_msgs/msg/Range", typestore=self.ts
            )
            for name in sonar_names
            for k in range(3)
        }

    def _header(self, stamp_ns: int, frame: str) -> Any:
        T = self.ts.types
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](
                sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
            ),
            frame_id=frame,
        )

    def _write(self, conn: Any, stamp_ns: int, msg: Any, typename: str) -> None:
        self.writer.write(conn, stamp_ns, self.ts.serialize_cdr(msg, typename))
        self.counts[conn.topic] = self.counts.get(conn.topic, 0) + 1

    def record(
        self, stamp_ns: int, pose: Pose2D, v: float, w: float, sonars: Sequence[tuple[str, SonarArrayReading]]
    ) -> None:
        T = self.ts.types
        q = T["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(pose.theta / 2), w=math.cos(pose.theta / 2)
        )
        pos = T["geometry_msgs/msg/Point"](x=pose.x, y=pose.y, z=0.0)
        vec = T["geometry_msgs/msg/Vector3"]
        odom = T["nav_msgs/msg/Odometry"](
            header=self._header(stamp_ns, "odom"),
            child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](position=pos, orientation=q), covariance=np.zeros(36)
            ),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](
                    linear=vec(x=v, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=w)
                ),
                covariance=np.zeros(36),
            ),
        )
        self._write(self._odom, stamp_ns, odom, "nav_msgs/msg/Odometry")
        tf = T["geometry_msgs/msg/TransformStamped"](
            header=self._header(stamp_ns, "odom"),
            child_frame_id="base_link",
            transform=T["geometry_msgs/msg/Transform"](
                translation=vec(x=pose.x, y=pose.y, z=0.0), rotation=q
            ),
        )
        self._write(
            self._tf, stamp_ns, T["tf2_msgs/msg/TFMessage"](transforms=[tf]), "tf2_msgs/msg/TFMessage"
        )
        rng = T["sensor_msgs/msg/Range"]
        for name, reading in sonars:
            for k, r in enumerate(reading.ranges_m):
                msg = rng(
                    header=self._header(reading.stamp_ns, f"{name}/sonar{k + 1}"),
                    radiation_type=0,  # ULTRASOUND
                    field_of_view=math.radians(60.0),
                    min_range=0.03,
                    max_range=self.max_range_m,
                    range=float(r) if math.isfinite(r) else math.inf,  # REP-117: +inf = nothing seen
                )
                self._write(self._sonar[(name, k)], reading.stamp_ns, msg, "sensor_msgs/msg/Range")

    def close(self) -> None:
        self.writer.close()


# --- the loop ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class RuntimeConfig:
    """Loop settings.

    Attributes:
        rate_hz: loop rate (sonars are read every cycle: six SRF08s at a 2 m range setting take 71 ms).
        deadline_slack: a cycle may end this fraction of a period late before it counts as missed.
        map_every: build the local map from the depth camera every this many cycles (0 = never).
        stop_on_driver_fault: end the run after a driver fault (the chair is stopped either way).
    """

    rate_hz: float = 10.0
    deadline_slack: float = 0.25
    map_every: int = 5
    stop_on_driver_fault: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ConfigError(f"runtime.rate_hz = {self.rate_hz!r}: expected a finite number > 0")
        if not (math.isfinite(self.deadline_slack) and self.deadline_slack >= 0):
            raise ConfigError(f"runtime.deadline_slack = {self.deadline_slack!r}: expected >= 0")
        if self.map_every < 0:
            raise ConfigError(f"runtime.map_every = {self.map_every!r}: expected >= 0")


@dataclass
class RunResult:
    """What a run did (also written as metrics.json)."""

    backend: str
    cycles: int = 0
    sim_time_s: float = 0.0
    deadline_misses: int = 0
    max_overrun_s: float = 0.0
    final_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    distance_m: float = 0.0
    route_completed: bool | None = None
    max_cross_track_m: float | None = None
    stops: list[dict[str, Any]] = field(default_factory=list)
    driver_fault: str | None = None
    limited_cycles: int = 0
    min_sonar_distance_m: float | None = None  # nearest obstacle ahead the sonars reported
    min_map_distance_m: float | None = None  # nearest obstacle ahead in the local 2D map
    map_frames: int = 0
    poses: list[tuple[float, float, float, float]] = field(default_factory=list)  # (t, x, y, theta)

    def metrics(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("poses")
        d["stop_counts"] = {}
        for s in self.stops:
            d["stop_counts"][s["reason"]] = d["stop_counts"].get(s["reason"], 0) + 1
        return d


class Runtime:
    """The loop over an *opened* backend.

    Args:
        backend: sim, emulated or real (:func:`hw.registry.get_backend`), already opened.
        source: the command source.
        spec: platform spec (default: load it).
        config: loop settings.
        safety: the safety layer (default: limits from the spec).
        recorder: optional :class:`BagRecorder`.
        start_pose: pose of the odometry at the start (e.g. a scenario's start in the world frame).
    """

    def __init__(self, backend: Backend, source: CommandSource, *, spec: Any = None,
                 config: RuntimeConfig | None = None, safety: SafetyLayer | None = None,
                 recorder: BagRecorder | None = None, start_pose: Pose2D | None = None) -> None:  # fmt: skip
        from robchair.spec import load_spec

        self.backend = backend
        self.source = source
        self.spec = spec if spec is not None else load_spec()
        self.config = config or RuntimeConfig()
        self.drive = DiffDrive(self.spec)
        self.safety = safety if safety is not None else SafetyLayer(SafetyLimits.from_spec(self.spec))
        self.recorder = recorder
        self.odometry = Odometry(self.spec, start_pose)
        self.corridor = Corridor.from_spec(self.spec)
        self.mapper = LocalMapper(self.spec, self.corridor) if backend.depth_camera is not None else None
        self.period_ns = round(1e9 / self.config.rate_hz)
        names = [getattr(a, "name", f"sonar_array_{i}") for i, a in enumerate(backend.sonar_arrays)]
        self._array_names = [n.removeprefix("sim-") for n in names]
        self._last_fresh: dict[str, int] = {}
        self._map_distance: float | None = None
        self.result = RunResult(backend=backend.name)

    # one-cycle pieces -------------------------------------------------------------------------

    def _read_motors(self) -> tuple[MotorState | None, str | None]:
        try:
            state = self.backend.motors.read_state()
        except HardwareError as exc:
            return None, f"{type(exc).__name__}: {exc}"
        if state.faults.any:
            return state, f"motor controller fault flags {state.faults.names()}"
        return state, None

    def _read_sonars(self, now_ns: int) -> tuple[list[tuple[str, SonarArrayReading]], float | None]:
        readings: list[tuple[str, SonarArrayReading]] = []
        points = []
        for name, arr in zip(self._array_names, self.backend.sonar_arrays):
            try:
                r = arr.read()
            except HardwareError as exc:
                log.info("%s: read failed: %s", name, exc)
                continue
            failing = getattr(arr, "consecutive_errors", (0, 0, 0))
            if all(c > 0 for c in failing):
                continue  # every sonar of the array failed this time: no fresh data
            self._last_fresh[name] = now_ns
            readings.append((name, r))
            mount = self.spec.mounts.get(name)
            if mount is not None:
                points.append(sonar_obstacle_points(r, mount))
        dist = self.corridor.distance_ahead(np.concatenate(points)) if points else None
        return readings, dist

    def _stale(self, now_ns: int) -> tuple[str, ...]:
        limit = round(self.safety.limits.stale_after_s * 1e9)
        out = [n for n in self._array_names if now_ns - self._last_fresh.get(n, now_ns) > limit]
        if self.mapper is not None and self.config.map_every:
            # the camera is only read every map_every cycles: allow for that interval on top
            cam_limit = limit + self.config.map_every * self.period_ns
            if now_ns - self._last_fresh.get(DEPTH_CAMERA, now_ns) > cam_limit:
                out.append(DEPTH_CAMERA)
        return tuple(out)

    def _act(self, decision: SafetyDecision) -> str | None:
        left, right = self.drive.motor_rpm(decision.v, decision.w)
        try:
            self.backend.motors.set_speeds_rpm(left, right)
        except HardwareError as exc:
            return f"{type(exc).__name__}: {exc}"
        return None

    def _stop_hard(self) -> None:
        try:
            self.backend.motors.emergency_stop()
        except HardwareError as exc:
            log.error("emergency stop could not be confirmed: %s", exc)

    # the loop ---------------------------------------------------------------------------------

    def run(self, duration_s: float) -> RunResult:
        """Run for ``duration_s`` seconds of the backend's clock, or until the source is done."""
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ConfigError(f"duration_s = {duration_s!r}: expected a finite number of seconds > 0")
        clock = self.backend.clock
        res = self.result
        t0 = clock.now_ns()
        for name in (*self._array_names, DEPTH_CAMERA):
            self._last_fresh[name] = t0
        state, fault = self._read_motors()
        if state is not None:
            self.odometry.update(*state.encoder_counts)
        n_cycles = max(1, round(duration_s * self.config.rate_hz))
        next_t = t0
        missed = False
        slack_ns = round(self.period_ns * self.config.deadline_slack)
        dt = self.period_ns / 1e9
        for k in range(n_cycles):
            cycle_start = next_t
            now = clock.now_ns()
            state, motor_fault = self._read_motors()
            fault = fault or motor_fault
            if state is not None:
                pose = self.odometry.update(*state.encoder_counts)
            else:
                pose = self.odometry.pose
            sonar_readings, sonar_dist = self._read_sonars(now)
            if self.mapper is not None and self.config.map_every and k % self.config.map_every == 0:
                try:
                    assert self.backend.depth_camera is not None
                    self._map_distance = self.mapper.distance(self.backend.depth_camera.read())
                    self._last_fresh[DEPTH_CAMERA] = now
                    res.map_frames += 1
                except HardwareError as exc:
                    log.info("depth camera: %s", exc)
            res.min_sonar_distance_m = _min_or(res.min_sonar_distance_m, sonar_dist)
            res.min_map_distance_m = _min_or(res.min_map_distance_m, self._map_distance)
            dists = [d for d in (sonar_dist, self._map_distance) if d is not None]
            obs = Observation(
                now, pose, state, tuple(r for _, r in sonar_readings), min(dists) if dists else None
            )
            try:
                cmd = self.source.command(obs)
            except HardwareError as exc:  # the joystick failed: treat it as a released dead-man
                log.warning("command source failed: %s", exc)
                cmd = Command(0.0, 0.0, deadman=False)
            inputs = SafetyInputs(
                stamp_ns=now,
                sonar_distance_m=sonar_dist,
                map_distance_m=self._map_distance,
                deadline_missed=missed,
                stale_sensors=self._stale(now),
                driver_fault=fault,
                deadman=cmd.deadman,
            )
            decision = self.safety.filter(cmd.v, cmd.w, inputs, dt)
            res.limited_cycles += decision.limited
            act_fault = self._act(decision) if fault is None else None
            if fault is None and act_fault is not None:
                fault = act_fault
                self.safety.filter(0.0, 0.0, SafetyInputs(stamp_ns=now, driver_fault=fault), dt)
            if self.recorder is not None:
                self.recorder.record(now, pose, decision.v, decision.w, sonar_readings)
            res.poses.append(((now - t0) / 1e9, pose.x, pose.y, pose.theta))
            if isinstance(self.source, PurePursuit):
                cte = self.source.cross_track_error(pose)
                res.max_cross_track_m = max(res.max_cross_track_m or 0.0, cte)
            res.cycles = k + 1
            if fault is not None:
                res.driver_fault = fault
                self._stop_hard()
                if self.config.stop_on_driver_fault:
                    log.error("run ended by a driver fault: %s", fault)
                    break
            if cmd.done:
                break
            end = clock.now_ns()
            next_t = cycle_start + self.period_ns
            overrun = end - next_t
            missed = overrun > slack_ns
            if missed:
                res.deadline_misses += 1
                res.max_overrun_s = max(res.max_overrun_s, overrun / 1e9)
                log.warning("cycle %d overran its period by %.1f ms", k, overrun / 1e6)
                next_t = end  # restart the schedule from now: no burst of catch-up cycles
            clock.sleep_until_ns(next_t)
        # settle: command zero so the chair ends at rest (and let it run down before the last reading)
        if res.driver_fault is None:
            try:
                self.backend.motors.set_speeds_rpm(0.0, 0.0)
            except HardwareError as exc:
                res.driver_fault = str(exc)
        end_ns = clock.now_ns()
        res.sim_time_s = (end_ns - t0) / 1e9
        pose = self.odometry.pose
        res.final_pose = (pose.x, pose.y, pose.theta)
        res.distance_m = self.odometry.distance
        if isinstance(self.source, PurePursuit):
            res.route_completed = self.source.done
        res.stops = [
            {"t_s": (s.stamp_ns - t0) / 1e9, "reason": s.reason.value, "detail": s.detail}
            for s in self.safety.stops
        ]
        return res


def run_to_dir(backend: Backend, source: CommandSource, duration_s: float, out_dir: Path | None, *,
               spec: Any = None, config: RuntimeConfig | None = None,
               safety: SafetyLayer | None = None, start_pose: Pose2D | None = None) -> RunResult:  # fmt: skip
    """Open the backend, run, close it, and (with ``out_dir``) write ``run_bag/`` and ``metrics.json``.

    The output folder is written all-or-nothing (:func:`robchair.outdir.staged_output_dir`).
    """
    from robchair.outdir import staged_output_dir

    def go(rec: BagRecorder | None) -> RunResult:
        rt = Runtime(
            backend, source, spec=spec, config=config, safety=safety, recorder=rec, start_pose=start_pose
        )
        try:
            return rt.run(duration_s)
        finally:
            if rec is not None:
                rec.close()

    with backend:
        if out_dir is None:
            return go(None)
        with staged_output_dir(out_dir) as stage:
            names = [
                getattr(a, "name", f"sonar_array_{i}").removeprefix("sim-")
                for i, a in enumerate(backend.sonar_arrays)
            ]
            result = go(BagRecorder(stage / "run_bag", names))
            metrics = result.metrics()
            (stage / "metrics.json").write_text(json.dumps(metrics, indent=2, default=_json_default))
            np.savetxt(stage / "odometry.csv", np.asarray(result.poses).reshape(-1, 4), delimiter=",",
                       header="t_s,x_m,y_m,theta_rad", comments="")  # fmt: skip
        return result


def _min_or(a: float | None, b: float | None) -> float | None:
    """min of two optional values (None = no value)."""
    if a is None:
        return b
    return a if b is None else min(a, b)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
