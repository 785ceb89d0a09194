"""The run recorder: one ROS 2 bag per run, one topic and frame naming scheme for every backend.

Messages use the ROS 2 Humble type store of ``rosbags``; the bag is rosbag2 format version 9, stored
as MCAP by default (ROS 2's default storage since Iron) or sqlite3 (the message builder and the bag
writer: :mod:`robchair.observers.bag_writer`; this module: the topic and frame scheme, the depth clouds'
thinning and their placement at the written poses). Topics and frames (REP-105):

=====================================  ===============================  ==================================
topic                                  type                             frame
=====================================  ===============================  ==================================
``/odom``                              nav_msgs/Odometry                ``odom`` -> ``base_link``
``/tf``                                tf2_msgs/TFMessage               ``map`` -> ``odom`` (scan-to-map
                                                                        matching, else identity), ``odom`` ->
                                                                        ``base_link`` each cycle;
                                                                        ``base_link`` -> ``<array>`` with
                                                                        the servo angle at each reading
``/tf_static``                         tf2_msgs/TFMessage               ``base_link`` -> camera frame;
                                                                        ``<array>`` -> ``<array>_<k>``
``/sonar/<array>/<k>`` (k = 1, 2, 3    sensor_msgs/Range (ULTRASOUND,   ``<array>_<k>``
left to right)                         +inf = no echo, REP-117)
``/kinect/points``                     sensor_msgs/PointCloud2          the frame's ``frame_id``
``/sonar/points`` (a chair without a   sensor_msgs/PointCloud2: the     ``<array>``
depth camera)                          fused reading's cone points
                                       (thesis Fig. 5.7) the sonar map
                                       is built from
``/scan``                              sensor_msgs/LaserScan            ``laser_link``
=====================================  ===============================  ==================================

Depth clouds (:data:`BAG_CLOUDS`): ``voxel`` (the default) keeps every delivered frame, the ones the
run's maps are built from, thinned to keep bags small: the measured points that build the same VHV
structures in the run's odometry map as the whole frame (:func:`mapping.thinning.structure_keeping_indices`:
per map cell and height slice the lowest and highest point, placed with that map's pose of the frame),
so ``robchair map`` on the bag rebuilds the run's map (a one-point-per-voxel filter, which robots often
record, changed each frame's structures and cost a 20 s round trip about 6 points of IoU). About 10 MB
per simulated second with the no-return rays (twice the voxel filter's points), and 7.7 to 8.3 ms CPU per
512 x 424 frame on the loop's thread against 6.3 to 6.5 ms for the voxel filter (medians, same frames,
loaded machine); ``decimated``
keeps every ``cloud_every``-th frame, decimated ``cloud_stride`` x ``cloud_stride`` (what the live view
sends); ``full`` keeps every frame
whole (about 70 MB per simulated second from the Kinect 2 model, 4 GB a minute).

No-return rays (:data:`NO_RETURN_TOPIC`, with ``voxel`` clouds when the run's maps clear free space
along pixels without a return): a sensor_msgs/PointCloud2 in the camera's frame, same header stamp as
the frame's cloud on :data:`CLOUD_TOPIC`: one point per ``camera_stride``-th pixel (each way) that has no
return, at depth (camera x) equal to the camera's maximum range along that pixel's ray
(:func:`robchair.perception_depth.no_return_points`; the thinned cloud has no NaN pixels left to say
it). The odometry map takes free space along these rays (OctoMap's max-range rays, for the rays that end
at least ``robchair.perception_layers.NO_RETURN_MIN_HEIGHT_M`` high); ``robchair map`` reads them back
from the topic ``<cloud topic>/no_return`` and does the same. A frame with no such pixel has no message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from robchair.loop_types import CycleResult, LoopView, Observer, RunResult
from robchair.observers.bag_writer import BagWriter, RosMessages
from robchair.platform.errors import ConfigError
from robchair.platform.frames import BASE_LINK, MAP, ODOM, se3_planar, se3_rpy

#: Depth clouds kept in the bag: name -> (every how many delivered frames, pixel stride, thinned to the
#: points that build the odometry map's structures, with the no-return rays). "voxel" keeps its name (the
#: `robchair sim --bag-clouds` choice users know) for what replaced the voxel filter.
BAG_CLOUDS = {"voxel": (1, 1, True), "decimated": (3, 4, False), "full": (1, 1, False)}
DEFAULT_BAG_CLOUDS = "voxel"
DEFAULT_VOXEL_M = 0.05  # when the run's map has no grid to take the cell size from
CLOUD_TOPIC = "/kinect/points"
SONAR_CLOUD_TOPIC = "/sonar/points"
SCAN_TOPIC = "/scan"
#: the message types of every topic :class:`RunTopics` may write (their serialisers are made up front)
RUN_TYPES = ("nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage", "sensor_msgs/msg/Range",
             "sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/LaserScan")  # fmt: skip
#: The no-return rays of each cloud on CLOUD_TOPIC (module docstring); the name ``robchair map`` looks for.
NO_RETURN_TOPIC = CLOUD_TOPIC + "/no_return"
POSE_HISTORY = 256  # cycles of written odometry kept to place a delivered frame at its capture stamp
SONAR_FOV_RAD = math.radians(60.0)
SONAR_MIN_RANGE_M = 0.03


def sonar_topic(array: str, k: int) -> str:
    """Topic of sonar ``k`` (1, 2, 3 left to right) of ``array``."""
    return f"/sonar/{array}/{k}"


def sonar_frame(array: str, k: int) -> str:
    """Frame id of sonar ``k`` of ``array``."""
    return f"{array}_{k}"


@dataclass(frozen=True)
class CycleSnapshot:
    """What one cycle gives the recorded topics, taken on the loop's thread (references, no copies but
    the thinned cloud's).

    Attributes:
        stamp_ns: the cycle's time.
        pose: odometry (x m, y m, yaw rad) at the start of the cycle.
        v, w: the written twist, m/s and rad/s.
        t_map_odom: (4, 4) ``map`` -> ``odom``.
        sonars: (array name, reading) of the arrays read this cycle.
        scan: the laser scan first seen this cycle, else None.
        cloud: (stamp ns, frame id, thinned (H, W, 3) or (M, 3) float32 points) of a kept depth frame,
            else None.
        no_return: (M, 3) float32 no-return ray ends of that frame in its frame (module docstring),
            else None.
    """

    stamp_ns: int
    pose: tuple[float, float, float]
    v: float
    w: float
    t_map_odom: np.ndarray
    sonars: tuple[tuple[str, Any], ...]
    scan: Any = None
    cloud: tuple[int, str, np.ndarray] | None = None
    no_return: np.ndarray | None = None


class RunTopics:
    """The topic and frame scheme of the module docstring: static transforms at the start, then the
    messages of each cycle, written to any :class:`RosMessages`.

    Args:
        cloud_every: keep every this many delivered depth frames (0: none).
        cloud_stride: pixel decimation of the kept clouds.
        cloud_voxel: thin the kept clouds to the points that build the same structures in the run's
            odometry map (unorganized; module docstring), and record their no-return rays.
    """

    def __init__(self, cloud_every: int = 3, cloud_stride: int = 4, cloud_voxel: bool = False) -> None:
        self.cloud_every, self.cloud_stride = int(cloud_every), int(cloud_stride)
        self.cloud_voxel = bool(cloud_voxel)
        self.voxel_m = DEFAULT_VOXEL_M
        self.tolerance_m = DEFAULT_VOXEL_M
        self.no_return_range_m: float | None = None
        self.no_return_stride = 1
        self._rays: dict[Any, np.ndarray] = {}
        self._poses: dict[int, tuple[float, float, float]] = {}  # stamp ns -> odometry pose written
        self.statics: list[tuple[str, str, np.ndarray]] = []
        self.sonar_limits: dict[str, tuple[float, float, float]] = {}  # name -> (min m, max m, fov rad)
        self.sonar_mounts: dict[str, Any] = {}
        self.has_scan = self.has_cloud = self.has_sonar_cloud = False
        self._spec: Any = None
        self._servo_tf: dict[tuple[str, float], np.ndarray] = {}
        self._frames = 0
        self._last_frame: Any = None
        self._last_scan: Any = None
        self._start: list[tuple[str, str, np.ndarray]] | None = None  # the moving tree at the start
        self._tree_from_ns = 0

    def start(self, runtime: LoopView) -> None:
        """Read the run's frames and sensors (at the episode's start)."""
        self._spec = runtime.spec
        perception = runtime.perception
        odometry_map = getattr(perception, "pose_maps", {}).get("odometry", getattr(perception, "map", None))
        spec = getattr(odometry_map, "spec", None)
        self.voxel_m = float(getattr(spec, "cell_size", DEFAULT_VOXEL_M))
        self.axis = str(getattr(spec, "axis", "z"))
        self.tolerance_m = float(getattr(perception, "tolerance", self.voxel_m))
        self._poses, self._rays = {}, {}
        self._servo_tf = {}
        self._frames, self._last_frame, self._last_scan = 0, None, None
        outer_deg = runtime.spec.sonar_arrays.outer_sonar_deg
        statics: list[tuple[str, str, np.ndarray]] = []
        self.has_scan = getattr(runtime.backend, "laser_scanner", None) is not None
        if self.has_scan:
            statics.append((BASE_LINK, "laser_link", runtime.perception.t_base_sensor("laser_link")))
        cam = runtime.backend.depth_camera
        self.has_cloud = cam is not None and self.cloud_every > 0
        # without a depth camera the sonars are what the chair maps from: their points go in the bag
        self.has_sonar_cloud = cam is None and bool(runtime.sonar_names)
        if cam is not None:
            for frame_id in ("kinect_link", getattr(cam, "frame_id", "kinect_link")):
                if frame_id in {c for _, c, _ in statics}:
                    continue
                statics.append((BASE_LINK, frame_id, runtime.perception.t_base_sensor(frame_id)))
        for name in runtime.sonar_names:
            for k, yaw_deg in enumerate((outer_deg, 0.0, -outer_deg), 1):
                statics.append(
                    (name, sonar_frame(name, k), se3_rpy((0.0, 0.0, 0.0), (0.0, 0.0, math.radians(yaw_deg))))
                )
        self.statics = statics
        self.sonar_limits = {}
        for name, arr in zip(runtime.sonar_names, runtime.backend.sonar_arrays):
            self.sonar_limits[name] = (float(getattr(arr, "min_range_m", SONAR_MIN_RANGE_M)),
                                       float(getattr(arr, "max_range_m", 6.0)),
                                       float(getattr(arr, "field_of_view_rad", SONAR_FOV_RAD)))  # fmt: skip
        self.sonar_mounts = {
            n: runtime.spec.mounts[n] for n in runtime.sonar_names if n in runtime.spec.mounts
        }
        self.no_return_range_m = None
        if self.has_cloud and self.cloud_voxel:  # the thinning's compiled kernel loads now, not in a cycle
            from mapping.thinning import structure_keeping_indices

            structure_keeping_indices(np.zeros((1, 3), np.float32), None, self.voxel_m, self.tolerance_m)
            if getattr(perception, "clear_no_return", False) and hasattr(odometry_map, "insert_free"):
                # the range the odometry map clears no-return rays to
                r = getattr(perception, "depth_max_range_m", None) or getattr(cam, "max_range_m", None)
                self.no_return_range_m = float(r) if r else None
                self.no_return_stride = int(getattr(perception, "camera_stride", 1))

    def topics(self) -> dict[str, str]:
        """Topic -> message type of every topic the run has."""
        out = {"/odom": "nav_msgs/msg/Odometry", "/tf": "tf2_msgs/msg/TFMessage",
               "/tf_static": "tf2_msgs/msg/TFMessage"}  # fmt: skip
        for name in self.sonar_limits:
            for k in (1, 2, 3):
                out[sonar_topic(name, k)] = "sensor_msgs/msg/Range"
        if self.has_cloud:
            out[CLOUD_TOPIC] = "sensor_msgs/msg/PointCloud2"
        if self.has_cloud and self.no_return_range_m is not None:
            out[NO_RETURN_TOPIC] = "sensor_msgs/msg/PointCloud2"
        if self.has_sonar_cloud:
            out[SONAR_CLOUD_TOPIC] = "sensor_msgs/msg/PointCloud2"
        if self.has_scan:
            out[SCAN_TOPIC] = "sensor_msgs/msg/LaserScan"
        return out

    def parents(self) -> dict[str, str]:
        """Child frame -> parent frame of the run's TF tree."""
        tree = {ODOM: MAP, BASE_LINK: ODOM, **{name: BASE_LINK for name in self.sonar_mounts}}
        tree.update({child: parent for parent, child, _ in self.statics})
        return tree

    def write_static(self, out: RosMessages, stamp_ns: int, pose: Any = None) -> None:
        """``/tf_static`` (nothing when the run has no static frame), and with the odometry's start
        ``pose`` (x, y, theta) the moving tree at ``stamp_ns`` (the start of the run): readings taken
        before the first cycle's transforms then lie inside the TF range."""
        stamp = max(int(stamp_ns), 1)
        if self.statics:
            out.tf(stamp, self.statics, static=True)
        self._start = None
        if pose is not None:
            self._start = [(MAP, ODOM, np.eye(4)), (ODOM, BASE_LINK, se3_planar(pose.x, pose.y, pose.theta))]
            self._tree_from_ns = stamp
            out.tf(stamp, self._start)

    def snapshot(self, runtime: LoopView, cycle: CycleResult, cloud: bool = True) -> CycleSnapshot:
        """The cycle's data (on the loop's thread); ``cloud=False`` skips the depth frame (it still counts
        towards ``cloud_every``)."""
        p = cycle.pose
        self._poses[int(cycle.stamp_ns)] = (p.x, p.y, p.theta)
        if len(self._poses) > POSE_HISTORY:
            del self._poses[next(iter(self._poses))]
        scan = runtime.last_scan
        if scan is not None and scan is not self._last_scan:
            self._last_scan = scan
        else:
            scan = None
        points = no_return = None
        frame = runtime.last_depth_frame
        if frame is not None and frame is not self._last_frame:
            self._last_frame = frame
            if cloud and self.cloud_every and self._frames % self.cloud_every == 0:
                s = self.cloud_stride
                pts = np.asarray(frame.points)[::s, ::s]
                if self.cloud_voxel:
                    points = (frame.stamp_ns, frame.frame_id, self._thin(runtime, frame, pts))
                    no_return = self._no_return(frame)
                else:
                    points = (frame.stamp_ns, frame.frame_id, np.array(pts))
            self._frames += 1
        t_map_odom = getattr(runtime.perception, "t_map_odom", np.eye(4))
        return CycleSnapshot(cycle.stamp_ns, (p.x, p.y, p.theta), cycle.decision.v, cycle.decision.w,
                             t_map_odom, tuple(runtime.last_sonars), scan, points, no_return)  # fmt: skip

    def _pose_at(self, stamp_ns: int) -> tuple[float, float, float] | None:
        """The odometry pose the bag's TF gives at ``stamp_ns``: the pose written at that stamp (a frame
        is captured at a cycle's start, the stamp of that cycle's ``odom`` -> ``base_link``), else the
        interpolation between the two written around it (linear, the yaw along the shorter arc, as
        ``robchair map`` interpolates TF); the start pose before the first cycle; None when the stamp
        lies outside the poses kept."""
        stamp = int(stamp_ns)
        pose = self._poses.get(stamp)
        if pose is not None:
            return pose
        if self._start is not None and stamp <= self._tree_from_ns:
            m = self._start[1][2]
            return float(m[0, 3]), float(m[1, 3]), math.atan2(float(m[1, 0]), float(m[0, 0]))
        before = after = None
        for t, p in self._poses.items():  # in time order
            if t < stamp:
                before = (t, p)
            elif after is None:
                after = (t, p)
        if before is None or after is None:
            return None
        (t0, p0), (t1, p1) = before, after
        a = (stamp - t0) / (t1 - t0)
        dyaw = math.remainder(p1[2] - p0[2], math.tau)
        return p0[0] + a * (p1[0] - p0[0]), p0[1] + a * (p1[1] - p0[1]), p0[2] + a * dyaw

    def _thin(self, runtime: LoopView, frame: Any, pts: np.ndarray) -> np.ndarray:
        """The frame's measured points that build the same VHV structures in the run's odometry map as
        the whole frame, placed with the pose that map and the bag's TF give it
        (:func:`mapping.thinning.structure_keeping_indices`); one point per voxel of the map's cell size
        on ``base_link``'s lattice when the frame's stamp lies outside the poses kept."""
        t_base = runtime.perception.t_base_sensor(frame.frame_id)
        flat = np.asarray(pts).reshape(-1, 3)
        pose = self._pose_at(frame.stamp_ns)
        if pose is None:
            from mapping.grid import voxel_filter

            return voxel_filter(flat, self.voxel_m, t_base)
        from mapping.thinning import structure_keeping_indices

        t = se3_planar(*pose) @ t_base
        keep = structure_keeping_indices(flat, t, self.voxel_m, self.tolerance_m, self.axis)
        return np.ascontiguousarray(flat[keep], dtype=np.float32)

    def _no_return(self, frame: Any) -> np.ndarray | None:
        """The frame's no-return ray ends (module docstring), None without any or without the range."""
        if self.no_return_range_m is None:
            return None
        from robchair.perception_depth import no_return_points

        far = no_return_points(frame, self.no_return_range_m, self.no_return_stride, self._rays)
        return None if far is None or not len(far) else np.asarray(far, dtype=np.float32)

    def write_cycle(self, out: RosMessages, snap: CycleSnapshot) -> None:
        """The cycle's ``/odom``, ``/tf``, sonar ranges, scan and cloud."""
        stamp = snap.stamp_ns
        out.odometry("/odom", stamp, ODOM, BASE_LINK, snap.pose, snap.v, snap.w)
        # REP-105: map -> odom is the localisation's part (identity without scan-to-map matching), so every
        # backend's bag has the same tree
        out.tf(stamp, [(MAP, ODOM, snap.t_map_odom), (ODOM, BASE_LINK, se3_planar(*snap.pose))])
        for name, reading in snap.sonars:
            if self._start is not None and reading.stamp_ns < self._tree_from_ns:
                # a reading ranged before the loop started: the chair stood at its start pose then
                self._tree_from_ns = int(reading.stamp_ns)
                out.tf(self._tree_from_ns, self._start)
            lo, hi, fov = self.sonar_limits.get(name, (SONAR_MIN_RANGE_M, 6.0, SONAR_FOV_RAD))
            for k, r in enumerate(reading.ranges_m, 1):
                out.range(sonar_topic(name, k), reading.stamp_ns, sonar_frame(name, k), r, lo, hi, fov)
            mount = self.sonar_mounts.get(name)
            if mount is not None:
                key = (name, float(reading.servo_angle_deg))  # a servo takes few distinct angles
                t_base_array = self._servo_tf.get(key)
                if t_base_array is None:
                    joint = self._spec.sonar_arrays.joint_angle(reading.servo_angle_deg)
                    t_base_array = self._servo_tf[key] = mount.transform(joint)
                out.tf(reading.stamp_ns, [(BASE_LINK, name, t_base_array)])
            if self.has_sonar_cloud:
                self._write_sonar_points(out, name, reading)
        if snap.scan is not None:
            from hw.laser_scan import to_ros_laser_scan

            out.write(SCAN_TOPIC, "sensor_msgs/msg/LaserScan", snap.scan.stamp_ns,
                      to_ros_laser_scan(snap.scan, typestore=out.store))  # fmt: skip
        if snap.cloud is not None:
            out.cloud(CLOUD_TOPIC, snap.cloud[0], snap.cloud[1], snap.cloud[2])
            if snap.no_return is not None:
                out.cloud(NO_RETURN_TOPIC, snap.cloud[0], snap.cloud[1], snap.no_return)

    def _write_sonar_points(self, out: RosMessages, name: str, reading: Any) -> None:
        """The cone points (array frame) of one array reading fused as the perception fuses it
        (:func:`mapping.sonar.array_points`); nothing when no sonar echoes."""
        from mapping.sonar import array_points
        from robchair.perception_sonar import _zone_tables

        ranges = tuple(float(r) if math.isfinite(r) else math.nan for r in reading.ranges_m)
        _, pts = array_points(ranges, tables=_zone_tables(self._spec.sonar_arrays.outer_sonar_deg))
        if len(pts):
            out.cloud(SONAR_CLOUD_TOPIC, reading.stamp_ns, name, pts)


