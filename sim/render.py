"""A rendered overview picture of a scenario (PyBullet's TinyRenderer), for run folders and docs.

The picture shows the scene, the chair (at the end of the driven path, or at its start), the scenario's
route (dashed, waypoints as dots) and the driven path (solid). The camera looks down at
:data:`PITCH_DEG` so that walls hide little of the floor, and is pulled back until the scene, the route,
the path and the chair all fit inside the picture with a :data:`FRAME_MARGIN` border. The route and the
path are drawn over the render after projecting them with the camera's own view and projection matrices,
so they stay visible behind walls.
"""

from __future__ import annotations

import math

import numpy as np

from robchair.platform.spec import RobChairSpec
from sim.scene import Scenario

YAW_DEG = -30.0  # camera yaw about z, PyBullet's computeViewMatrixFromYawPitchRoll convention
PITCH_DEG = -62.0  # steep enough that the 2.5 m walls of the office scene leave its corridor visible
FOV_DEG = 50.0
FRAME_MARGIN = 0.06  # fraction of the picture kept free at each border
LINE_Z_M = 0.03  # height of the drawn route and path above the floor
CHAIR_HEIGHT_M = 1.7  # top of the chair's bounding box used for framing (seated user and sensors)


def _matrices(target: np.ndarray, dist: float, aspect: float) -> tuple[list[float], list[float], np.ndarray]:
    import pybullet as p

    view = p.computeViewMatrixFromYawPitchRoll(
        target.tolist(), dist, yaw=YAW_DEG, pitch=PITCH_DEG, roll=0, upAxisIndex=2
    )
    proj = p.computeProjectionMatrixFOV(fov=FOV_DEG, aspect=aspect, nearVal=0.1, farVal=500)
    # PyBullet's matrices are column-major 4x4 lists
    pv = np.asarray(proj, dtype=float).reshape(4, 4).T @ np.asarray(view, dtype=float).reshape(4, 4).T
    return list(view), list(proj), pv


