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
from mapping.io.arrays import read_kitti, read_npy, write_kitti
from mapping.io.frame import CloudFrame
from mapping.io.pcd import read_pcd, read_pcd_cloud, write_pcd
from mapping.io.ply import read_ply, read_ply_mesh, write_ply

__all__ = [
    "SUFFIXES",
    "CloudFrame",
    "CloudSource",
    "open_clouds",
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
        kind: ``pcd``, ``ply``, ``kitti``, ``npy``, ``ros1-bag`` or ``ros2-bag``.
        topic: The bag topic read (None for files).
    """

    path: Path
    n_frames: int
    kind: str
    topic: str | None
    _frames: Iterable[CloudFrame]

    def __iter__(self) -> Iterator[CloudFrame]:
        return iter(self._frames)


def _single_file_frames(path: Path, kind: str) -> Iterator[CloudFrame]:
    origin = None
    if kind == "pcd":
        cloud = read_pcd_cloud(path)
        points = cloud.xyz(organized=True)
        if cloud.header.viewpoint != _DEFAULT_VIEWPOINT:
            origin = tuple(float(v) for v in cloud.header.viewpoint[:3])
    elif kind == "ply":
        points = read_ply(path)
    elif kind == "kitti":
        points = read_kitti(path)
    else:
        points = read_npy(path)
    yield CloudFrame(points=points, stamp_ns=0, frame_id="", source=str(path), sensor_origin=origin)  # type: ignore[arg-type]


def open_clouds(path: Path | str, topic: str | None = None) -> CloudSource:
    """Open one input by its extension.

    Args:
        path: A .pcd, .ply, KITTI .bin, .npy file, a ROS 1 .bag, or a ROS 2 bag (folder with
            metadata.yaml, or its .db3 / .mcap file).
        topic: Point-cloud topic of a bag (default: the only one); ignored for plain files so one
            ``--topic`` can serve a mix of files and bags.

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
        return CloudSource(path, src.n_frames, kind, src.topic, src)
    kinds = {".pcd": "pcd", ".ply": "ply", ".bin": "kitti", ".npy": "npy"}
    kind = kinds.get(path.suffix.lower(), "")
    if not kind or path.is_dir():
        raise PointCloudFormatError(
            f"{path}: unknown point-cloud format {path.suffix or '(no extension)'!r}; "
            f"expected one of {', '.join(SUFFIXES)}"
        )
    return CloudSource(path, 1, kind, None, _LazyFrames(path, kind))


@dataclass
class _LazyFrames:
    path: Path
    kind: str

    def __iter__(self) -> Iterator[CloudFrame]:
        return _single_file_frames(self.path, self.kind)


def read_clouds(path: Path | str, topic: str | None = None) -> Iterator[CloudFrame]:
    """Yield the frames of one input (see :func:`open_clouds`)."""
    return iter(open_clouds(path, topic))
