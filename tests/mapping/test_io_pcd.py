"""PCD reader and writer: files from Open3D's writer and hand-built byte layouts, strict header checks."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from mapping._deps import import_open3d
from mapping.errors import PointCloudFormatError
from mapping.io.pcd import read_pcd, read_pcd_cloud, write_pcd

ENCODINGS = ("ascii", "binary", "binary_compressed")


def _literal_lzf(data: bytes) -> bytes:
    """A valid LZF stream made of literal runs only (an encoder independent of the one under test)."""
    out = bytearray()
    for k in range(0, len(data), 32):
        chunk = data[k : k + 32]
        out.append(len(chunk) - 1)
        out += chunk
    return bytes(out)


def _header(fields, sizes, types, counts, width, height, data, viewpoint="0 0 0 1 0 0 0", points=None):
    return (
        "# hand-built\nVERSION .7\n"
        f"FIELDS {fields}\nSIZE {sizes}\nTYPE {types}\nCOUNT {counts}\n"
        f"WIDTH {width}\nHEIGHT {height}\nVIEWPOINT {viewpoint}\n"
        f"POINTS {width * height if points is None else points}\nDATA {data}\n"
    ).encode()


@pytest.fixture(scope="module")
def cloud():
    return np.random.default_rng(5).uniform(-10, 10, size=(500, 3))


@pytest.mark.parametrize(("ascii_", "compressed"), [(True, False), (False, False), (False, True)])
def test_open3d_written_pcd_reads_back_the_same_points(tmp_path, cloud, ascii_, compressed):
    o3d = import_open3d()
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
    pc.normals = o3d.utility.Vector3dVector(cloud[::-1] * 0.1)
    path = tmp_path / "o3d.pcd"
    assert o3d.io.write_point_cloud(str(path), pc, write_ascii=ascii_, compressed=compressed)
    encoding = path.read_bytes().split(b"DATA ")[1].split(b"\n")[0].decode()
    assert encoding == ("ascii" if ascii_ else "binary_compressed" if compressed else "binary")
    points = read_pcd(path)
    tol = 1e-6 * 10 if ascii_ else 0.0  # Open3D's ascii keeps ~10 significant digits of float32
    np.testing.assert_allclose(points, cloud.astype(np.float32), atol=tol, rtol=0)
    full = read_pcd_cloud(path)
    np.testing.assert_allclose(
        full.data["normal_x"], (cloud[::-1, 0] * 0.1).astype(np.float32), atol=max(tol, 0)
    )


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_pcd_written_here_is_read_by_open3d(tmp_path, cloud, encoding):
    o3d = import_open3d()
    path = write_pcd(tmp_path / "ours.pcd", cloud.astype(np.float32), encoding)
    got = np.asarray(o3d.io.read_point_cloud(str(path)).points)
    # Open3D parses ascii text into float64, so the 9 printed digits come back within float32 rounding.
    rtol = 1e-7 if encoding == "ascii" else 0.0
    np.testing.assert_allclose(got, cloud.astype(np.float32).astype(np.float64), rtol=rtol, atol=0)


def _exotic_records():
    """x y z as int16, a padding field, normals with COUNT 3 (float32), a uint8 label, a float64 time."""
    rows = [
        ((1, -2, 300), b"\xaa\xbb", (0.5, 0.25, -1.0), 7, 1e9 + 0.5),
        ((-32768, 32767, 0), b"\xcc\xdd", (1.0, 0.0, 0.0), 255, -3.25),
        ((10, 20, 30), b"\x00\x01", (0.0, 1.0, 0.0), 0, 2.0),
    ]
    header_args = ("x y z _ normal label t", "2 2 2 2 4 1 8", "I I I U F U F", "1 1 1 1 3 1 1")
    return rows, header_args


def test_hand_built_binary_pcd_with_int16_padding_count3_and_float64_fields(tmp_path):
    rows, (f, s, t, c) = _exotic_records()
    body = b"".join(
        struct.pack("<3h", *xyz)
        + pad
        + struct.pack("<3f", *nrm)
        + struct.pack("<B", lab)
        + struct.pack("<d", tm)
        for xyz, pad, nrm, lab, tm in rows
    )
    path = tmp_path / "exotic.pcd"
    path.write_bytes(_header(f, s, t, c, 3, 1, "binary") + body)
    full = read_pcd_cloud(path)
    assert full.data.dtype.names == ("x", "y", "z", "normal", "label", "t")  # padding left out
    np.testing.assert_array_equal(read_pcd(path), [[1, -2, 300], [-32768, 32767, 0], [10, 20, 30]])
    assert read_pcd(path).dtype == np.float64  # integer coordinates come back as float64
    np.testing.assert_array_equal(full.data["normal"], [[0.5, 0.25, -1.0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(full.data["label"], [7, 255, 0])
    np.testing.assert_array_equal(full.data["t"], [1e9 + 0.5, -3.25, 2.0])


def test_hand_built_binary_compressed_pcd_is_field_major(tmp_path):
    rows, (f, s, t, c) = _exotic_records()
    cols = [
        struct.pack("<3h", *(r[0][0] for r in rows)),
        struct.pack("<3h", *(r[0][1] for r in rows)),
        struct.pack("<3h", *(r[0][2] for r in rows)),
        b"".join(r[1] for r in rows),
        b"".join(struct.pack("<3f", *r[2]) for r in rows),
        bytes(r[3] for r in rows),
        struct.pack("<3d", *(r[4] for r in rows)),
    ]
    raw = b"".join(cols)
    packed = _literal_lzf(raw)
    path = tmp_path / "exotic_c.pcd"
    path.write_bytes(
        _header(f, s, t, c, 3, 1, "binary_compressed") + struct.pack("<II", len(packed), len(raw)) + packed
    )
    full = read_pcd_cloud(path)
    np.testing.assert_array_equal(read_pcd(path), [[1, -2, 300], [-32768, 32767, 0], [10, 20, 30]])
    np.testing.assert_array_equal(full.data["label"], [7, 255, 0])
    np.testing.assert_array_equal(full.data["normal"][0], [0.5, 0.25, -1.0])


def test_hand_built_ascii_pcd_with_padding_and_count3(tmp_path):
    rows, (f, s, t, c) = _exotic_records()
    lines = [f"{x} {y} {z} 0 {n[0]} {n[1]} {n[2]} {lab} {tm!r}" for (x, y, z), _, n, lab, tm in rows]
    path = tmp_path / "exotic_a.pcd"
    path.write_bytes(_header(f, s, t, c, 3, 1, "ascii") + ("\n".join(lines) + "\n").encode())
    full = read_pcd_cloud(path)
    np.testing.assert_array_equal(read_pcd(path)[1], [-32768, 32767, 0])
    np.testing.assert_array_equal(full.data["t"], [1e9 + 0.5, -3.25, 2.0])
    np.testing.assert_array_equal(full.data["label"], [7, 255, 0])


def test_organized_cloud_keeps_its_image_shape_and_nan_pixels(tmp_path):
    h, w = 48, 64
    grid = np.random.default_rng(2).normal(size=(h, w, 3)).astype(np.float32)
    grid[5, 7] = np.nan
    grid[40, :] = np.nan
    body = grid.reshape(-1, 3).astype("<f4").tobytes()
    path = tmp_path / "organized.pcd"
    path.write_bytes(
        _header("x y z", "4 4 4", "F F F", "1 1 1", w, h, "binary", viewpoint="1 2 3 1 0 0 0") + body
    )
    got = read_pcd(path, organized=True)
    assert got.shape == (h, w, 3)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(grid))
    np.testing.assert_array_equal(got[~np.isnan(got)], grid[~np.isnan(grid)])
    assert read_pcd(path).shape == (h * w, 3)
    assert read_pcd_cloud(path).header.viewpoint == (1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0)


def test_uint64_and_int8_fields_are_read_exactly(tmp_path):
    body = struct.pack("<fff", 1, 2, 3) + struct.pack("<Qb", 2**64 - 1, -5)
    path = tmp_path / "wide.pcd"
    path.write_bytes(_header("x y z id s", "4 4 4 8 1", "F F F U I", "1 1 1 1 1", 1, 1, "binary") + body)
    data = read_pcd_cloud(path).data
    assert int(data["id"][0]) == 2**64 - 1
    assert int(data["s"][0]) == -5


# ------------------------------------------------------------------ refusals


def _simple(tmp_path, header: bytes, body: bytes = b""):
    path = tmp_path / "bad.pcd"
    path.write_bytes(header + body)
    return path


def test_unknown_type_letter_is_refused_naming_file_and_field(tmp_path):
    path = _simple(tmp_path, _header("x y z", "4 4 4", "F F Q", "1 1 1", 1, 1, "binary"), b"\0" * 12)
    with pytest.raises(PointCloudFormatError, match=r"bad\.pcd: unknown PCD TYPE 'Q' for field 'z'"):
        read_pcd(path)


def test_size_count_mismatch_with_fields_is_refused(tmp_path):
    path = _simple(tmp_path, _header("x y z", "4 4", "F F F", "1 1 1", 1, 1, "binary"), b"\0" * 12)
    with pytest.raises(PointCloudFormatError, match="3 FIELDS but 2 SIZE entries"):
        read_pcd(path)


def test_float_of_size_two_is_refused(tmp_path):
    path = _simple(tmp_path, _header("x y z", "4 4 2", "F F F", "1 1 1", 1, 1, "binary"), b"\0" * 10)
    with pytest.raises(PointCloudFormatError, match="F needs SIZE 4 or 8"):
        read_pcd(path)


def test_truncated_binary_data_is_refused(tmp_path):
    path = _simple(tmp_path, _header("x y z", "4 4 4", "F F F", "1 1 1", 10, 1, "binary"), b"\0" * 119)
    with pytest.raises(
        PointCloudFormatError, match=r"bad\.pcd: binary data truncated: 119 bytes, 10 points need 120"
    ):
        read_pcd(path)


def test_truncated_ascii_data_is_refused(tmp_path):
    path = _simple(tmp_path, _header("x y z", "4 4 4", "F F F", "1 1 1", 2, 1, "ascii"), b"1 2 3\n4 5\n")
    with pytest.raises(PointCloudFormatError, match="ascii data truncated"):
        read_pcd(path)


def test_truncated_compressed_data_is_refused(tmp_path):
    raw = np.arange(6, dtype="<f4").tobytes()
    packed = _literal_lzf(raw)
    head = _header("x y z", "4 4 4", "F F F", "1 1 1", 2, 1, "binary_compressed")
    path = _simple(tmp_path, head, struct.pack("<II", len(packed), len(raw)) + packed[:-3])
    with pytest.raises(PointCloudFormatError, match="binary_compressed data truncated"):
        read_pcd(path)


def test_compressed_size_disagreeing_with_header_is_refused(tmp_path):
    raw = np.arange(6, dtype="<f4").tobytes()
    packed = _literal_lzf(raw)
    head = _header("x y z", "4 4 4", "F F F", "1 1 1", 3, 1, "binary_compressed")
    path = _simple(tmp_path, head, struct.pack("<II", len(packed), len(raw)) + packed)
    with pytest.raises(PointCloudFormatError, match="declares 24 uncompressed bytes"):
        read_pcd(path)


def test_corrupt_lzf_stream_is_refused(tmp_path):
    head = _header("x y z", "4 4 4", "F F F", "1 1 1", 1, 1, "binary_compressed")
    bad = bytes([0, 1, 0x3F, 0xFF])  # back-reference far before the start
    path = _simple(tmp_path, head, struct.pack("<II", len(bad), 12) + bad)
    with pytest.raises(PointCloudFormatError, match="corrupt"):
        read_pcd(path)


def test_missing_z_field_is_refused(tmp_path):
    path = _simple(tmp_path, _header("x y i", "4 4 4", "F F F", "1 1 1", 1, 1, "binary"), b"\0" * 12)
    with pytest.raises(PointCloudFormatError, match="no 'z' field"):
        read_pcd(path)


def test_points_disagreeing_with_width_times_height_is_refused(tmp_path):
    path = _simple(
        tmp_path, _header("x y z", "4 4 4", "F F F", "1 1 1", 2, 1, "binary", points=3), b"\0" * 36
    )
    with pytest.raises(PointCloudFormatError, match="POINTS 3 differs"):
        read_pcd(path)


def test_unknown_data_encoding_and_unknown_key_are_refused(tmp_path):
    path = _simple(tmp_path, _header("x y z", "4 4 4", "F F F", "1 1 1", 1, 1, "zip"), b"\0" * 12)
    with pytest.raises(PointCloudFormatError, match="unknown PCD DATA encoding 'zip'"):
        read_pcd(path)
    path = _simple(
        tmp_path, b"COLOR red\n" + _header("x y z", "4 4 4", "F F F", "1 1 1", 1, 1, "binary"), b"\0" * 12
    )
    with pytest.raises(PointCloudFormatError, match="unknown PCD header key 'COLOR'"):
        read_pcd(path)


def test_file_without_data_line_is_refused(tmp_path):
    path = _simple(tmp_path, b"VERSION .7\nFIELDS x y z\n")
    with pytest.raises(PointCloudFormatError, match="no DATA line"):
        read_pcd(path)


# ------------------------------------------------------------------ round trips


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_write_then_read_returns_identical_points_and_extra_fields(tmp_path, encoding, dtype):
    rng = np.random.default_rng(9)
    pts = rng.normal(size=(300, 3)).astype(dtype) * 1e3
    pts[3] = np.nan
    extra = {"intensity": rng.integers(0, 2**16, 300).astype(np.uint16), "normal": rng.normal(size=(300, 3))}
    path = write_pcd(tmp_path / "rt.pcd", pts, encoding, extra_fields=extra, viewpoint=(1, 2, 3, 1, 0, 0, 0))
    cloud = read_pcd_cloud(path)
    assert cloud.xyz().dtype == dtype
    np.testing.assert_array_equal(cloud.xyz(), pts)
    np.testing.assert_array_equal(cloud.data["intensity"], extra["intensity"])
    np.testing.assert_array_equal(cloud.data["normal"], extra["normal"])
    assert cloud.header.viewpoint == (1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_organized_write_then_read_keeps_shape(tmp_path, encoding):
    pts = np.arange(2 * 5 * 3, dtype=np.float32).reshape(2, 5, 3)
    pts[1, 2] = np.nan
    got = read_pcd(write_pcd(tmp_path / "o.pcd", pts, encoding), organized=True)
    np.testing.assert_array_equal(got, pts)


@settings(max_examples=30, deadline=None)
@given(
    hnp.arrays(
        np.float32, st.tuples(st.integers(0, 40), st.just(3)), elements=st.floats(width=32, allow_nan=True)
    ),
    st.sampled_from(ENCODINGS),
)
def test_any_float32_cloud_round_trips_bit_exactly(tmp_path_factory, pts, encoding):
    path = write_pcd(tmp_path_factory.mktemp("h") / "h.pcd", pts, encoding)
    got = read_pcd(path)
    assert got.shape == pts.shape
    np.testing.assert_array_equal(got, pts)


def test_ascii_uint64_field_keeps_every_digit(tmp_path):
    head = _header("x y z id", "4 4 4 8", "F F F U", "1 1 1 1", 2, 1, "ascii")
    path = _simple(tmp_path, head, b"1 2 3 18446744073709551615\n0.5 nan -1 9007199254740993\n")
    data = read_pcd_cloud(path).data
    assert data["id"].tolist() == [2**64 - 1, 2**53 + 1]
    np.testing.assert_array_equal(read_pcd(path), np.array([[1, 2, 3], [0.5, np.nan, -1]], np.float32))


def test_ascii_with_a_non_number_is_refused(tmp_path):
    path = _simple(tmp_path, _header("x y z", "4 4 4", "F F F", "1 1 1", 1, 1, "ascii"), b"1 two 3\n")
    with pytest.raises(PointCloudFormatError, match="field 'y' holds a non-number"):
        read_pcd(path)


def test_big_organized_compressed_cloud_with_rgb_and_nan_rows(tmp_path):
    """A 640 x 480 Kinect-like frame: x y z rgb, field-major LZF payload, invalid rows and pixels as NaN."""
    h, w = 480, 640
    rng = np.random.default_rng(11)
    xyz = rng.uniform(-4, 4, size=(h * w, 3)).astype("<f4")
    xyz[rng.random(h * w) < 0.1] = np.nan
    xyz[: w * 3] = np.nan  # the first three image rows saw nothing
    rgb = rng.integers(0, 2**24, size=h * w).astype("<u4")
    raw = xyz[:, 0].tobytes() + xyz[:, 1].tobytes() + xyz[:, 2].tobytes() + rgb.tobytes()
    packed = _literal_lzf(raw)
    head = _header("x y z rgb", "4 4 4 4", "F F F U", "1 1 1 1", w, h, "binary_compressed")
    path = _simple(tmp_path, head, struct.pack("<II", len(packed), len(raw)) + packed)
    got = read_pcd(path, organized=True)
    assert got.shape == (h, w, 3)
    np.testing.assert_array_equal(got.reshape(-1, 3), xyz)  # NaN positions compare equal too
    assert np.isnan(got[:3]).all() and not np.isnan(got[3:]).all()
    np.testing.assert_array_equal(read_pcd_cloud(path).data["rgb"], rgb)


def test_open3d_compressed_large_cloud_decodes_with_back_references(tmp_path):
    o3d = import_open3d()
    # A regular lattice compresses well, so Open3D's LZF stream is full of back-references.
    g = np.stack(np.meshgrid(np.arange(100), np.arange(100), np.arange(10), indexing="ij"), -1).reshape(-1, 3)
    pts = (g * 0.05).astype(np.float64)
    path = tmp_path / "lattice.pcd"
    assert o3d.io.write_point_cloud(
        str(path), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)), compressed=True
    )
    assert path.stat().st_size < pts.size * 4 / 2  # really compressed
    np.testing.assert_array_equal(read_pcd(path), pts.astype(np.float32))
