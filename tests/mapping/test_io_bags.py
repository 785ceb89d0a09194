"""ROS 1 and ROS 2 bags written by rosbags' writers: PointCloud2 layouts, compression, topics, damage."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from mapping.errors import BagTopicError, PointCloudFormatError
from mapping.io import open_clouds, read_clouds

PC2 = "sensor_msgs/msg/PointCloud2"


def _cloud_msg(ts, ros2: bool, stamp_s: int, layout: str, frame_id: str = "cam"):
    """A PointCloud2 built field by field with numpy (independent of mapping.pointcloud2.encode)."""
    t = ts.types
    xyz = np.array([[1.0, -2.0, 3.0], [4.5, 5.0, -6.25], [0.0, 0.0, 0.0]])
    if layout == "padded_f32":
        # intensity first, 4 bytes of padding, x y z, then 8 bytes of padding: point_step 28
        dt = np.dtype(
            {"names": ["i", "x", "y", "z"], "formats": ["<f4"] * 4, "offsets": [0, 8, 12, 16], "itemsize": 28}
        )
        spec = [("i", 0, 7), ("x", 8, 7), ("y", 12, 7), ("z", 16, 7)]
        big = False
    elif layout == "bigendian_i16":
        dt = np.dtype({"names": ["x", "y", "z"], "formats": [">i2"] * 3, "offsets": [0, 2, 4], "itemsize": 6})
        spec = [("x", 0, 3), ("y", 2, 3), ("z", 4, 3)]
        big = True
        xyz = np.array([[1, -2, 3], [300, 32767, -32768], [0, 0, 0]], dtype=np.float64)
    elif layout == "u16_f64":
        dt = np.dtype(
            {"names": ["x", "y", "z"], "formats": ["<u2", "<u2", "<f8"], "offsets": [0, 2, 8], "itemsize": 16}
        )
        spec = [("x", 0, 4), ("y", 2, 4), ("z", 8, 8)]
        big = False
        xyz = np.array([[1, 2, -0.5], [65535, 0, 1e6], [7, 8, 9]], dtype=np.float64)
    elif layout == "no_z":
        dt = np.dtype({"names": ["x", "y"], "formats": ["<f4"] * 2, "offsets": [0, 4], "itemsize": 8})
        spec = [("x", 0, 7), ("y", 4, 7)]
        big = False
    else:
        raise AssertionError(layout)
    rec = np.zeros(3, dtype=dt)
    for k, c in enumerate("xyz"):
        if c in dt.names:
            rec[c] = xyz[:, k]
    data = np.frombuffer(rec.tobytes(), dtype=np.uint8)
    stamp = t["builtin_interfaces/msg/Time"](sec=stamp_s, nanosec=5)
    header = (
        t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)
        if ros2
        else t["std_msgs/msg/Header"](seq=1, stamp=stamp, frame_id=frame_id)
    )
    fields = [t["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=d, count=1) for n, o, d in spec]
    msg = t[PC2](header=header, height=1, width=3, fields=fields, is_bigendian=big, point_step=dt.itemsize,
                 row_step=3 * dt.itemsize, data=data, is_dense=True)  # fmt: skip
    return msg, xyz


def _ros1_bag(path, layouts, compression=None, extra_topics=()):
    ts = get_typestore(Stores.ROS1_NOETIC)
    w = Writer1(path)
    if compression:
        w.set_compression(compression)
    expected = []
    with w as writer:
        conn = writer.add_connection("/camera/points", PC2, typestore=ts)
        for k, layout in enumerate(layouts):
            msg, xyz = _cloud_msg(ts, False, 100 + k, layout)
            writer.write(conn, (100 + k) * 10**9, ts.serialize_ros1(msg, PC2))
            expected.append(xyz)
        for topic in extra_topics:
            c = writer.add_connection(topic, "std_msgs/msg/String", typestore=ts)
            writer.write(
                c, 1, ts.serialize_ros1(ts.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String")
            )
    return expected


def _ros2_bag(path, layouts, storage, topics=("/camera/points",)):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    expected = []
    with Writer2(path, version=8, storage_plugin=storage) as writer:
        for topic in topics:
            conn = writer.add_connection(topic, PC2, typestore=ts)
            for k, layout in enumerate(layouts):
                msg, xyz = _cloud_msg(ts, True, 200 + k, layout)
                writer.write(conn, (200 + k) * 10**9, ts.serialize_cdr(msg, PC2))
                expected.append(xyz)
    return expected


LAYOUTS = ["padded_f32", "bigendian_i16", "u16_f64"]


@pytest.mark.parametrize("compression", [None, Writer1.CompressionFormat.LZ4, Writer1.CompressionFormat.BZ2])
def test_ros1_bag_frames_decode_for_every_layout_and_chunk_compression(tmp_path, compression):
    path = tmp_path / "run.bag"
    expected = _ros1_bag(path, LAYOUTS, compression)
    src = open_clouds(path)
    assert (src.kind, src.topic, src.n_frames) == ("ros1-bag", "/camera/points", 3)
    frames = list(src)
    for frame, xyz, k in zip(frames, expected, range(3)):
        np.testing.assert_array_equal(frame.points, xyz)
        assert frame.stamp_ns == (100 + k) * 10**9 + 5
        assert frame.frame_id == "cam"
        assert frame.source == f"{path}:/camera/points"


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_ros2_bag_frames_decode_from_folder_and_storage_file(tmp_path, storage):
    path = tmp_path / "run2"
    expected = _ros2_bag(path, LAYOUTS, storage)
    for target in (path, next(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))):
        frames = list(read_clouds(target))
        assert len(frames) == 3
        for frame, xyz in zip(frames, expected):
            np.testing.assert_array_equal(frame.points, xyz)
        assert frames[2].stamp_ns == 202 * 10**9 + 5


def test_named_topic_is_selected_among_several_cloud_topics(tmp_path):
    path = tmp_path / "two"
    _ros2_bag(path, ["padded_f32"], StoragePlugin.SQLITE3, topics=("/front/points", "/rear/points"))
    with pytest.raises(
        BagTopicError,
        match="several point-cloud topics, choose one with --topic: /front/points, /rear/points",
    ):
        open_clouds(path)
    src = open_clouds(path, topic="/rear/points")
    assert src.topic == "/rear/points"
    assert len(list(src)) == 1


def test_absent_topic_is_refused_listing_available_topics(tmp_path):
    path = tmp_path / "run.bag"
    _ros1_bag(path, ["padded_f32"], extra_topics=("/chatter",))
    with pytest.raises(
        BagTopicError,
        match=r"run\.bag: bag has no topic '/lidar'; available topics: "
        r"/camera/points \(sensor_msgs/msg/PointCloud2\), /chatter",
    ):
        open_clouds(path, topic="/lidar")
    with pytest.raises(
        BagTopicError, match="topic '/chatter' is std_msgs/msg/String, not sensor_msgs/msg/PointCloud2"
    ):
        open_clouds(path, topic="/chatter")


def test_bag_without_any_cloud_topic_is_refused(tmp_path):
    path = tmp_path / "empty.bag"
    _ros1_bag(path, [], extra_topics=("/chatter",))
    # a PointCloud2 topic with no messages is still selected: it just yields no frames
    assert open_clouds(path).n_frames == 0
    path2 = tmp_path / "strings.bag"
    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer1(path2) as writer:
        c = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        writer.write(
            c, 1, ts.serialize_ros1(ts.types["std_msgs/msg/String"](data="x"), "std_msgs/msg/String")
        )
    with pytest.raises(
        BagTopicError,
        match=r"bag has no sensor_msgs/msg/PointCloud2 \(or PointCloud\) topic; available topics: /chatter",
    ):
        open_clouds(path2)


def test_cloud_without_z_field_in_a_bag_is_refused(tmp_path):
    path = tmp_path / "noz.bag"
    _ros1_bag(path, ["no_z"])
    with pytest.raises(
        PointCloudFormatError, match=r"noz\.bag: topic /camera/points: PointCloud2 has no z field"
    ):
        list(read_clouds(path))


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_truncated_bag_is_refused_naming_the_file(tmp_path, kind):
    if kind == "ros1":
        target = tmp_path / "cut.bag"
        _ros1_bag(target, LAYOUTS * 3, Writer1.CompressionFormat.LZ4)
    else:
        folder = tmp_path / "cut"
        _ros2_bag(folder, LAYOUTS * 3, StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP)
        target = next(p for p in folder.iterdir() if p.suffix in (".db3", ".mcap"))
    data = target.read_bytes()
    target.write_bytes(data[: len(data) // 2])
    with pytest.raises(PointCloudFormatError, match=rf"{target.name}: cannot (open bag|read messages)"):
        list(read_clouds(target))


def test_bag_written_by_the_project_writer_round_trips(tmp_path):
    from mapping.io.bags import to_ros_pointcloud2, write_bag
    from mapping.pointcloud2 import INT16, encode

    pts = np.arange(24, dtype=np.float64).reshape(2, 4, 3)
    cloud = encode(
        pts, datatype=INT16, is_bigendian=True, point_step=11, row_padding=3, frame_id="f", stamp_ns=7
    )
    for ros2, name in ((False, "w.bag"), (True, "w2")):
        write_bag(tmp_path / name, [("/c", PC2, 7, to_ros_pointcloud2(cloud, ros2=ros2))], ros2=ros2)
        (frame,) = list(read_clouds(tmp_path / name))
        np.testing.assert_array_equal(frame.points, pts)  # organized clouds keep their shape
        assert (frame.stamp_ns, frame.frame_id) == (7, "f")


def _pointcloud1(ts, ros2: bool, frame_id: str, xyz: np.ndarray, stamp_s: int):
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=stamp_s, nanosec=9)
    header = (
        t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)
        if ros2
        else t["std_msgs/msg/Header"](seq=3, stamp=stamp, frame_id=frame_id)
    )
    pts = [t["geometry_msgs/msg/Point32"](x=float(a), y=float(b), z=float(c)) for a, b, c in xyz]
    chan = t["sensor_msgs/msg/ChannelFloat32"](name="intensity", values=np.arange(len(xyz), dtype=np.float32))
    return t["sensor_msgs/msg/PointCloud"](header=header, points=pts, channels=[chan])


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_old_pointcloud_messages_decode_whatever_the_frame_id_length(tmp_path, kind):
    msgtype = "sensor_msgs/msg/PointCloud"
    ros2 = kind != "ros1"
    ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    rng = np.random.default_rng(8)
    # Frame ids of 1 to 4 characters move the CDR padding before the point count through every case.
    frames = [
        (fid, rng.normal(size=(k + 2, 3)).astype(np.float32))
        for k, fid in enumerate(["a", "ab", "abc", "abcd"])
    ]
    serialize = ts.serialize_cdr if ros2 else ts.serialize_ros1
    if ros2:
        path = tmp_path / "pc1"
        plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
        with Writer2(path, version=8, storage_plugin=plugin) as writer:
            conn = writer.add_connection("/sonar_cloud", msgtype, typestore=ts)
            for k, (fid, xyz) in enumerate(frames):
                writer.write(conn, k + 1, serialize(_pointcloud1(ts, True, fid, xyz, 10 + k), msgtype))
    else:
        path = tmp_path / "pc1.bag"
        with Writer1(path) as writer:
            conn = writer.add_connection("/sonar_cloud", msgtype, typestore=ts)
            for k, (fid, xyz) in enumerate(frames):
                writer.write(conn, k + 1, serialize(_pointcloud1(ts, False, fid, xyz, 10 + k), msgtype))
    got = list(read_clouds(path))
    assert [f.frame_id for f in got] == ["a", "ab", "abc", "abcd"]
    assert [f.stamp_ns for f in got] == [(10 + k) * 10**9 + 9 for k in range(4)]
    for frame, (_, xyz) in zip(got, frames):
        np.testing.assert_array_equal(frame.points, xyz)


def test_truncated_old_pointcloud_message_is_refused():
    from mapping.io.bags import decode_pointcloud1

    ts = get_typestore(Stores.ROS2_HUMBLE)
    raw = ts.serialize_cdr(
        _pointcloud1(ts, True, "cam", np.ones((5, 3), np.float32), 1), "sensor_msgs/msg/PointCloud"
    )
    points, _, frame = decode_pointcloud1(raw, ros2=True)
    assert points.shape == (5, 3) and frame == "cam"
    cut = bytes(raw)[: 4 + 8 + 4 + 4 + 4 + 12 * 3 + 4]  # CDR header, stamp, "cam", count, 3 points + 4 bytes
    with pytest.raises(PointCloudFormatError, match="declares 5 points but holds 3"):
        decode_pointcloud1(cut, ros2=True)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_cloud_topic_s_no_return_companion_comes_with_each_frame_of_its_stamp(tmp_path, storage):
    """``<topic>/no_return`` is not a topic of its own to choose; each frame carries the companion message
    of its stamp (written before or after it, or not at all), in one read of the bag, in the bag's order."""
    from mapping.io.bags import to_ros_pointcloud2, write_bag
    from mapping.pointcloud2 import encode

    def msg(points, stamp_ns):
        return to_ros_pointcloud2(encode(np.asarray(points, np.float32), frame_id="cam", stamp_ns=stamp_ns))

    frames = {k: np.full((3 + k, 3), float(k), np.float32) for k in range(5)}
    rays = {0: [[4.5, 0.0, 1.0]], 2: [[4.5, 1.0, 2.0], [4.5, 2.0, 3.0]], 3: [[4.5, 3.0, 3.0]]}
    messages = []
    for k in range(5):
        t = (k + 1) * 10**8
        cloud = ("/kinect/points", PC2, t, msg(frames[k], t))
        ray = [("/kinect/points/no_return", PC2, t, msg(rays[k], t))] if k in rays else []
        messages += [*ray, cloud] if k == 3 else [cloud, *ray]  # frame 3's rays come first
    bag = write_bag(tmp_path / "bag", messages, storage=storage)
    src = open_clouds(bag)
    assert src.topic == "/kinect/points" and src.no_return_topic == "/kinect/points/no_return"
    got = list(src)
    assert [f.stamp_ns for f in got] == [(k + 1) * 10**8 for k in range(5)]
    for k, f in enumerate(got):
        np.testing.assert_array_equal(f.points, frames[k])
        if k in rays:
            np.testing.assert_array_equal(f.no_return, np.asarray(rays[k], np.float32))
        else:
            assert f.no_return is None
    # the companion can still be read as a topic of its own
    assert len(list(open_clouds(bag, topic="/kinect/points/no_return"))) == len(rays)
