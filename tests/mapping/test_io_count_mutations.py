"""Files that declare more points than they hold are refused, never read short (PLY and PCD); every
refusal names the file and what is wrong; the edge cases of the PLY and PCD readers.

Each file is written by hand here; the declared counts and the rows present are the hand values.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from mapping.errors import PointCloudFormatError
from mapping.io.pcd import read_pcd, read_pcd_cloud
from mapping.io.ply import read_ply, read_ply_mesh

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


# Format refusals name the file and say what is wrong; the edge cases of the readers, each file hand made
# from the PLY format (Paul Bourke's description, 1994) or the PCD v0.7 format (pointclouds.org).


def _pcd(points: int, data: str) -> bytes:
    """A PCD v0.7 header of ``points`` xyz float32 points (12 bytes each), unorganized."""
    return (
        f"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {points}\nHEIGHT 1\n"
        f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA {data}\n"
    ).encode()


def _lzf_literal(raw: bytes) -> bytes:
    """An LZF stream of one literal run (control byte ``len - 1``, then the bytes; at most 32)."""
    assert 0 < len(raw) <= 32
    return bytes([len(raw) - 1]) + raw


POINT = struct.pack("<3f", 1.0, -2.0, 0.5)


def _refusal(path: Path) -> str:
    with pytest.raises(PointCloudFormatError) as err:
        read_pcd_cloud(path) if path.suffix == ".pcd" else read_ply_mesh(path)
    return str(err.value)


@pytest.mark.parametrize("data", ["binary", "binary_compressed"])
def test_a_pcd_of_zero_points_is_read_as_an_empty_cloud_of_its_fields(tmp_path, data) -> None:
    """PCD v0.7: POINTS 0 is a valid, empty cloud; binary_compressed data is the compressed and the
    uncompressed size (two little-endian uint32, here 0 and 0) then the LZF stream (empty)."""
    path = tmp_path / "empty.pcd"
    path.write_bytes(_pcd(0, data) + (struct.pack("<II", 0, 0) if data == "binary_compressed" else b""))
    cloud = read_pcd_cloud(path).data
    assert cloud.shape == (0,)
    assert cloud.dtype.names == ("x", "y", "z")
    assert all(cloud.dtype[n] == np.float32 for n in "xyz")


def test_a_compressed_pcd_without_its_two_size_words_is_refused_naming_the_file(tmp_path) -> None:
    """PCD v0.7 binary_compressed: the data starts with two uint32 sizes (8 bytes); 5 bytes cannot hold
    them."""
    path = tmp_path / "short.pcd"
    path.write_bytes(_pcd(1, "binary_compressed") + b"\x01\x02\x03\x04\x05")
    assert _refusal(path) == f"{path}: binary_compressed data truncated: missing the two size words"


def test_a_compressed_pcd_whose_sizes_disagree_with_its_header_is_refused_with_both_counts(tmp_path) -> None:
    """3 points of 3 float32 fields need 3 x 12 = 36 uncompressed bytes; the file declares 24."""
    path = tmp_path / "sizes.pcd"
    packed = _lzf_literal(POINT * 2)
    path.write_bytes(_pcd(3, "binary_compressed") + struct.pack("<II", len(packed), 24) + packed)
    assert (
        _refusal(path)
        == f"{path}: binary_compressed declares 24 uncompressed bytes, 3 points of 12 bytes need 36"
    )


def test_a_compressed_pcd_cut_short_is_refused_with_the_bytes_present_and_declared(tmp_path) -> None:
    """One point: a literal LZF run of 12 bytes is 13 compressed bytes; only 10 follow the size words."""
    path = tmp_path / "cut.pcd"
    packed = _lzf_literal(POINT)
    path.write_bytes(_pcd(1, "binary_compressed") + struct.pack("<II", 13, 12) + packed[:10])
    assert _refusal(path) == f"{path}: binary_compressed data truncated: 10 bytes present, 13 declared"


def test_a_compressed_pcd_is_read_from_its_declared_bytes_only(tmp_path) -> None:
    """The compressed size says where the LZF stream ends: a byte after it (a trailing newline) is not
    part of the stream, and the point is read as written: (1.0, -2.0, 0.5)."""
    path = tmp_path / "trailing.pcd"
    packed = _lzf_literal(POINT)
    path.write_bytes(_pcd(1, "binary_compressed") + struct.pack("<II", len(packed), 12) + packed + b"\n")
    cloud = read_pcd_cloud(path).data
    assert [tuple(map(float, p)) for p in cloud[["x", "y", "z"]]] == [(1.0, -2.0, 0.5)]


def test_a_corrupt_lzf_stream_is_refused_naming_the_file_and_the_reason(tmp_path) -> None:
    """LZF: a control byte of 0x20 or more is a back reference; as the first byte it points before the
    start of the output."""
    path = tmp_path / "corrupt.pcd"
    packed = b"\xe0\x00\x00" + POINT
    path.write_bytes(_pcd(1, "binary_compressed") + struct.pack("<II", len(packed), 12) + packed)
    msg = _refusal(path)
    assert msg.startswith(f"{path}: binary_compressed data is corrupt (")
    assert msg.endswith(")") and len(msg) > len(f"{path}: binary_compressed data is corrupt ()")


def _ply(tmp_path: Path, header: str, body: bytes, fmt: str = "ascii") -> Path:
    path = tmp_path / "m.ply"
    path.write_bytes(f"ply\nformat {fmt} 1.0\n{header}end_header\n".encode() + body)
    return path


XYZ = "property float x\nproperty float y\nproperty float z\n"
FACE = "element face 1\nproperty list uchar int vertex_indices\n"


def test_a_file_that_is_not_ply_is_refused_naming_the_file(tmp_path) -> None:
    """A PLY file starts with the magic line ``ply``."""
    path = tmp_path / "m.ply"
    path.write_bytes(b"OFF\n3 1 0\n")
    assert _refusal(path) == f"{path}: not a PLY file (does not start with 'ply')"


def test_a_ply_without_vertices_is_refused_naming_its_elements(tmp_path) -> None:
    path = _ply(tmp_path, FACE, b"3 0 1 2\n")
    assert _refusal(path) == f"{path}: PLY has no vertex element (elements: ['face'])"


def test_a_ply_whose_vertices_have_no_z_is_refused_naming_the_file(tmp_path) -> None:
    path = _ply(tmp_path, "element vertex 1\nproperty float x\nproperty float y\n", b"1 2\n")
    assert _refusal(path) == f"{path}: PLY vertex element has no 'z' property (properties: ['x', 'y'])"


def test_a_ply_whose_vertex_x_is_a_list_is_refused(tmp_path) -> None:
    header = "element vertex 1\nproperty list uchar float x\nproperty float y\nproperty float z\n"
    path = _ply(tmp_path, header, b"1 1 2 3\n")
    assert _refusal(path) == f"{path}: PLY vertex property 'x' is a list"


def test_an_ascii_ply_with_a_row_too_many_names_the_file(tmp_path) -> None:
    path = _ply(tmp_path, "element vertex 1\n" + XYZ, b"1 2 3\n4 5 6\n")
    assert _refusal(path).startswith(
        f"{path}: PLY ascii data has 1 rows more than the header declares (vertex 1)"
    )


def test_a_binary_ply_with_bytes_left_over_names_the_file_and_their_count(tmp_path) -> None:
    """One vertex of three float32 is 12 bytes; 14 follow the header."""
    path = _ply(tmp_path, "element vertex 1\n" + XYZ, POINT + b"\0\0", "binary_little_endian")
    assert _refusal(path).startswith(
        f"{path}: PLY binary data has 2 bytes more than the header declares (vertex 1)"
    )


def test_a_binary_ply_cut_short_is_refused_with_the_bytes_left_and_needed(tmp_path) -> None:
    """Three vertices of three float32 need 36 bytes; 20 follow the header."""
    path = _ply(tmp_path, "element vertex 3\n" + XYZ, (POINT * 2)[:20], "binary_little_endian")
    assert (
        _refusal(path) == f"{path}: PLY binary data truncated in element 'vertex': 20 bytes left, 36 needed"
    )


def test_a_binary_ply_whose_vertices_carry_a_list_is_refused(tmp_path) -> None:
    header = "element vertex 1\n" + XYZ + "property list uchar int tags\n"
    path = _ply(tmp_path, header, POINT + b"\x01" + struct.pack("<i", 7), "binary_little_endian")
    assert _refusal(path) == f"{path}: PLY vertex element with list properties is not supported"


def test_a_ply_face_outside_the_vertices_is_refused_naming_the_file(tmp_path) -> None:
    path = _ply(tmp_path, "element vertex 3\n" + XYZ + FACE, b"0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n")
    assert _refusal(path) == f"{path}: PLY face indices outside the 3 vertices"


def test_an_ascii_ply_row_with_bytes_that_are_not_ascii_is_refused(tmp_path) -> None:
    """The ascii PLY body is ASCII text: the bytes C2 85 (U+0085, a line break in UTF-8) at the end of a
    vertex row are not a number and not a row break."""
    path = _ply(tmp_path, "element vertex 1\n" + XYZ, b"1 2 3\xc2\x85\n")
    assert _refusal(path).startswith(f"{path}: PLY ascii")


def test_the_faces_are_read_from_the_face_element_only(tmp_path) -> None:
    """A PLY may hold other elements with lists (the format lets a file add any element): the faces are
    the ``face`` element's rows, here the one triangle (0, 1, 2), not the ``edge_loop`` (2, 1, 0)."""
    header = (
        "element vertex 3\n" + XYZ + FACE + "element edge_loop 1\nproperty list uchar int vertex_indices\n"
    )
    path = _ply(tmp_path, header, b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 2 1 0\n")
    assert read_ply_mesh(path).faces.tolist() == [[0, 1, 2]]


def test_a_ply_read_without_faces_has_an_empty_integer_face_array(tmp_path) -> None:
    """``faces=False``: no face is decoded; the faces are (0, 3) indices, the same type as read faces."""
    path = _ply(tmp_path, "element vertex 3\n" + XYZ + FACE, b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    mesh = read_ply_mesh(path, faces=False)
    assert mesh.faces.shape == (0, 3)
    assert mesh.faces.dtype == np.int64
    assert mesh.vertices.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]]


def test_an_ascii_pcd_field_of_two_values_beside_a_64_bit_label_keeps_both_values(tmp_path) -> None:
    """PCD v0.7: COUNT is the number of values a field holds per point; here x, y, z one float32 each,
    ``uv`` two float32 and ``label`` one uint64 (SIZE 8, TYPE U, read exactly, not through float64): the
    points' uv are (1.5, 2.5) and (3.5, 4.5), their labels 7 and 9."""
    path = tmp_path / "uv.pcd"
    path.write_bytes(
        b"VERSION 0.7\nFIELDS x y z uv label\nSIZE 4 4 4 4 8\nTYPE F F F F U\nCOUNT 1 1 1 2 1\nWIDTH 2\n"
        b"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n0 0 0 1.5 2.5 7\n1 1 1 3.5 4.5 9\n"
    )
    data = read_pcd_cloud(path).data
    assert data["uv"].tolist() == [[1.5, 2.5], [3.5, 4.5]]
    assert data["label"].tolist() == [7, 9]
