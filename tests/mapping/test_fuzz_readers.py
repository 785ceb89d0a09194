"""Fuzzed readers: a corrupted input ends in a well-formed cloud or the project's own error.

Valid PCD (ascii, binary, binary_compressed), PLY (ascii and binary), KITTI ``.bin`` files,
PointCloud2 messages and bags (ROS 1, ROS 2 sqlite3 and MCAP) are mutated by truncation, bit flips,
overwritten and inserted bytes, and header numbers replaced by zero, negative or huge values. Every
read must either return points of shape (N, 3) or (H, W, 3) in float32 or float64, or raise a
:class:`mapping.MappingError`; and it must not allocate far more memory than the input could fill
(counts are checked against the data before anything is allocated). Hangs are caught by the
per-test timeout.

The default run tries a few hundred cases; ``-m slow`` tries many thousands.
"""

from __future__ import annotations

import dataclasses
import re
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mapping.errors import MappingError
from mapping.io import read_bin, read_clouds, read_pcd_cloud, read_ply_mesh, write_pcd, write_ply
from mapping.io.bags import decode_pointcloud1, to_ros_pointcloud2, write_bag
from mapping.pointcloud2 import FLOAT32, FLOAT64, PointField, decode, encode

QUICK = 50  # cases per file, message and bag test in the default run: 230 cases in all
QUICK_BAGS = 30  # bags cost a storage open each
MANY = 2500  # cases per test under -m slow
# Memory a reader may use beyond the input's own size: interpreter, numpy and rosbags bookkeeping.
# A reader that trusts a huge declared count allocates gigabytes and fails this by far.
MEMORY_BASE = 48 * 2**20
MEMORY_PER_INPUT_BYTE = 64
HUGE = [0, 1, 2, 3, 7, 255, 65535, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 10**12, 2**63 - 1, 10**30, -1]
PC2 = "sensor_msgs/msg/PointCloud2"


def _fuzz(max_examples: int) -> Callable[[Callable[..., None]], Callable[..., None]]:
    return settings(
        max_examples=max_examples,
        deadline=None,  # no wall-clock assertion; a hang trips the test timeout instead
        derandomize=max_examples < MANY,  # the default run tries the same cases every time
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    )


# ------------------------------------------------------------------------------------ valid inputs


def _cloud(n: int = 24) -> np.ndarray:
    rng = np.random.default_rng(n)
    pts = rng.uniform(-3, 3, (n, 3)).astype(np.float32)
    pts[n // 2] = np.nan
    return pts


def _pcd_bytes(tmp: Path, encoding: str) -> bytes:
    path = tmp / f"seed_{encoding}.pcd"
    write_pcd(path, _cloud(), encoding=encoding, extra_fields={"intensity": np.arange(24, dtype=np.float32)})
    return path.read_bytes()


def _ply_bytes(tmp: Path, encoding: str) -> bytes:
    path = tmp / f"seed_{encoding}.ply"
    faces = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6]])
    write_ply(path, _cloud(), faces=faces, encoding=encoding)
    return path.read_bytes()


def _kitti_bytes() -> bytes:
    rec = np.zeros((24, 4), "<f4")
    rec[:, :3] = _cloud()
    rec[:, 3] = np.linspace(0, 1, 24)
    return rec.tobytes()


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, bytes]:
    tmp = tmp_path_factory.mktemp("seeds")
    out = {f"pcd_{e}": _pcd_bytes(tmp, e) for e in ("ascii", "binary", "binary_compressed")}
    out.update({f"ply_{e}": _ply_bytes(tmp, e) for e in ("ascii", "binary_little_endian")})
    out["kitti"] = _kitti_bytes()
    messages = [
        ("/points", PC2, 1000 * (k + 1), to_ros_pointcloud2(encode(_cloud(8 + k)), ros2=False))
        for k in range(2)
    ]
    out["ros1_bag"] = write_bag(tmp / "seed.bag", messages, ros2=False).read_bytes()
    for storage in ("sqlite3", "mcap"):
        msgs = [("/points", PC2, 1000 * (k + 1), to_ros_pointcloud2(encode(_cloud(8 + k)))) for k in range(2)]
        folder = write_bag(tmp / f"seed_{storage}", msgs, storage=storage)
        (f,) = [p for p in folder.iterdir() if p.suffix in (".db3", ".mcap")]
        out[f"ros2_{storage}"] = f.read_bytes()
    return out


