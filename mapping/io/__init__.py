"""Point-cloud input and output: PCD, PLY, KITTI .bin, .npy and ROS 1 / ROS 2 bags.

:func:`read_clouds` picks the reader from the file extension and yields :class:`CloudFrame` objects;
a file holds one frame, a bag one per PointCloud2 (or PointCloud) message on the selected topic.
:func:`open_clouds` does the same but also says how many frames to expect (for progress bars).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from mapping.errors import PointCloudFormatError
from mapping.io.arrays import BIN_LAYOUTS, detect_bin_layout, read_bin, read_kitti, read_npy, write_kitti
from mapping.io.frame import CloudFrame
from mapping.io.pcd import read_pcd, read_pcd_cloud, write_pcd
from mapping.io.ply import read_ply, read_ply_mesh, write_ply

__all__ = [
    "BIN_LAYOUTS",
    "SUFFIXES",
    "CloudFrame",
    "CloudSource",
    "detect_bin_layout",
    "open_clouds",
    "read_bin",
    "read_clouds",
    "read_kitti",
    "read_npy",
    "read_pcd",
    "read_pcd_cloud",
    "read_ply",
    "read_ply_mesh",
    "write_kitti",
    "write_pcd",
    "write_ply",
]

SUFFIXES = (".pcd", ".ply", ".bin", ".npy", ".bag", ".db3", ".mcap", "<ROS 2 bag folder>")
_DEFAULT_VIEWPOINT = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


@dataclass
class CloudSource:
    """Frames of one input, decoded lazily on iteration.

    Attributes:
        path: The input.
        n_frames: How many frames iteration yields.
        kind: ``pcd``, ``ply``, a ``.bin`` layout (``kitti``, ``nuscenes``, ``xyz``, ``xyzrgb``),
            ``npy``, ``ros1-bag`` or ``ros2-bag``.
        topic: The bag topic read (None for files).
        no_return_topic: The bag's ``<topic>/no_return`` companion read with it (None: none), whose
            messages come as each frame's ``no_return``.
    """

    path: Path
    n_frames: int
    kind: str
    topic: str | None
    _frames: Iterable[CloudFrame]
    no_return_topic: str | None = None

    def __iter__(self) -> Iterator[CloudFrame]:
        return iter(self._frames)


def _single_file_frames(path: Path, kind: str, bin_layout: str | None) -> Iterator[CloudFrame]:
    origin = None
    if kind == "pcd":
        cloud = read_pcd_cloud(path)
        points = cloud.xyz(organized=True)
        if cloud.header.viewpoint != _DEFAULT_VIEWPOINT:
            origin = tuple(float(v) for v in cloud.header.viewpoint[:3])
    elif kind == "ply":
        points = read_ply(path)
    elif kind == "bin":
        points = read_bin(path, bin_layout)
    else:
        points = read_npy(path)
    yield CloudFrame(points=points, stamp_ns=0, frame_id="", source=str(path), sensor_origin=origin)  # type: ignore[arg-type]


def open_clouds(path: Path | str, topic: str | None = None, *, bin_layout: str | None = None) -> CloudSource:
    """Open one input by its extension.

    Args:
        path: A .pcd, .ply, float32 .bin (KITTI, nuScenes, ...), .npy file, a ROS 1 .bag, or a ROS 2
            bag (folder with metadata.yaml, or its .db3 / .mcap file).
        topic: Point-cloud topic of a bag (default: the only one); ignored for plain files so one
            ``--topic`` can serve a mix of files and bags.
        bin_layout: Layout of .bin inputs (:data:`BIN_LAYOUTS`); None detects it from the name and
            data (:func:`detect_bin_layout`). Ignored for other inputs.

    Raises:
        FileNotFoundError: The path does not exist.
        PointCloudFormatError: Unknown extension.
        BagTopicError: Topic problems in a bag.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    from mapping.io import bags

    if path.suffix == ".bag" or bags.is_ros2_bag(path):
        src = bags.open_bag_clouds(path, topic)
        kind = "ros2-bag" if bags.is_ros2_bag(path) else "ros1-bag"
        return CloudSource(path, src.n_frames, kind, src.topic, src, src.no_return_topic)
    if path.name.endswith(".bag.active"):
        raise PointCloudFormatError(
            f"{path}: a ROS 1 bag whose recording never finished (no index); reindex it with "
            f"'rosbag reindex {path.name}' and map the {path.name.removesuffix('.active')} it writes"
        )
    kinds = {".pcd": "pcd", ".ply": "ply", ".bin": "bin", ".npy": "npy"}
    kind = kinds.get(path.suffix.lower(), "")
    if not kind or path.is_dir():
        raise PointCloudFormatError(
            f"{path}: unknown point-cloud format {path.suffix or '(no extension)'!r}; "
            f"expected one of {', '.join(SUFFIXES)}"
        )
    if kind == "bin":
        if bin_layout is not None and bin_layout not in BIN_LAYOUTS:
            raise PointCloudFormatError(
                f"{path}: unknown .bin layout {bin_layout!r}; expected one of {', '.join(BIN_LAYOUTS)}"
            )
        bin_layout = bin_layout or detect_bin_layout(path)  # refuse a doubtful layout before any work
        return CloudSource(path, 1, bin_layout, None, _LazyFrames(path, kind, bin_layout))
    return CloudSource(path, 1, kind, None, _LazyFrames(path, kind, None))


@dataclass
class _LazyFrames:
    path: Path
    kind: str
    bin_layout: str | None

    def __iter__(self) -> Iterator[CloudFrame]:
        return _single_file_frames(self.path, self.kind, self.bin_layout)


def read_clouds(
    path: Path | str, topic: str | None = None, *, bin_layout: str | None = None
) -> Iterator[CloudFrame]:
    """Yield the frames of one input (see :func:`open_clouds`)."""
    return iter(open_clouds(path, topic, bin_layout=bin_layout))
