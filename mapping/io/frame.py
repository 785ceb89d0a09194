"""One frame of points read from a file or a bag, with where and when it came from."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CloudFrame:
    """Points of one cloud and their provenance.

    Attributes:
        points: (N, 3) or organized (H, W, 3) float coordinates; NaN marks no return.
        stamp_ns: Acquisition time in nanoseconds (0 when the format stores none).
        frame_id: The coordinate frame of the points ("" when unknown).
        source: Human-readable origin, e.g. ``scan.pcd`` or ``run.bag:/camera/points``.
        sensor_origin: Sensor position in the points' frame when the format stores one (a PCD
            VIEWPOINT other than the default), else None.
        no_return: (M, 3) ends of the rays of the frame's pixels without a return, at the sensor's
            maximum range, in the points' frame (a bag's ``<topic>/no_return`` message of the same
            stamp: :data:`mapping.io.bags.NO_RETURN_SUFFIX`), else None.
    """

    points: np.ndarray
    stamp_ns: int
    frame_id: str
    source: str
    sensor_origin: tuple[float, float, float] | None = None
    no_return: np.ndarray | None = None
