"""Device interfaces shared by the simulated, emulated and real backends.

Every device has an explicit lifecycle: ``open()`` before use, ``close()`` after (idempotent), and
each is a context manager. Using a closed device raises :class:`hw.errors.DeviceClosedError`.
Units are SI unless the name says otherwise (``speed_rpm``, ``range_cm``, ``angle_deg``); time
stamps are integer nanoseconds of the backend's :class:`Clock`.

Frames follow ROS REP-103/REP-105: ``base_link`` x forward, y left, z up.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, Protocol, Self, runtime_checkable

import numpy as np
import numpy.typing as npt

from hw.errors import DeviceClosedError


class Channel(enum.IntEnum):
    """Motor channels of a dual-channel controller (Roboteq numbering: 1 and 2)."""

    LEFT = 1
    RIGHT = 2


@dataclass(frozen=True)
class MotorFaults:
    """Decoded fault flags of a motor controller (Roboteq ``?FF``)."""

    overheat: bool = False
    overvoltage: bool = False
    undervoltage: bool = False
    short_circuit: bool = False
    emergency_stop: bool = False
    sepex_excitation: bool = False
    mosfet_failure: bool = False
    startup_config: bool = False

    @property
    def any(self) -> bool:
        return any(getattr(self, f) for f in self.__dataclass_fields__)

    def names(self) -> list[str]:
        return [f for f in self.__dataclass_fields__ if getattr(self, f)]


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
    """One ultrasonic range reading. ``range_m`` is NaN when there was no echo."""

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


class Device:
    """Lifecycle mixin: ``open``/``close``, context manager, and a guard for use while closed."""

    name: str = "device"
    _is_open: bool = False

    def open(self) -> None:
        self._is_open = True

    def close(self) -> None:
        self._is_open = False

    @property
    def is_open(self) -> bool:
        return self._is_open

    def _check_open(self) -> None:
        if not self._is_open:
            raise DeviceClosedError(f"{self.name} is closed: call open() (or use it in a 'with' block) first")

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


@runtime_checkable
class Clock(Protocol):
    """Time source: simulated time in sim, monotonic time on hardware."""

    def now_ns(self) -> int: ...

    def sleep_until_ns(self, t_ns: int) -> None: ...


@runtime_checkable
class MotorController(Protocol):
    """A dual-channel wheel motor controller in closed-loop speed mode."""

    name: str

    def open(self) -> None: ...

    def close(self) -> None: ...

    def set_speeds_rpm(self, left_rpm: float, right_rpm: float) -> None:
        """Command motor-shaft speeds; also refreshes the controller's watchdog."""
        ...

    def read_state(self) -> MotorState: ...

    def configure_pid(self, left: PIDConfig, right: PIDConfig) -> None: ...

    def emergency_stop(self) -> None:
        """Stop both motors now (Roboteq ``!EX``). Must not raise if the device is reachable."""
        ...

    def release_stop(self) -> None:
        """Leave the emergency-stop state (Roboteq ``!MG``)."""
        ...


@runtime_checkable
class Ranger(Protocol):
    """One range sensor (SRF08, SRF04)."""

    name: str

    def open(self) -> None: ...

    def close(self) -> None: ...

    def read(self) -> RangeReading: ...


@runtime_checkable
class Servo(Protocol):
    name: str

    def open(self) -> None: ...

    def close(self) -> None: ...

    def set_angle_deg(self, angle_deg: float) -> None: ...

    def angle_deg(self) -> float: ...


@runtime_checkable
class SonarArray(Protocol):
    """Three sonars, the outer ones at +-30 deg from the middle one, on a servo."""

    name: str

    def open(self) -> None: ...

    def close(self) -> None: ...

    def read(self) -> SonarArrayReading: ...

    def set_servo_deg(self, angle_deg: float) -> None: ...


@runtime_checkable
class DepthCamera(Protocol):
    name: str

    def open(self) -> None: ...

    def close(self) -> None: ...

    def read(self) -> DepthFrame: ...


@runtime_checkable
class Joystick(Protocol):
    name: str

    def open(self) -> None: ...

    def close(self) -> None: ...

    def read(self) -> JoystickReading: ...


@dataclass
class Backend:
    """One of each device, as the runtime sees a chair. Optional devices may be None."""

    name: str
    clock: Clock
    motors: MotorController
    sonar_arrays: Sequence[SonarArray] = ()
    depth_camera: DepthCamera | None = None
    joystick: Joystick | None = None

    def devices(self) -> list[Any]:
        devs: list[Any] = [self.motors, *self.sonar_arrays]
        if self.depth_camera is not None:
            devs.append(self.depth_camera)
        if self.joystick is not None:
            devs.append(self.joystick)
        return devs

    def open(self) -> None:
        opened: list[Any] = []
        try:
            for d in self.devices():
                d.open()
                opened.append(d)
        except BaseException:
            for d in reversed(opened):
                d.close()
            raise

    def close(self) -> None:
        """Stop the motors first, then close everything (never raises on the stop)."""
        try:
            self.motors.set_speeds_rpm(0.0, 0.0)
        except Exception:
            pass
        for d in reversed(self.devices()):
            d.close()

    def __enter__(self) -> Backend:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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


@runtime_checkable
class LaserScanner(Protocol):
    """A planar scanning laser range finder (Hokuyo URG-04LX on the chair; simulated in sim/).

    Lifecycle as every device: ``open()`` (connect, identify, switch the laser on), ``read()`` any
    number of times, ``close()`` (laser off; idempotent).
    """

    name: str

    def open(self) -> None:
        """Connect and start measuring.

        Raises:
            DeviceDisconnectedError: the port cannot be opened.
            DeviceTimeoutError: the device does not answer.
            ProtocolError: it answers, but not as the expected device / protocol.
            DeviceFaultError: it reports a hardware fault (laser or motor malfunction).
        """
        ...

    def close(self) -> None:
        """Stop measuring (laser off) and release the port; never raises on a lost device."""
        ...

    def read(self) -> LaserScan:
        """The next complete scan (blocks at most about two scan periods plus the reply deadline).

        Raises:
            DeviceClosedError: used before ``open()`` or after ``close()``.
            DeviceTimeoutError: no scan within the deadline after the retries.
            ProtocolError: replies stayed garbled or failed their checksums after the retries.
            DeviceDisconnectedError: the link went away (cable pulled).
            DeviceFaultError: the device reports a hardware fault.
        """
        ...
