"""The data devices hand to the runtime: readings, scans, faults and gains (frozen dataclasses).

Units are SI unless the name says otherwise (``speed_rpm``, ``range_cm``); time stamps are integer
nanoseconds of the backend's :class:`hw.interfaces.Clock`; frames follow ROS REP-103/REP-105 and range
values REP-117. The device protocols that return them are in :mod:`hw.interfaces`, which re-exports
every name here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = [
    "DepthFrame",
    "JoystickReading",
    "LaserScan",
    "MotorFaults",
    "MotorState",
    "PIDConfig",
    "RangeReading",
    "SonarArrayReading",
]


@dataclass(frozen=True)
class MotorFaults:
    """Decoded fault flags of a motor controller (Roboteq ``?FF``, bits f1..f8 in field order).

    ``startup_config`` is the manual's "default configuration loaded at startup" (the controller
    restarted with factory settings). ``unknown_bits`` keeps set bits the manual does not name
    (``?FF`` is a 16-bit word on firmware 2.x); any of them counts as a fault.
    """

    overheat: bool = False
    overvoltage: bool = False
    undervoltage: bool = False
    short_circuit: bool = False
    emergency_stop: bool = False
    sepex_excitation: bool = False
    mosfet_failure: bool = False
    startup_config: bool = False
    unknown_bits: int = 0

    @property
    def any(self) -> bool:
        return bool(self.names())

    def names(self) -> list[str]:
        named = [f for f in self.__dataclass_fields__ if f != "unknown_bits" and getattr(self, f)]
        return named + [f"f{i + 1}" for i in range(16) if self.unknown_bits >> i & 1]


@dataclass(frozen=True)
class MotorState:
    """One reading of both channels."""

    stamp_ns: int
    encoder_counts: tuple[int, int]  # signed 32-bit, quadrature x4, (left, right)
    speed_rpm: tuple[float, float]  # motor shaft RPM as the controller reports it
    faults: MotorFaults = field(default_factory=MotorFaults)


@dataclass(frozen=True)
class PIDConfig:
    """PID gains for one channel, in the control module's continuous units (not firmware units)."""

    kp: float
    ki: float
    kd: float


@dataclass(frozen=True)
class RangeReading:
    """One ultrasonic range reading (REP-117 values, as ``sensor_msgs/Range``).

    ``range_m``: metres; ``+inf`` when nothing echoed within ``max_range_m``; NaN when the reading is
    invalid (an echo under ``min_range_m``, or a failed sonar in an array).
    """

    stamp_ns: int
    range_m: float
    min_range_m: float
    max_range_m: float
    field_of_view_rad: float


@dataclass(frozen=True)
class SonarArrayReading:
    """Three sonar ranges of one array (sonars 1, 2, 3 from left to right) and its servo angle."""

    stamp_ns: int
    ranges_m: tuple[float, float, float]
    servo_angle_deg: float


@dataclass(frozen=True)
class DepthFrame:
    """An organized point cloud in the camera's optical-free ROS frame (x forward, y left, z up).

    ``points`` has shape (H, W, 3); pixels without a return are NaN.
    """

    stamp_ns: int
    frame_id: str
    points: npt.NDArray[np.floating[Any]]


@dataclass(frozen=True)
class JoystickReading:
    """Normalised joystick axes in [-1, 1] (x forward, y turn-left) and the dead-man button."""

    stamp_ns: int
    forward: float
    turn: float
    deadman: bool


@dataclass(frozen=True)
class LaserScan:
    """One planar laser scan in the ``sensor_msgs/LaserScan`` layout (REP-103, REP-117).

    Beam ``i`` points at ``angle_min + i * angle_increment`` rad in the sensor frame (``laser_link``:
    x forward, y left, z up; angle 0 is x, counter-clockwise positive) and was measured
    ``i * time_increment`` s after the first beam.

    Range values (REP-117): a finite value in ``[range_min, range_max]`` is a measurement, in m;
    ``+inf`` means no return (nothing within ``range_max``, or the echo was too weak to measure);
    ``-inf`` means an object closer than ``range_min``; ``NaN`` means an invalid measurement (the
    sensor reported an error for that beam). Consumers keep only finite values in range.

    Attributes:
        stamp_ns: Acquisition time of the first beam, integer ns of the backend's clock.
        frame_id: Sensor frame, ``laser_link``.
        angle_min: Angle of the first beam, rad.
        angle_max: Angle of the last beam, rad (``angle_min + (N - 1) * angle_increment``).
        angle_increment: Angle between beams, rad (> 0: counter-clockwise).
        time_increment: Time between beams, s.
        scan_time: Time between scans, s.
        range_min: Smallest valid range, m.
        range_max: Largest valid range, m.
        ranges: (N,) float32 ranges, m, with the special values above.
        intensities: (N,) float32 intensities (device units) or None when not measured.
    """

    stamp_ns: int
    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: npt.NDArray[np.float32]
    intensities: npt.NDArray[np.float32] | None = None
    frame_id: str = "laser_link"

    @property
    def n_beams(self) -> int:
        return int(self.ranges.shape[0])

    def angles(self) -> npt.NDArray[np.float64]:
        """(N,) beam angles, rad."""
        return self.angle_min + self.angle_increment * np.arange(self.n_beams, dtype=np.float64)
