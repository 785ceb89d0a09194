"""PointCloud2: decoding hand-built payloads (padding, big-endian, integer fields, row padding); encoding."""

from __future__ import annotations

import struct
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.errors import PointCloudFormatError
from mapping.pointcloud2 import (
    FLOAT32,
    FLOAT64,
    INT8,
    INT16,
    UINT8,
    UINT16,
    UINT32,
    PointField,
    decode,
    encode,
)


def _msg(fields, data, width, height=1, point_step=None, row_step=None, big=False):
    point_step = point_step if point_step is not None else 16
    return SimpleNamespace(
        height=height,
        width=width,
        fields=fields,
        is_bigendian=big,
        point_step=point_step,
        row_step=row_step if row_step is not None else width * point_step,
        data=data,
    )


def test_float32_with_padding_and_intensity_before_xyz():
    # point: intensity f32 @0, pad 4, x @8, y @12, z @16, pad to 24 (like many lidar drivers)
    fields = [PointField("intensity", 0, FLOAT32), PointField("x", 8, FLOAT32), PointField("y", 12, FLOAT32),
              PointField("z", 16, FLOAT32)]  # fmt: skip
    data = struct.pack("<f4xfff4x", 9.0, 1.0, 2.0, 3.0) + struct.pack("<f4xfff4x", 8.0, -1.0, -2.0, -3.5)
    got = decode(_msg(fields, data, 2, point_step=24))
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, [[1, 2, 3], [-1, -2, -3.5]])


def test_big_endian_int16_coordinates_are_decoded_as_floats():
    fields = [
        PointField("z", 0, INT16),
        PointField("y", 2, INT16),
        PointField("x", 4, INT16),
        PointField("r", 6, UINT8),
    ]
    data = struct.pack(">hhhB", 300, -2, 1, 7) + struct.pack(">hhhB", -32768, 32767, 5, 0)
    got = decode(_msg(fields, data, 2, point_step=7, big=True))
    np.testing.assert_array_equal(got, [[1, -2, 300], [5, 32767, -32768]])


def test_uint16_and_float64_mixed_fields_little_endian():
    fields = [PointField("x", 0, UINT16), PointField("y", 2, UINT16), PointField("z", 8, FLOAT64)]
    data = struct.pack("<HH4xd", 65535, 1, -0.125)
    got = decode(_msg(fields, data, 1, point_step=16))
    assert got.dtype == np.float64  # float64 z needs float64 output
    np.testing.assert_array_equal(got, [[65535, 1, -0.125]])


def test_big_endian_float64_organized_cloud_with_row_padding_keeps_shape():
    h, w = 3, 4
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(h, w, 3))
    xyz[1, 2] = np.nan
    rows = [
        b"".join(struct.pack(">ddd", *xyz[r, c]) + b"\xee" * 8 for c in range(w)) + b"\xff" * 5
        for r in range(h)
    ]
    fields = [PointField(c, 8 * k, FLOAT64) for k, c in enumerate("xyz")]
    msg = _msg(fields, b"".join(rows), w, height=h, point_step=32, row_step=w * 32 + 5, big=True)
    got = decode(msg, organized=True)
    assert got.shape == (h, w, 3)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(xyz))
    np.testing.assert_array_equal(got[~np.isnan(got)], xyz[~np.isnan(xyz)])
    assert decode(msg).shape == (h * w, 3)


def test_last_row_padding_may_be_absent():
    fields = [PointField(c, 4 * k, FLOAT32) for k, c in enumerate("xyz")]
    data = struct.pack("<fff", 1, 2, 3) + b"\0\0" + struct.pack("<fff", 4, 5, 6)
    got = decode(_msg(fields, data, 1, height=2, point_step=12, row_step=14))
    np.testing.assert_array_equal(got, [[1, 2, 3], [4, 5, 6]])


def test_cloud_without_z_is_refused_listing_fields():
    fields = [PointField("x", 0, FLOAT32), PointField("y", 4, FLOAT32), PointField("rgb", 8, UINT32)]
    with pytest.raises(PointCloudFormatError, match=r"no z field\(s\); fields are \['x', 'y', 'rgb'\]"):
        decode(_msg(fields, b"\0" * 12, 1, point_step=12))


