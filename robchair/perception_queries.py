"""The safety layer's questions to the perception stage: the corridor ahead and distances in it.

:class:`Corridor` is the strip the chair sweeps driving forward, and the distance from its front edge
to the nearest point inside it; :func:`_travelled` carries a distance measured at an earlier pose to the
current one, :func:`_min_opt` takes the nearer of two optional distances, :func:`points_in_base` places
obstacle points taken at earlier poses in ``base_link`` now. Used by
:meth:`robchair.perception.Perception.depth_distance_m` and the zoom's corridor distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import RobChairSpec


@dataclass(frozen=True)
class Corridor:
    """The strip the chair will sweep driving forward, in ``base_link`` (x forward, y left).

    Ahead of the front edge it is the chair's width plus a lateral margin on each side. Beside the body
    (between ``base_link`` and the front edge) only the footprint itself counts: a point there is
    touching the chair (distance 0), while one in the lateral margin beside it is passed, not driven
    into (a door post 5 cm beside the chair's side, or one that a pose correction of a few centimetres
    moves into the margin, is no obstacle ahead).
    """

    front_x: float  # x of the footprint's front edge, m
    half_width: float  # half of the chair's width plus a lateral margin, m
    body_half_width: float | None = None  # half of the chair's width, m (None: half_width)

    @classmethod
    def from_spec(cls, spec: RobChairSpec, lateral_margin: float = 0.05) -> Corridor:
        b = spec.body
        return cls(b.centre_x + 0.5 * b.depth, 0.5 * b.width + lateral_margin, 0.5 * b.width)

    def distance_ahead(self, xy: np.ndarray) -> float | None:
        """Distance from the front edge to the nearest point (N, 2) in the corridor ahead (None: none)."""
        if xy.size == 0:
            return None
        x, ay = xy[:, 0], np.abs(xy[:, 1])
        beside = self.half_width if self.body_half_width is None else self.body_half_width
        inside = ((ay <= self.half_width) & (x > self.front_x)) | ((ay <= beside) & (x > 0.0))
        if not inside.any():
            return None
        return max(0.0, float(x[inside].min()) - self.front_x)


def _travelled(measured: tuple[float | None, Pose2D] | None, pose: Pose2D) -> float | None:
    """A corridor distance measured at pose ``p0``, less the forward travel from ``p0`` to ``pose``."""
    if measured is None:
        return None
    d, p0 = measured
    if d is None:
        return None
    fwd = (pose.x - p0.x) * math.cos(p0.theta) + (pose.y - p0.y) * math.sin(p0.theta)
    return max(0.0, d - max(0.0, fwd))


def _min_opt(a: float | None, b: float | None) -> float | None:
    """The smaller of two optional distances (None = no obstacle)."""
    if a is None:
        return b
    return a if b is None else min(a, b)


def points_in_base(
    pose: Pose2D, odom_xy: np.ndarray | None, arcs: list[tuple[np.ndarray, Pose2D]]
) -> np.ndarray:
    """Points placed at the odometry ``pose`` in ``base_link``: (N, 2), m (empty (0, 2): none).

    ``odom_xy`` (M, 2) are in ``odom`` (the last laser scan's returns); each of ``arcs`` is
    ``(points (K, 2) in base_link at the pose p0 they were taken at, p0)``: placed through ``odom``
    to the chair's pose now (a sonar arc at its reading, the zoom's cells at their frame).
    """
    parts = []
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    if odom_xy is not None and len(odom_xy):
        q = odom_xy - (pose.x, pose.y)
        parts.append(np.stack([c * q[:, 0] + s * q[:, 1], c * q[:, 1] - s * q[:, 0]], 1))
    for arc, p0 in arcs:
        # base_link at the reading (or frame) -> odom -> base_link now
        c0, s0 = math.cos(p0.theta), math.sin(p0.theta)
        wx, wy = (
            p0.x + c0 * arc[:, 0] - s0 * arc[:, 1] - pose.x,
            p0.y + s0 * arc[:, 0] + c0 * arc[:, 1] - pose.y,
        )
        parts.append(np.stack([c * wx + s * wy, c * wy - s * wx], 1))
    return np.concatenate(parts) if parts else np.zeros((0, 2))
