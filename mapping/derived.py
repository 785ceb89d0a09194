"""Maps derived from the variable-height structures (thesis Fig. 4.3, 5.14; SPEC section 2).

All functions read a :class:`mapping.vhv.VHVMap` and are vectorised over its structures:

* :func:`occupancy_2d` — a 2D grid, a cell occupied when one of its structures overlaps a height band
  (e.g. floor clearance to chair height);
* :func:`elevation` — 2.5D: highest top and lowest bottom per cell;
* :func:`voxels` / :func:`voxel_centres` — the standard cubic voxels of side ``cell_size`` the same
  structures occupy (for comparison and export);
* :func:`vhv_boxes` — one world-frame box per structure;
* :func:`free_space` — free structures between the sensor and each occupied structure (Fig. 5.14);
* :func:`occupancy_probability` — occupied / (occupied + free) extent per cell (thesis future work 6.2);
* :func:`occupancy_codes` — the three-valued 2D map (``nav_msgs/OccupancyGrid`` -1 / 0 / 100) of either
  map kind: the evidence of a :class:`mapping.probabilistic.ProbabilisticVHV`, or what the
  accumulate-only map can tell (seen structures, free space from one sensor origin).

The functions take a :class:`mapping.vhv.VHVMap` or a :class:`mapping.probabilistic.ProbabilisticVHV`
(whose ``structures()`` are its occupied intervals). Elevation is NaN where a cell holds no occupied
structure: unknown (or, for the probabilistic map, known free with no surface).

"Height" means the kept axis of the grid (z for the default axis); bands and heights are in metres.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.errors import MappingError
from mapping.vhv import Structures, VHVMap


def _first_last(keys: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Index of the first and of the last structure of every occupied cell (keys are sorted)."""
    if keys.shape[0] == 0:
        e = np.empty(0, np.int64)
        return e, e
    change = np.flatnonzero(keys[1:] != keys[:-1]) + 1
    first = np.r_[0, change]
    last = np.r_[change - 1, keys.shape[0] - 1]
    return first, last


def occupancy_2d(m: VHVMap, z_min: float, z_max: float) -> NDArray[np.bool_]:
    """2D occupancy ``(nx, ny)``: True where a structure overlaps the band ``[z_min, z_max]``.

    A structure ``[bottom, top]`` overlaps the band when ``top >= z_min`` and ``bottom <= z_max``:
    a wheelchair hits a table top between floor clearance and its own height, not the floor.

    Raises:
        MappingError: the band is not finite or ``z_min > z_max``.
    """
    if not (math.isfinite(z_min) and math.isfinite(z_max)) or z_min > z_max:
        raise MappingError(f"occupancy band [{z_min!r}, {z_max!r}]: expected finite z_min <= z_max")
    grid = np.zeros(m.spec.shape, dtype=bool)
    if type(m) is VHVMap:  # its sorted cell keys i * ny + j are the grid's flat indices: no (i, j) split
        from mapping._derived_kernels import mark_band

        mark_band(m._key, m._bottom, m._top, z_min, z_max, grid.reshape(-1))
        return grid
    s = m.structures()
    hit = (s.top >= z_min) & (s.bottom <= z_max)
    grid[s.i[hit], s.j[hit]] = True
    return grid


def occupancy_codes(
    m: object,
    band: tuple[float, float],
    unknown: int = -1,
    sensor_origin: ArrayLike | None = None,
) -> NDArray[np.int8]:
    """Three-valued 2D map ``(nx, ny)`` int8 of a height band: 100 occupied, 0 free, ``unknown`` else.

    Args:
        m: a :class:`mapping.probabilistic.ProbabilisticVHV` (its evidence decides) or a
            :class:`mapping.vhv.VHVMap` (a structure in the band: occupied; a cell holding only
            structures outside the band, or crossed by :func:`free_space` from ``sensor_origin``: free).
        band: ``(z_min, z_max)`` metres along the kept axis.
        unknown: the code for unknown cells: -1 (default), or 100 / 0 to plan as blocked / free.
        sensor_origin: only for the accumulate-only map, see above.

    Raises:
        MappingError: a malformed band or ``unknown`` value.
    """
    if unknown not in (-1, 0, 100):
        raise MappingError(f"occupancy_codes unknown={unknown!r}: expected -1, 0 or 100")
    occupancy_2d_three = getattr(m, "occupancy_2d", None)
    if occupancy_2d_three is not None:
        return np.asarray(occupancy_2d_three(band, unknown=unknown), dtype=np.int8)
    if not isinstance(m, VHVMap):
        raise MappingError(f"occupancy_codes: expected a VHVMap or ProbabilisticVHV, got {type(m).__name__}")
    occ = occupancy_2d(m, float(band[0]), float(band[1]))
    codes = np.full(m.spec.shape, unknown, dtype=np.int8)
    s = m.structures()
    codes[s.i, s.j] = 0
    if sensor_origin is not None and m.n_structures:
        fi, fj = free_cells(m, sensor_origin)  # the cells of free_space(m, sensor_origin)
        codes[fi, fj] = 0
    codes[occ] = 100
    return codes


