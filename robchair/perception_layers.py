"""The maps the perception stage feeds: what it needs of a map, and a further map placed with another pose.

:class:`PointMap` is the one method a map needs (``insert``); :class:`MapLayer` is a map that
:class:`robchair.perception.Perception` feeds with the same frames as its main map, each placed with the
layer's own ``T_world_base`` (e.g. the simulation's ground truth beside odometry).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


class PointMap(Protocol):
    """What the perception stage needs of a map."""

    def insert(self, points: Any, sensor_origin: Any = None) -> Any: ...


@dataclass
class MapLayer:
    """A further map fed with the same frames, placed with another pose source.

    ``t_world_base()`` is called when a frame is taken (on the loop's thread) and returns the
    (4, 4) ``T_world_base`` to place that frame with (e.g. the physics' ground truth).
    """

    name: str
    map: PointMap
    t_world_base: Callable[[], np.ndarray]
