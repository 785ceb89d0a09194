"""Triangle meshes of axis-aligned boxes (the VHV boxes, or standard voxels) written as PLY."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mapping.io.ply import write_ply

# Corner k of a box has coordinate bit (k >> axis) & 1 of (min, max) along each axis.
_CORNERS = np.array([[(k >> a) & 1 for a in range(3)] for k in range(8)], dtype=np.intp)
# Twelve outward-facing triangles (counter-clockwise seen from outside) over those corners.
_TRIANGLES = np.array(
    [
        [0, 2, 1], [1, 2, 3],  # -z
        [4, 5, 6], [5, 7, 6],  # +z
        [0, 1, 4], [1, 5, 4],  # -y
        [2, 6, 3], [3, 6, 7],  # +y
        [0, 4, 2], [2, 4, 6],  # -x
        [1, 3, 5], [3, 7, 5],  # +x
    ],
    dtype=np.int64,
)  # fmt: skip


def box_mesh(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (8K, 3) and triangles (12K, 3) of K boxes given as (K, 2, 3) min/max corners."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3)
    k = b.shape[0]
    # vertices[box, corner, axis] = b[box, bit(corner, axis), axis]
    verts = b[:, _CORNERS, np.arange(3)]
    faces = (_TRIANGLES[None, :, :] + 8 * np.arange(k)[:, None, None]).reshape(-1, 3)
    return verts.reshape(-1, 3), faces


def height_colors(values: np.ndarray, vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    """RGBA in [0, 1] from the viridis colour map, scaled over [vmin, vmax] (default: data range)."""
    from matplotlib import colormaps

    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return np.zeros((0, 4))
    lo = float(np.min(v)) if vmin is None else vmin
    hi = float(np.max(v)) if vmax is None else vmax
    scaled = (v - lo) / (hi - lo) if hi > lo else np.zeros_like(v)
    return np.asarray(colormaps["viridis"](np.clip(scaled, 0.0, 1.0)))


def write_box_ply(path: Path | str, boxes: np.ndarray, colors: np.ndarray | None = None) -> Path:
    """Write boxes as a binary PLY triangle mesh; optional (K, 4) or (K, 3) colours in [0, 1] per box."""
    verts, faces = box_mesh(boxes)
    vcols = None
    if colors is not None:
        c = np.asarray(colors, dtype=np.float64)[:, :3]
        vcols = np.repeat(np.round(c * 255).astype(np.uint8), 8, axis=0)
    return write_ply(path, verts, faces=faces, colors=vcols)