def elevation(m: VHVMap) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """2.5D elevation: ``(top_max, bottom_min)`` per cell, each ``(nx, ny)`` float64, NaN where empty."""
    s = m.structures()
    top_max = np.full(m.spec.shape, np.nan)
    bottom_min = np.full(m.spec.shape, np.nan)
    first, last = _first_last(m.cell_keys)
    # Structures of a cell are disjoint and sorted by bottom, so the last one has the highest top.
    top_max[s.i[last], s.j[last]] = s.top[last]
    bottom_min[s.i[first], s.j[first]] = s.bottom[first]
    return top_max, bottom_min


def voxels(m: VHVMap) -> NDArray[np.int64]:
    """Standard voxels ``(K, 3)`` int64 ``(i, j, k)`` covering the structures, unique, sorted.

    ``k = floor(h / cell_size)`` is the lattice index along the kept axis (voxel centre at
    ``(k + 0.5) * cell_size``), the same binning as the grid's. ``K == m.n_voxels``.
    """
    s = m.structures()
    if len(s) == 0:
        return np.empty((0, 3), np.int64)
    kb = m.spec.height_index(s.bottom)
    kt = m.spec.height_index(s.top)
    counts = kt - kb + 1
    idx = np.repeat(np.arange(len(s)), counts)
    k = kb[idx] + (np.arange(idx.shape[0]) - np.repeat(np.cumsum(counts) - counts, counts))
    out = np.stack([s.i[idx].astype(np.int64), s.j[idx].astype(np.int64), k], axis=1)
    # Two structures of one cell may touch the same cube (when tolerance < cell_size): keep it once.
    keep = np.ones(out.shape[0], bool)
    keep[1:] = np.any(out[1:] != out[:-1], axis=1)
    return out[keep]


def voxel_centres(m: VHVMap) -> NDArray[np.float64]:
    """World xyz ``(K, 3)`` of the centres of :func:`voxels`."""
    v = voxels(m)
    u, w = m.spec.index_to_world(v[:, 0], v[:, 1])
    h = (v[:, 2] + 0.5) * m.spec.cell_size
    return m.spec.to_world_frame(np.stack([u, w, h], axis=1))


def vhv_boxes(m: VHVMap) -> NDArray[np.float64]:
    """One box per structure: ``(K, 2, 3)`` world-frame ``[min_xyz, max_xyz]`` corners.

    Across the grid the box spans its cell; along the kept axis it spans ``[bottom, top]`` exactly
    (zero thickness for a single-height structure).
    """
    s = m.structures()
    cs = m.spec.cell_size
    u, v = m.spec.index_to_world(s.i, s.j)
    lo = np.stack([u - cs / 2, v - cs / 2, s.bottom], axis=1)
    hi = np.stack([u + cs / 2, v + cs / 2, s.top], axis=1)
    return np.stack([m.spec.to_world_frame(lo), m.spec.to_world_frame(hi)], axis=1)


def _sensor_uvh(m: VHVMap, sensor_origin: ArrayLike | None) -> NDArray[np.float64]:
    if sensor_origin is None:
        if not m.sensor_origins:
            raise MappingError("free_space: no sensor_origin given and none was recorded by VHVMap.insert")
        sensor_origin = m.sensor_origins[-1]
    o = np.asarray(sensor_origin, dtype=np.float64).reshape(-1)
    if o.shape != (3,) or not bool(np.all(np.isfinite(o))):
        raise MappingError(f"free_space sensor_origin={sensor_origin!r}: expected finite (x, y, z) in metres")
    return m.spec.to_grid_frame(o)