# -------------------------------------------------------------------------------------- mutations


def _header_end(data: bytes) -> int:
    for token in (b"DATA ", b"end_header"):
        k = data.find(token)
        if k >= 0:
            nl = data.find(b"\n", k)
            return len(data) if nl < 0 else nl
    return min(len(data), 512)


@st.composite
def mutated(draw: Any, seed: bytes) -> bytes:
    """``seed`` after one to three mutations."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["truncate", "flip", "overwrite", "insert", "header_number"]))
        n = len(data)
        if kind == "truncate":
            del data[draw(st.integers(0, n)) :]
        elif kind == "flip" and n:
            pos = draw(st.integers(0, n - 1))
            data[pos] ^= 1 << draw(st.integers(0, 7))
        elif kind == "overwrite" and n:
            pos = draw(st.integers(0, n - 1))
            chunk = draw(st.binary(min_size=1, max_size=8))
            data[pos : pos + len(chunk)] = chunk
        elif kind == "insert":
            pos = draw(st.integers(0, n))
            data[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "header_number":
            numbers = list(re.finditer(rb"-?\d+", bytes(data[: _header_end(bytes(data))])))
            if numbers:
                m = draw(st.sampled_from(numbers))
                value = str(draw(st.sampled_from(HUGE))).encode()
                data[m.start() : m.end()] = value
    return bytes(data)


# ------------------------------------------------------------------------------------------ checks


def _well_formed(points: Any) -> None:
    assert isinstance(points, np.ndarray)
    assert points.dtype in (np.float32, np.float64), points.dtype
    assert (points.ndim == 2 and points.shape[1] == 3) or (points.ndim == 3 and points.shape[2] == 3), (
        points.shape
    )


def _read_bounded(read: Callable[[], Any], input_size: int) -> Any:
    """Run ``read``; return its result or None for a project error; check its peak memory."""
    tracemalloc.start()
    try:
        return read()
    except MappingError as exc:
        assert str(exc)  # the one line the CLI prints
        return None
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak <= MEMORY_BASE + MEMORY_PER_INPUT_BYTE * input_size, f"peak {peak / 2**20:.0f} MB"


def _check_file(tmp: Path, name: str, data: bytes, read: Callable[[Path], Any]) -> None:
    path = tmp / name
    path.write_bytes(data)
    result = _read_bounded(lambda: read(path), len(data))
    if result is not None:
        _well_formed(result)


def _frames(path: Path) -> list[np.ndarray]:
    return [f.points for f in read_clouds(path)]


# ------------------------------------------------------------------------------------ file readers


def _pcd(tmp_path, seeds, data) -> None:
    encoding = data.draw(st.sampled_from(["ascii", "binary", "binary_compressed"]))
    raw = data.draw(mutated(seeds[f"pcd_{encoding}"]))
    _check_file(tmp_path, "f.pcd", raw, lambda p: read_pcd_cloud(p).xyz(organized=True))


def _ply(tmp_path, seeds, data) -> None:
    encoding = data.draw(st.sampled_from(["ascii", "binary_little_endian"]))
    raw = data.draw(mutated(seeds[f"ply_{encoding}"]))
    with_faces = data.draw(st.booleans())
    _check_file(tmp_path, "f.ply", raw, lambda p: read_ply_mesh(p, faces=with_faces).vertices)


def _kitti(tmp_path, seeds, data) -> None:
    raw = data.draw(mutated(seeds["kitti"]))
    layout = data.draw(st.sampled_from([None, "kitti", "nuscenes", "xyz", "xyzrgb"]))
    _check_file(tmp_path, "f.bin", raw, lambda p: read_bin(p, layout))


def _bag(tmp_path, seeds, data) -> None:
    kind = data.draw(st.sampled_from(["ros1_bag", "ros2_sqlite3", "ros2_mcap"]))
    raw = data.draw(mutated(seeds[kind]))
    name = {"ros1_bag": "f.bag", "ros2_sqlite3": "f.db3", "ros2_mcap": "f.mcap"}[kind]
    path = tmp_path / name
    path.write_bytes(raw)
    frames = _read_bounded(lambda: _frames(path), len(raw))
    for points in frames or []:
        _well_formed(points)


# ------------------------------------------------------------------------------------- PointCloud2


@st.composite
def pointcloud2(draw: Any) -> Any:
    """A valid PointCloud2 payload, then its layout fields and bytes mutated."""
    n = draw(st.integers(0, 12))
    organized = draw(st.booleans()) and n % 3 == 0 and n > 0
    pts = _cloud(max(n, 1))[:n]
    msg = encode(
        pts.reshape(3, n // 3, 3) if organized else pts,
        datatype=draw(st.sampled_from([FLOAT32, FLOAT64])),
        is_bigendian=draw(st.booleans()),
        row_padding=draw(st.sampled_from([0, 0, 3, 8])),
        extra_fields={"intensity": np.ones(n, np.float32).reshape(pts.shape[:-1])}
        if draw(st.booleans())
        else None,
    )
    number = st.sampled_from(HUGE) | st.integers(-4, 64)
    changes: dict[str, Any] = {}
    for attr in ("height", "width", "point_step", "row_step"):
        if draw(st.integers(0, 4)) == 0:
            changes[attr] = draw(number)
    fields = list(msg.fields)
    if fields and draw(st.booleans()):
        k = draw(st.integers(0, len(fields) - 1))
        attr = draw(st.sampled_from(["offset", "datatype", "count", "name"]))
        value = draw(st.sampled_from(["x", "y", "z", "", "intensity"])) if attr == "name" else draw(number)
        fields[k] = PointField(**{**dataclasses.asdict(fields[k]), attr: value})
        changes["fields"] = fields
    payload = msg.data.tobytes()
    changes["data"] = np.frombuffer(
        draw(mutated(payload)) if payload and draw(st.booleans()) else payload, np.uint8
    )
    return dataclasses.replace(msg, **changes)


def _pointcloud1_bytes(ros2: bool) -> bytes:
    """A serialized ``sensor_msgs/PointCloud`` (the older message) of 5 points."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=3, nanosec=9)
    extra = {} if ros2 else {"seq": 3}
    header = t["std_msgs/msg/Header"](stamp=stamp, frame_id="cam", **extra)
    pts = [t["geometry_msgs/msg/Point32"](x=float(a), y=float(b), z=float(c)) for a, b, c in _cloud(5)]
    msg = t["sensor_msgs/msg/PointCloud"](header=header, points=pts, channels=[])
    msgtype = "sensor_msgs/msg/PointCloud"
    return bytes(ts.serialize_cdr(msg, msgtype) if ros2 else ts.serialize_ros1(msg, msgtype))


