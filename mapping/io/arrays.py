"""Raw array formats: float32 ``.bin`` scans (KITTI, nuScenes, x y z, x y z r g b) and numpy ``.npy``.

A ``.bin`` scan is a headerless run of little-endian float32 records, so its layout cannot be read
from the file; :func:`detect_bin_layout` takes it from the name or the data, and refuses to guess
when neither settles it:

* ``*.pcd.bin`` (nuScenes' file-name convention) is ``nuscenes``: x y z intensity ring;
* any other ``.bin`` is ``kitti`` (x y z intensity) when its size is a multiple of 16 bytes, its
  data fits KITTI, and the data rules out every other layout the size fits. The data fits a layout
  when its extra columns hold what they should (intensity: finite, 0 to 255; ring: a whole number 0 to
  1023; r g b: finite, 0 to 255) and the float32 stream repeats with the layout's record length: the
  values at equal positions of neighbouring records are alike (Kolmogorov-Smirnov distance at most
  0.3 between the columns of a record-aligned reshape), where a wrong record length pairs unlike
  columns (x with intensity, y with a colour). A 1.2 MB x y z r g b file (50,000 points) fits KITTI,
  nuScenes, x y z and x y z r g b by size, and its colours pass the intensity check; the repetition
  test tells it is not KITTI;
* otherwise the file is refused with the layouts its size fits: give the layout explicitly
  (``robchair map --bin-layout kitti|nuscenes|xyz|xyzrgb``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mapping.errors import PointCloudFormatError

_KITTI_RECORD = 16  # four little-endian float32 per point

#: Layout name -> (floats per point, what they are).
BIN_LAYOUTS: dict[str, tuple[int, str]] = {
    "kitti": (4, "x y z intensity"),
    "nuscenes": (5, "x y z intensity ring"),
    "xyz": (3, "x y z"),
    "xyzrgb": (6, "x y z r g b"),
}
_MAX_INTENSITY = 255.0  # KITTI stores 0-1, other drivers 0-255
_MAX_RING = 1023.0  # laser index: 32 on nuScenes' HDL-32E, at most 128 on today's lidars
_MIN_ROWS = 64  # fewer record-aligned rows than this: too few to judge the repetition
_MAX_ROWS = 20_000  # rows compared (the start of a long file is enough)
_MAX_KS = 0.3  # largest distance of like columns; unlike ones (x vs intensity) are far apart


def _columns_fit(values: np.ndarray, layout: str) -> bool:
    """Whether the records of ``values`` ((N, k) float32) hold what ``layout``'s extra columns hold."""
    if values.shape[0] == 0 or layout == "xyz":
        return True
    extra = values[:, 3:4] if layout == "nuscenes" else values[:, 3:]  # intensity, or r g b
    ok = bool(np.all(np.isfinite(extra)) and extra.min() >= 0.0 and extra.max() <= _MAX_INTENSITY)
    if ok and layout == "nuscenes":
        ring = values[:, 4]
        ok = bool(
            np.all(np.isfinite(ring))
            and ring.min() >= 0
            and ring.max() <= _MAX_RING
            and np.all(ring == np.round(ring))
        )
    return ok


