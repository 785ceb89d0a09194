"""Streaming ROS 2 bag of a simulated run: PointCloud2, Range, Odometry and TF, written as it happens.

Messages use the ROS 2 Humble type store of ``rosbags``; clouds are packed by
:func:`mapping.pointcloud2.encode`. Frames (REP-105): ``odom`` -> ``base_link`` from the chair's
wheel odometry (``/odom``, ``/tf``), ``map`` -> ``base_link_gt`` from the physics (``/ground_truth/odom``),
``base_link`` -> ``kinect_link`` (``/tf_static``), ``base_link`` -> ``sonar_array_*`` with the servo angle
(``/tf``), and each sonar's own frame ``sonar_array_*_<k>`` (k = 1, 2, 3 left to right) on ``/tf_static``.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any

import numpy as np

from sim.errors import SimError


def _quat_from_matrix(r: np.ndarray) -> tuple[float, float, float, float]:
    from sim.raycast import matrix_to_quat

    return matrix_to_quat(r)


class BagRecorder:
    """Write messages to a ROS 2 bag folder (sqlite3) one at a time.

    Args:
        path: The bag folder to create (must not exist).
    """

    def __init__(self, path: Path | str) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        if self.path.exists():
            raise SimError(f"bag {self.path} already exists")
        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.t = self.store.types
        self._writer: Any = Writer(self.path, version=8, storage_plugin=StoragePlugin.SQLITE3)
        self._writer.open()
        self._conns: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self._lock = threading.Lock()  # the runner records clouds from its mapping thread

    # -- low level ---------------------------------------------------------------------------------
    def _write(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        data = self.store.serialize_cdr(msg, msgtype)
        with self._lock:
            if self._writer is None:
                raise SimError(f"bag {self.path} is closed")
            if topic not in self._conns:
                self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=self.store)
            # rosbag2 tools dislike a zero receive time: the first frames at t = 0 are stamped 1 ns
            self._writer.write(self._conns[topic], max(int(stamp_ns), 1), data)
            self.counts[topic] = self.counts.get(topic, 0) + 1

    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        t = self.t
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](
                sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000)
            ),
            frame_id=frame_id,
        )

    def _transform(self, stamp_ns: int, parent: str, child: str, m: np.ndarray) -> Any:
        t = self.t
        q = _quat_from_matrix(m[:3, :3])
        return t["geometry_msgs/msg/TransformStamped"](
            header=self._header(stamp_ns, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](
                    x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3])
                ),
                rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            ),
        )

    # -- messages ----------------------------------------------------------------------------------
    def tf(self, stamp_ns: int, transforms: list[tuple[str, str, np.ndarray]], static: bool = False) -> None:
        """One TFMessage with (parent, child, 4x4 parent <- child) transforms."""
        msg = self.t["tf2_msgs/msg/TFMessage"](
            transforms=[self._transform(stamp_ns, p, c, m) for p, c, m in transforms]
        )
        self._write("/tf_static" if static else "/tf", "tf2_msgs/msg/TFMessage", stamp_ns, msg)

    def odometry(
        self,
        topic: str,
        stamp_ns: int,
        parent: str,
        child: str,
        x: float,
        y: float,
        yaw: float,
        v: float = 0.0,
        w: float = 0.0,
    ) -> None:
        """nav_msgs/Odometry of a planar pose (z = 0) and body twist."""
        t = self.t
        cov = np.zeros(36, dtype=np.float64)
        msg = t["nav_msgs/msg/Odometry"](
            header=self._header(stamp_ns, parent),
            child_frame_id=child,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=t["geometry_msgs/msg/Pose"](
                    position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                    orientation=t["geometry_msgs/msg/Quaternion"](
                        x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
                    ),
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
        self._write(topic, "nav_msgs/msg/Odometry", stamp_ns, msg)

    def range(
        self,
        topic: str,
        stamp_ns: int,
        frame_id: str,
        range_m: float,
        min_m: float,
        max_m: float,
        fov_rad: float,
    ) -> None:
        """sensor_msgs/Range (ULTRASOUND). No echo is written as +inf (REP-117)."""
        t = self.t
        r = float(range_m) if math.isfinite(range_m) else math.inf
        msg = t["sensor_msgs/msg/Range"](
            header=self._header(stamp_ns, frame_id),
            radiation_type=0,
            field_of_view=float(fov_rad),
            min_range=float(min_m),
            max_range=float(max_m),
            range=r,
        )
        self._write(topic, "sensor_msgs/msg/Range", stamp_ns, msg)

    def cloud(self, topic: str, stamp_ns: int, frame_id: str, points: np.ndarray) -> None:
        """sensor_msgs/PointCloud2 (float32 x, y, z; organized clouds keep their rows, NaN = no return)."""
        from mapping.pointcloud2 import encode

        t = self.t
        d = encode(np.asarray(points, dtype=np.float32), frame_id=frame_id, stamp_ns=stamp_ns)
        msg = t["sensor_msgs/msg/PointCloud2"](
            header=self._header(stamp_ns, frame_id),
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
        self._write(topic, "sensor_msgs/msg/PointCloud2", stamp_ns, msg)

    def close(self) -> None:
        with self._lock:
            if self._writer is not None:
                self._writer.close()
                self._writer = None

    def __enter__(self) -> BagRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
