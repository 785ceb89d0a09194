"""Everything written out of a VHV map: pictures, map_server files, PLY meshes, a ROS 2 bag, summary.json.

:func:`write_map_outputs` writes the whole set into one folder (pair it with
``robchair.outdir.staged_output_dir`` for all-or-nothing output). The lower-level writers live in
:mod:`mapping.export.pictures`, :mod:`mapping.export.rosmap` and :mod:`mapping.export.meshes`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from mapping.export.meshes import height_colors, write_box_ply
from mapping.export.rosmap import FREE, OCCUPIED, UNKNOWN, write_map_server, write_ros2_map_bag

__all__ = ["DEFAULT_BAND", "map_codes", "voxel_boxes", "write_map_outputs"]

#: Default 2D band (kept-axis metres): above floor clutter, up to a seated person's head on the chair.
DEFAULT_BAND = (0.10, 1.50)

OUTPUT_FILES = {
    "occupancy_png": "occupancy.png",
    "elevation_png": "elevation.png",
    "vhv_3d_png": "vhv_3d.png",
    "map_pgm": "map.pgm",
    "map_yaml": "map.yaml",
    "vhv_ply": "vhv_boxes.ply",
    "voxels_ply": "voxels.ply",
    "ros2_bag": "map_bag",
    "summary": "summary.json",
}


def map_codes(m: Any, band: tuple[float, float], sensor_origin: Any = None) -> np.ndarray:
    """Ternary 2D map (nx, ny) int8 (-1 unknown, 0 free, 100 occupied) of the height ``band``.

    For a :class:`mapping.probabilistic.ProbabilisticVHV` this is its evidence
    (:meth:`~mapping.probabilistic.ProbabilisticVHV.occupancy_2d`: occupied intervals, remembered free
    space, unknown where no evidence came). For the accumulate-only :class:`mapping.vhv.VHVMap`: 100
    where a structure overlaps ``band``, 0 where the cell was seen and nothing in the band blocks it (it
    holds only structures outside the band, or free space from ``sensor_origin``), -1 elsewhere."""
    from mapping.derived import occupancy_codes

    return occupancy_codes(m, band, UNKNOWN, sensor_origin)


def voxel_boxes(m: Any) -> np.ndarray:
    """(K, 2, 3) world min/max corners of the standard voxels of ``mapping.derived.voxels``."""
    from mapping.derived import voxels

    idx = np.asarray(voxels(m), dtype=np.int64).reshape(-1, 3)
    cs = m.spec.cell_size
    u, v = m.spec.index_to_world(idx[:, 0], idx[:, 1])
    uvh = np.stack([u - cs / 2, v - cs / 2, idx[:, 2] * cs], axis=1)
    lo = m.spec.to_world_frame(uvh)
    return np.stack([lo, lo + cs], axis=1)


def write_map_outputs(
    m: Any,
    out_dir: Path | str,
    *,
    band: tuple[float, float] = DEFAULT_BAND,
    sensor_origin: Any = None,
    frame_id: str = "map",
    points_dropped_min_range: int = 0,
    stamp_ns: int = 0,
    build_ms: float | None = None,
    parameters: dict[str, Any] | None = None,
    max_boxes_3d: int = 1500,
    bag_storage: str = "sqlite3",
    extra: dict[str, Any] | None = None,
    pictures: bool = True,
) -> dict[str, Any]:
    """Write pictures, map_server PGM + YAML, PLY meshes, a ROS 2 bag and ``summary.json`` for a map.

    Args:
        m: A :class:`mapping.vhv.VHVMap`.
        out_dir: Existing folder to write into.
        band: Kept-axis interval (metres) that makes a cell occupied in the 2D map.
        sensor_origin: World xyz of the sensor; adds ray-traced free space to the 2D map.
        frame_id: Frame of the ROS messages.
        points_dropped_min_range: Points dropped before insertion for being closer to the sensor
            than the minimum range (counted in ``points_in`` like the map's own drops).
        stamp_ns: Stamp of the ROS messages.
        build_ms: Total insert time to report (the map does not time itself across frames).
        parameters: Extra entries for the summary's ``parameters``.
        max_boxes_3d: Cap on boxes drawn in the 3D picture (the PLY and the bag hold all).
        bag_storage: ``sqlite3`` (default of ROS 2 Humble) or ``mcap``.
        extra: Further top-level entries of the summary (after ``parameters``).
        pictures: Draw the three PNG pictures (matplotlib: most of the time spent here).

    Returns:
        The summary written to ``summary.json``.
    """
    from mapping.derived import elevation, vhv_boxes
    from mapping.export.pictures import boxes_3d_png, elevation_png, occupancy_png

    out = Path(out_dir)
    spec = m.spec
    if not band[0] <= band[1]:
        from mapping.errors import MappingError

        raise MappingError(f"2D band [{band[0]}, {band[1]}]: expected min <= max")
    extent = spec.extent  # (u_min, u_max, v_min, v_max), cell edges
    sensor_uv = None
    if sensor_origin is not None:
        so = np.asarray(sensor_origin, dtype=np.float64)
        sensor_uv = (float(so[spec.columns[0]]), float(so[spec.columns[1]]))
    codes = map_codes(m, band, sensor_origin)
    top_max, bottom_min = elevation(m)
    boxes = np.asarray(vhv_boxes(m), dtype=np.float64).reshape(-1, 2, 3)
    h_col = spec.columns[2]
    colors = height_colors(boxes[:, 1, h_col])
    vboxes = voxel_boxes(m)

    drawn = None
    if pictures:
        occupancy_png(
            out / OUTPUT_FILES["occupancy_png"], codes, extent, axis=spec.axis, band=band, sensor_uv=sensor_uv
        )
        elevation_png(out / OUTPUT_FILES["elevation_png"], top_max, bottom_min, extent, axis=spec.axis,
                      sensor_uv=sensor_uv)  # fmt: skip
        _, drawn = boxes_3d_png(out / OUTPUT_FILES["vhv_3d_png"], boxes, max_boxes=max_boxes_3d)
    write_map_server(out, codes, spec.cell_size, (extent[0], extent[2]), name="map")
    write_box_ply(out / OUTPUT_FILES["vhv_ply"], boxes, colors)
    write_box_ply(out / OUTPUT_FILES["voxels_ply"], vboxes, height_colors(vboxes[:, 1, h_col]))
    write_ros2_map_bag(
        out / OUTPUT_FILES["ros2_bag"],
        codes=codes,
        resolution=spec.cell_size,
        origin_xy=(extent[0], extent[2]),
        boxes=boxes,
        colors=colors,
        frame_id=frame_id,
        stamp_ns=stamp_ns,
        storage=bag_storage,
    )
    points_in = int(
        m.points_inserted + m.points_dropped_nonfinite + m.points_outside_grid + points_dropped_min_range
    )
    summary: dict[str, Any] = {
        "points_in": points_in,
        "points_dropped_min_range": int(points_dropped_min_range),
        "points_dropped_nonfinite": int(m.points_dropped_nonfinite),
        "points_outside_grid": int(m.points_outside_grid),
        "points_inserted": int(m.points_inserted),
        "frames": int(m.frames),
        "cells_occupied": int(m.n_cells_occupied),
        "structures": int(m.n_structures),
        "voxels": int(m.n_voxels),
        "voxels_exported": int(vboxes.shape[0]),
        "cells_occupied_2d": int(np.count_nonzero(codes == OCCUPIED)),
        "cells_free_2d": int(np.count_nonzero(codes == FREE)),
        "cells_unknown_2d": int(np.count_nonzero(codes == UNKNOWN)),
        "map_kind": "probabilistic" if hasattr(m, "occupancy_2d") else "thesis",
        "build_ms": None if build_ms is None else float(build_ms),
        "boxes_drawn_3d": drawn,
        "parameters": {
            "cell_size": spec.cell_size,
            "tolerance": float(m.tolerance),
            "axis": spec.axis,
            "band": [float(band[0]), float(band[1])],
            "grid_size": [spec.size_x, spec.size_y],
            "grid_shape": list(spec.shape),
            "grid_centre": list(spec.centre),
            "grid_extent": list(extent),
            "sensor_origin": None if sensor_origin is None else [float(v) for v in np.asarray(sensor_origin)],
            "frame_id": frame_id,
            **(parameters or {}),
        },
        **(extra or {}),
        "outputs": {k: v for k, v in OUTPUT_FILES.items() if pictures or not k.endswith("_png")},
    }
    (out / OUTPUT_FILES["summary"]).write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return summary
