"""A small run folder written from scratch (rosbags Writer, MCAP storage), with the files and bag topics of
a ``robchair sim`` run: the viewers and readers are tested on it without running the simulator.

The chair drives a quarter circle at 60 Hz; the Kinect cloud (a 12 x 16 organized grid, a few NaN) comes
at 10 Hz, both sonar arrays at 15 Hz (array ``sonar_array_right``'s outer sonar never echoes), a laser
scan at 10 Hz; two safety stops.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from robchair.platform.frames import BASE_LINK, ODOM, quat_from_matrix, quat_from_yaw, se3_planar, se3_rpy

RATE_HZ = 60
CLOUD_EVERY = 6  # 10 Hz
SONAR_EVERY = 4  # 15 Hz
SCAN_EVERY = 6  # 10 Hz
CLOUD_SHAPE = (12, 16)
SCAN_BEAMS = 181
SONAR_ARRAYS = ("sonar_array_left", "sonar_array_right")
CAMERA_FRAME = "kinect_depth_optical_frame"
LASER_FRAME = "laser_link"
CELL = 0.05
GRID_EXTENT = (-2.0, 6.0, -3.0, 5.0)  # u_min, u_max, v_min, v_max (m)


@dataclass
class SyntheticRun:
    """What was written, for the tests' expectations."""

    path: Path
    cycles: int
    counts: dict[str, int] = field(default_factory=dict)  # topic -> messages
    n_structures: int = 0
    stops: list[dict[str, object]] = field(default_factory=list)


def _header(t: dict, stamp_ns: int, frame_id: str):  # type: ignore[no-untyped-def]
    return t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](
            sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
        ),
        frame_id=frame_id,
    )


def _tf(t: dict, stamp_ns: int, transforms: list[tuple[str, str, np.ndarray]]):  # type: ignore[no-untyped-def]
    out = []
    for parent, child, m in transforms:
        q = quat_from_matrix(m[:3, :3])
        out.append(
            t["geometry_msgs/msg/TransformStamped"](
                header=_header(t, stamp_ns, parent),
                child_frame_id=child,
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](
                        x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3])
                    ),
                    rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                ),
            )
        )
    return t["tf2_msgs/msg/TFMessage"](transforms=out)


