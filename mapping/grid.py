"""The 2D grid of the variable-height-voxel map: its specification and the world <-> cell indexing.

A :class:`GridSpec` describes a bounded square-cell grid lying in the plane of the two *grid axes*
``(u, v)``; the third, *kept* axis ``h`` keeps the sensor's full definition (SPEC section 2):

========  ==========  ==========  =========
``axis``  ``u``       ``v``       ``h``
========  ==========  ==========  =========
``"z"``   x           y           z (default: heights)
``"x"``   y           z           x (a wall seen from the front keeps its depth)
``"y"``   x           z           y
========  ==========  ==========  =========

Indexing convention (thesis equations 4.2.1-4.2.3, SPEC erratum 4)
-------------------------------------------------------------------
Cells sit on the world lattice of pitch ``cell_size``: lattice cell ``k`` covers
``[k * cell_size, (k + 1) * cell_size)`` along a grid axis, and its centre is ``(k + 0.5) * cell_size``,
which is exactly the value of equation 4.2.1 (``floor(raw / cell_size) * cell_size + cell_size / 2``).

``centre`` is the world position ``(u, v)`` of the middle of the grid. It is snapped to the lattice:
the grid's cell ``i = 0`` is lattice cell ``origin_u = floor(centre_u / cell_size) - nx // 2`` (same for
``v``). Then::

    i = floor(u * (1 / cell_size)) - origin_u    (4.2.1 followed by 4.2.2)
    u_centre = (i + origin_u + 0.5) * cell_size  (4.2.3)

In the thesis's notation this is ``Coord = floor((Val + Centre) / cellSize - 1)`` and
``Val = (Coord + 1.5) * cellSize - Centre`` with ``Centre = (1 - origin) * cellSize``: ``Centre`` is
added in one equation and subtracted in the other (which is consistent), *but* the round trip is
exact only when ``Centre`` is a whole number of cells — with, say, ``cell_size = 1`` and
``Centre = 0.7`` the value 0.5 goes to address 0 and comes back as 0.8. Snapping the centre to the
lattice is where this module differs from the thesis; it makes world -> index -> world return the cell
centre for every in-grid point and any ``centre``, and makes maps built with different centres share
cells. Indices are computed in float64 whatever the input dtype, so a float32 and a float64 copy of a
cloud land in the same cells.

The grid is bounded: points outside ``0 <= i < nx, 0 <= j < ny`` are dropped (and counted by the map).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.errors import GridSpecError

Axis = Literal["x", "y", "z"]

#: For each kept axis, the column indices (u, v, h) of a point (x, y, z).
AXIS_COLUMNS: dict[str, tuple[int, int, int]] = {"z": (0, 1, 2), "x": (1, 2, 0), "y": (0, 2, 1)}

# Grids larger than this many cells would not fit an int32 cell key nor in memory as dense rasters.
_MAX_CELLS = 2**31 - 1


@dataclass(frozen=True)
class GridSpec:
    """A bounded 2D grid of square cells with one kept (full-definition) axis.

    Args:
        cell_size: side of a square cell in metres (> 0).
        size_x: extent of the grid along its first axis ``u`` in metres (x for axis z and y; y for
            axis x); a whole number of cells.
        size_y: extent along the second axis ``v`` in metres (y for axis z; z for axes x and y); a
            whole number of cells.
        centre: world ``(u, v)`` of the middle of the grid (snapped to the cell lattice, see module
            docstring).
        axis: the kept axis, ``"z"`` (default), ``"x"`` or ``"y"``.

    Raises:
        GridSpecError: a field is not finite, not positive, not a whole number of cells, or the grid
            has more than 2**31 - 1 cells.
    """

    cell_size: float = 0.05
    size_x: float = 20.0
    size_y: float = 20.0
    centre: tuple[float, float] = (0.0, 0.0)
    axis: Axis = "z"

    def __post_init__(self) -> None:
        for name in ("cell_size", "size_x", "size_y"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
                raise GridSpecError(f"GridSpec.{name}={value!r}: expected a positive number of metres")
            if not math.isfinite(float(value)) or float(value) <= 0.0:
                raise GridSpecError(f"GridSpec.{name}={value!r}: expected a finite number of metres > 0")
            object.__setattr__(self, name, float(value))
        try:
            cu, cv = (float(c) for c in self.centre)
        except (TypeError, ValueError):
            raise GridSpecError(
                f"GridSpec.centre={self.centre!r}: expected a pair of numbers (u, v) in metres"
            ) from None
        if not (math.isfinite(cu) and math.isfinite(cv)):
            raise GridSpecError(f"GridSpec.centre={self.centre!r}: expected finite coordinates")
        object.__setattr__(self, "centre", (cu, cv))
        if self.axis not in AXIS_COLUMNS:
            raise GridSpecError(f"GridSpec.axis={self.axis!r}: expected one of 'z', 'x', 'y'")
        for name in ("size_x", "size_y"):
            cells = getattr(self, name) / self.cell_size
            if abs(cells - round(cells)) > 1e-6 * max(1.0, cells) or round(cells) < 1:
                raise GridSpecError(
                    f"GridSpec.{name}={getattr(self, name)!r}: expected a whole number (>= 1) of cells of "
                    f"cell_size={self.cell_size!r} (got {cells:.6g} cells)"
                )
        nx, ny = self.shape
        if nx * ny > _MAX_CELLS:
            raise GridSpecError(
                f"GridSpec size {self.size_x!r} x {self.size_y!r} m at cell_size={self.cell_size!r} gives "
                f"{nx * ny} cells; expected at most {_MAX_CELLS}"
            )
        if abs(cu) / self.cell_size > 2**40 or abs(cv) / self.cell_size > 2**40:
            raise GridSpecError(
                f"GridSpec.centre={self.centre!r}: too far from the origin for this cell_size"
            )

    @classmethod
    def covering(
        cls,
        lo: tuple[float, float],
        hi: tuple[float, float],
        cell_size: float,
        margin: float | tuple[float, float] = 0.0,
        axis: Axis = "z",
    ) -> GridSpec:
        """The smallest grid of ``cell_size`` cells that covers the box ``lo``..``hi`` plus ``margin``.

        The box is ``[lo_u - m_u, hi_u + m_u] x [lo_v - m_v, hi_v + m_v]`` in grid coordinates ``(u, v)``
        (world x, y for the default kept axis z); every point of it lies in a cell of the grid, taking
        the snapping of the centre to the lattice into account (see the module docstring), and no row
        or column of cells lies wholly outside it.

        Args:
            lo: ``(u_min, v_min)`` of the box, m.
            hi: ``(u_max, v_max)`` of the box, m (``>= lo``).
            cell_size: Cell side, m (> 0).
            margin: Added on each side, m (>= 0); one value, or one per grid axis ``(m_u, m_v)``.
            axis: The kept axis.

        Raises:
            GridSpecError: A bound or the margin is not finite, ``hi < lo``, the margin is negative,
                or the resulting grid is invalid (see the class).

        Example:
            >>> GridSpec.covering((0.0, 0.0), (1.0, 0.5), 0.5).extent
            (0.0, 1.5, 0.0, 1.0)
        """
        if isinstance(cell_size, bool) or not isinstance(cell_size, int | float) or not cell_size > 0:
            raise GridSpecError(f"GridSpec.covering cell_size={cell_size!r}: expected a number of metres > 0")
        ms = (margin, margin) if isinstance(margin, int | float) else tuple(margin)
        if len(ms) != 2 or not all(math.isfinite(m) and m >= 0 for m in ms):
            raise GridSpecError(f"GridSpec.covering margin={margin!r}: expected finite metres >= 0")
        bounds = [(float(lo[k]), float(hi[k])) for k in range(2)]
        if not all(math.isfinite(a) and math.isfinite(b) and a <= b for a, b in bounds):
            raise GridSpecError(
                f"GridSpec.covering lo={lo!r}, hi={hi!r}: expected finite bounds with lo <= hi"
            )
        ics = 1.0 / cell_size
        cells, centre = [], []
        for (a, b), m in zip(bounds, ms, strict=True):
            # lattice cells holding the box's two ends (the same floor as world_to_index)
            first, last = math.floor((a - m) * ics), math.floor((b + m) * ics)
            n = last - first + 1
            cells.append(n)
            # a centre inside lattice cell first + n // 2 makes cell 0 of the grid lattice cell first
            centre.append((first + n // 2 + 0.5) * cell_size)
        return cls(cell_size, cells[0] * cell_size, cells[1] * cell_size, (centre[0], centre[1]), axis)

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple[int, int]:
        """Number of cells ``(nx, ny)`` along ``(u, v)``."""
        return round(self.size_x / self.cell_size), round(self.size_y / self.cell_size)

    @property
    def inv_cell_size(self) -> float:
        """``1 / cell_size``: indexing multiplies by it, as equation 4.2.1 does."""
        return 1.0 / self.cell_size

    @property
    def origin(self) -> tuple[int, int]:
        """Lattice indices ``(origin_u, origin_v)`` of the grid's cell ``(0, 0)``."""
        nx, ny = self.shape
        # Same float operation as world_to_index, so the centre always lands in cell (nx // 2, ny // 2).
        ics = self.inv_cell_size
        return math.floor(self.centre[0] * ics) - nx // 2, math.floor(self.centre[1] * ics) - ny // 2

    @property
    def columns(self) -> tuple[int, int, int]:
        """Column indices ``(u, v, h)`` into an ``(N, 3)`` xyz array for this kept axis."""
        return AXIS_COLUMNS[self.axis]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """World bounds ``(u_min, u_max, v_min, v_max)`` of the grid (cell edges)."""
        (ou, ov), (nx, ny) = self.origin, self.shape
        cs = self.cell_size
        return ou * cs, (ou + nx) * cs, ov * cs, (ov + ny) * cs

    # ------------------------------------------------------------------ indexing
    def world_to_index(self, u: ArrayLike, v: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Cell indices ``(i, j)`` of world grid-plane coordinates (equations 4.2.1 + 4.2.2).

        Points outside the grid get indices outside ``[0, nx) x [0, ny)``; use :meth:`contains_index`.
        Non-finite inputs give meaningless indices; filter them first.
        """
        ou, ov = self.origin
        with np.errstate(invalid="ignore", over="ignore"):
            ics = self.inv_cell_size
            i = np.floor(np.asarray(u, dtype=np.float64) * ics).astype(np.int64) - ou
            j = np.floor(np.asarray(v, dtype=np.float64) * ics).astype(np.int64) - ov
        return i, j

    def height_index(self, h: ArrayLike) -> NDArray[np.int64]:
        """Standard-voxel lattice index along the kept axis, ``floor(h * (1 / cell_size))``.

        The same binning as :meth:`world_to_index` uses in the grid plane, so cubes line up with cells.
        Every voxel count and voxel list goes through this one function (``floor(h / cs)`` differs
        from it at bin edges, e.g. ``0.7 / 0.1 < 7``).
        """
        with np.errstate(invalid="ignore", over="ignore"):
            return np.floor(np.asarray(h, dtype=np.float64) * self.inv_cell_size).astype(np.int64)

    def index_to_world(self, i: ArrayLike, j: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """World ``(u, v)`` of the centres of cells ``(i, j)`` (equation 4.2.3)."""
        ou, ov = self.origin
        cs = self.cell_size
        u = (np.asarray(i, dtype=np.int64) + ou + 0.5) * cs
        v = (np.asarray(j, dtype=np.int64) + ov + 0.5) * cs
        return np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)

    def contains_index(self, i: ArrayLike, j: ArrayLike) -> NDArray[np.bool_]:
        """True where ``(i, j)`` addresses a cell of this (bounded) grid."""
        nx, ny = self.shape
        i, j = np.asarray(i), np.asarray(j)
        return (i >= 0) & (i < nx) & (j >= 0) & (j < ny)

    # ------------------------------------------------------------------ frames
    def to_grid_frame(self, xyz: ArrayLike) -> NDArray[np.float64]:
        """Reorder xyz coordinates (..., 3) into grid-frame ``(u, v, h)`` (float64)."""
        a = np.asarray(xyz, dtype=np.float64)
        return a[..., list(self.columns)]

    def to_world_frame(self, uvh: ArrayLike) -> NDArray[np.float64]:
        """Inverse of :meth:`to_grid_frame`: grid-frame ``(u, v, h)`` (..., 3) back to xyz."""
        a = np.asarray(uvh, dtype=np.float64)
        out = np.empty_like(a)
        out[..., list(self.columns)] = a
        return out


def voxel_filter(points: ArrayLike, size: float, t_lattice: ArrayLike | None = None) -> NDArray[np.float32]:
    """One measured point per cubic voxel of side ``size``: the first of each voxel, in input order.

    PCL's ``VoxelGrid`` keeps each voxel's centroid instead; a centroid moves up to half a voxel away
    from the points, across the border of a map cell, while a measured point stays in the map cell it
    was seen in. Voxels sit on the lattice ``floor(T p / size)`` of the frame ``t_lattice`` maps the
    points into (e.g. ``T_base_sensor``: voxel heights on the lattice of the map's height bands), while
    the kept points stay in their own frame. Non-finite points are dropped.

    Args:
        points: ``(..., 3)`` coordinates, m (an organized ``(H, W, 3)`` frame is flattened row by row).
        size: Voxel side, m (> 0).
        t_lattice: ``(4, 4)`` transform into the lattice's frame (default: the points' own frame).

    Returns:
        ``(M, 3)`` float32 points, M at most the number of finite points.

    Raises:
        ValueError: ``size`` is not a positive finite number, or the last axis is not 3.
    """
    if not (math.isfinite(size) and size > 0):
        raise ValueError(f"voxel_filter size={size!r}: expected a voxel side in metres > 0")
    p = np.asarray(points)
    if p.shape[-1:] != (3,):
        raise ValueError(f"voxel_filter points: expected shape (..., 3), got {p.shape}")
    p = p.reshape(-1, 3)
    t = np.eye(4) if t_lattice is None else np.asarray(t_lattice, dtype=np.float64)
    if p.dtype in (np.float32, np.float64) and p.shape[0]:
        from mapping._voxel_first import first_per_voxel  # one pass with a hash table: no sort

        keep = np.empty(p.shape[0], np.int64)
        m = first_per_voxel(
            p, np.ascontiguousarray(t[:3, :3]), np.ascontiguousarray(t[:3, 3]), 1.0 / size, keep
        )
        if m >= 0:
            return np.asarray(p[keep[:m]], dtype=np.float32)
    # other dtypes, and voxel indices beyond the kernel's packing: sort the voxel keys
    p = p[np.isfinite(p).all(axis=1)]
    if not len(p):
        return np.empty((0, 3), dtype=np.float32)
    q = p.astype(np.float64)
    if t_lattice is not None:
        q = q @ t[:3, :3].T + t[:3, 3]
    keys = np.floor(q * (1.0 / size)).astype(np.int64)
    keys -= keys.min(axis=0)
    span = keys.max(axis=0) + 1
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]  # one integer per voxel
    _, first = np.unique(flat, return_index=True)
    return np.asarray(p[np.sort(first)], dtype=np.float32)
