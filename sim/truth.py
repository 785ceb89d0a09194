"""Ground truth of a scene as a raster: which grid cells hold static scene surface in a height band.

The one rasteriser of the scene truth: the runs' map evaluation compares maps against it, and the
navigation environment builds its free space from it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from sim.scene import Scene, ground_truth_points

_cache: dict[tuple[Any, ...], npt.NDArray[np.bool_]] = {}


def scene_occupancy(scene: Scene, grid: Any, band: tuple[float, float]) -> npt.NDArray[np.bool_]:
    """Cells (bool, ``grid.shape``) holding static scene surface between ``band`` = (z_min, z_max) m.

    Surfaces are sampled about four times per cell side (spacing cell/2, area-weighted), so even a 5 cm
    table leg marks its cell; scripted people are left out. The sampling generator is fixed: the raster
    belongs to the scene, not to a run. Cached per (scene, grid, band); a copy is returned.
    """
    key = (str(scene.path), scene.objects, grid, tuple(band))
    hit = _cache.get(key)
    if hit is not None:
        return hit.copy()
    pts = ground_truth_points(scene, grid.cell_size / 2, np.random.default_rng(0))
    occ = np.zeros(grid.shape, dtype=bool)
    if len(pts):
        pts = pts[(pts[:, 2] >= band[0]) & (pts[:, 2] <= band[1])]
        i, j = grid.world_to_index(pts[:, 0], pts[:, 1])
        ok = (i >= 0) & (i < grid.shape[0]) & (j >= 0) & (j < grid.shape[1])
        occ[i[ok], j[ok]] = True
    _cache[key] = occ
    return occ.copy()
