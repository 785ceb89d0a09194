"""A rendered overview picture of a scenario's scene (PyBullet's TinyRenderer), for run folders and docs."""

from __future__ import annotations

import numpy as np

from robchair.spec import RobChairSpec
from sim.scene import Scenario


def render_scene(
    scenario: Scenario,
    spec: RobChairSpec,
    path: np.ndarray | None = None,
    width: int = 960,
    height: int = 600,
) -> np.ndarray:
    """A rendered overview of the scene (PyBullet's TinyRenderer), with the chair at its start pose."""
    import pybullet as p

    from sim.backend import SimChair

    chair = SimChair(spec, scenario.scene, scenario.start, sensor=None, sonars=False)
    try:
        x0, y0, x1, y1 = scenario.scene.bounds_xy()
        target = ((x0 + x1) / 2, (y0 + y1) / 2, 0.0)
        dist = 0.75 * max(x1 - x0, y1 - y0) + 2.0
        view = p.computeViewMatrixFromYawPitchRoll(target, dist, yaw=-30, pitch=-50, roll=0, upAxisIndex=2)
        proj = p.computeProjectionMatrixFOV(fov=50, aspect=width / height, nearVal=0.1, farVal=200)
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
        rgba = np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))
        return rgba[..., :3].copy()
    finally:
        chair.close()