def project(points: np.ndarray, pv: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pixel coordinates (N, 2) (u right, v down) of world points (N, 3) through ``pv`` = P x V (4, 4)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    clip = np.c_[pts, np.ones(len(pts))] @ pv.T
    ndc = clip[:, :2] / clip[:, 3:4]
    return np.c_[(ndc[:, 0] + 1.0) * 0.5 * width, (1.0 - ndc[:, 1]) * 0.5 * height]


def _frame(points: np.ndarray, aspect: float) -> tuple[np.ndarray, float]:
    """Camera target and distance so that every point (N, 3) projects inside the margin-reduced frame."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    target = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
    limit = 1.0 - 2.0 * FRAME_MARGIN

    def extent(t: np.ndarray, d: float) -> tuple[float, np.ndarray]:
        ndc = project(points, _matrices(t, d, aspect)[2], 2, 2) - 1.0  # pixels of a 2x2 picture -> [-1, 1]
        return float(np.abs(ndc).max()), (ndc.min(axis=0) + ndc.max(axis=0)) / 2

    # centre the points in the picture: move the target (on the floor) by the inverse of the
    # finite-difference Jacobian of the picture centre with respect to the target's x, y (a few passes)
    d = 1.5 * float(np.hypot(*(hi[:2] - lo[:2]))) + 2.0
    for _ in range(4):
        _, c0 = extent(target, d)
        jac = np.stack([extent(target + e, d)[1] - c0 for e in np.eye(3)[:2]], axis=1)
        target[:2] -= np.linalg.solve(jac, c0)
    lo_d, hi_d = 0.5, d
    while extent(target, hi_d)[0] > limit:
        hi_d *= 1.5
    for _ in range(30):  # bisection on the distance: the smallest that keeps every point inside
        mid = (lo_d + hi_d) / 2
        if extent(target, mid)[0] > limit:
            lo_d = mid
        else:
            hi_d = mid
    return target, hi_d


def overview_camera(
    scenario: Scenario, spec: RobChairSpec, path: np.ndarray | None, aspect: float
) -> tuple[list[float], list[float], np.ndarray]:
    """The camera of :func:`render_scene`: PyBullet view and projection matrices and P x V (4, 4).

    Framed so that the scene's bounds, the route, the driven path (N, 2+) and a box around the chair at
    its start and at the path's last pose (up to :data:`CHAIR_HEIGHT_M`) all project inside the picture.
    """
    start = tuple(float(c) for c in scenario.start)
    route = np.array([start[:2], *scenario.route.waypoints], dtype=float)
    x0, y0, x1, y1 = scenario.scene.bounds_xy()
    r = 0.5 * math.hypot(spec.body.width, spec.body.depth) + 0.1
    ends = [start] if path is None or len(path) == 0 else [start, tuple(np.asarray(path)[-1, :2])]
    xy = [np.array([[x0, y0], [x1, y1]]), route]
    xy += [np.array([[c[0] - r, c[1] - r], [c[0] + r, c[1] + r]]) for c in ends]
    if path is not None and len(path):
        xy.append(np.asarray(path, dtype=float)[:, :2])
    pts2 = np.concatenate(xy)
    corners = np.array([(x, y, z) for x, y in pts2 for z in (0.0, CHAIR_HEIGHT_M)])
    target, dist = _frame(corners, aspect)
    return _matrices(target, dist, aspect)


def render_scene(
    scenario: Scenario,
    spec: RobChairSpec,
    path: np.ndarray | None = None,
    width: int = 960,
    height: int = 600,
) -> np.ndarray:
    """A rendered overview (H, W, 3) uint8 of the scene, the chair, the route and the driven path.

    Args:
        scenario: the scenario (scene, start pose, route).
        spec: platform spec (the chair's model).
        path: the driven path (N, 2) or (N, 3) of base_link x, y (m) [, yaw (rad)] in ``map``; the chair
            is drawn at its last pose. None: the chair at its start pose and no path.
        width, height: picture size, pixels.

    Returns:
        The RGB picture, shape (height, width, 3), dtype uint8.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pybullet as p

    from sim.backend import SimChair

    start = (float(scenario.start[0]), float(scenario.start[1]), float(scenario.start[2]))
    route = np.array([start[:2], *scenario.route.waypoints], dtype=float)
    driven = None if path is None or len(path) == 0 else np.asarray(path, dtype=float)
    pose = start
    if driven is not None:
        last = driven[-1]
        pose = (float(last[0]), float(last[1]), float(last[2]) if len(last) > 2 else start[2])
    view, proj, pv = overview_camera(scenario, spec, driven, width / height)
    chair = SimChair(spec, scenario.scene, pose, sensor=None, sonars=False)
    try:
        img = p.getCameraImage(
            width,
            height,
            view,
            proj,
            renderer=p.ER_TINY_RENDERER,
            lightDirection=(0.4, -0.3, 1.0),
            shadow=1,
            physicsClientId=chair.world.client,
        )
        rgb = np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))[..., :3]
    finally:
        chair.close()

    dpi = 100
    fig = plt.figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    try:
        ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
        ax.imshow(rgb, interpolation="nearest")
        ax.set_xlim(-0.5, width - 0.5)
        ax.set_ylim(height - 0.5, -0.5)
        ax.axis("off")
        on_floor = np.c_[route, np.full(len(route), LINE_Z_M)]
        uv = project(on_floor, pv, width, height)
        ax.plot(uv[:, 0], uv[:, 1], "--", color="#1f5fd6", lw=2.0, label="route")
        ax.plot(uv[1:, 0], uv[1:, 1], "o", color="#1f5fd6", ms=5)
        if driven is not None:
            uv = project(np.c_[driven[:, :2], np.full(len(driven), LINE_Z_M)], pv, width, height)
            ax.plot(uv[:, 0], uv[:, 1], "-", color="#e8590c", lw=2.2, label="driven path")
        uv = project(np.array([[start[0], start[1], LINE_Z_M]]), pv, width, height)
        ax.plot(uv[:, 0], uv[:, 1], "s", color="#2b8a3e", ms=7, label="start")
        ax.legend(loc="upper left", fontsize=9, framealpha=0.85)
        fig.canvas.draw()
        out = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()  # type: ignore[attr-defined]
    finally:
        plt.close(fig)
    return out