def _pc2(data) -> None:
    if data.draw(st.integers(0, 3)) == 0:  # the older PointCloud message, read in place
        ros2 = data.draw(st.booleans())
        raw = data.draw(mutated(_pointcloud1_bytes(ros2)))
        result = _read_bounded(lambda: decode_pointcloud1(raw, ros2=ros2)[0], len(raw) + 1024)
    else:
        msg = data.draw(pointcloud2())
        organized = data.draw(st.booleans())
        result = _read_bounded(lambda: decode(msg, organized=organized), int(msg.data.size) + 1024)
    if result is not None:
        _well_formed(result)


# --------------------------------------------------------------------------- the tests, quick + many


@pytest.mark.timeout(300)
@_fuzz(QUICK)
@given(data=st.data())
def test_mutated_pcd_files_give_points_or_a_mapping_error(tmp_path, seeds, data):
    _pcd(tmp_path, seeds, data)


@pytest.mark.timeout(300)
@_fuzz(QUICK)
@given(data=st.data())
def test_mutated_ply_files_give_points_or_a_mapping_error(tmp_path, seeds, data):
    _ply(tmp_path, seeds, data)


@pytest.mark.timeout(300)
@_fuzz(QUICK)
@given(data=st.data())
def test_mutated_kitti_scans_give_points_or_a_mapping_error(tmp_path, seeds, data):
    _kitti(tmp_path, seeds, data)


