"""The navigation environment's ``rgb_array`` picture: a top-down view of truth, map, path, chair and goal."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from robchair.platform.kinematics import Pose2D


def top_down_picture(
    grid: Any,
    truth: npt.NDArray[np.bool_],
    occupied: npt.NDArray[np.bool_] | None,
    episode: tuple[tuple[float, float], float, list[tuple[float, float]], Pose2D, Any] | None,
    px: int = 3,
) -> npt.NDArray[np.uint8]:
    """Top-down picture (uint8, (H, W, 3)), north (+y) up, east (+x) right, ``px`` pixels per cell.

    Light grey: ``truth`` (the scene's surfaces in the height band); black: ``occupied`` (the episode's
    map); with ``episode`` = (goal, goal tolerance, driven path, true pose, body spec): green the goal
    and its tolerance circle, blue the path, red the chair's footprint.
    """
    nx, ny = grid.shape
    img = np.full((nx, ny, 3), 255, dtype=np.uint8)
    img[truth] = (200, 200, 200)
    if occupied is not None:
        img[occupied] = (0, 0, 0)
    if episode is not None:
        (gx, gy), tolerance, path, pose, body = episode
        ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
        u, v = grid.index_to_world(ii, jj)
        img[np.hypot(u - gx, v - gy) <= max(tolerance, grid.cell_size)] = (0, 170, 0)
        if path:
            pts = np.asarray(path)
            pi, pj = grid.world_to_index(pts[:, 0], pts[:, 1])
            ok = grid.contains_index(pi, pj)
            img[pi[ok], pj[ok]] = (40, 80, 255)
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        lx = c * (u - pose.x) + s * (v - pose.y)
        ly = -s * (u - pose.x) + c * (v - pose.y)
        foot = (np.abs(lx - body.centre_x) <= body.depth / 2) & (np.abs(ly) <= body.width / 2)
        img[foot] = (220, 30, 30)
    # (i along x, j along y) -> rows = -y, columns = x
    pic = np.ascontiguousarray(np.transpose(img, (1, 0, 2))[::-1])
    return np.repeat(np.repeat(pic, px, axis=0), px, axis=1)