def test_truncated_data_is_refused():
    fields = [PointField(c, 4 * k, FLOAT32) for k, c in enumerate("xyz")]
    with pytest.raises(PointCloudFormatError, match="data has 23 bytes, needs 24"):
        decode(_msg(fields, b"\0" * 23, 2, point_step=12))


def test_field_outside_point_step_and_unknown_datatype_are_refused():
    fields = [PointField("x", 0, FLOAT32), PointField("y", 4, FLOAT32), PointField("z", 10, FLOAT32)]
    with pytest.raises(PointCloudFormatError, match="does not fit in point_step 12"):
        decode(_msg(fields, b"\0" * 12, 1, point_step=12))
    fields = [PointField("x", 0, FLOAT32), PointField("y", 4, FLOAT32), PointField("z", 8, 42)]
    with pytest.raises(PointCloudFormatError, match="unknown PointField datatype 42"):
        decode(_msg(fields, b"\0" * 12, 1, point_step=12))


def test_empty_cloud_decodes_to_no_points():
    fields = [PointField(c, 4 * k, FLOAT32) for k, c in enumerate("xyz")]
    assert decode(_msg(fields, b"", 0, point_step=12)).shape == (0, 3)


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 5),
    st.integers(0, 7),
    st.sampled_from([FLOAT32, FLOAT64, INT16, INT8]),
    st.booleans(),
    st.integers(0, 9),
    st.integers(0, 6),
)
def test_encode_then_decode_returns_the_points(height, width, datatype, big, extra_step, row_padding):
    rng = np.random.default_rng(height * 100 + width)
    pts = rng.integers(-100, 100, size=(height, width, 3)).astype(np.float64)
    cloud = encode(
        pts,
        datatype=datatype,
        is_bigendian=big,
        point_step=None,
        row_padding=row_padding,
        extra_fields={"intensity": np.arange(height * width, dtype=np.uint16)},
    )
    if extra_step:
        cloud = encode(pts, datatype=datatype, is_bigendian=big, point_step=cloud.point_step + extra_step,
                       row_padding=row_padding)  # fmt: skip
    np.testing.assert_array_equal(decode(cloud, organized=True), pts)


_NP = {INT8: "i1", UINT8: "u1", INT16: "i2", UINT16: "u2", UINT32: "u4", FLOAT32: "f4", FLOAT64: "f8"}


@settings(max_examples=80, deadline=None)
@given(
    st.permutations(["x", "y", "z", "rgb"]),
    st.lists(st.sampled_from(sorted(_NP)), min_size=4, max_size=4),
    st.lists(st.integers(0, 5), min_size=5, max_size=5),
    st.booleans(),
    st.integers(1, 3),
    st.integers(0, 6),
    st.integers(0, 6),
)
def test_any_field_order_types_gaps_and_byte_order_decode(order, types, gaps, big, height, width, row_pad):
    """Lay the bytes out with struct, field by field, independently of the decoder's numpy view."""
    offsets, pos = {}, 0
    for name, dtype, gap in zip(order, types, gaps):
        pos += gap
        offsets[name] = (pos, dtype)
        pos += np.dtype(_NP[dtype]).itemsize
    point_step = pos + gaps[4]
    rng = np.random.default_rng(width * 10 + height)
    values = rng.integers(0, 100, size=(height, width, 4))
    endian = ">" if big else "<"
    fmt = {INT8: "b", UINT8: "B", INT16: "h", UINT16: "H", UINT32: "I", FLOAT32: "f", FLOAT64: "d"}
    rows = []
    for r in range(height):
        row = bytearray(point_step * width + row_pad)
        for c in range(width):
            for k, name in enumerate(["x", "y", "z", "rgb"]):
                off, dtype = offsets[name]
                struct.pack_into(endian + fmt[dtype], row, c * point_step + off, values[r, c, k])
        rows.append(bytes(row))
    fields = [PointField(n, offsets[n][0], offsets[n][1]) for n in order]
    msg = _msg(fields, b"".join(rows), width, height, point_step, point_step * width + row_pad, big)
    np.testing.assert_array_equal(decode(msg, organized=True), values[..., :3])
