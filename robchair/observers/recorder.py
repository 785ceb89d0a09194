"""The run recorder: one ROS 2 bag per run, one topic and frame naming scheme for every backend.

Messages use the ROS 2 Humble type store of ``rosbags``; the bag is rosbag2 format version 9, stored
as MCAP by default (ROS 2's default storage since Iron) or sqlite3. Topics and frames (REP-105):

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
``/scan``                              sensor_msgs/LaserScan            ``laser_link``
=====================================  ===============================  ==================================

Depth clouds are kept every ``cloud_every``-th delivered frame, decimated ``cloud_stride`` x
``cloud_stride`` (:data:`BAG_CLOUDS` ``decimated``, the default); ``full`` keeps every frame whole, what
the run's maps are built from, so ``robchair map`` on the bag rebuilds them (about 70 MB per simulated
second from the Kinect 2 model, 4 GB a minute).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from robchair.loop_types import CycleResult, LoopView, Observer, RunResult
from robchair.platform.errors import ConfigError
from robchair.platform.frames import (
    BASE_LINK,
    MAP,
    ODOM,
    quat_from_matrix,
    quat_from_yaw,
    se3_planar,
    se3_rpy,
)

STORAGES = ("mcap", "sqlite3")
#: Depth clouds kept in the bag: name -> (every how many delivered frames, pixel stride).
BAG_CLOUDS = {"decimated": (3, 4), "full": (1, 1)}
CLOUD_TOPIC = "/kinect/points"
SCAN_TOPIC = "/scan"
SONAR_FOV_RAD = math.radians(60.0)
SONAR_MIN_RANGE_M = 0.03


def sonar_topic(array: str, k: int) -> str:
    """Topic of sonar ``k`` (1, 2, 3 left to right) of ``array``."""
    return f"/sonar/{array}/{k}"


def sonar_frame(array: str, k: int) -> str:
    """Frame id of sonar ``k`` of ``array``."""
    return f"{array}_{k}"


class BagWriter:
    """Typed, counted writes to a rosbag2 folder (one connection per topic, created on first use).

    Args:
        path: the bag folder to create (must not exist).
        storage: ``"mcap"`` (default) or ``"sqlite3"``.

    Raises:
        ConfigError: unknown storage, or the folder exists.
    """

    def __init__(self, path: Path | str, storage: str = "mcap") -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        if storage not in STORAGES:
            raise ConfigError(f"bag storage {storage!r}: expected one of {', '.join(STORAGES)}")
        self.path = Path(path)
        if self.path.exists():
            raise ConfigError(f"bag {self.path} already exists")
        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.t = self.store.types
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer: Any = Writer(self.path, version=9, storage_plugin=plugin)
        self._writer.open()
        self._conns: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    def write(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        if self._writer is None:
            raise ConfigError(f"bag {self.path} is closed")
        if topic not in self._conns:
            self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=self.store)
        # rosbag2 tools dislike a zero receive time: messages at t = 0 are stamped 1 ns
        self._writer.write(self._conns[topic], max(int(stamp_ns), 1), self.store.serialize_cdr(msg, msgtype))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        t = self.t
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](
                sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000)
            ),
            frame_id=frame_id,
        )

    def tf(self, stamp_ns: int, transforms: list[tuple[str, str, np.ndarray]], static: bool = False) -> None:
        """One TFMessage of (parent, child, ``T_parent_child`` (4, 4)) transforms."""
        t = self.t
        msgs = []
        for parent, child, m in transforms:
            q = quat_from_matrix(m[:3, :3])
            msgs.append(
                t["geometry_msgs/msg/TransformStamped"](
                    header=self.header(stamp_ns, parent),
                    child_frame_id=child,
                    transform=t["geometry_msgs/msg/Transform"](
                        translation=t["geometry_msgs/msg/Vector3"](
                            x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3])
                        ),
                        rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                    ),
                )
            )
        msg = t["tf2_msgs/msg/TFMessage"](transforms=msgs)
        self.write("/tf_static" if static else "/tf", "tf2_msgs/msg/TFMessage", stamp_ns, msg)

    def odometry(self, topic: str, stamp_ns: int, parent: str, child: str, pose: tuple[float, float, float],
                 v: float = 0.0, w: float = 0.0) -> None:  # fmt: skip
        """nav_msgs/Odometry of a planar pose (x, y, yaw; z = 0) and a body twist."""
        t = self.t
        x, y, yaw = pose
        qx, qy, qz, qw = quat_from_yaw(yaw)
        cov = np.zeros(36, dtype=np.float64)
        msg = t["nav_msgs/msg/Odometry"](
            header=self.header(stamp_ns, parent),
            child_frame_id=child,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=t["geometry_msgs/msg/Pose"](
                    position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                    orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                ),
                covariance=cov,
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=t["geometry_msgs/msg/Vector3"](x=float(v), y=0.0, z=0.0),
                    angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=float(w)),
                ),
                covariance=cov.copy(),
            ),
        )
        self.write(topic, "nav_msgs/msg/Odometry", stamp_ns, msg)

    def range(self, topic: str, stamp_ns: int, frame_id: str, range_m: float, min_m: float, max_m: float,
              fov_rad: float) -> None:  # fmt: skip
        """sensor_msgs/Range (ULTRASOUND). No echo is written as +inf (REP-117)."""
        r = float(range_m) if math.isfinite(range_m) else math.inf
        msg = self.t["sensor_msgs/msg/Range"](
            header=self.header(stamp_ns, frame_id),
            radiation_type=0,
            field_of_view=float(fov_rad),
            min_range=float(min_m),
            max_range=float(max_m),
            range=r,
        )
        self.write(topic, "sensor_msgs/msg/Range", stamp_ns, msg)

    def cloud(self, topic: str, stamp_ns: int, frame_id: str, points: np.ndarray) -> None:
        """sensor_msgs/PointCloud2 (float32 x, y, z; organized clouds keep their rows, NaN = no return)."""
        from mapping.pointcloud2 import encode

        t = self.t
        d = encode(np.asarray(points, dtype=np.float32), frame_id=frame_id, stamp_ns=stamp_ns)
        msg = t["sensor_msgs/msg/PointCloud2"](
            header=self.header(stamp_ns, frame_id),
            height=d.height,
            width=d.width,
            fields=[
                t["sensor_msgs/msg/PointField"](
                    name=f.name, offset=f.offset, datatype=f.datatype, count=f.count
                )
                for f in d.fields
            ],
            is_bigendian=d.is_bigendian,
            point_step=d.point_step,
            row_step=d.row_step,
            data=np.ascontiguousarray(d.data, dtype=np.uint8).reshape(-1),
            is_dense=d.is_dense,
        )
        self.write(topic, "sensor_msgs/msg/PointCloud2", stamp_ns, msg)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None


class RunRecorder(Observer):
    """Records a run (any backend) into a bag with the topics of the module docstring.

    Args:
        path: bag folder to create.
        storage: ``"mcap"`` or ``"sqlite3"``.
        cloud_every: keep every this many delivered depth frames (0: none).
        cloud_stride: pixel decimation of the kept clouds.
    """

    def __init__(self, path: Path | str, storage: str = "mcap", cloud_every: int = 3,
                 cloud_stride: int = 4) -> None:  # fmt: skip
        self.bag = BagWriter(path, storage)
        self.cloud_every, self.cloud_stride = int(cloud_every), int(cloud_stride)
        self._frames = 0
        self._last_frame: Any = None
        self._last_scan: Any = None

    @property
    def counts(self) -> dict[str, int]:
        return self.bag.counts

    def episode_start(self, runtime: LoopView) -> None:
        outer_deg = runtime.spec.sonar_arrays.outer_sonar_deg
        stamp = max(runtime.t0_ns, 1)
        statics: list[tuple[str, str, np.ndarray]] = []
        if getattr(runtime.backend, "laser_scanner", None) is not None:
            statics.append((BASE_LINK, "laser_link", runtime.perception.t_base_sensor("laser_link")))
        cam = runtime.backend.depth_camera
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
        if statics:
            self.bag.tf(stamp, statics, static=True)

    def after_cycle(self, runtime: LoopView, cycle: CycleResult) -> None:
        bag = self.bag
        stamp = cycle.stamp_ns
        p = cycle.pose
        bag.odometry("/odom", stamp, ODOM, BASE_LINK, (p.x, p.y, p.theta), cycle.decision.v, cycle.decision.w)
        # REP-105: map -> odom is the localisation's part (identity without scan-to-map matching), so every
        # backend's bag has the same tree
        t_map_odom = getattr(runtime.perception, "t_map_odom", np.eye(4))
        bag.tf(stamp, [(MAP, ODOM, t_map_odom), (ODOM, BASE_LINK, se3_planar(p.x, p.y, p.theta))])
        arrays = dict(zip(runtime.sonar_names, runtime.backend.sonar_arrays))
        for name, reading in runtime.last_sonars:
            arr = arrays.get(name)
            lo = float(getattr(arr, "min_range_m", SONAR_MIN_RANGE_M))
            hi = float(getattr(arr, "max_range_m", 6.0))
            fov = float(getattr(arr, "field_of_view_rad", SONAR_FOV_RAD))
            for k, r in enumerate(reading.ranges_m, 1):
                bag.range(sonar_topic(name, k), reading.stamp_ns, sonar_frame(name, k), r, lo, hi, fov)
            mount = runtime.spec.mounts.get(name)
            if mount is not None:
                joint = runtime.spec.sonar_arrays.joint_angle(reading.servo_angle_deg)
                bag.tf(reading.stamp_ns, [(BASE_LINK, name, mount.transform(joint))])
        scan = runtime.last_scan
        if scan is not None and scan is not self._last_scan:
            from hw.laser_scan import to_ros_laser_scan

            self._last_scan = scan
            bag.write(SCAN_TOPIC, "sensor_msgs/msg/LaserScan", scan.stamp_ns,
                      to_ros_laser_scan(scan, typestore=bag.store))  # fmt: skip
        frame = runtime.last_depth_frame
        if frame is not None and frame is not self._last_frame:
            self._last_frame = frame
            if self.cloud_every and self._frames % self.cloud_every == 0:
                s = self.cloud_stride
                bag.cloud(CLOUD_TOPIC, frame.stamp_ns, frame.frame_id, np.asarray(frame.points)[::s, ::s])
            self._frames += 1

    def episode_end(self, runtime: LoopView, result: RunResult) -> None:
        self.bag.close()
        result.extra["bag"] = {"path": self.bag.path.name, "messages": dict(sorted(self.bag.counts.items()))}
