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


def test_an_ascii_pcd_with_more_values_than_declared_is_refused_with_the_counts(tmp_path) -> None:
    """``POINTS 3`` of ``FIELDS x y z`` is 9 values (PCD v0.7); a file with 10 is refused naming the
    file, the 10 values found, the 9 expected and the 3 points."""
    path = tmp_path / "long.pcd"
    path.write_text(PCD_HEADER + "0 0 0\n1 2 3\n4 5 6 7\n")
    with pytest.raises(PointCloudFormatError) as err:
        read_pcd(path)
    assert str(err.value) == f"{path}: ascii data has 10 values, expected 9 (3 points)"


def test_an_ascii_pcd_value_far_longer_than_any_number_is_refused_by_its_length(tmp_path) -> None:
    """A 65-character word where a float belongs is no printed number (a float64 needs at most 24
    characters): refused naming the file and the word's length."""
    path = tmp_path / "word.pcd"
    path.write_text(PCD_HEADER + "0 0 0\n1 2 3\n4 5 " + "x" * 65 + "\n")
    with pytest.raises(PointCloudFormatError) as err:
        read_pcd(path)
    assert str(err.value) == f"{path}: ascii data holds a 65-character value (not a number)"


def test_an_ascii_pcd_skips_its_padding_fields(tmp_path) -> None:
    """PCD v0.7: a field named ``_`` is padding, not data. Rows of x, y, z, a padding float and a 64-bit
    integer label (``I 8``) read as the hand-written points (1, 2, 3) and (4, 5, 6)."""
    header = (
        "VERSION 0.7\nFIELDS x y z _ label\nSIZE 4 4 4 4 8\nTYPE F F F F I\nCOUNT 1 1 1 1 1\nWIDTH 2\n"
        "HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n"
    )
    path = tmp_path / "padded.pcd"
    path.write_text(header + "1 2 3 0 7\n4 5 6 0 8\n")
    assert read_pcd(path).tolist() == [[1, 2, 3], [4, 5, 6]]


PCD_LABELS = (
    "VERSION 0.7\nFIELDS x y z label\nSIZE 4 4 4 8\nTYPE F F F I\nCOUNT 1 1 1 1\nWIDTH 1\n"
    "HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1\nDATA ascii\n"
)


def test_an_ascii_pcd_word_where_a_label_belongs_is_refused_naming_the_file_and_field(tmp_path) -> None:
    """A 64-bit integer field (``I 8``, PCD v0.7) holding the word ``seven``: refused naming the file
    and the field ``label``."""
    path = tmp_path / "label.pcd"
    path.write_text(PCD_LABELS + "1 2 3 seven\n")
    with pytest.raises(PointCloudFormatError) as err:
        read_pcd(path)
    assert str(err.value).startswith(f"{path}: ascii data: field 'label' holds a non-number")


def test_a_zero_padded_64_character_integer_is_read_as_its_value(tmp_path) -> None:
    """The reader refuses words longer than 64 characters (longer than any printed number); a label
    written zero-padded to exactly 64 characters, 63 zeros and a 7, is a number: it reads as 7."""
    path = tmp_path / "padded_label.pcd"
    path.write_text(PCD_LABELS + "1 2 3 " + "0" * 63 + "7\n")
    from mapping.io.pcd import read_pcd_cloud

    assert read_pcd_cloud(path).data["label"].tolist() == [7]
