"""The MCAP writer of the run recorder: the run's ROS 2 messages built once, written to a rosbag2 folder.

:class:`RosMessages` builds every message the project sends or records (ROS 2 Humble types of
``rosbags``: odometry, transforms, ranges, point clouds, occupancy grids, markers, logs) and hands each
to :meth:`RosMessages.write`; :class:`BagWriter` writes them to a rosbag2 bag (format version 9, MCAP
by default or sqlite3), one connection per topic. The topic and frame scheme, the depth clouds' thinning
and their placement at the written poses are :mod:`robchair.observers.recorder`'s.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any

import numpy as np

from robchair.platform.errors import ConfigError
from robchair.platform.frames import quat_from_matrix, quat_from_yaw

STORAGES = ("mcap", "sqlite3")


def _quat(m: np.ndarray) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) of a transform's rotation; a rotation about z alone (odometry, ``map`` ->
    ``odom``) directly from its yaw (scipy's general conversion costs ~0.1 ms)."""
    r = m[:3, :3]
    if r[2, 2] == 1.0 and r[0, 2] == r[1, 2] == r[2, 0] == r[2, 1] == 0.0:
        return quat_from_yaw(math.atan2(float(r[1, 0]), float(r[0, 0])))
    return quat_from_matrix(r)


@functools.lru_cache(maxsize=1)
def typestore() -> Any:
    """The ROS 2 Humble type store of ``rosbags``, one per process (its serialisers are cached in it)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


class RosMessages:
    """Builds the run's ROS 2 messages (Humble types of ``rosbags``) and hands each one to :meth:`write`.

    The one message builder of the project: the bag (:class:`BagWriter`) and the live view
    (:mod:`robchair.observers.live`) subclass it and differ only in what :meth:`write` does.
    """

    def __init__(self) -> None:
        self.store = typestore()
        self.t = self.store.types

    def precompile(self, msgtypes: list[str]) -> None:
        """Generate the (de)serialisers of these message types now (``rosbags`` makes each on first use,
        tens of milliseconds a type: not while a run is being sent)."""
        for msgtype in msgtypes:
            self.store.get_msgdef(msgtype)

    def write(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        """Take one built message (``msgtype`` e.g. ``"nav_msgs/msg/Odometry"``, ``stamp_ns`` its time)."""
        raise NotImplementedError

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
            q = _quat(m)
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

    def occupancy_grid(self, topic: str, stamp_ns: int, frame_id: str, codes: np.ndarray, cell_size: float,
                       origin_xy: tuple[float, float]) -> None:  # fmt: skip
        """nav_msgs/OccupancyGrid of three-valued codes (``(nx, ny)`` int8 indexed ``[i, j]``, i along x;
        100 occupied, 0 free, -1 unknown), ``cell_size`` m, cell (0, 0)'s corner at ``origin_xy``."""
        t = self.t
        codes = np.asarray(codes, dtype=np.int8)
        nx, ny = codes.shape
        header = self.header(stamp_ns, frame_id)
        msg = t["nav_msgs/msg/OccupancyGrid"](
            header=header,
            info=t["nav_msgs/msg/MapMetaData"](
                map_load_time=header.stamp,
                resolution=float(cell_size),
                width=int(nx),
                height=int(ny),
                origin=t["geometry_msgs/msg/Pose"](
                    position=t["geometry_msgs/msg/Point"](
                        x=float(origin_xy[0]), y=float(origin_xy[1]), z=0.0
                    ),
                    orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                ),
            ),
            data=np.ascontiguousarray(codes.T).reshape(-1),  # row-major, row = y index
        )
        self.write(topic, "nav_msgs/msg/OccupancyGrid", stamp_ns, msg)

    def marker(self, header: Any, ns: str, mid: int, kind: int, action: int, scale: Any,
               points: np.ndarray, rgba: np.ndarray | None = None,
               color: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)) -> Any:  # fmt: skip
        """One visualization_msgs/Marker (``kind``: 4 LINE_STRIP, 6 CUBE_LIST ...; ``action``: 0 ADD,
        3 DELETEALL) at the frame's origin: (K, 3) ``points`` m, optional (K, 4) per-point ``rgba``
        in [0, 1]."""
        t = self.t
        pt, rgba_t = t["geometry_msgs/msg/Point"], t["std_msgs/msg/ColorRGBA"]
        no_bytes = np.zeros(0, dtype=np.uint8)
        q = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        origin = t["geometry_msgs/msg/Pose"](position=pt(x=0.0, y=0.0, z=0.0), orientation=q)
        xyz = np.asarray(points, dtype=np.float64)
        return t["visualization_msgs/msg/Marker"](
            header=header, ns=ns, id=int(mid), type=int(kind), action=int(action),
            pose=origin,
            scale=t["geometry_msgs/msg/Vector3"](x=float(scale[0]), y=float(scale[1]), z=float(scale[2])),
            color=rgba_t(r=color[0], g=color[1], b=color[2], a=color[3]),
            lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
            points=[pt(x=float(x), y=float(y), z=float(z)) for x, y, z in xyz],
            colors=[] if rgba is None else [rgba_t(r=float(r), g=float(g), b=float(b), a=float(a))
                                            for r, g, b, a in rgba],
            texture_resource="",
            texture=t["sensor_msgs/msg/CompressedImage"](header=header, format="", data=no_bytes),
            uv_coordinates=[], text="", mesh_resource="",
            mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=no_bytes),
            mesh_use_embedded_materials=False,
        )  # fmt: skip

    def box_markers(self, topic: str, stamp_ns: int, frame_id: str, ns: str, mins: np.ndarray,
                    maxs: np.ndarray, rgb: np.ndarray, height_step_m: float = 0.01) -> None:  # fmt: skip
        """visualization_msgs/MarkerArray of axis-aligned boxes ((K, 3) ``mins`` / ``maxs`` m, (K, 3) uint8
        colours): a DELETEALL, then one CUBE_LIST per box size, heights rounded to ``height_step_m`` (a
        CUBE_LIST has one scale)."""
        header = self.header(stamp_ns, frame_id)
        mins, maxs = np.asarray(mins, dtype=np.float64), np.asarray(maxs, dtype=np.float64)
        size = maxs - mins
        size[:, 2] = np.maximum(np.round(size[:, 2] / height_step_m), 1) * height_step_m
        centre = (mins + maxs) / 2
        rgba = np.column_stack([np.asarray(rgb, dtype=np.float64) / 255.0, np.ones(len(mins))])
        markers = [self.marker(header, ns, 0, 6, 3, np.zeros(3), np.zeros((0, 3)))]
        if len(mins):
            sizes, inverse = np.unique(np.round(size, 6), axis=0, return_inverse=True)
            for mid, scale in enumerate(sizes):
                rows = np.flatnonzero(inverse.reshape(-1) == mid)
                markers.append(self.marker(header, ns, mid, 6, 0, scale, centre[rows], rgba[rows]))
        self.write(topic, "visualization_msgs/msg/MarkerArray", stamp_ns,
                   self.t["visualization_msgs/msg/MarkerArray"](markers=markers))  # fmt: skip

    def line_markers(self, topic: str, stamp_ns: int,
                     lines: list[tuple[str, str, int, np.ndarray, np.ndarray]]) -> None:  # fmt: skip
        """visualization_msgs/MarkerArray of LINE_LISTs (segments between points 0-1, 2-3 ...): (frame
        id, namespace, id, (2K, 3) points m, (2K, 4) RGBA in [0, 1]) each, 1 cm wide."""
        markers = [self.marker(self.header(stamp_ns, frame), ns, mid, 5, 0, (0.01, 0.0, 0.0), pts, rgba)
                   for frame, ns, mid, pts, rgba in lines]  # fmt: skip
        self.write(topic, "visualization_msgs/msg/MarkerArray", stamp_ns,
                   self.t["visualization_msgs/msg/MarkerArray"](markers=markers))  # fmt: skip

    def log(self, topic: str, stamp_ns: int, level: int, name: str, text: str) -> None:
        """rcl_interfaces/msg/Log (``level``: 10 DEBUG, 20 INFO, 30 WARN, 40 ERROR, 50 FATAL)."""
        t = self.t
        stamp = self.header(stamp_ns, "").stamp
        msg = t["rcl_interfaces/msg/Log"](stamp=stamp, level=int(level), name=name, msg=text, file="",
                                          function="", line=0)  # fmt: skip
        self.write(topic, "rcl_interfaces/msg/Log", stamp_ns, msg)


class BagWriter(RosMessages):
    """Typed, counted writes to a rosbag2 folder (one connection per topic, created on first use).

    Args:
        path: the bag folder to create (must not exist).
        storage: ``"mcap"`` (default) or ``"sqlite3"``.

    Raises:
        ConfigError: unknown storage, or the folder exists.
    """

    def __init__(self, path: Path | str, storage: str = "mcap") -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        super().__init__()
        if storage not in STORAGES:
            raise ConfigError(f"bag storage {storage!r}: expected one of {', '.join(STORAGES)}")
        self.path = Path(path)
        if self.path.exists():
            raise ConfigError(f"bag {self.path} already exists")
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

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
