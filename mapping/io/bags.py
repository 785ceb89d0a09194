"""ROS bags through the ``rosbags`` library: read ``sensor_msgs/PointCloud2`` (and the older
``sensor_msgs/PointCloud``) frames and the TF tree (``/tf``, ``/tf_static``, odometry), write messages.

ROS 1 ``.bag`` files (any chunk compression rosbags reads: none, bz2, lz4) use the ROS 1 Noetic type
store; ROS 2 bags (a folder with ``metadata.yaml``, or a bare ``.db3`` / ``.mcap`` file) use ROS 2
Humble's. Topic selection: the named topic, or the only point-cloud topic when none is named.

A bare ``.db3`` recorded with rosbag2's per-message compression (zstd) is decoded when the file's own
``metadata`` table (rosbag2 Iron and later) says so; without that table, messages that start with the
zstd frame magic are refused with what to do (open the bag folder with its ``metadata.yaml``).
"""

from __future__ import annotations

import dataclasses
import os
import struct
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mapping.errors import BagTopicError, PointCloudFormatError
from mapping.io.frame import CloudFrame
from mapping.io.tf import TfBuffer
from mapping.pointcloud2 import decode

ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"  # the first bytes of every zstd frame (RFC 8878)
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
POINTCLOUD = "sensor_msgs/msg/PointCloud"  # the older message, one Point32 per point (thesis inputs)
CLOUD_TYPES = (POINTCLOUD2, POINTCLOUD)
TF_TOPICS = ("/tf", "/tf_static")
TFMESSAGE = "tf2_msgs/msg/TFMessage"
ODOMETRY = "nav_msgs/msg/Odometry"
#: A point-cloud topic ``T + NO_RETURN_SUFFIX`` next to a cloud topic ``T`` carries, per cloud of ``T``
#: (same header stamp), the ends of the rays of the pixels without a return at the sensor's maximum
#: range, in the same frame (``robchair.observers.recorder``): free space along them, no hit.
NO_RETURN_SUFFIX = "/no_return"


def is_ros2_bag(path: Path) -> bool:
    """True for a ROS 2 bag folder (has metadata.yaml) or a bare .db3 / .mcap storage file."""
    return (path.is_dir() and (path / "metadata.yaml").exists()) or path.suffix in (".db3", ".mcap")


