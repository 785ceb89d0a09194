"""Raw array formats: KITTI Velodyne ``.bin`` (float32 x y z intensity) and numpy ``.npy``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mapping.errors import PointCloudFormatError

_KITTI_RECORD = 16  # four little-endian float32 per point


def read_kitti(path: Path | str, *, with_intensity: bool = False) -> np.ndarray:
    """Read a KITTI Velodyne scan: (N, 3) float32 x, y, z, or (N, 4) with intensity.

    Raises:
        PointCloudFormatError: The file size is not a multiple of 16 bytes (truncated or not KITTI).
    """
    raw = Path(path).read_bytes()
    if len(raw) % _KITTI_RECORD:
        raise PointCloudFormatError(
            f"{path}: KITTI .bin size {len(raw)} bytes is not a multiple of 16 (4 float32 per point); "
            "the file is truncated or not a KITTI scan"
        )
    arr = np.frombuffer(raw, dtype="<f4").reshape(-1, 4).astype(np.float32)
    return arr if with_intensity else np.ascontiguousarray(arr[:, :3])


def write_kitti(path: Path | str, points: np.ndarray, intensity: np.ndarray | None = None) -> Path:
    """Write (N, 3) points (and optional (N,) intensity, default 0) as a KITTI ``.bin`` scan."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise PointCloudFormatError(f"{path}: KITTI points must be (N, 3), got {pts.shape}")
    out = np.zeros((pts.shape[0], 4), dtype="<f4")
    out[:, :3] = pts
    if intensity is not None:
        out[:, 3] = np.asarray(intensity).reshape(-1)
    path = Path(path)
    path.write_bytes(out.tobytes())
    return path


def read_npy(path: Path | str) -> np.ndarray:
    """Read a ``.npy`` array of points, (N, 3) or organized (H, W, 3), any real dtype -> float.

    Raises:
        PointCloudFormatError: Not a readable npy file, pickled objects, or a shape other than
            (N, 3) / (H, W, 3).
    """
    try:
        arr = np.load(Path(path), allow_pickle=False)
    except (ValueError, EOFError) as exc:
        raise PointCloudFormatError(f"{path}: not a readable .npy array ({exc})") from None
    if not isinstance(arr, np.ndarray):
        raise PointCloudFormatError(f"{path}: expected one .npy array, got {type(arr).__name__}")
    if not ((arr.ndim == 2 and arr.shape[1] == 3) or (arr.ndim == 3 and arr.shape[2] == 3)):
        raise PointCloudFormatError(f"{path}: .npy points must be (N, 3) or (H, W, 3), got shape {arr.shape}")
    if arr.dtype.kind not in "iuf":
        raise PointCloudFormatError(f"{path}: .npy points must be numbers, got dtype {arr.dtype}")
    if arr.dtype.kind != "f":
        arr = arr.astype(np.float64)
    return arr