def write_synthetic_run(path: Path, seconds: float = 1.0, *, scan: bool = True, storage: str = "mcap",
                        t0_ns: int = 2_000_000_000) -> SyntheticRun:  # fmt: skip
    """Write a run folder into ``path`` (created) and return what it holds."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from mapping.pointcloud2 import encode

    path.mkdir(parents=True)
    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types
    rng = np.random.default_rng(7)
    cycles = round(seconds * RATE_HZ)
    run = SyntheticRun(path=path, cycles=cycles)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(path / "bag", version=9, storage_plugin=plugin)
    writer.open()
    conns: dict[str, object] = {}

    def write(topic: str, msgtype: str, stamp_ns: int, msg: object) -> None:
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
        writer.write(conns[topic], stamp_ns, store.serialize_cdr(msg, msgtype))
        run.counts[topic] = run.counts.get(topic, 0) + 1

    statics = [
        (BASE_LINK, "kinect_link", se3_rpy((-0.2, 0.0, 1.58), (0.0, 0.2618, 0.0))),
        ("kinect_link", CAMERA_FRAME, se3_rpy((0.0, 0.0, 0.0), (-math.pi / 2, 0.0, -math.pi / 2))),
        (BASE_LINK, LASER_FRAME, se3_rpy((0.6, 0.0, 0.3), (0.0, 0.0, 0.0))),
    ]
    for name in SONAR_ARRAYS:
        for k, yaw_deg in enumerate((40.0, 0.0, -40.0), 1):
            statics.append((name, f"{name}_{k}", se3_rpy((0.0, 0.0, 0.0), (0.0, 0.0, math.radians(yaw_deg)))))
    write("/tf_static", "tf2_msgs/msg/TFMessage", t0_ns, _tf(t, t0_ns, statics))

    radius, v = 2.0, 0.5
    w = v / radius
    for c in range(1, cycles + 1):
        stamp = t0_ns + c * 1_000_000_000 // RATE_HZ
        s = c / RATE_HZ
        yaw = w * s
        x, y = radius * math.sin(yaw), radius * (1 - math.cos(yaw))
        qx, qy, qz, qw = quat_from_yaw(yaw)
        cov = np.zeros(36)
        odom = t["nav_msgs/msg/Odometry"](
            header=_header(t, stamp, ODOM),
            child_frame_id=BASE_LINK,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=t["geometry_msgs/msg/Pose"](
                    position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                    orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                ),
                covariance=cov,
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=t["geometry_msgs/msg/Vector3"](x=v, y=0.0, z=0.0),
                    angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=w),
                ),
                covariance=cov.copy(),
            ),
        )
        write("/odom", "nav_msgs/msg/Odometry", stamp, odom)
        write(
            "/tf", "tf2_msgs/msg/TFMessage", stamp, _tf(t, stamp, [(ODOM, BASE_LINK, se3_planar(x, y, yaw))])
        )
        if c % SONAR_EVERY == 0:
            for side, name in enumerate(SONAR_ARRAYS):
                servo = math.radians(20.0 * math.sin(s))
                mount = se3_rpy((0.55, 0.29 if side == 0 else -0.29, 0.4), (0.0, 0.0, servo))
                write("/tf", "tf2_msgs/msg/TFMessage", stamp, _tf(t, stamp, [(BASE_LINK, name, mount)]))
                for k in (1, 2, 3):
                    r = math.inf if (side == 1 and k == 3) else float(rng.uniform(0.5, 3.0))
                    msg = t["sensor_msgs/msg/Range"](
                        header=_header(t, stamp, f"{name}_{k}"), radiation_type=0,
                        field_of_view=math.radians(60.0), min_range=0.03, max_range=6.0, range=r,
                    )  # fmt: skip
                    write(f"/sonar/{name}/{k}", "sensor_msgs/msg/Range", stamp, msg)
        if c % CLOUD_EVERY == 0:
            h, wd = CLOUD_SHAPE
            vv, uu = np.meshgrid(np.linspace(-0.4, 0.4, h), np.linspace(-0.6, 0.6, wd), indexing="ij")
            depth = rng.uniform(1.0, 4.0, (h, wd))
            pts = np.stack([uu * depth, vv * depth, depth], axis=-1).astype(np.float32)
            pts[0, :4] = np.nan  # no returns
            d = encode(pts, frame_id=CAMERA_FRAME, stamp_ns=stamp)
            msg = t["sensor_msgs/msg/PointCloud2"](
                header=_header(t, stamp, CAMERA_FRAME), height=d.height, width=d.width,
                fields=[t["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset, datatype=f.datatype,
                                                         count=f.count) for f in d.fields],
                is_bigendian=d.is_bigendian, point_step=d.point_step, row_step=d.row_step,
                data=np.ascontiguousarray(d.data, dtype=np.uint8).reshape(-1), is_dense=d.is_dense,
            )  # fmt: skip
            write("/kinect/points", "sensor_msgs/msg/PointCloud2", stamp, msg)
        if scan and c % SCAN_EVERY == 0:
            ranges = rng.uniform(0.5, 5.0, SCAN_BEAMS).astype(np.float32)
            ranges[:10] = np.inf  # out of range
            msg = t["sensor_msgs/msg/LaserScan"](
                header=_header(t, stamp, LASER_FRAME), angle_min=-math.pi / 2, angle_max=math.pi / 2,
                angle_increment=math.pi / (SCAN_BEAMS - 1), time_increment=0.0, scan_time=0.1,
                range_min=0.02, range_max=5.6, ranges=ranges, intensities=np.zeros(0, dtype=np.float32),
            )  # fmt: skip
            write("/scan", "sensor_msgs/msg/LaserScan", stamp, msg)
    writer.close()

    # maps.npz: a wall along y = 4 (one structure per cell, 0-1.2 m) and boxes on the floor
    nx = round((GRID_EXTENT[1] - GRID_EXTENT[0]) / CELL)
    i_wall = np.arange(nx, dtype=np.int32)
    j_wall = np.full(nx, round((4.0 - GRID_EXTENT[2]) / CELL), dtype=np.int32)
    i_obj = np.array([60, 61, 60, 61], dtype=np.int32)
    j_obj = np.array([80, 80, 81, 81], dtype=np.int32)
    i = np.concatenate([i_wall, i_obj, i_obj])
    j = np.concatenate([j_wall, j_obj, j_obj])
    bottom = np.concatenate([np.zeros(nx), np.zeros(4), np.full(4, 0.7)]).astype(np.float32)
    top = np.concatenate([np.full(nx, 1.2), np.full(4, 0.4), np.full(4, 0.75)]).astype(np.float32)
    run.n_structures = int(i.size)
    ts = np.arange(1, cycles + 1) / RATE_HZ
    path_xy = np.stack([radius * np.sin(w * ts), radius * (1 - np.cos(w * ts)), w * ts], axis=1)
    np.savez_compressed(
        path / "maps.npz",
        odometry_i=i, odometry_j=j, odometry_bottom=bottom, odometry_top=top,
        ground_truth_i=i[:-4], ground_truth_j=j[:-4],
        ground_truth_bottom=bottom[:-4], ground_truth_top=top[:-4],
        path_t=(t0_ns + np.arange(1, cycles + 1) * 1_000_000_000 // RATE_HZ).astype(np.int64),
        path_odometry=path_xy, path_ground_truth=path_xy + 0.01,
    )  # fmt: skip
    (path / "map").mkdir()
    summary = {
        "structures": int(i.size),
        "parameters": {"cell_size": CELL, "axis": "z", "grid_extent": list(GRID_EXTENT), "frame_id": "map"},
    }
    (path / "map" / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    import matplotlib.pyplot as plt

    img = np.zeros((40, 60, 3))
    img[10:30, 20:40] = (0.2, 0.6, 0.9)
    plt.imsave(path / "scene.png", img)
    occ = np.full((int(nx), int(nx)), 205, dtype=np.uint8)
    occ[0, :] = 0
    _write_map_server(path / "map", occ)
    run.stops = [
        {"t_s": seconds * 0.3, "reason": "obstacle", "detail": "sonar 0.42 m ahead"},
        {"t_s": seconds * 0.7, "reason": "stale_sensor", "detail": "kinect 0.30 s old"},
    ]
    metrics = {
        "backend": "sim",
        "status": "ok",
        "cycles": cycles,
        "sim_time_s": seconds,
        "route": {"goal_reached": False, "distance_travelled_m": v * seconds},
        "safety": {"enabled": True, "stops": run.stops, "stop_counts": {"obstacle": 1, "stale_sensor": 1}},
        "scenario": "synthetic_quarter_circle",
        "bag": {"path": "bag", "messages": dict(sorted(run.counts.items()))},
    }
    (path / "metrics.json").write_text(json.dumps(metrics, indent=2), encoding="utf-8")
    return run


def _write_map_server(folder: Path, img: np.ndarray) -> None:
    """map.pgm (P5, top row = highest y) + map.yaml as map_server writes them."""
    h, w = img.shape
    (folder / "map.pgm").write_bytes(f"P5\n{w} {h}\n255\n".encode() + img.tobytes())
    (folder / "map.yaml").write_text(
        f"image: map.pgm\nmode: trinary\nresolution: {CELL}\n"
        f"origin: [{GRID_EXTENT[0]}, {GRID_EXTENT[2]}, 0.0]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.25\n",
        encoding="utf-8",
    )


def write_timeseries(path: Path, cycles: int) -> None:
    """``timeseries.csv`` of the report's schema; mapping time only on cycles with a cloud."""
    rows = ["t_s,v_cmd,w_cmd,left_rpm_cmd,left_rpm_meas,right_rpm_cmd,right_rpm_meas,mapping_ms"]
    for c in range(1, cycles + 1):
        t = c / RATE_HZ
        mapping = f"{2.0 + 0.1 * (c % 5):.3f}" if c % CLOUD_EVERY == 0 else ""
        rows.append(f"{t:.6f},0.5,0.25,28.1,{28.1 - 0.3 * math.exp(-t):.4f},31.2,{31.0:.4f},{mapping}")
    (path / "timeseries.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