def _typestore(ros2: bool) -> Any:
    """ROS 2 Humble's type store, or ROS 1 Noetic's with ``tf2_msgs/TFMessage`` added (rosbags ships
    the Noetic store without tf2_msgs; its definition is the one of ROS 1 ``tf2_msgs/TFMessage.msg``)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    if TFMESSAGE not in store.types:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TFMESSAGE))
    return store


class _BoundedReads:
    """A binary file whose ``read(n)`` never asks for more than the bytes left.

    Bag readers read a record by the length the record declares; on a corrupt file that length can
    be anything up to 2**64, and a plain ``read(n)`` reserves ``n`` bytes before it finds the end of
    the file. Capping ``n`` at what is left changes no result and keeps memory bounded by the file.
    """

    def __init__(self, raw: Any) -> None:
        self._raw = raw
        self._size = os.fstat(raw.fileno()).st_size

    def read(self, n: int | None = -1) -> bytes:
        if n is None or n < 0:
            return bytes(self._raw.read())
        return bytes(self._raw.read(min(n, max(self._size - self._raw.tell(), 0))))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._raw, name)

    def __enter__(self) -> _BoundedReads:
        return self

    def __exit__(self, *exc: object) -> None:
        self._raw.close()


class _BoundedPath(type(Path())):  # type: ignore[misc]
    """A path whose binary opens for reading are :class:`_BoundedReads` (paths derived from it too)."""

    def open(self, mode: str = "r", *args: Any, **kwargs: Any) -> Any:  # type: ignore[override]
        f = super().open(mode, *args, **kwargs)
        return _BoundedReads(f) if mode == "rb" else f


def _open_reader(path: Path) -> tuple[Any, bool]:
    from rosbags.rosbag1 import Reader as Reader1
    from rosbags.rosbag2 import Reader as Reader2

    ros2 = is_ros2_bag(path)
    try:
        bounded = _BoundedPath(path)
        reader = Reader2(bounded) if ros2 else Reader1(bounded)
        reader.open()
    except (FileNotFoundError, PermissionError, MemoryError):
        raise
    except Exception as exc:  # rosbags, sqlite3 and mcap report damaged files with unrelated error types
        raise PointCloudFormatError(f"{path}: cannot open bag ({type(exc).__name__}: {exc})") from None
    return reader, ros2


def db3_compression(path: Path) -> tuple[str | None, str | None]:
    """(compression_mode, compression_format) of a bare ROS 2 ``.db3`` from its ``metadata`` table.

    rosbag2 (Iron and later) stores the bag's metadata.yaml text in that table, so a ``.db3`` shared
    without its folder still says whether its messages are compressed. Returns (None, None) when
    the table is absent or unreadable (older recorders), or says there is no compression.
    """
    import sqlite3

    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            row = con.execute("SELECT metadata FROM metadata ORDER BY id DESC LIMIT 1").fetchone()
        finally:
            con.close()
        from ruamel.yaml import YAML

        info = YAML(typ="safe").load(row[0])
        # rosbag2 stores the metadata.yaml text (with its root key); rosbags the mapping below it
        info = info.get("rosbag2_bagfile_information", info)
        mode = str(info.get("compression_mode") or "").lower() or None
        fmt = str(info.get("compression_format") or "").lower() or None
    except Exception:  # no table, no row, not YAML, or missing keys: nothing is known
        return None, None
    return (None, None) if mode in (None, "none") else (mode, fmt)


def _decompressor(path: Path) -> Any:
    """A function undoing the per-message compression of a bare ``.db3`` (None: not compressed).

    Raises:
        PointCloudFormatError: The compression cannot be decoded here.
    """
    if not (path.is_file() and path.suffix == ".db3"):
        return None  # folders and MCAP files: rosbags reads the compression from metadata / chunks
    mode, fmt = db3_compression(path)
    if mode is None:
        return None
    if mode != "message" or fmt != "zstd":
        raise PointCloudFormatError(
            f"{path}: bag is recorded with {mode} compression ({fmt}), which is not supported; "
            "decompress it with 'ros2 bag convert'"
        )
    if sys.version_info >= (3, 14):
        from compression import zstd
    else:  # the backport rosbags itself depends on
        from backports import zstd
    return zstd.decompress


def bag_topics(path: Path | str) -> dict[str, str]:
    """Topic -> message type of every connection in a bag."""
    path = Path(path)
    reader, _ = _open_reader(path)
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def select_topic(path: Path | str, topics: dict[str, str], topic: str | None) -> str:
    """The PointCloud2 topic to read: ``topic`` if given (and present), else the only one (a
    ``<T>/no_return`` companion of a cloud topic ``T`` is not a choice of its own).

    Raises:
        BagTopicError: The topic is absent or not PointCloud2, or there is no / more than one
            PointCloud2 topic to choose from; the message lists the bag's topics.
    """
    clouds = sorted(t for t, ty in topics.items() if ty in CLOUD_TYPES)
    clouds = [
        t for t in clouds if not (t.endswith(NO_RETURN_SUFFIX) and t[: -len(NO_RETURN_SUFFIX)] in clouds)
    ]
    listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "none"
    if topic is not None:
        if topic not in topics:
            raise BagTopicError(f"{path}: bag has no topic {topic!r}; available topics: {listing}")
        if topics[topic] not in CLOUD_TYPES:
            raise BagTopicError(
                f"{path}: topic {topic!r} is {topics[topic]}, not {POINTCLOUD2} or PointCloud"
            )
        return topic
    if not clouds:
        raise BagTopicError(
            f"{path}: bag has no {POINTCLOUD2} (or PointCloud) topic; available topics: {listing}"
        )
    if len(clouds) > 1:
        raise BagTopicError(
            f"{path}: bag has several point-cloud topics, choose one with --topic: {', '.join(clouds)}"
        )
    return clouds[0]


@dataclass
class BagClouds:
    """The PointCloud2 frames of one topic of a bag; iterate to decode them one by one.

    Attributes:
        path: The bag.
        topic: The topic read.
        n_frames: Number of messages on the topic (for progress bars).
        no_return_topic: The topic's ``<topic>/no_return`` companion when the bag has one: each
            frame then carries the companion message of its stamp as ``no_return``.
    """

    path: Path
    topic: str
    n_frames: int
    no_return_topic: str | None = None

    def __iter__(self) -> Iterator[CloudFrame]:
        """The frames in the bag's order, in one read of the bag: a frame waits for the companion message
        of its stamp (written with it) until a message of a later receive time comes."""
        decompress = _decompressor(self.path)
        reader, ros2 = _open_reader(self.path)
        store = _typestore(ros2)
        topics = (self.topic, self.no_return_topic)
        try:
            conns = [c for c in reader.connections if c.topic in topics]
            pending: list[tuple[int, CloudFrame]] = []  # (receive time, frame) waiting for its rays
            rays: dict[int, np.ndarray] = {}  # rays that came before their frame
            try:
                for conn, bag_stamp, raw in reader.messages(connections=conns):
                    while pending and pending[0][0] < int(bag_stamp):
                        yield pending.pop(0)[1]
                    if decompress is not None:
                        raw = self._decompress(decompress, raw)
                    elif bytes(raw[:4]) == ZSTD_MAGIC:
                        raise PointCloudFormatError(
                            "messages are zstd-compressed (rosbag2 message compression) and this "
                            ".db3 has no metadata table saying so; open the bag folder with its "
                            "metadata.yaml instead, or decompress it with 'ros2 bag convert'"
                        )
                    if conn.msgtype == POINTCLOUD:
                        points, stamp, frame_id = decode_pointcloud1(raw, ros2=ros2)
                    else:
                        msg = self._deserialize(store, ros2, raw, conn)
                        points = decode(msg, organized=int(msg.height) > 1)
                        stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                        frame_id = str(msg.header.frame_id)
                    stamp = stamp if stamp > 0 else int(bag_stamp)
                    if conn.topic != self.topic:  # the companion of a frame
                        k = next((n for n, (_, f) in enumerate(pending) if f.stamp_ns == stamp), None)
                        if k is None:
                            rays[stamp] = points.reshape(-1, 3)
                        else:
                            yield from (f for _, f in pending[:k])
                            frame = pending[k][1]
                            del pending[: k + 1]
                            yield dataclasses.replace(frame, no_return=points.reshape(-1, 3))
                        continue
                    source = f"{self.path}:{self.topic}"
                    frame = CloudFrame(points, stamp, frame_id, source, no_return=rays.pop(stamp, None))
                    if frame.no_return is not None or self.no_return_topic is None:
                        yield from (f for _, f in pending)
                        pending.clear()
                        yield frame
                    else:
                        pending.append((int(bag_stamp), frame))
                yield from (f for _, f in pending)
            except PointCloudFormatError as exc:
                raise PointCloudFormatError(f"{self.path}: topic {self.topic}: {exc}") from None
            except (OSError, MemoryError):
                raise
            except Exception as exc:  # corrupt storage: rosbags, sqlite3 and mcap share no error base
                raise PointCloudFormatError(
                    f"{self.path}: cannot read messages ({type(exc).__name__}: {exc})"
                ) from None
        finally:
            reader.close()

    @staticmethod
    def _decompress(decompress: Any, raw: bytes) -> bytes:
        try:
            return bytes(decompress(raw))
        except Exception as exc:  # zstd reports a damaged frame with its own error type
            raise PointCloudFormatError(
                f"a zstd-compressed message cannot be decompressed ({type(exc).__name__}: {exc})"
            ) from None

    def _deserialize(self, store: Any, ros2: bool, raw: bytes, conn: Any) -> Any:
        try:
            if ros2:
                return store.deserialize_cdr(raw, conn.msgtype)
            return store.deserialize_ros1(raw, conn.msgtype)
        except Exception as exc:  # rosbags raises assorted errors on a short or corrupt payload
            # (the caller prefixes the file and topic)
            raise PointCloudFormatError(
                f"a {conn.msgtype} message cannot be decoded ({type(exc).__name__}: {exc})"
            ) from None


def open_bag_clouds(path: Path | str, topic: str | None = None) -> BagClouds:
    """Select the PointCloud2 topic of a bag and count its messages (frames decode on iteration)."""
    path = Path(path)
    reader, _ = _open_reader(path)
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        chosen = select_topic(path, topics, topic)
        n = sum(int(c.msgcount) for c in reader.connections if c.topic == chosen)
    finally:
        reader.close()
    companion = chosen + NO_RETURN_SUFFIX
    return BagClouds(path, chosen, n, companion if topics.get(companion) in CLOUD_TYPES else None)


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def read_bag_tf(path: Path | str, pose_topic: str | None = None) -> TfBuffer:
    """The TF tree of a bag: every ``tf2_msgs/TFMessage`` of ``/tf`` and ``/tf_static``, and with
    ``pose_topic`` the poses of that ``nav_msgs/Odometry`` topic (``header.frame_id`` ->
    ``child_frame_id``, replacing any ``/tf`` edge into the same child).

    Returns:
        A :class:`mapping.io.tf.TfBuffer` (empty when the bag has neither topic).

    Raises:
        BagTopicError: ``pose_topic`` is absent or not Odometry; the message lists the bag's topics.
        PointCloudFormatError: A message cannot be read.
    """
    from mapping.io.tf import TfBuffer

    path = Path(path)
    decompress = _decompressor(path)
    reader, ros2 = _open_reader(path)
    store = _typestore(ros2)
    buf = TfBuffer()
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        if pose_topic is not None and topics.get(pose_topic) != ODOMETRY:
            listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "none"
            what = "has no topic" if pose_topic not in topics else f"has {topics[pose_topic]} on"
            raise BagTopicError(
                f"{path}: --pose-topic: bag {what} {pose_topic!r}, expected {ODOMETRY}; topics: {listing}"
            )
        conns = [
            c
            for c in reader.connections
            if (c.topic in TF_TOPICS and c.msgtype == TFMESSAGE) or c.topic == pose_topic
        ]
        poses: list[tuple[str, str, int, Any]] = []
        try:
            for conn, _, raw in reader.messages(connections=conns) if conns else ():  # [] means all
                raw = BagClouds._decompress(decompress, raw) if decompress is not None else raw
                msg = (
                    store.deserialize_cdr(raw, conn.msgtype)
                    if ros2
                    else store.deserialize_ros1(raw, conn.msgtype)
                )
                if conn.topic == pose_topic:
                    p = msg.pose.pose
                    poses.append((msg.header.frame_id, msg.child_frame_id, _stamp_ns(msg.header.stamp), p))
                    continue
                for tr in msg.transforms:
                    t, q = tr.transform.translation, tr.transform.rotation
                    static = conn.topic == "/tf_static"
                    stamp = _stamp_ns(tr.header.stamp)
                    xyz, xyzw = (t.x, t.y, t.z), (q.x, q.y, q.z, q.w)
                    buf.add(tr.header.frame_id, tr.child_frame_id, stamp, xyz, xyzw, static=static)
        except PointCloudFormatError:
            raise
        except (OSError, MemoryError):
            raise
        except Exception as exc:  # rosbags, sqlite3 and mcap share no error base
            raise PointCloudFormatError(f"{path}: cannot read TF ({type(exc).__name__}: {exc})") from None
    finally:
        reader.close()
    for child in {pose[1] for pose in poses}:
        buf.drop(child)
    for parent, child, stamp, p in poses:
        o = p.orientation
        buf.add(parent, child, stamp, (p.position.x, p.position.y, p.position.z), (o.x, o.y, o.z, o.w))
    return buf


def to_ros_pointcloud2(cloud: Any, *, ros2: bool = True) -> Any:
    """A rosbags ``sensor_msgs/msg/PointCloud2`` from a :class:`mapping.pointcloud2.PointCloud2Data`."""
    store = _typestore(ros2)
    t = store.types
    stamp = t["builtin_interfaces/msg/Time"](
        sec=int(cloud.stamp_ns // 1_000_000_000), nanosec=int(cloud.stamp_ns % 1_000_000_000)
    )
    if ros2:
        header = t["std_msgs/msg/Header"](stamp=stamp, frame_id=cloud.frame_id)
    else:  # the ROS 1 Header also has a sequence number
        header = t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=cloud.frame_id)
    fields = [
        t["sensor_msgs/msg/PointField"](name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
        for f in cloud.fields
    ]
    return t[POINTCLOUD2](
        header=header,
        height=cloud.height,
        width=cloud.width,
        fields=fields,
        is_bigendian=bool(cloud.is_bigendian),
        point_step=cloud.point_step,
        row_step=cloud.row_step,
        data=np.asarray(cloud.data, dtype=np.uint8),
        is_dense=bool(cloud.is_dense),
    )


def decode_pointcloud1(raw: bytes | memoryview, *, ros2: bool) -> tuple[np.ndarray, int, str]:
    """Points (N, 3) float32, stamp_ns and frame_id of a serialized ``sensor_msgs/PointCloud``.

    The points array sits right after the header in both wire formats, so it is read in place with
    numpy instead of deserializing one Point32 object per point. ROS 1: ``seq, sec, nsec`` (uint32),
    ``frame_id`` (uint32 length + bytes), point count (uint32), then x y z float32 per point. ROS 2
    CDR: a 4-byte encapsulation header (byte 1 = 1 for little-endian), then ``sec`` (int32),
    ``nanosec`` (uint32), ``frame_id`` (uint32 length including the NUL + bytes), padding to a
    multiple of 4 from the start of the body, the count (uint32) and the points.

    Raises:
        PointCloudFormatError: The message is shorter than its declared sizes.
    """
    buf = bytes(raw)

    def u32(fmt: str, pos: int) -> int:
        if pos + 4 > len(buf):
            raise PointCloudFormatError("PointCloud message is truncated")
        return int(struct.unpack_from(fmt, buf, pos)[0])

    if ros2:
        if len(buf) < 4:
            raise PointCloudFormatError("PointCloud message is truncated")
        order = "<" if buf[1] == 1 else ">"
        body = 4
        sec, nsec = u32(order + "i", body), u32(order + "I", body + 4)
        slen = u32(order + "I", body + 8)
        frame = buf[body + 12 : body + 12 + max(slen - 1, 0)]
        pos = body + 12 + slen
        pos = body + (pos - body + 3) // 4 * 4
    else:
        order = "<"
        sec, nsec = u32("<I", 4), u32("<I", 8)
        slen = u32("<I", 12)
        frame = buf[16 : 16 + slen]
        pos = 16 + slen
    n = u32(order + "I", pos)
    pos += 4
    if pos + 12 * n > len(buf):
        raise PointCloudFormatError(
            f"PointCloud message declares {n} points but holds {(len(buf) - pos) // 12}"
        )
    points = np.frombuffer(buf, dtype=order + "f4", count=3 * n, offset=pos).reshape(n, 3).astype(np.float32)
    return points, sec * 1_000_000_000 + nsec, frame.decode("utf-8", errors="replace")


def _latched_qos() -> Any:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    infinite = QosTime(sec=9223372036, nsec=854775807)  # rmw's "infinite" duration as rosbag2 stores it
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=1,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL,
        deadline=infinite,
        lifespan=infinite,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=infinite,
        avoid_ros_namespace_conventions=False,
    )


def write_bag(
    path: Path | str,
    messages: list[tuple[str, str, int, Any]],
    *,
    ros2: bool = True,
    storage: str = "sqlite3",
    compression: str | None = None,
    latched_topics: tuple[str, ...] = (),
) -> Path:
    """Write messages to a new bag.

    Args:
        path: Target (a folder for ROS 2, a ``.bag`` file for ROS 1); must not exist.
        messages: (topic, msgtype, stamp_ns, message) in order; a message is an object of the matching
            type store, or ``bytes`` already serialized (CDR for ROS 2, ROS 1 wire format for ROS 1).
        ros2: ROS 2 (Humble types, bag version 8) or ROS 1 (Noetic types).
        storage: ROS 2 storage plugin, ``sqlite3`` or ``mcap``.
        compression: ROS 1 chunk compression, ``None``, ``"bz2"`` or ``"lz4"``.
        latched_topics: ROS 2 topics recorded as offered with transient-local durability (what a
            map server offers), so ``ros2 bag play`` republishes them the way RViz's Map display
            subscribes; ROS 1 connections get ``latching=1``.
    """
    path = Path(path)
    store = _typestore(ros2)
    if ros2:
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
        with Writer2(path, version=8, storage_plugin=plugin) as writer:
            conns: dict[str, Any] = {}
            for topic, msgtype, stamp, msg in messages:
                if topic not in conns:
                    qos = [_latched_qos()] if topic in latched_topics else []
                    conns[topic] = writer.add_connection(
                        topic, msgtype, typestore=store, offered_qos_profiles=qos
                    )
                raw = msg if isinstance(msg, bytes) else store.serialize_cdr(msg, msgtype)
                writer.write(conns[topic], int(stamp), raw)
    else:
        from rosbags.rosbag1 import Writer as Writer1

        w1 = Writer1(path)
        if compression is not None:
            w1.set_compression(
                {"bz2": Writer1.CompressionFormat.BZ2, "lz4": Writer1.CompressionFormat.LZ4}[compression]
            )
        with w1 as writer:
            conns = {}
            for topic, msgtype, stamp, msg in messages:
                if topic not in conns:
                    latching = 1 if topic in latched_topics else None
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=store, latching=latching)
                raw = msg if isinstance(msg, bytes) else store.serialize_ros1(msg, msgtype)
                writer.write(conns[topic], int(stamp), raw)
    return path