class RunRecorder(Observer):
    """Records a run (any backend) into a bag with the topics of the module docstring.

    Args:
        path: bag folder to create.
        storage: ``"mcap"`` or ``"sqlite3"``.
        clouds: the depth clouds kept, a key of :data:`BAG_CLOUDS`.

    Raises:
        ConfigError: unknown storage or ``clouds``, or the folder exists.
    """

    def __init__(self, path: Path | str, storage: str = "mcap", clouds: str = DEFAULT_BAG_CLOUDS) -> None:
        if clouds not in BAG_CLOUDS:
            raise ConfigError(f"bag clouds {clouds!r}: expected one of {', '.join(BAG_CLOUDS)}")
        self.bag = BagWriter(path, storage)
        self.scheme = RunTopics(*BAG_CLOUDS[clouds])
        self.bag.precompile(list(RUN_TYPES))  # before the loop's clock starts, not in its first cycle

    @property
    def counts(self) -> dict[str, int]:
        return self.bag.counts

    def episode_start(self, runtime: LoopView) -> None:
        self.scheme.start(runtime)
        odometry = getattr(runtime, "odometry", None)  # the Runtime's; not part of every LoopView
        self.scheme.write_static(self.bag, runtime.t0_ns, getattr(odometry, "pose", None))

    def after_cycle(self, runtime: LoopView, cycle: CycleResult) -> None:
        self.scheme.write_cycle(self.bag, self.scheme.snapshot(runtime, cycle))

    def episode_end(self, runtime: LoopView, result: RunResult) -> None:
        self.bag.close()
        result.extra["bag"] = {"path": self.bag.path.name, "messages": dict(sorted(self.bag.counts.items()))}
