"""2D maps for ROS: ``map_server`` PGM + YAML files and ``nav_msgs/OccupancyGrid`` / marker bags.

The 2D map is a ternary grid ``codes[i, j]`` (i along the grid's first axis u, j along v) with the
``nav_msgs/OccupancyGrid`` values: -1 unknown, 0 free, 100 occupied. ``map_server`` images put the
highest v on the top row and take ``origin`` as the world pose of the lower-left pixel's corner.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mapping.errors import MappingError

UNKNOWN, FREE, OCCUPIED = -1, 0, 100
# map_server trinary image values (negate = 0): black occupied, white free, grey unknown.
PGM_OCCUPIED, PGM_FREE, PGM_UNKNOWN = 0, 254, 205
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.196


def _check_codes(codes: np.ndarray) -> np.ndarray:
    c = np.asarray(codes)
    if c.ndim != 2 or not np.isin(c, (UNKNOWN, FREE, OCCUPIED)).all():
        raise MappingError("2D map codes must be a (nx, ny) array of -1, 0, 100")
    return c.astype(np.int8)


def pgm_image(codes: np.ndarray) -> np.ndarray:
    """The (ny, nx) uint8 map_server image of ``codes`` (row 0 = highest v)."""
    c = _check_codes(codes)
    img = np.full(c.shape, PGM_UNKNOWN, dtype=np.uint8)
    img[c == FREE] = PGM_FREE
    img[c == OCCUPIED] = PGM_OCCUPIED
    return np.ascontiguousarray(img.T[::-1])


def write_pgm(path: Path | str, image: np.ndarray) -> Path:
    """Write a uint8 (rows, cols) image as binary PGM (P5, maxval 255)."""
    img = np.asarray(image, dtype=np.uint8)
    path = Path(path)
    with path.open("wb") as fh:
        fh.write(f"P5\n{img.shape[1]} {img.shape[0]}\n255\n".encode("ascii"))
        fh.write(np.ascontiguousarray(img).tobytes())
    return path


def read_pgm(path: Path | str) -> np.ndarray:
    """Read a binary PGM (P5, maxval <= 255) into a uint8 (rows, cols) array."""
    raw = Path(path).read_bytes()
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        while pos < len(raw) and raw[pos : pos + 1].isspace():
            pos += 1
        if raw[pos : pos + 1] == b"#":
            pos = raw.find(b"\n", pos) + 1
            continue
        start = pos
        while pos < len(raw) and not raw[pos : pos + 1].isspace():
            pos += 1
        if start == pos:
            raise MappingError(f"{path}: truncated PGM header")
        tokens.append(raw[start:pos])
    if tokens[0] != b"P5":
        raise MappingError(f"{path}: not a binary PGM (magic {tokens[0]!r})")
    width, height, maxval = (int(t) for t in tokens[1:])
    if maxval > 255:
        raise MappingError(f"{path}: 16-bit PGM not supported")
    pos += 1  # exactly one whitespace byte separates the header from the pixels
    data = np.frombuffer(raw, dtype=np.uint8, count=width * height, offset=pos)
    return data.reshape(height, width).copy()


def write_map_server(
    directory: Path | str,
    codes: np.ndarray,
    resolution: float,
    origin_xy: tuple[float, float],
    name: str = "map",
) -> tuple[Path, Path]:
    """Write ``name.pgm`` and ``name.yaml`` that ROS ``map_server`` / ``nav2_map_server`` load.

    Args:
        directory: Target folder.
        codes: (nx, ny) ternary map (-1, 0, 100).
        resolution: Cell size in metres.
        origin_xy: World (x, y) of the lower-left corner of cell (0, 0).
        name: File stem.

    Returns:
        (pgm path, yaml path).
    """
    directory = Path(directory)
    pgm = write_pgm(directory / f"{name}.pgm", pgm_image(codes))
    yaml = directory / f"{name}.yaml"
    yaml.write_text(
        f"image: {pgm.name}\n"
        f"resolution: {float(resolution)!r}\n"
        f"origin: [{float(origin_xy[0])!r}, {float(origin_xy[1])!r}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n"
        "mode: trinary\n",
        encoding="ascii",
    )
    return pgm, yaml


def _humble() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE).types


def _header(t: Any, frame_id: str, stamp_ns: int) -> Any:
    stamp = t["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9))
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def _pose(t: Any, xyz: tuple[float, float, float]) -> Any:
    return t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )


def occupancy_grid_msg(
    codes: np.ndarray,
    resolution: float,
    origin_xy: tuple[float, float],
    frame_id: str = "map",
    stamp_ns: int = 0,
) -> Any:
    """A ROS 2 Humble ``nav_msgs/msg/OccupancyGrid`` (row-major by j: ``data[j * nx + i]``)."""
    c = _check_codes(codes)
    t = _humble()
    nx, ny = c.shape
    stamp = t["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9))
    info = t["nav_msgs/msg/MapMetaData"](
        map_load_time=stamp,
        resolution=float(resolution),
        width=nx,
        height=ny,
        origin=_pose(t, (origin_xy[0], origin_xy[1], 0.0)),
    )
    return t["nav_msgs/msg/OccupancyGrid"](
        header=_header(t, frame_id, stamp_ns), info=info, data=np.ascontiguousarray(c.T).reshape(-1)
    )


def marker_array_msg(
    boxes: np.ndarray,
    colors: np.ndarray,
    frame_id: str = "map",
    stamp_ns: int = 0,
    min_thickness: float = 1e-3,
) -> Any:
    """A ROS 2 Humble ``visualization_msgs/msg/MarkerArray``: one DELETEALL, then one CUBE per box.

    Args:
        boxes: (K, 2, 3) world min and max corners of the VHV boxes.
        colors: (K, 4) RGBA in [0, 1].
        frame_id: Frame of the boxes.
        stamp_ns: Time stamp.
        min_thickness: Smallest scale drawn (a one-point structure has zero height; RViz needs > 0).
    """
    t = _humble()
    header = _header(t, frame_id, stamp_ns)
    Marker = t["visualization_msgs/msg/Marker"]
    Vector3 = t["geometry_msgs/msg/Vector3"]
    Color = t["std_msgs/msg/ColorRGBA"]
    Duration = t["builtin_interfaces/msg/Duration"]
    MeshFile = t["visualization_msgs/msg/MeshFile"]
    Image = t["sensor_msgs/msg/CompressedImage"]
    empty_img = Image(header=header, format="", data=np.zeros(0, np.uint8))

    def marker(k: int, mtype: int, action: int, centre: Any, scale: Any, rgba: Any) -> Any:
        return Marker(
            header=header,
            ns="vhv",
            id=k,
            type=mtype,
            action=action,
            pose=_pose(t, centre),
            scale=Vector3(x=float(scale[0]), y=float(scale[1]), z=float(scale[2])),
            color=Color(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3])),
            lifetime=Duration(sec=0, nanosec=0),
            frame_locked=False,
            points=[],
            colors=[],
            texture_resource="",
            texture=empty_img,
            uv_coordinates=[],
            text="",
            mesh_resource="",
            mesh_file=MeshFile(filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )

    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3)
    centres = b.mean(axis=1)
    scales = np.maximum(b[:, 1] - b[:, 0], min_thickness)
    markers = [marker(0, Marker.CUBE, Marker.DELETEALL, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0, 0, 0, 0))]
    cols = np.asarray(colors, dtype=np.float64).reshape(-1, 4)
    markers += [
        marker(k + 1, Marker.CUBE, Marker.ADD, c, s, rgba)
        for k, (c, s, rgba) in enumerate(zip(centres.tolist(), scales.tolist(), cols.tolist()))
    ]
    return t["visualization_msgs/msg/MarkerArray"](markers=markers)


_MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"


def marker_array_cdr(
    boxes: np.ndarray,
    colors: np.ndarray,
    frame_id: str = "map",
    stamp_ns: int = 0,
    min_thickness: float = 1e-3,
) -> bytes:
    """The CDR bytes of :func:`marker_array_msg`, built with numpy instead of one object per box.

    Every CUBE marker with the same header and namespace serializes to the same bytes except for its
    id, position, scale and colour, and (one marker being a multiple of 8 bytes) at the same alignment.
    So one marker is serialized by rosbags, tiled, and those fields are written in place; the field
    offsets are found by serializing sentinel values. Equality with rosbags' own serialization is tested.
    """
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3)
    n = b.shape[0]
    centres = b.mean(axis=1)
    scales = np.maximum(b[:, 1] - b[:, 0], min_thickness)
    cols = np.asarray(colors, dtype=np.float64).reshape(-1, 4)

    def ser(bx: np.ndarray, cl: np.ndarray) -> bytes:
        return bytes(
            store.serialize_cdr(marker_array_msg(bx, cl, frame_id, stamp_ns, min_thickness), _MARKER_ARRAY)
        )

    # Sentinels: exact binary values unlikely to occur elsewhere in a marker.
    sentinel_box = np.array([[[1001.0, 2002.0, 3003.0], [1001.0 + 0.5, 2002.0 + 0.25, 3003.0 + 0.125]]])
    sentinel_col = np.array([[0.1015625, 0.203125, 0.3046875, 0.40625]])
    base = ser(np.zeros((0, 2, 3)), np.zeros((0, 4)))
    one = ser(sentinel_box, sentinel_col)
    two = ser(np.repeat(sentinel_box, 2, axis=0), np.repeat(sentinel_col, 2, axis=0))
    stride = len(two) - len(one)
    chunk = one[len(base) :]

    def offset(value: bytes) -> int:
        k = chunk.find(value)
        return k if k >= 0 and chunk.find(value, k + 1) < 0 else -1

    pos = [offset(np.float64(v).tobytes()) for v in sentinel_box.mean(axis=1)[0]]
    scl = [offset(np.float64(v).tobytes()) for v in (sentinel_box[0, 1] - sentinel_box[0, 0])]
    col = [offset(np.float32(v).tobytes()) for v in sentinel_col[0]]
    # The two markers of ``two`` differ only in their id (1 and 2): that locates the id field.
    diff = np.flatnonzero(np.frombuffer(two[len(one) :], np.uint8) != np.frombuffer(chunk, np.uint8))
    if stride != len(chunk) or stride % 8 or min(pos + scl + col) < 0 or diff.shape[0] != 1:
        # Not the fixed layout this fast path relies on: let rosbags serialize every marker.
        msg = marker_array_msg(b, cols, frame_id, stamp_ns, min_thickness)
        return bytes(store.serialize_cdr(msg, _MARKER_ARRAY))
    ident = int(diff[0])  # little-endian: ids 1 and 2 differ in the first byte of the field
    out = np.tile(np.frombuffer(chunk, dtype=np.uint8), (n, 1))
    out[:, ident : ident + 4] = np.arange(1, n + 1, dtype="<i4").view(np.uint8).reshape(n, 4)
    for k in range(3):
        out[:, pos[k] : pos[k] + 8] = centres[:, k].astype("<f8").view(np.uint8).reshape(n, 8)
        out[:, scl[k] : scl[k] + 8] = scales[:, k].astype("<f8").view(np.uint8).reshape(n, 8)
    for k in range(4):
        out[:, col[k] : col[k] + 4] = cols[:, k].astype("<f4").view(np.uint8).reshape(n, 4)
    head = bytearray(base)
    head[4:8] = np.uint32(n + 1).astype("<u4").tobytes()  # marker count after the 4-byte CDR header
    return bytes(head) + out.reshape(-1).tobytes()


def write_ros2_map_bag(
    path: Path | str,
    *,
    codes: np.ndarray,
    resolution: float,
    origin_xy: tuple[float, float],
    boxes: np.ndarray,
    colors: np.ndarray,
    frame_id: str = "map",
    stamp_ns: int = 0,
    storage: str = "sqlite3",
) -> Path:
    """Write a ROS 2 bag (Humble types) with ``/map`` (OccupancyGrid) and ``/vhv_markers`` (MarkerArray).

    Replay with ``ros2 bag play`` and show both in RViz with fixed frame ``frame_id``. Both topics are
    recorded as offered transient-local (latched), the QoS RViz's Map display subscribes with.
    """
    from mapping.io.bags import write_bag

    stamp = int(stamp_ns) if stamp_ns > 0 else 1  # rosbag2 tools dislike a zero receive time
    grid = occupancy_grid_msg(codes, resolution, origin_xy, frame_id, stamp)
    markers = marker_array_cdr(boxes, colors, frame_id, stamp)
    return write_bag(
        path,
        [
            ("/map", "nav_msgs/msg/OccupancyGrid", stamp, grid),
            ("/vhv_markers", "visualization_msgs/msg/MarkerArray", stamp, markers),
        ],
        ros2=True,
        storage=storage,
        latched_topics=("/map", "/vhv_markers"),
    )
