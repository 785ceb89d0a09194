"""The perception stage: sensor data x mount x pose -> world -> map, and what the safety layer asks of it.

This is the one place that places sensor data in the world: ``T_world_sensor = T_world_base(pose) x
T_base_sensor(mount)`` (:mod:`robchair.frames`), then ``map.insert(points_world, sensor_origin)``.

* depth frames (:class:`hw.interfaces.DepthFrame`, organized (H, W, 3) in the camera frame): into the
  map; the points of the frame that stand in the chair's height band inside its corridor ahead give
  the *map distance* the safety layer checks;
* sonar array readings: five-zone fusion and the cone -> points algorithm (:mod:`mapping.sonar`) into
  a sonar map; the fused arc gives the *sonar distance*; the servo is turned toward the nearest echo;
* laser scans: points (N, 3) in the scanner's frame, into the map.

The map is pluggable: any object with ``insert(points_world (N, 3), sensor_origin=(3,))`` (a
:class:`mapping.vhv.VHVMap` by default; a probabilistic map is one ``map=`` argument away). Further
*layers* (e.g. the simulation's map placed with ground-truth poses) receive the same frames placed
with their own pose source.

Depth frames go through a small pipeline so that capturing and mapping overlap the rest of the loop:
a camera offering ``submit_read()`` (the simulated Kinect) captures up to ``camera.max_inflight``
frames ahead on background threads; frames are delivered in order, and their map insertion runs on one
mapping thread. Delivery waits for the same number of frames whether threads are used or not, so a
threaded run and a serial one give the same maps and decisions bit for bit.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from hw.interfaces import DepthFrame, SonarArrayReading
from robchair.frames import se3_planar, transform_points
from robchair.kinematics import Pose2D
from robchair.spec import RobChairSpec

SERVO_CENTRE_DEG = 90.0  # hw convention: servo 0..180 deg, 90 = the array faces its mount's x axis
DEFAULT_BAND_MIN_M = 0.10  # occupancy band starts above the floor's noise


class PointMap(Protocol):
    """What the perception stage needs of a map."""

    def insert(self, points: Any, sensor_origin: Any = None) -> Any: ...


@dataclass(frozen=True)
class Corridor:
    """The strip the chair will sweep driving forward, in ``base_link`` (x forward, y left)."""

    front_x: float  # x of the footprint's front edge, m
    half_width: float  # half of the chair's width plus a lateral margin, m

    @classmethod
    def from_spec(cls, spec: RobChairSpec, lateral_margin: float = 0.05) -> Corridor:
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


def explained_arc(arc: np.ndarray, origin: Any, scan_xy: np.ndarray | None, tol: float = 0.06) -> np.ndarray:
    """The part of a fused sonar arc (N, 2) that laser returns ``scan_xy`` (M, 2) explain, else the arc.

    All in ``base_link``. The echo comes from the nearest surface in the cone: laser returns at the
    arc's range (within ``tol`` m) from the sonar ``origin`` (x, y) and inside its bearing interval
    locate that surface (e.g. a door post beside the chair's path); without such returns (a table
    top above the scan plane) the whole arc stays.
    """
    if scan_xy is None or len(scan_xy) == 0 or len(arc) < 2:
        return arc
    o = np.asarray(origin, dtype=float)[:2]
    d = float(np.hypot(*(arc[0] - o)))
    b = np.arctan2(arc[:, 1] - o[1], arc[:, 0] - o[0])
    mid = b[len(b) // 2]
    rel = np.angle(np.exp(1j * (b - mid)))
    q = scan_xy - o
    qb = np.angle(np.exp(1j * (np.arctan2(q[:, 1], q[:, 0]) - mid)))
    near = (np.abs(np.hypot(q[:, 0], q[:, 1]) - d) <= tol) & (qb >= rel.min()) & (qb <= rel.max())
    return scan_xy[near] if near.any() else arc


@dataclass
class MapLayer:
    """A further map fed with the same frames, placed with another pose source.

    ``t_world_base()`` is called when a frame is taken (on the loop's thread) and returns the
    (4, 4) ``T_world_base`` to place that frame with (e.g. the physics' ground truth).
    """

    name: str
    map: PointMap
    t_world_base: Callable[[], np.ndarray]


class _Done:
    """A finished future (a camera without background capture)."""

    def __init__(self, value: Any) -> None:
        self.value = value

    def result(self) -> Any:
        return self.value


class Perception:
    """Owns the maps and the obstacle distances of one run.

    Args:
        spec: platform spec (mounts, body size).
        map: the map depth frames and laser scans go into (``insert(points_world, sensor_origin)``);
            default a :class:`mapping.vhv.VHVMap` on ``grid``.
        grid: grid of the default maps (default 20 m x 20 m at 5 cm around the origin).
        sonar_map: map of the sonar points (default another VHV map on ``grid``; None: the main map).
        band: (z_min, z_max) m of the chair's height band; z_max None = the chair's height.
        camera_stride: pixel stride of the depth points used for the corridor distance.
        threaded: insert frames into the maps on a background thread.
        frames: extra sensor frames ``{frame_id: T_base_frame (4, 4)}`` beyond the spec's mounts.
        tolerance: merge tolerance of the default VHV maps, m.
    """

    def __init__(
        self,
        spec: RobChairSpec,
        *,
        map: PointMap | None = None,
        grid: Any = None,
        sonar_map: PointMap | str | None = "default",
        band: tuple[float, float | None] = (DEFAULT_BAND_MIN_M, None),
        camera_stride: int = 4,
        threaded: bool = False,
        frames: dict[str, np.ndarray] | None = None,
        tolerance: float = 0.05,
    ) -> None:
        from mapping.grid import GridSpec
        from mapping.vhv import VHVMap

        self.spec = spec
        self.grid = grid if grid is not None else GridSpec(cell_size=0.05, size_x=20.0, size_y=20.0)
        self.map: PointMap = map if map is not None else VHVMap(self.grid, tolerance)
        if isinstance(sonar_map, str):
            sonar_map = VHVMap(self.grid, tolerance)
        self.sonar_map: PointMap = sonar_map if sonar_map is not None else self.map
        self.band = (float(band[0]), float(band[1]) if band[1] is not None else float(spec.body.height))
        self.corridor = Corridor.from_spec(spec)
        self.camera_stride = int(camera_stride)
        self.layers: list[MapLayer] = []
        self._frames: dict[str, np.ndarray] = {n: m.transform() for n, m in spec.mounts.items()}
        self._frames.update(frames or {})
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="perception-map") if threaded else None
        self._pending: deque[Future[None]] = deque()
        self._inflight: deque[tuple[Any, np.ndarray, list[np.ndarray], Pose2D]] = deque()
        self._lock = threading.Lock()
        self._depth: tuple[float | None, Pose2D] | None = None  # (distance at capture, pose at capture)
        self._sonar: dict[str, float | None] = {}
        self._scan_world: np.ndarray | None = None  # (M, 2) the last laser scan's returns, world x, y
        self._servo: dict[str, float] = {}
        self.map_ms: list[float] = []
        self.stats = {
            "depth_frames": 0,
            "points_in": 0,
            "points_dropped_nonfinite": 0,
            "points_outside_grid": 0,
            "sonar_readings": 0,
            "sonar_fusions_with_obstacle": 0,
            "sonar_points": 0,
            "laser_scans": 0,
        }
        self.last_depth_stamp_ns: int | None = None

    # --- frames -----------------------------------------------------------------------------------

    def t_base_sensor(self, frame_id: str) -> np.ndarray:
        """``T_base_sensor`` (4, 4) of a sensor frame (the spec's mounts plus ``frames``)."""
        try:
            return self._frames[frame_id]
        except KeyError:
            from robchair.errors import ConfigError

            raise ConfigError(
                f"sensor frame {frame_id!r} has no mount; known: {', '.join(sorted(self._frames))}"
            ) from None

    def add_layer(self, name: str, map: PointMap, t_world_base: Callable[[], np.ndarray]) -> MapLayer:
        """Feed ``map`` with the same frames placed with ``t_world_base()`` (see :class:`MapLayer`)."""
        layer = MapLayer(name, map, t_world_base)
        self.layers.append(layer)
        return layer

    # --- depth camera -----------------------------------------------------------------------------

    def take_depth(self, camera: Any, pose: Pose2D) -> DepthFrame | None:
        """Take a frame from ``camera`` at odometry ``pose``; returns the frame delivered now, if any.

        With a camera that captures in the background (``submit_read``), the frame delivered is the
        one taken ``camera.max_inflight`` calls earlier.
        """
        t_world_base = se3_planar(pose.x, pose.y, pose.theta)
        layer_poses = [layer.t_world_base() for layer in self.layers]
        submit = getattr(camera, "submit_read", None)
        depth = int(getattr(camera, "max_inflight", 0)) if submit is not None else 0
        fut: Any = submit() if submit is not None else _Done(camera.read())
        self._inflight.append((fut, t_world_base, layer_poses, pose))
        out = None
        while len(self._inflight) > depth:
            out = self._deliver()
        return out

    def _deliver(self) -> DepthFrame:
        fut, t_world_base, layer_poses, pose = self._inflight.popleft()
        frame: DepthFrame = fut.result()
        t_base_sensor = self.t_base_sensor(frame.frame_id)
        s = self.camera_stride
        pts = np.asarray(frame.points)
        sub = pts[::s, ::s].reshape(-1, 3) if pts.ndim == 3 else pts[::s].reshape(-1, 3)
        sub = transform_points(t_base_sensor, sub[np.isfinite(sub).all(axis=1)], np.float32)
        z0, z1 = self.band
        band = sub[(sub[:, 2] >= z0) & (sub[:, 2] <= z1)]
        self._depth = (self.corridor.distance_ahead(band[:, :2]), pose)
        self.last_depth_stamp_ns = frame.stamp_ns
        placed = [(self.map, t_world_base @ t_base_sensor, True)]
        placed += [(ly.map, tw @ t_base_sensor, False) for ly, tw in zip(self.layers, layer_poses)]
        self._submit(self._insert_frame, frame, placed)
        return frame

    def _insert_frame(self, frame: DepthFrame, placed: list[tuple[PointMap, np.ndarray, bool]]) -> None:
        pts = np.asarray(frame.points).reshape(-1, 3)
        for m, t, main in placed:
            s = m.insert(transform_points(t, pts, np.float32), sensor_origin=t[:3, 3])
            if main and s is not None:
                with self._lock:
                    self.map_ms.append(float(getattr(s, "build_ms", math.nan)))
                    st = self.stats
                    st["depth_frames"] += 1
                    st["points_in"] += int(getattr(s, "points_in", 0))
                    st["points_dropped_nonfinite"] += int(getattr(s, "points_dropped_nonfinite", 0))
                    st["points_outside_grid"] += int(getattr(s, "points_outside_grid", 0))

    def _submit(self, fn: Callable[..., None], *args: Any) -> None:
        if self._pool is None:
            fn(*args)
            return
        while self._pending and self._pending[0].done():
            self._pending.popleft().result()  # a mapping error surfaces here, in the loop
        while len(self._pending) >= 3:
            self._pending.popleft().result()
        self._pending.append(self._pool.submit(fn, *args))

    def depth_distance_m(self, pose: Pose2D) -> float | None:
        """Nearest depth point in the band inside the corridor ahead, from the front edge, m.

        Measured at the pose of its frame; the forward travel since then is taken off.
        """
        if self._depth is None:
            return None
        d, p0 = self._depth
        if d is None:
            return None
        fwd = (pose.x - p0.x) * math.cos(p0.theta) + (pose.y - p0.y) * math.sin(p0.theta)
        return max(0.0, d - max(0.0, fwd))

    # --- sonars -----------------------------------------------------------------------------------

    def add_sonar(self, name: str, reading: SonarArrayReading, pose: Pose2D) -> float | None:
        """Fuse one array reading, map its points, and return the servo angle to turn to (deg; None: none).

        ``name`` is the array's mount (``sonar_array_left``...).
        """
        from mapping.sonar import array_points, servo_command_deg

        mount = self.spec.mounts.get(name)
        self.stats["sonar_readings"] += 1
        if mount is None:
            self._sonar[name] = None
            return None
        ranges = tuple(float(r) if math.isfinite(r) else math.nan for r in reading.ranges_m)
        fusion, pts = array_points(ranges)
        arc = sonar_obstacle_points(reading, mount)
        if len(arc) and self._scan_world is not None:  # the laser locates the echo's surface if it sees it
            c, s = math.cos(pose.theta), math.sin(pose.theta)
            q = self._scan_world - (pose.x, pose.y)
            arc = explained_arc(
                arc, mount.xyz, np.stack([c * q[:, 0] + s * q[:, 1], c * q[:, 1] - s * q[:, 0]], 1)
            )
        self._sonar[name] = self.corridor.distance_ahead(arc) if len(arc) else None
        if fusion.has_obstacle:
            self.stats["sonar_fusions_with_obstacle"] += 1
        if len(pts):
            joint = math.radians(reading.servo_angle_deg - SERVO_CENTRE_DEG)
            t = se3_planar(pose.x, pose.y, pose.theta) @ mount.transform(joint)
            self.sonar_map.insert(transform_points(t, pts), sensor_origin=t[:3, 3])
            self.stats["sonar_points"] += len(pts)
        if mount.joint is None:
            return None
        cmd = servo_command_deg(
            fusion, self._servo.get(name, reading.servo_angle_deg), gain=0.5, max_step_deg=15.0
        )
        self._servo[name] = cmd
        return float(cmd)

    def sonar_distance_m(self) -> float | None:
        """Nearest fused sonar obstacle ahead over the arrays' latest readings, from the front edge, m."""
        ds = [d for d in self._sonar.values() if d is not None]
        return min(ds) if ds else None

    # --- laser scanner ----------------------------------------------------------------------------

    def add_scan(self, frame_id: str, points: Any, pose: Pose2D) -> None:
        """Insert a laser scan: ``points`` (N, 3) in ``frame_id`` (NaN rows = no return), at ``pose``."""
        t = se3_planar(pose.x, pose.y, pose.theta) @ self.t_base_sensor(frame_id)
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        w = transform_points(t, p[np.isfinite(p).all(axis=1)])
        self._scan_world = w[(w[:, 2] >= self.band[0]) & (w[:, 2] <= self.band[1]), :2]
        self._submit(lambda: self.map.insert(transform_points(t, p), sensor_origin=t[:3, 3]))
        self.stats["laser_scans"] += 1

    # --- maps -------------------------------------------------------------------------------------

    def flush(self) -> None:
        """Deliver the frames still being captured and wait for every map insertion."""
        while self._inflight:
            self._deliver()
        while self._pending:
            self._pending.popleft().result()

    def occupancy_2d(self, which: PointMap | None = None) -> np.ndarray:
        """2D occupancy (bool, grid shape) of the height band in a map (default the main one)."""
        from mapping.derived import occupancy_2d

        self.flush()
        return occupancy_2d(which if which is not None else self.map, *self.band)  # type: ignore[arg-type]

    def close(self) -> None:
        """Finish pending work and stop the mapping thread."""
        try:
            self.flush()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None
