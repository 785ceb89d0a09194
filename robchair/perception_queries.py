"""The safety layer's questions to the perception stage: the corridor ahead and distances in it.

:class:`Corridor` is the strip the chair sweeps driving forward, and the distance from its front edge
to the nearest point inside it; :func:`_travelled` carries a distance measured at an earlier pose to the
current one, :func:`_min_opt` takes the nearer of two optional distances. Used by
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