@pytest.mark.timeout(300)
@_fuzz(QUICK)
@given(data=st.data())
def test_mutated_pointcloud2_messages_give_points_or_a_mapping_error(data):
    _pc2(data)


@pytest.mark.timeout(300)
@_fuzz(QUICK_BAGS)
@given(data=st.data())
def test_mutated_bags_give_frames_or_a_mapping_error(tmp_path, seeds, data):
    _bag(tmp_path, seeds, data)


@pytest.mark.slow
@pytest.mark.timeout(3600)
@pytest.mark.parametrize("reader", ["pcd", "ply", "kitti", "pointcloud2", "bag"])
@_fuzz(MANY)
@given(data=st.data())
def test_many_mutated_inputs_give_points_or_a_mapping_error(tmp_path, seeds, reader, data):
    if reader == "pointcloud2":
        _pc2(data)
    else:
        {"pcd": _pcd, "ply": _ply, "kitti": _kitti, "bag": _bag}[reader](tmp_path, seeds, data)


# ---------------------------------------------------- the fuzzer's findings, kept as plain tests


def _pcd_header(fields: str, points: int, data: str) -> bytes:
    k = len(fields.split())
    return (
        f"VERSION .7\nFIELDS {fields}\nSIZE {' '.join(['4'] * k)}\nTYPE {' '.join(['F'] * k)}\n"
        f"COUNT {' '.join(['1'] * k)}\nWIDTH {points}\nHEIGHT 1\nPOINTS {points}\nDATA {data}\n"
    ).encode()


def test_compressed_pcd_declaring_a_huge_size_is_refused_before_allocating(tmp_path):
    n = 100_000_000  # 1.2 GB once expanded, from a 20-byte body
    raw = _pcd_header("x y z", n, "binary_compressed") + np.array([12, 12 * n], "<u4").tobytes() + b"\0" * 12
    path = tmp_path / "bomb.pcd"
    path.write_bytes(raw)
    with pytest.raises(MappingError, match="cannot expand to the declared 1200000000 bytes"):
        _read_bounded_or_raise(lambda: read_pcd_cloud(path), len(raw))


def test_ascii_pcd_with_one_overlong_value_is_refused_without_widening_every_value(tmp_path):
    body = " ".join(["1"] * 59_999) + " " + "9" * 1_000_000  # numpy would store 60 GB of fixed-width text
    raw = _pcd_header("x y z", 20_000, "ascii") + body.encode()
    path = tmp_path / "long.pcd"
    path.write_bytes(raw)
    with pytest.raises(MappingError, match="1000000-character value"):
        _read_bounded_or_raise(lambda: read_pcd_cloud(path), len(raw))


def test_pointcloud2_with_a_huge_row_step_reads_only_its_rows():
    msg = dataclasses.replace(encode(_cloud(4)), row_step=2**32 - 1)  # one row: the step is never used
    points = _read_bounded_or_raise(lambda: decode(msg), int(msg.data.size))
    np.testing.assert_array_equal(points, _cloud(4))
    with pytest.raises(MappingError, match="row_step 1000000000000 is not a uint32"):
        decode(dataclasses.replace(msg, row_step=10**12))
    with pytest.raises(MappingError, match="point_step 2147483648 is not a plausible point size"):
        decode(dataclasses.replace(msg, width=0, point_step=2**31, row_step=0))


def test_mcap_record_declaring_a_huge_length_is_refused_within_the_files_size(tmp_path, seeds):
    raw = bytearray(seeds["ros2_mcap"])
    raw[9:17] = (2**40).to_bytes(8, "little")  # the header record's length
    path = tmp_path / "f.mcap"
    path.write_bytes(bytes(raw))
    with pytest.raises(MappingError, match="cannot open bag"):
        _read_bounded_or_raise(lambda: _frames(path), len(raw))


def _read_bounded_or_raise(read: Callable[[], Any], input_size: int) -> Any:
    tracemalloc.start()
    try:
        return read()
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak <= MEMORY_BASE + MEMORY_PER_INPUT_BYTE * input_size, f"peak {peak / 2**20:.0f} MB"
