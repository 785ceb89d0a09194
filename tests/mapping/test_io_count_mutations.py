"""Files that declare more points than they hold are refused, never read short (PLY and PCD, ascii).

Each file is written by hand here; the declared counts and the rows present are the hand values.
"""

from __future__ import annotations

import pytest

from mapping.errors import PointCloudFormatError
from mapping.io.pcd import read_pcd
from mapping.io.ply import read_ply

PLY_HEADER = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    "end_header\n"
)


def test_an_ascii_ply_with_fewer_vertex_rows_than_declared_is_refused(tmp_path) -> None:
    """PLY format (Bourke, "PLY - Polygon File Format"): ``element vertex 3`` declares three rows; the
    file holds two complete rows, so it was cut between rows."""
    path = tmp_path / "short.ply"
    path.write_text(PLY_HEADER + "0 0 0\n1 2 3\n")
    with pytest.raises(PointCloudFormatError, match=r"short\.ply: PLY ascii data truncated .*2 of 3 rows"):
        read_ply(path)


def test_an_ascii_ply_cut_in_the_middle_of_a_vertex_is_refused(tmp_path) -> None:
    """Three declared vertices of x, y, z; the third row stops after its x: two values of three."""
    path = tmp_path / "cut.ply"
    path.write_text(PLY_HEADER + "0 0 0\n1 2 3\n4")
    with pytest.raises(PointCloudFormatError, match=r"cut\.ply"):
        read_ply(path)


def test_an_ascii_ply_with_all_its_rows_is_read(tmp_path) -> None:
    """The same header with its three rows reads as the three hand-written points."""
    path = tmp_path / "full.ply"
    path.write_text(PLY_HEADER + "0 0 0\n1 2 3\n4 5 6\n")
    assert read_ply(path).tolist() == [[0, 0, 0], [1, 2, 3], [4, 5, 6]]


PCD_HEADER = (
    "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\n"
    "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n"
)


def test_an_ascii_pcd_with_fewer_points_than_declared_is_refused(tmp_path) -> None:
    """PCL's PCD v0.7 format: ``POINTS 3`` of ``FIELDS x y z``; two points and a half are present."""
    path = tmp_path / "short.pcd"
    path.write_text(PCD_HEADER + "0 0 0\n1 2 3\n4 5\n")
    with pytest.raises(PointCloudFormatError, match=r"short\.pcd: .*truncated"):
        read_pcd(path)


def test_an_ascii_pcd_with_all_its_points_is_read(tmp_path) -> None:
    """The same header with its three points reads as the three hand-written points."""
    path = tmp_path / "full.pcd"
    path.write_text(PCD_HEADER + "0 0 0\n1 2 3\n4 5 6\n")
    assert read_pcd(path).tolist() == [[0, 0, 0], [1, 2, 3], [4, 5, 6]]


def test_a_binary_pcd_is_read_as_the_points_it_declares(tmp_path) -> None:
    """PCL's PCD v0.7 format: ``POINTS`` is the number of points in the cloud. A binary file declaring 2
    points of x, y, z (F 4) followed by a third point's 12 bytes (trailing data a writer left) reads as
    the two declared points, (1, 2, 3) and (4, 5, 6)."""
    import numpy as np

    header = PCD_HEADER.replace("WIDTH 3", "WIDTH 2").replace("POINTS 3", "POINTS 2")
    header = header.replace("DATA ascii", "DATA binary")
    data = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9]], dtype="<f4").tobytes()
    path = tmp_path / "two.pcd"
    path.write_bytes(header.encode("ascii") + data)
    assert read_pcd(path).tolist() == [[1, 2, 3], [4, 5, 6]]


def test_an_ascii_ply_with_rows_left_over_names_every_declared_element(tmp_path) -> None:
    """A PLY header declaring ``element vertex 2`` and ``element face 1`` (Bourke's format) followed by
    four rows, one more than declared: the message gives what the header declares, element by element,
    as ``(vertex 2, face 1)``."""
    path = tmp_path / "extra.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n3 0 1 1\n9 9 9\n"
    )
    with pytest.raises(PointCloudFormatError, match=r"the header declares \(vertex 2, face 1\)"):
        read_ply(path)
