"""Geometry of the navigation task (pure functions and the scene's free space): goal in the robot's
frame, egocentric patches of a world grid, depth noise of a decimated Kinect, where the chair fits."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from mapping.grid import GridSpec
from robchair.platform.kinematics import Pose2D, wrap_angle
from sim.envs.errors import NavigationEnvError
from sim.scene import Scene

PATCH_SHAPE = (64, 64)
PATCH_CELL = 0.10  # m
PATCH_BEHIND = 1.6  # m of the patch behind base_link (the Kinect looks forward)


def goal_in_robot_frame(pose: Pose2D, goal: tuple[float, float]) -> tuple[float, float]:
    """Distance (m) and bearing (rad, (-pi, pi], counter-clockwise from the robot's x axis) of the goal."""
    dx, dy = goal[0] - pose.x, goal[1] - pose.y
    return math.hypot(dx, dy), wrap_angle(math.atan2(dy, dx) - pose.theta)


def patch_cell_centres(
    shape: tuple[int, int], cell: float, behind: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Robot-frame (x, y) of every patch cell centre: row ``i`` runs forward, column ``j`` to the left.

    Row 0 starts ``behind`` metres behind base_link; the columns are centred on the robot's x axis.
    The arrays are read-only (one pair per patch geometry, made once: every step crops a patch).
    """
    return _cell_centres((int(shape[0]), int(shape[1])), float(cell), float(behind))


@functools.lru_cache(maxsize=16)
def _cell_centres(
    shape: tuple[int, int], cell: float, behind: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    h, w = shape
    fx = -behind + (np.arange(h) + 0.5) * cell
    ly = (np.arange(w) + 0.5 - w / 2) * cell
    x, y = np.meshgrid(fx, ly, indexing="ij")
    x.flags.writeable = False
    y.flags.writeable = False
    return x, y


def egocentric_values(
    values: npt.NDArray[Any],
    grid: GridSpec,
    pose: Pose2D,
    shape: tuple[int, int],
    cell: float,
    behind: float,
    fill: float = 0.0,
    *,
    compiled: bool = True,
) -> npt.NDArray[Any]:
    """Like :func:`egocentric_patch` for any per-cell values (``fill`` outside the grid)."""
    return _crop(values, grid, pose, shape, cell, behind, fill, values.dtype, compiled)


def _crop(values: Any, grid: GridSpec, pose: Pose2D, shape: tuple[int, int], cell: float, behind: float,
          fill: float, dtype: Any, compiled: bool) -> npt.NDArray[Any]:  # fmt: skip
    """``compiled``: one pass (:mod:`sim.envs._patch_kernels`); False: numpy (the tests' reference)."""
    x, y = patch_cell_centres(shape, cell, behind)
    if compiled and values.ndim == 2 and all(math.isfinite(v) for v in (pose.x, pose.y, pose.theta)):
        from sim.envs._patch_kernels import crop

        return crop(values, x, y, (pose.x, pose.y, pose.theta), grid.inv_cell_size, grid.origin, fill, dtype)
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    i, j = grid.world_to_index(pose.x + c * x - s * y, pose.y + s * x + c * y)
    inside = grid.contains_index(i, j)
    out = np.full(shape, fill, dtype=dtype)
    out[inside] = values[i[inside], j[inside]]
    return out


def egocentric_patch(
    occupancy: npt.NDArray[np.bool_],
    grid: GridSpec,
    pose: Pose2D,
    shape: tuple[int, int] = PATCH_SHAPE,
    cell: float = PATCH_CELL,
    behind: float = PATCH_BEHIND,
    *,
    compiled: bool = True,
) -> npt.NDArray[np.uint8]:
    """Crop the world-frame occupancy grid into the robot's frame (nearest cell, outside the grid = 0).

    Args:
        occupancy: ``(nx, ny)`` bool grid of ``grid``.
        grid: The grid's spec (axis z).
        pose: The robot's pose.
        shape: Patch size ``(rows forward, columns lateral)``.
        cell: Patch cell size, m.
        behind: Metres of the patch behind base_link.

    Returns:
        ``shape`` uint8 array, 1 = occupied; ``[i, j]`` is the cell at robot-frame
        ``x = -behind + (i + 0.5) cell``, ``y = (j + 0.5 - shape[1] / 2) cell``.
    """
    return _crop(np.asarray(occupancy), grid, pose, shape, cell, behind, 0, np.uint8, compiled)


def decimated_depth_noise(
    points: Any, model: Any, rng: np.random.Generator, scale: float = 1.0, *, compiled: bool = True
) -> npt.NDArray[np.float64]:
    """Axial depth noise and quantisation for a clean organized cloud from a reduced-resolution Kinect.

    Each valid pixel's depth ``z`` (its x coordinate, REP-103 camera frame) moves along its own ray by
    ``N(0, sigma_z(z, theta)^2)`` with the model's axial noise
    (:func:`sim.kinect.fankhauser2015_axial_sigma_m` for the v2,
    :func:`sim.kinect.nguyen2012_axial_sigma_m` for the v1), ``theta`` the angle between
    the ray and the surface normal estimated from the cloud itself (0 where undefined), then is
    rounded like the device's output. Lateral noise (1.6 px of the full 512x424 image for the v2, i.e.
    under half a pixel once decimated 4x) is left out. NaN pixels stay NaN.

    Args:
        points: ``(H, W, 3)`` clean cloud in the camera frame.
        model: The :class:`sim.kinect.KinectModel` (noise model and quantisation).
        rng: Generator; draws one standard normal per pixel.
        scale: Factor on the axial standard deviation (domain randomisation).
        compiled: one compiled pass (:mod:`sim._decimated_kernels`, default); False runs the same
            formulas through the documented numpy functions (the reference the tests compare with).
    """
    from sim.kinect import (
        fankhauser2015_axial_sigma_m,
        nguyen2012_axial_sigma_m,
        organized_normals,
        quantize_depth,
    )

    p = np.asarray(points, dtype=np.float64)
    z = p[..., 0]
    if compiled and p.ndim == 3 and p.shape[-1] == 3:
        from sim._decimated_kernels import axial_noise
        from sim.kinect_params import NOISE_CODES, QUANT_CODES

        draws = scale * rng.standard_normal(z.shape)
        return axial_noise(  # type: ignore[no-any-return]
            np.ascontiguousarray(p), draws, NOISE_CODES[model.noise_model], QUANT_CODES[model.quantization]
        )
    normals = organized_normals(p)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_t = np.abs(np.einsum("...k,...k->...", normals, p)) / np.linalg.norm(p, axis=-1)
    theta = np.where(np.isfinite(cos_t), np.arccos(np.clip(cos_t, 0.0, 1.0)), 0.0)
    axial = (
        fankhauser2015_axial_sigma_m if model.noise_model == "fankhauser2015" else nguyen2012_axial_sigma_m
    )
    noise = scale * rng.standard_normal(z.shape)
    with np.errstate(invalid="ignore"):
        zn = quantize_depth(z + axial(np.where(np.isfinite(z), z, 1.0), theta) * noise, model.quantization)
        return p * (zn / z)[..., None]


def planar_transform(pose: Pose2D) -> npt.NDArray[np.float64]:
    """4x4 world <- base_link for a pose on the floor."""
    t = np.eye(4)
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:2, 3] = (pose.x, pose.y)
    return t


@dataclass(frozen=True)
class FreeSpace:
    """Where the chair may start and where goals may lie, from the scene's ground truth.

    Attributes:
        grid: The raster's grid (axis z).
        occupied: ``(nx, ny)`` cells holding scene surface in the chair's height band.
        clearance: ``(nx, ny)`` lower bound of the distance (m) from each cell centre to scene surface.
        region: ``(nx, ny)`` one connected region inside the scene's bounds where the chair fits through.
        labels: ``(nx, ny)`` int, the connected regions where the chair fits through (0 = none).
        scene: The scene (for naming the object nearest to a point).
        band: The height band (z_min, z_max) of ``occupied``, m.
    """

    grid: GridSpec
    occupied: npt.NDArray[np.bool_]
    clearance: npt.NDArray[np.float64]
    region: npt.NDArray[np.bool_]
    labels: npt.NDArray[np.int32]
    scene: Scene
    band: tuple[float, float]

    @classmethod
    def from_scene(
        cls,
        scene: Scene,
        grid: GridSpec,
        band: tuple[float, float],
        pass_radius: float,
        anchor: tuple[float, float] | None = None,
    ) -> FreeSpace:
        """The scene's ground truth in ``band`` (:func:`sim.truth.scene_occupancy`) and its free region.

        Args:
            scene: The scene (moving people are left out).
            grid: Raster grid; its cells outside the scene's bounds never belong to the region.
            band: Height band (z_min, z_max) in metres.
            pass_radius: Clearance (m) a cell needs to connect the region (half the chair's width).
            anchor: A point (x, y) the region must contain; None takes the largest region.

        Raises:
            NavigationEnvError: No free region (or the anchor is not in one).
        """
        from scipy import ndimage

        from sim.truth import scene_occupancy

        cs = grid.cell_size
        band = (float(band[0]), float(band[1]))
        occupied = scene_occupancy(scene, grid, band)
        # distance between cell centres, less half a diagonal: the surface may lie anywhere in its cell
        clearance = ndimage.distance_transform_edt(~occupied) * cs - cs * math.sqrt(0.5)
        x0, y0, x1, y1 = scene.bounds_xy()
        ii, jj = np.meshgrid(np.arange(grid.shape[0]), np.arange(grid.shape[1]), indexing="ij")
        u, v = grid.index_to_world(ii, jj)
        in_bounds = (u >= x0) & (u <= x1) & (v >= y0) & (v <= y1)
        passable = (clearance >= pass_radius) & in_bounds
        labels, n = ndimage.label(passable)
        if n == 0:
            raise NavigationEnvError(f"scene {scene.name!r}: no free space wide enough for the chair")
        if anchor is not None:
            ai, aj = grid.world_to_index(anchor[0], anchor[1])
            if not bool(grid.contains_index(ai, aj)) or labels[ai, aj] == 0:
                raise NavigationEnvError(f"scene {scene.name!r}: the point {anchor} is not in free space")
            chosen = int(labels[ai, aj])
        else:
            chosen = int(np.argmax(np.bincount(labels.ravel())[1:])) + 1
        return cls(grid, occupied, clearance, labels == chosen, labels.astype(np.int32), scene, band)

    def nearest_obstacle(self, xy: tuple[float, float]) -> tuple[str, float]:
        """Name of the scene object nearest to ``xy`` in the height band, and its distance (m, cells).

        Each object's cells come from the same rasteriser as ``occupied`` (that object alone).
        """
        from sim.truth import scene_occupancy

        best = ("nothing", math.inf)
        i, j = self.grid.world_to_index(xy[0], xy[1])
        for obj in self.scene.objects:
            if obj.is_dynamic:  # people are not part of the ground truth
                continue
            cells = scene_occupancy(Scene(self.scene.name, self.scene.path, (obj,)), self.grid, self.band)
            oi, oj = np.nonzero(cells)
            if len(oi) == 0:
                continue
            k = int(np.argmin((oi - int(i)) ** 2 + (oj - int(j)) ** 2))
            u, v = self.grid.index_to_world(oi[k], oj[k])
            d = float(math.hypot(u - xy[0], v - xy[1]))
            if d < best[1]:
                best = (obj.name, d)
        return best

    def label_near(self, xy: tuple[float, float], reach: float) -> int:
        """Label of the passable region nearest to ``xy`` within ``reach`` metres (0: none)."""
        i, j = self.grid.world_to_index(xy[0], xy[1])
        r = math.ceil(reach / self.grid.cell_size)
        nx, ny = self.grid.shape
        i0, i1, j0, j1 = (
            max(int(i) - r, 0),
            min(int(i) + r + 1, nx),
            max(int(j) - r, 0),
            min(int(j) + r + 1, ny),
        )
        if i0 >= i1 or j0 >= j1:
            return 0
        win = self.labels[i0:i1, j0:j1]
        ii, jj = np.nonzero(win)
        if len(ii) == 0:
            return 0
        d = (ii + i0 - int(i)) ** 2 + (jj + j0 - int(j)) ** 2
        k = int(np.argmin(d))
        if d[k] * self.grid.cell_size**2 > reach**2:
            return 0
        return int(win[ii[k], jj[k]])

    def candidates(self, min_clearance: float) -> npt.NDArray[np.float64]:
        """(K, 2) world (x, y) of the region's cell centres with at least ``min_clearance`` metres."""
        i, j = np.nonzero(self.region & (self.clearance >= min_clearance))
        u, v = self.grid.index_to_world(i, j)
        return np.stack([u, v], axis=1)
