"""KITTI .bin and .npy inputs, and the extension dispatcher."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from mapping.errors import PointCloudFormatError
from mapping.io import open_clouds, read_clouds, read_kitti, read_npy, write_kitti, write_pcd


def test_hand_packed_kitti_scan_reads_xyz_and_intensity(tmp_path):
    path = tmp_path / "000000.bin"
    path.write_bytes(struct.pack("<8f", 1.5, -2.0, 0.25, 0.9, 10.0, 20.0, -1.0, 0.1))
    np.testing.assert_array_equal(read_kitti(path), np.array([[1.5, -2.0, 0.25], [10, 20, -1]], np.float32))
    np.testing.assert_allclose(read_kitti(path, with_intensity=True)[:, 3], [0.9, 0.1], rtol=1e-7)


def test_kitti_size_not_multiple_of_16_is_refused(tmp_path):
    path = tmp_path / "cut.bin"
    path.write_bytes(b"\0" * 20)
    with pytest.raises(
        PointCloudFormatError, match=r"cut\.bin: KITTI \.bin size 20 bytes is not a multiple of 16"
    ):
        read_kitti(path)


def test_kitti_write_then_read_round_trips(tmp_path):
    pts = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32)
    inten = np.linspace(0, 1, 50, dtype=np.float32)
    got = read_kitti(write_kitti(tmp_path / "s.bin", pts, inten), with_intensity=True)
    np.testing.assert_array_equal(got[:, :3], pts)
    np.testing.assert_array_equal(got[:, 3], inten)


def test_npy_flat_and_organized_are_accepted_and_integers_become_float(tmp_path):
    np.save(tmp_path / "a.npy", np.arange(12, dtype=np.int16).reshape(4, 3))
    got = read_npy(tmp_path / "a.npy")
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, np.arange(12).reshape(4, 3))
    org = np.zeros((2, 3, 3), np.float32)
    np.save(tmp_path / "o.npy", org)
    assert read_npy(tmp_path / "o.npy").shape == (2, 3, 3)


def test_npy_of_wrong_shape_or_garbage_is_refused(tmp_path):
    np.save(tmp_path / "w.npy", np.zeros((4, 2)))
    with pytest.raises(PointCloudFormatError, match=r"w\.npy: \.npy points must be \(N, 3\) or \(H, W, 3\)"):
        read_npy(tmp_path / "w.npy")
    (tmp_path / "g.npy").write_bytes(b"not numpy")
    with pytest.raises(PointCloudFormatError, match=r"not a readable \.npy"):
        read_npy(tmp_path / "g.npy")


def test_dispatcher_reads_each_extension_and_reports_one_frame(tmp_path):
    pts = np.array([[1, 2, 3], [4, 5, 6]], np.float32)
    write_pcd(tmp_path / "a.pcd", pts, viewpoint=(0.5, 0.0, 1.0, 1, 0, 0, 0))
    np.save(tmp_path / "b.npy", pts)
    write_kitti(tmp_path / "c.bin", pts)
    for name in ("a.pcd", "b.npy", "c.bin"):
        src = open_clouds(tmp_path / name)
        assert src.n_frames == 1
        (frame,) = list(read_clouds(tmp_path / name))
        np.testing.assert_array_equal(frame.points, pts)
        assert frame.source == str(tmp_path / name)
    (frame,) = list(read_clouds(tmp_path / "a.pcd"))
    assert frame.sensor_origin == (0.5, 0.0, 1.0)  # a non-default PCD VIEWPOINT gives the sensor position


def test_unknown_extension_is_refused_with_the_supported_list(tmp_path):
    (tmp_path / "scan.xyz").write_text("1 2 3\n")
    with pytest.raises(
        PointCloudFormatError, match=r"scan\.xyz: unknown point-cloud format '\.xyz'; expected one of \.pcd"
    ):
        open_clouds(tmp_path / "scan.xyz")


def test_missing_input_is_a_file_not_found_error(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothing\.pcd"):
        open_clouds(tmp_path / "nothing.pcd")