def _crossings(
    start: float, ends: NDArray[np.float64], ics: float
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Ray ids and parameters ``s`` in (0, 1) where segments start -> ends cross grid lines of one axis."""
    k0 = math.floor(start * ics)
    k1 = np.floor(ends * ics).astype(np.int64)
    n = np.abs(k1 - k0)
    ray = np.repeat(np.arange(ends.shape[0]), n)
    step = np.arange(ray.shape[0]) - np.repeat(np.cumsum(n) - n, n)
    # Moving up we cross lines k0+1, k0+2, ...; moving down, lines k0, k0-1, ...
    up = k1[ray] > k0
    line = np.where(up, k0 + 1 + step, k0 - step).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (line / ics - start) / (ends[ray] - start)
    return ray, s


def free_space(m: VHVMap, sensor_origin: ArrayLike | None = None, merge: bool = True) -> Structures:
    """Free structures between the sensor and every occupied structure (thesis Fig. 5.14).

    From the sensor centre two lines go to the top and to the bottom of each occupied structure (at
    its cell centre). Every cell the segment crosses in the grid plane before reaching the structure's
    cell gets one free structure from the bottom line to the top line, both evaluated at the middle of
    the segment's passage through that cell ("one point per line and per cell"). Cells crossed only
    at a corner are skipped; cells outside the grid are dropped.

    Args:
        m: the map.
        sensor_origin: world xyz of the sensor; defaults to the last origin given to ``m.insert``.
        merge: join overlapping or touching free structures of a cell (thesis future work 6.2: the
            raw method overlaps when obstacles lie behind each other). With False every ray's free
            structure is returned, sorted by cell then bottom.

    Returns:
        Free structures (same SoA layout as the map's).

    Raises:
        MappingError: no sensor origin is known or it is not a finite xyz.
    """
    s = m.structures()
    if len(s) == 0:
        _sensor_uvh(m, sensor_origin)  # the same errors as with structures
        return Structures.empty()
    sh, i, j, ray, mid = _free_passages(m, s, sensor_origin)
    spec = m.spec
    bottom = sh + mid * (s.bottom[ray] - sh)
    top = sh + mid * (s.top[ray] - sh)
    key = i * spec.shape[1] + j
    order = np.lexsort((bottom, key))
    key, bottom, top = key[order], bottom[order], top[order]
    if merge and key.shape[0]:
        key, bottom, top = _union_intervals(key, bottom, top)
    ny = spec.shape[1]
    return Structures.from_bounds(key // ny, key % ny, bottom, top)


def free_cells(
    m: VHVMap, sensor_origin: ArrayLike | None = None
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Grid indices ``(i, j)`` (M,) each of the cells holding a :func:`free_space` structure, with
    repeats (one per passage of a line through the cell), in no particular order.

    The cells of ``free_space(m, sensor_origin)`` without its heights, sort by height and merge (two
    thirds of its time on a map of 8 000 structures): what a 2D map needs.

    Raises:
        MappingError: no sensor origin is known or it is not a finite xyz.
    """
    s = m.structures()
    if len(s) == 0:
        _sensor_uvh(m, sensor_origin)
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    _sh, i, j, _ray, _mid = _free_passages(m, s, sensor_origin)
    return i, j


def _free_passages(
    m: VHVMap, s: Structures, sensor_origin: ArrayLike | None
) -> tuple[float, NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """``(sh, i, j, ray, mid)``: the sensor's height and, for each passage of a sensor-to-structure line
    through a grid cell inside the grid, the cell ``(i, j)``, the structure ``ray`` of ``s`` (a
    non-empty ``m.structures()``) and the line parameter ``mid`` of the passage's middle."""
    su, sv, sh = _sensor_uvh(m, sensor_origin)
    spec = m.spec
    ics = spec.inv_cell_size
    cu, cv = spec.index_to_world(s.i, s.j)
    ray_u, s_u = _crossings(su, cu, ics)
    ray_v, s_v = _crossings(sv, cv, ics)
    ray = np.concatenate([ray_u, ray_v])
    par = np.concatenate([s_u, s_v])
    order = np.lexsort((par, ray))
    ray, par = ray[order], par[order]
    prev = np.empty_like(par)
    prev[0:1] = 0.0
    prev[1:] = np.where(ray[1:] == ray[:-1], par[:-1], 0.0)
    keep = par > prev  # zero-length passages: the line went exactly through a cell corner
    ray, mid = ray[keep], (par[keep] + prev[keep]) / 2.0
    pu = su + mid * (cu[ray] - su)
    pv = sv + mid * (cv[ray] - sv)
    i, j = spec.world_to_index(pu, pv)
    inside = spec.contains_index(i, j)
    return float(sh), i[inside], j[inside], ray[inside], mid[inside]


def _union_intervals(
    key: NDArray[np.int64], bottom: NDArray[np.float64], top: NDArray[np.float64]
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Union of overlapping/touching intervals per key (input sorted by key then bottom)."""
    from mapping import _vhv_kernels as K

    e = np.empty(0)
    # A gap <= 0 joins, i.e. overlapping or touching intervals.
    k, b, t = K.merge_structures(np.empty(0, np.int64), e, e, key, bottom, top, 0.0)
    return k, b, t


def occupancy_probability(
    m: VHVMap, free: Structures | None = None, sensor_origin: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Per-cell occupancy probability ``occupied / (occupied + free)`` extents along the kept axis.

    Occupied extent is the summed height of the cell's structures, each at least ``cell_size`` thick
    (a single-height structure is a surface seen at the sensor's resolution); free extent is the
    summed height of the (merged) free structures. Cells with neither are NaN (unknown).
    """
    if free is None:
        free = free_space(m, sensor_origin)
    shape = m.spec.shape
    cs = m.spec.cell_size
    occ = np.zeros(shape)
    fre = np.zeros(shape)
    s = m.structures()
    np.add.at(occ, (s.i, s.j), np.maximum(s.top - s.bottom, cs))
    np.add.at(fre, (free.i, free.j), free.top - free.bottom)
    total = occ + fre
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.where(total > 0, occ / total, np.nan)
    return p
