"""The maps the perception stage feeds: what it needs of a map, and a further map placed with another pose.

:class:`PointMap` is the one method a map needs (``insert``); :class:`MapLayer` is a map that
:class:`robchair.perception.Perception` feeds with the same frames as its main map, each placed with the
layer's own ``T_world_base`` (e.g. the simulation's ground truth beside odometry). The evidence
parameters of a run's probabilistic maps (:func:`run_evidence_params`) and :func:`load_kernels`, which
loads the compiled mapping kernels before a loop's clock starts, live here too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

# Probabilistic maps: a hit where free space was seen (a person walking in) is dynamic and forgotten this
# long after its last hit, so a walker leaving the camera's view leaves no trail; "seen free" asks for
# about five passes of free space (p < 0.15), so range noise at a static surface's edge does not count.
# Only what was hit for at most DYNAMIC_MAX_DWELL_S decays (a person passes a cell within a second or
# two): a wall first seen free at grazing incidence keeps being hit as long as it is in view.
DYNAMIC_DECAY_S = 0.5
DYNAMIC_VOID_PROBABILITY = 0.15
DYNAMIC_MAX_DWELL_S = 2.0


def run_evidence_params() -> Any:
    """The :class:`mapping.probabilistic.EvidenceParams` of a run's probabilistic maps (the dynamic-hit
    decay above)."""
    from mapping.probabilistic import EvidenceParams

    return EvidenceParams(
        dynamic_decay_s=DYNAMIC_DECAY_S,
        dynamic_void_probability=DYNAMIC_VOID_PROBABILITY,
        dynamic_max_dwell_s=DYNAMIC_MAX_DWELL_S,
    )


class _Done:
    """A finished future (a camera without background capture)."""

    def __init__(self, value: Any) -> None:
        self.value = value

    def result(self) -> Any:
        return self.value


def load_kernels(scratch: Any, outer_sonar_deg: float, sonar_free_range_m: float) -> None:
    """Insert one sonar reading and two points into the empty map ``scratch``.

    The first insertion imports and loads the compiled mapping kernels (seconds on a cold start); the
    runtime has this done before its clock starts, so that its first cycle keeps its deadline.
    """
    from mapping.sonar import array_points, zone_tables

    fusion, _ = array_points((1.0, 1.0, 1.0), tables=zone_tables(outer_sonar_deg))
    t = np.eye(4)
    t[2, 3] = 0.5
    insert_sonar = getattr(scratch, "insert_sonar", None)
    if insert_sonar is not None:
        insert_sonar(fusion, t, max_range_m=sonar_free_range_m)
    scratch.insert(np.array([[1.0, 0.0, 0.3], [1.5, 0.2, 0.8]]), sensor_origin=t[:3, 3])


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