def _ks_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sample Kolmogorov-Smirnov distance of two equally long samples (non-finite values last)."""
    sa, sb = np.sort(a), np.sort(b)
    both = np.concatenate([sa, sb])
    fa = np.searchsorted(sa, both, side="right") / sa.size
    fb = np.searchsorted(sb, both, side="right") / sb.size
    return float(np.max(np.abs(fa - fb)))


def _repeats_every(stream: np.ndarray, k: int, period: int) -> bool:
    """Whether the float stream (reshaped into rows of ``period`` values, a multiple of ``k``) looks
    alike at columns ``c`` and ``c + k``: what records of ``k`` floats look like. True when there are
    too few rows to tell."""
    n_rows = min(stream.size // period, _MAX_ROWS)
    if n_rows < _MIN_ROWS or k == period:
        return True
    table = stream[: n_rows * period].astype(np.float64).reshape(n_rows, period)
    table[~np.isfinite(table)] = np.inf
    return all(_ks_distance(table[:, c], table[:, c + k]) <= _MAX_KS for c in range(period - k))


def _data_fits(raw: bytes, layouts: list[str]) -> list[str]:
    """The layouts among ``layouts`` (all fitting the size) whose columns and record length the data fits."""
    stream = np.frombuffer(raw, "<f4")
    cols = [name for name in layouts if _columns_fit(stream.reshape(-1, BIN_LAYOUTS[name][0]), name)]
    period = math.lcm(*(BIN_LAYOUTS[name][0] for name in cols)) if cols else 1
    return [name for name in cols if _repeats_every(stream, BIN_LAYOUTS[name][0], period)]


def detect_bin_layout(path: Path | str, raw: bytes | None = None) -> str:
    """The layout of a ``.bin`` scan, from its name or its data (see the module docstring).

    Raises:
        PointCloudFormatError: The layout cannot be told safely; the message lists the layouts the
            size fits and how to choose one.
    """
    path = Path(path)
    raw = path.read_bytes() if raw is None else raw
    size = len(raw)
    fits = [name for name, (k, _) in BIN_LAYOUTS.items() if size % (4 * k) == 0]
    hint = (
        f"its size ({size} bytes) fits: {', '.join(fits)}; give the layout with --bin-layout"
        if fits
        else f"its size ({size} bytes) fits no layout ({', '.join(BIN_LAYOUTS)}): the file is truncated"
    )
    if path.name.lower().endswith(".pcd.bin"):
        if "nuscenes" not in fits:
            raise PointCloudFormatError(
                f"{path}: a nuScenes .pcd.bin holds 5 float32 per point (20 bytes), but {hint}"
            )
        return "nuscenes"
    if "kitti" not in fits:
        raise PointCloudFormatError(f"{path}: not a KITTI scan (4 float32 per point); {hint}")
    if not _columns_fit(np.frombuffer(raw, "<f4").reshape(-1, 4), "kitti"):
        raise PointCloudFormatError(
            f"{path}: not a KITTI scan: every 4th float32 should be an intensity in [0, 255]; {hint}"
        )
    data_fits = _data_fits(raw, fits)
    if "kitti" not in data_fits:
        raise PointCloudFormatError(
            f"{path}: not a KITTI scan: the data does not repeat every 4 float32 "
            f"(it fits {', '.join(data_fits) or 'no layout'}); {hint}"
        )
    if data_fits != ["kitti"]:
        raise PointCloudFormatError(
            f"{path}: layout is ambiguous: the data fits {', '.join(data_fits)}; {hint}"
        )
    return "kitti"


def read_bin(path: Path | str, layout: str | None = None) -> np.ndarray:
    """Read the x, y, z of a float32 ``.bin`` scan as (N, 3) float32.

    Args:
        path: The scan.
        layout: One of :data:`BIN_LAYOUTS`; None detects it (:func:`detect_bin_layout`).

    Raises:
        PointCloudFormatError: Unknown layout, a size that is not a whole number of records, or a
            layout that cannot be detected safely.
    """
    raw = Path(path).read_bytes()
    if layout is None:
        layout = detect_bin_layout(path, raw)
    if layout not in BIN_LAYOUTS:
        raise PointCloudFormatError(
            f"{path}: unknown .bin layout {layout!r}; expected one of {', '.join(BIN_LAYOUTS)}"
        )
    k, what = BIN_LAYOUTS[layout]
    if len(raw) % (4 * k):
        raise PointCloudFormatError(
            f"{path}: {layout} .bin size {len(raw)} bytes is not a multiple of {4 * k} "
            f"({k} float32 per point: {what}); the file is truncated or of another layout"
        )
    arr = np.frombuffer(raw, dtype="<f4").reshape(-1, k)
    return np.ascontiguousarray(arr[:, :3], dtype=np.float32)


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
