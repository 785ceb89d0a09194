"""`robchair map` on the kinds of real files that used to fail: nuScenes and x y z r g b `.bin`
scans, Blender PLY with mixed polygons, a message-compressed bare `.db3`, lidar "no return" zeros and
an unfinished ROS 1 recording. Every input is generated here in its real layout."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
from rosbags.rosbag2 import CompressionFormat, CompressionMode
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from mapping.errors import PointCloudFormatError
from mapping.io import open_clouds, read_clouds
from mapping.io.bags import to_ros_pointcloud2
from mapping.io.ply import read_ply, read_ply_mesh
from mapping.pointcloud2 import encode
from robchair.cli import main

PC2 = "sensor_msgs/msg/PointCloud2"


# the map commands whose pictures these tests do not look at (test_cli_map.py checks them): ~1 s each
MAP = ("map", "--no-pictures")


def _summary(out):
    return json.loads((out / "summary.json").read_text())


def _one_error_line(capsys) -> str:
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.strip().splitlines()
    return line


# ------------------------------------------------------------------------------------ .bin layouts


def _nuscenes(tmp_path, name="n015__LIDAR_TOP__0.pcd.bin"):
    rng = np.random.default_rng(0)
    pts = rng.uniform(-50, 50, (400, 5)).astype("<f4")
    pts[:, 3] = rng.uniform(0, 255, 400)  # intensity
    pts[:, 4] = np.arange(400) % 32  # ring
    pts.tofile(tmp_path / name)
    return pts


def test_nuscenes_pcd_bin_is_read_as_five_floats_per_point(tmp_path, capsys):
    pts = _nuscenes(tmp_path)
    (frame,) = read_clouds(tmp_path / "n015__LIDAR_TOP__0.pcd.bin")
    np.testing.assert_array_equal(frame.points, pts[:, :3])
    out = tmp_path / "out"
    assert main([*MAP, str(tmp_path / "n015__LIDAR_TOP__0.pcd.bin"), "--out", str(out)]) == 0
    assert _summary(out)["points_in"] == 400
    assert _summary(out)["parameters"]["bin_layout"] == "nuscenes"


def test_nuscenes_scan_without_its_file_name_is_refused_not_read_as_kitti(tmp_path, capsys):
    _nuscenes(tmp_path, "scan.bin")  # 400 x 20 bytes: also a multiple of 16
    assert main(["map", str(tmp_path / "scan.bin"), "--out", str(tmp_path / "out")]) == 2
    line = _one_error_line(capsys)
    assert "scan.bin: not a KITTI scan: every 4th float32 should be an intensity" in line
    assert "fits: kitti, nuscenes" in line and "--bin-layout" in line
    assert not (tmp_path / "out").exists()
    out = tmp_path / "out"
    assert main([*MAP, str(tmp_path / "scan.bin"), "--bin-layout", "nuscenes", "--out", str(out)]) == 0
    assert _summary(out)["points_in"] == 400


def test_indoor_xyzrgb_bin_is_refused_by_default_and_read_with_its_layout(tmp_path, capsys):
    rng = np.random.default_rng(1)
    pts = np.empty((200, 6), "<f4")
    pts[:, :3] = rng.uniform(-3, 3, (200, 3))
    pts[:, 3:] = rng.integers(0, 256, (200, 3))  # r g b
    pts.tofile(tmp_path / "room.bin")  # 200 x 24 bytes: a multiple of 16 too
    assert main(["map", str(tmp_path / "room.bin"), "--out", str(tmp_path / "o")]) == 2
    assert "room.bin: not a KITTI scan" in _one_error_line(capsys)
    out = tmp_path / "out"
    assert main([*MAP, str(tmp_path / "room.bin"), "--bin-layout", "xyzrgb", "--out", str(out)]) == 0
    assert _summary(out)["points_in"] == 200
    (frame,) = read_clouds(tmp_path / "room.bin", bin_layout="xyzrgb")
    np.testing.assert_array_equal(frame.points, pts[:, :3])


def test_kitti_scan_is_still_the_default_and_a_doubtful_size_is_refused(tmp_path):
    rng = np.random.default_rng(2)
    kitti = rng.uniform(-40, 40, (1000, 4)).astype("<f4")  # 1000 points: a multiple of 80 bytes
    kitti[:, 3] = rng.uniform(0, 1, 1000)
    kitti.tofile(tmp_path / "000000.bin")
    (frame,) = read_clouds(tmp_path / "000000.bin")
    np.testing.assert_array_equal(frame.points, kitti[:, :3])
    assert open_clouds(tmp_path / "000000.bin").kind == "kitti"
    # All zeros fits KITTI and nuScenes equally well: no guess.
    np.zeros((20, 4), "<f4").tofile(tmp_path / "zeros.bin")
    with pytest.raises(PointCloudFormatError, match=r"zeros\.bin: layout is ambiguous"):
        open_clouds(tmp_path / "zeros.bin")
    (tmp_path / "cut.pcd.bin").write_bytes(b"\0" * 30)
    with pytest.raises(PointCloudFormatError, match=r"cut\.pcd\.bin: a nuScenes \.pcd\.bin holds 5 float32"):
        open_clouds(tmp_path / "cut.pcd.bin")


def test_xyzrgb_bin_whose_colours_pass_for_intensities_is_refused_naming_the_layouts(tmp_path, capsys):
    """50,000 x y z r g b float32 points with colours in [0, 1] (1,200,000 bytes): the size fits
    16-, 20-, 12- and 24-byte records (hand division) and every 4th float (r, y or b, all in [0, 10])
    passes for a KITTI intensity; only the layout given with --bin-layout reads its 50,000 points."""
    rng = np.random.default_rng(3)
    pts = np.empty((50_000, 6), "<f4")
    pts[:, 0], pts[:, 1] = rng.uniform(0, 10, 50_000), rng.uniform(0, 8, 50_000)
    pts[:, 2], pts[:, 3:] = rng.uniform(0, 2.5, 50_000), rng.uniform(0, 1, (50_000, 3))
    pts.tofile(tmp_path / "room.bin")
    assert (tmp_path / "room.bin").stat().st_size == 1_200_000
    assert main(["map", str(tmp_path / "room.bin"), "--out", str(tmp_path / "o")]) == 2
    line = _one_error_line(capsys)
    assert "room.bin: not a KITTI scan" in line
    assert "fits: kitti, nuscenes, xyz, xyzrgb" in line and "--bin-layout" in line
    assert not (tmp_path / "o").exists()
    out = tmp_path / "out"
    assert main([*MAP, str(tmp_path / "room.bin"), "--bin-layout", "xyzrgb", "--out", str(out)]) == 0
    assert _summary(out)["points_in"] == 50_000


def test_kitti_scan_whose_size_also_fits_xyz_and_xyzrgb_is_still_read_as_kitti(tmp_path):
    """30,000 KITTI points are 480,000 bytes, a multiple of 12, 16, 20 and 24 (hand division); the
    data repeats every 4 floats only, so x y z and x y z r g b are ruled out and no flag is needed."""
    rng = np.random.default_rng(4)
    kitti = rng.uniform(-40, 40, (30_000, 4)).astype("<f4")
    kitti[:, 2], kitti[:, 3] = rng.uniform(-2, 1, 30_000), rng.uniform(0, 1, 30_000)
    kitti.tofile(tmp_path / "000001.bin")
    assert open_clouds(tmp_path / "000001.bin").kind == "kitti"
    (frame,) = read_clouds(tmp_path / "000001.bin")
    np.testing.assert_array_equal(frame.points, kitti[:, :3])
    cube = rng.uniform(0, 10, (24_000, 3)).astype("<f4")  # x y z alike: nothing tells the record length
    cube.tofile(tmp_path / "cube.bin")
    with pytest.raises(
        PointCloudFormatError, match=r"cube\.bin: layout is ambiguous: the data fits kitti, xyz"
    ):
        open_clouds(tmp_path / "cube.bin")


# ------------------------------------------------------------------------------------------- PLY


BLENDER_PLY = b"""ply
format ascii 1.0
comment Created by Blender
element vertex 5
property float x
property float y
property float z
element face 2
property list uchar uint vertex_indices
end_header
0 0 0
1 0 0
1 1 0
0 1 0
2 0.5 0.5
4 0 1 2 3
3 1 4 2
"""


def test_blender_ply_with_triangles_and_quads_is_mapped_from_its_vertices(tmp_path, capsys):
    path = tmp_path / "blender.ply"
    path.write_bytes(BLENDER_PLY)
    np.testing.assert_array_equal(read_ply(path)[:, 0], [0, 1, 1, 0, 2])
    # the quad becomes two triangles of a fan, the triangle stays
    assert read_ply_mesh(path).faces.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2]]
    out = tmp_path / "out"
    assert main([*MAP, str(path), "--out", str(out)]) == 0
    assert _summary(out)["points_in"] == 5


# ------------------------------------------------------------------------- compressed bare .db3


def _compressed_bag(tmp_path, points):
    store = get_typestore(Stores.ROS2_HUMBLE)
    folder = tmp_path / "lidar_bag"
    writer = Writer2(folder, version=8)
    writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection("/points", PC2, typestore=store)
        msg = to_ros_pointcloud2(encode(points, frame_id="lidar", stamp_ns=5))
        writer.write(conn, 5, store.serialize_cdr(msg, PC2))
    (db3,) = folder.glob("*.db3")
    bare = tmp_path / "shared.db3"
    bare.write_bytes(db3.read_bytes())  # shared without its metadata.yaml
    return folder, bare


def test_message_compressed_db3_without_its_folder_is_decoded_from_its_metadata_table(tmp_path, capsys):
    pts = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9]], np.float32)
    folder, bare = _compressed_bag(tmp_path, pts)
    (from_folder,) = read_clouds(folder)
    (from_file,) = read_clouds(bare)
    np.testing.assert_array_equal(from_file.points, pts)
    np.testing.assert_array_equal(from_file.points, from_folder.points)
    out = tmp_path / "out"
    assert main([*MAP, str(bare), "--out", str(out)]) == 0
    assert _summary(out)["points_in"] == 3


def test_compressed_db3_without_a_metadata_table_is_refused_saying_it_is_compressed(tmp_path, capsys):
    _, bare = _compressed_bag(tmp_path, np.ones((3, 3), np.float32))
    with sqlite3.connect(bare) as con:
        con.execute("DROP TABLE metadata")  # as written by recorders before ROS 2 Iron
    assert main(["map", str(bare), "--out", str(tmp_path / "out")]) == 2
    line = _one_error_line(capsys)
    assert "zstd-compressed" in line and "metadata.yaml" in line and "ros2 bag convert" in line
    assert line.count("shared.db3") == 1
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------------- no-return zeros


def test_lidar_no_return_zeros_are_dropped_and_counted(tmp_path, capsys):
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5, 5, (100, 3)).astype(np.float32)
    pts[::4] = 0.0  # 25 "no return" points at the sensor
    np.save(tmp_path / "scan.npy", pts)
    out = tmp_path / "out"
    assert main([*MAP, str(tmp_path / "scan.npy"), "--out", str(out)]) == 0
    s = _summary(out)
    assert s["points_dropped_min_range"] == 25
    assert s["points_in"] == 100 and s["points_inserted"] == 75
    assert s["parameters"]["min_range"] == 0.0
    # a real minimum range counts every point inside it
    near = int(np.count_nonzero(np.linalg.norm(pts.astype(np.float64), axis=1) <= 3.0))
    out2 = tmp_path / "out2"
    assert main([*MAP, str(tmp_path / "scan.npy"), "--min-range", "3", "--out", str(out2)]) == 0
    assert _summary(out2)["points_dropped_min_range"] == near > 25


# -------------------------------------------------------------------------- unfinished ROS 1 bag


def test_unfinished_ros1_recording_gets_a_reindex_hint(tmp_path, capsys):
    (tmp_path / "drive.bag.active").write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 64)
    assert main(["map", str(tmp_path / "drive.bag.active"), "--out", str(tmp_path / "out")]) == 2
    line = _one_error_line(capsys)
    assert "drive.bag.active: a ROS 1 bag whose recording never finished" in line
    assert "rosbag reindex drive.bag.active" in line
