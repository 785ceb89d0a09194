"""PNG pictures of a map (matplotlib, Agg backend): 2D occupancy, elevation, 3D view of the VHV boxes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mapping.export.rosmap import FREE, OCCUPIED

_AXIS_NAMES = {"z": ("x", "y", "z"), "x": ("y", "z", "x"), "y": ("x", "z", "y")}


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _mark_origin_and_sensor(ax: Any, sensor_uv: tuple[float, float] | None) -> None:
    ax.plot([0.0], [0.0], marker="+", color="tab:blue", markersize=12, mew=2, label="world origin")
    if sensor_uv is not None:
        ax.plot([sensor_uv[0]], [sensor_uv[1]], marker="^", color="tab:red", markersize=9, label="sensor")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.1), fontsize=8, ncol=2, frameon=False)


def occupancy_png(
    path: Path | str,
    codes: np.ndarray,
    extent: tuple[float, float, float, float],
    *,
    axis: str = "z",
    band: tuple[float, float] | None = None,
    sensor_uv: tuple[float, float] | None = None,
) -> Path:
    """Draw the ternary 2D map (black occupied, white free, grey unknown) with axes in metres."""
    plt = _pyplot()
    c = np.asarray(codes)
    shade = np.full(c.shape, 0.8)
    shade[c == FREE] = 1.0
    shade[c == OCCUPIED] = 0.0
    fig, ax = plt.subplots(figsize=(7, 6), dpi=110)
    ax.imshow(
        shade.T, origin="lower", extent=extent, cmap="gray", vmin=0.0, vmax=1.0, interpolation="nearest"
    )
    u, v, h = _AXIS_NAMES[axis]
    ax.set_xlabel(f"{u} (m)")
    ax.set_ylabel(f"{v} (m)")
    title = "2D occupancy (black occupied, white free, grey unknown)"
    if band is not None:
        title += f"\nstructures overlapping {h} in [{band[0]:g}, {band[1]:g}] m"
    ax.set_title(title, fontsize=10)
    _mark_origin_and_sensor(ax, sensor_uv)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)


def elevation_png(
    path: Path | str,
    top_max: np.ndarray,
    bottom_min: np.ndarray,
    extent: tuple[float, float, float, float],
    *,
    axis: str = "z",
    sensor_uv: tuple[float, float] | None = None,
) -> Path:
    """Draw the 2.5D elevation map (highest top, lowest bottom per cell) with colour bars in metres."""
    plt = _pyplot()
    u, v, h = _AXIS_NAMES[axis]
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), dpi=110)
    finite = np.concatenate([np.asarray(top_max).ravel(), np.asarray(bottom_min).ravel()])
    finite = finite[np.isfinite(finite)]
    vmin, vmax = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    for ax, grid, label in (
        (axes[0], top_max, f"highest top {h}"),
        (axes[1], bottom_min, f"lowest bottom {h}"),
    ):
        img = ax.imshow(
            np.ma.masked_invalid(np.asarray(grid, dtype=np.float64)).T,
            origin="lower",
            extent=extent,
            cmap="viridis",
            vmin=vmin,
            vmax=vmax,
            interpolation="nearest",
        )
        ax.set_facecolor("0.85")
        ax.set_xlabel(f"{u} (m)")
        ax.set_ylabel(f"{v} (m)")
        ax.set_title(f"2.5D elevation: {label} (grey = no surface: unknown or free)", fontsize=10)
        fig.colorbar(img, ax=ax, label=f"{h} (m)")
        _mark_origin_and_sensor(ax, sensor_uv)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)


def boxes_3d_png(
    path: Path | str,
    boxes: np.ndarray,
    *,
    max_boxes: int = 1500,
    title: str = "variable-height voxels",
) -> tuple[Path, int]:
    """Draw the VHV boxes (K, 2, 3) in 3D, coloured by height; at most ``max_boxes`` (the tallest).

    Returns:
        The path and how many boxes were drawn.
    """
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from mapping.export.meshes import _CORNERS, height_colors

    plt = _pyplot()
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3)
    k = b.shape[0]
    if k > max_boxes:
        # The tallest boxes carry the obstacles; thin floor slabs are what a capped view can drop.
        tallest = np.argsort(-(b[:, 1, 2] - b[:, 0, 2]), kind="stable")[:max_boxes]
        b = b[np.sort(tallest)]
    fig = plt.figure(figsize=(8, 7), dpi=110)
    ax = fig.add_subplot(projection="3d")
    if b.shape[0]:
        corners = b[:, _CORNERS, np.arange(3)]  # (K, 8, 3)
        quads = np.array([[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]])
        faces = corners[:, quads].reshape(-1, 4, 3)
        cols = np.repeat(height_colors(b[:, 1, 2]), 6, axis=0)
        ax.add_collection3d(
            Poly3DCollection(faces, facecolors=cols, edgecolors=(0, 0, 0, 0.25), linewidths=0.2)
        )
        lo, hi = b[:, 0].min(axis=0), b[:, 1].max(axis=0)
        span = np.maximum(hi - lo, 1e-3)
        ax.set_xlim(lo[0], lo[0] + span[0])
        ax.set_ylim(lo[1], lo[1] + span[1])
        ax.set_zlim(lo[2], lo[2] + span[2])
        ax.set_box_aspect(tuple(span / span.max()))  # metres look like metres on every axis
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    shown = b.shape[0]
    label = f"the {shown} tallest of {k} boxes drawn" if shown < k else f"{k} boxes"
    ax.set_title(f"{title}: {label}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path), int(shown)
