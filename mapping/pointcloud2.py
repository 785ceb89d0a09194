"""Decode and encode ``sensor_msgs/PointCloud2`` payloads with numpy structured dtypes (no per-point loop).

A PointCloud2 is ``height`` rows of ``width`` points; each point is ``point_step`` bytes holding the
fields at their declared offsets (anything else is padding); each row is ``row_step`` bytes (rows may
be padded too); ``is_bigendian`` applies to every field. :func:`decode` accepts any object with those
attributes (a rosbags message, :class:`PointCloud2Data`, a ROS 1 or ROS 2 message) and returns the
x, y, z coordinates whatever their storage type.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from mapping.errors import PointCloudFormatError

# sensor_msgs/PointField datatype constants.
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)

DATATYPES: dict[int, np.dtype] = {
    INT8: np.dtype("i1"),
    UINT8: np.dtype("u1"),
    INT16: np.dtype("i2"),
    UINT16: np.dtype("u2"),
    INT32: np.dtype("i4"),
    UINT32: np.dtype("u4"),
    FLOAT32: np.dtype("f4"),
    FLOAT64: np.dtype("f8"),
}
_DATATYPE_OF: dict[str, int] = {dt.str[1:]: code for code, dt in DATATYPES.items()}


@dataclass(frozen=True)
class PointField:
    """One field of a PointCloud2 (same attribute names as ``sensor_msgs/PointField``)."""

    name: str
    offset: int
    datatype: int
    count: int = 1


@dataclass
class PointCloud2Data:
    """A PointCloud2 payload without the ROS header (attribute names as in ``sensor_msgs/PointCloud2``)."""

    height: int
    width: int
    fields: list[PointField]
    is_bigendian: bool
    point_step: int
    row_step: int
    data: np.ndarray  # uint8 bytes
    is_dense: bool = False
    frame_id: str = ""
    stamp_ns: int = 0
    extra: dict[str, Any] = field(default_factory=dict)


_UINT32_MAX = 2**32 - 1  # height, width, steps, offsets and counts are uint32 in sensor_msgs
_MAX_POINT_STEP = 2**31 - 1  # the largest numpy record (a C int); real points are tens of bytes


def as_bytes_array(data: Any) -> np.ndarray:
    """Any bytes-like payload (bytes, memoryview, numpy array, list of ints) as a flat uint8 array."""
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).view(np.uint8).reshape(-1)
    if isinstance(data, bytes | bytearray | memoryview):
        return np.frombuffer(data, dtype=np.uint8)
    return np.asarray(data, dtype=np.uint8).reshape(-1)


def _describe(msg: Any) -> str:
    return f"PointCloud2 {msg.height}x{msg.width}, point_step {msg.point_step}, row_step {msg.row_step}"


def structured_dtype(fields: Sequence[Any], point_step: int, is_bigendian: bool) -> np.dtype:
    """The numpy structured dtype of one point described by ``fields`` (padding kept by ``itemsize``).

    Raises:
        PointCloudFormatError: A field has an unknown datatype, a non-positive count, a duplicate
            name, or does not fit inside ``point_step``.
    """
    order: Literal["<", ">"] = ">" if is_bigendian else "<"
    names: list[str] = []
    formats: list[Any] = []
    offsets: list[int] = []
    for f in fields:
        name = str(f.name)
        if int(f.datatype) not in DATATYPES:
            raise PointCloudFormatError(f"field {name!r} has unknown PointField datatype {f.datatype}")
        count, offset = int(f.count), int(f.offset)
        if not (0 <= count <= _UINT32_MAX and 0 <= offset <= _UINT32_MAX):
            raise PointCloudFormatError(f"field {name!r}: offset {offset} or count {count} is not a uint32")
        if count < 1:
            # Some drivers write count 0 for scalars; ROS treats that as 1.
            count = 1
        base = DATATYPES[int(f.datatype)].newbyteorder(order)
        size = base.itemsize * count
        if offset + size > point_step:
            raise PointCloudFormatError(
                f"field {name!r} (offset {offset}, {size} bytes) does not fit in point_step {point_step}"
            )
        if name in names:
            if name in ("x", "y", "z"):
                raise PointCloudFormatError(f"field {name!r} appears twice")
            continue  # a duplicate non-coordinate field (e.g. several padding fields) is ignored
        names.append(name)
        formats.append(base if count == 1 else (base, (count,)))
        offsets.append(offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})


def structured(msg: Any) -> np.ndarray:
    """All fields of a PointCloud2 as a structured array of shape (height, width).

    Sizes are checked against the data before anything is allocated, so a corrupt header cannot
    make the reader reserve more memory than the message holds.

    Raises:
        PointCloudFormatError: The layout is inconsistent or the data is shorter than declared.
    """
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    for name, value in (
        ("height", height),
        ("width", width),
        ("point_step", point_step),
        ("row_step", row_step),
    ):
        if not 0 <= value <= _UINT32_MAX:
            raise PointCloudFormatError(f"{_describe(msg)}: {name} {value} is not a uint32")
    if point_step <= 0 and height * width > 0:
        raise PointCloudFormatError(f"{_describe(msg)}: point_step must be positive")
    if point_step > _MAX_POINT_STEP:
        raise PointCloudFormatError(
            f"{_describe(msg)}: point_step {point_step} is not a plausible point size"
        )
    dtype = structured_dtype(msg.fields, max(point_step, 1), bool(msg.is_bigendian))
    raw = as_bytes_array(msg.data)
    if height * width == 0:
        return np.zeros((height, width), dtype=dtype)
    if row_step < width * point_step:
        raise PointCloudFormatError(
            f"{_describe(msg)}: row_step is smaller than width * point_step = {width * point_step}"
        )
    needed = (height - 1) * row_step + width * point_step
    if raw.size < needed:
        raise PointCloudFormatError(
            f"{_describe(msg)}: data has {raw.size} bytes, needs {needed} (truncated)"
        )
    if row_step == width * point_step:
        return raw[: height * row_step].view(dtype).reshape(height, width)
    # Padded rows: a strided view of the rows without their padding (the last row's padding may be
    # absent), copied once into whole points.
    rows = np.lib.stride_tricks.as_strided(
        raw, shape=(height, width * point_step), strides=(row_step, 1), writeable=False
    )
    return np.ascontiguousarray(rows).view(dtype).reshape(height, width)


def decode(msg: Any, *, organized: bool = False, dtype: Any = None) -> np.ndarray:
    """x, y, z of a PointCloud2 as float coordinates.

    Args:
        msg: Any object with ``height, width, fields, is_bigendian, point_step, row_step, data``.
        organized: Return (height, width, 3) instead of (height * width, 3).
        dtype: Output dtype; default float32 when x, y and z are all stored as FLOAT32 (or smaller
            integers), float64 otherwise.

    Returns:
        The coordinates; NaN points are kept (the mapper drops and counts them).

    Raises:
        PointCloudFormatError: A field x, y or z is missing or the layout is broken.
    """
    names = [str(f.name) for f in msg.fields]
    missing = [c for c in ("x", "y", "z") if c not in names]
    if missing:
        raise PointCloudFormatError(
            f"PointCloud2 has no {'/'.join(missing)} field(s); fields are {names or 'none'}"
        )
    arr = structured(msg)
    kinds = [arr.dtype[c] for c in ("x", "y", "z")]
    for c, k in zip(("x", "y", "z"), kinds, strict=True):
        if k.shape != ():
            raise PointCloudFormatError(f"PointCloud2 field {c!r} has count {k.shape[0]}, expected 1")
    if dtype is None:
        wide = any(k.itemsize > 4 or (k.kind in "iu" and k.itemsize >= 4) for k in kinds)
        dtype = np.float64 if wide else np.float32
    out = np.empty((*arr.shape, 3), dtype=dtype)
    for col, c in enumerate(("x", "y", "z")):
        out[..., col] = arr[c]
    return out if organized else out.reshape(-1, 3)


def encode(
    points: np.ndarray,
    *,
    datatype: int = FLOAT32,
    is_bigendian: bool = False,
    point_step: int | None = None,
    row_padding: int = 0,
    extra_fields: Mapping[str, np.ndarray] | None = None,
    frame_id: str = "",
    stamp_ns: int = 0,
) -> PointCloud2Data:
    """Pack points (N, 3) or organized (H, W, 3) into a PointCloud2 payload.

    Layout: x, y, z of ``datatype`` at offsets 0, s, 2s, then each extra field in order, then zero
    padding up to ``point_step``; every row is followed by ``row_padding`` zero bytes.

    Args:
        points: Coordinates; integer datatypes round them.
        datatype: PointField datatype of x, y, z (e.g. FLOAT32, FLOAT64, INT16).
        is_bigendian: Byte order of every field.
        point_step: Bytes per point (>= the packed size); default the packed size.
        row_padding: Extra bytes at the end of each row.
        extra_fields: name -> per-point values (N,) or (H, W) with their own dtype.
        frame_id: Frame of the coordinates.
        stamp_ns: Time stamp.
    """
    pts = np.asarray(points)
    if pts.ndim == 2 and pts.shape[1] == 3:
        height, width = 1, pts.shape[0]
    elif pts.ndim == 3 and pts.shape[2] == 3:
        height, width = pts.shape[0], pts.shape[1]
    else:
        raise PointCloudFormatError(f"points must be (N, 3) or (H, W, 3), got shape {pts.shape}")
    if datatype not in DATATYPES:
        raise PointCloudFormatError(f"unknown PointField datatype {datatype}")
    order: Literal["<", ">"] = ">" if is_bigendian else "<"
    base = DATATYPES[datatype]
    fields = [PointField(c, k * base.itemsize, datatype) for k, c in enumerate("xyz")]
    offset = 3 * base.itemsize
    extras: list[tuple[str, np.ndarray]] = []
    for name, values in (extra_fields or {}).items():
        v = np.asarray(values).reshape(height * width)
        code = _DATATYPE_OF.get(v.dtype.newbyteorder("<").str[1:])
        if code is None:
            raise PointCloudFormatError(f"extra field {name!r} has unsupported dtype {v.dtype}")
        fields.append(PointField(name, offset, code))
        extras.append((name, v))
        offset += v.dtype.itemsize
    step = offset if point_step is None else int(point_step)
    if step < offset:
        raise PointCloudFormatError(f"point_step {step} is smaller than the packed fields ({offset} bytes)")
    dt = structured_dtype(fields, step, is_bigendian)
    arr = np.zeros(height * width, dtype=dt)
    flat = pts.reshape(-1, 3)
    for k, c in enumerate("xyz"):
        col = flat[:, k]
        if base.kind in "iu":
            col = np.rint(col)
        arr[c] = col.astype(base.newbyteorder(order))
    for name, v in extras:
        arr[name] = v
    row_bytes = width * step
    row_step = row_bytes + int(row_padding)
    buf = np.zeros((height, row_step), dtype=np.uint8)
    buf[:, :row_bytes] = arr.view(np.uint8).reshape(height, row_bytes)
    return PointCloud2Data(
        height=height,
        width=width,
        fields=fields,
        is_bigendian=is_bigendian,
        point_step=step,
        row_step=row_step,
        data=buf.reshape(-1),
        is_dense=bool(np.isfinite(flat).all()),
        frame_id=frame_id,
        stamp_ns=int(stamp_ns),
    )
