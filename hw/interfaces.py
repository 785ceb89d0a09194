"""Device interfaces shared by the simulated, emulated and real backends.

Every device has an explicit lifecycle: ``open()`` before use, ``close()`` after (idempotent), and
each is a context manager. Using a closed device raises :class:`hw.errors.DeviceClosedError`.
Units are SI unless the name says otherwise (``speed_rpm``, ``range_cm``, ``angle_deg``); time
stamps are integer nanoseconds of the backend's :class:`Clock`.

Frames follow ROS REP-103/REP-105: ``base_link`` x forward, y left, z up.

The data the devices return (readings, faults, gains) lives in :mod:`hw.messages` and is re-exported
here, beside the protocols that return it.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Protocol, Self, runtime_checkable

from hw.errors import DeviceClosedError
from hw.messages import (
    DepthFrame,
    JoystickReading,
    LaserScan,
    MotorFaults,
    MotorState,
    PIDConfig,
    RangeReading,
    SonarArrayReading,
)

__all__ = [
    "Backend",
    "Channel",
    "Clock",
    "DepthCamera",
    "DepthFrame",
    "Device",
    "Joystick",
    "JoystickReading",
    "LaserScan",
    "LaserScanner",
    "LifecycleState",
    "MotorController",
    "MotorControllerLifecycle",
    "MotorFaults",
    "MotorState",
    "PIDConfig",
    "RangeReading",
    "Ranger",
    "Servo",
    "SonarArray",
    "SonarArrayReading",
]


class Channel(enum.IntEnum):
    """Motor channels of a dual-channel controller (Roboteq numbering: 1 and 2)."""

    LEFT = 1
    RIGHT = 2


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
    """Time source: simulated time in sim, monotonic time on hardware (:mod:`hw.clock`).

    Every stamp in these interfaces is an integer number of nanoseconds of the backend's clock; only
    differences between stamps of one clock mean anything (the epoch is the clock's own).
    """

    def now_ns(self) -> int:
        """The current time, ns; never decreases. Does not raise."""
        ...

    def sleep_until_ns(self, t_ns: int) -> None:
        """Block until :meth:`now_ns` >= ``t_ns`` (returns at once if it already is).

        A simulated clock advances the simulation to ``t_ns`` instead of waiting; a manual clock jumps.
        Does not raise for a time in the past; the simulator's clock raises its own error class when
        the physics fails while advancing.
        """
        ...


class LifecycleState(enum.Enum):
    """Lifecycle states of a motor controller, as ros2_control's ``hardware_interface::SystemInterface``.

    * ``UNCONFIGURED``: created, no communication.
    * ``INACTIVE``: communication up, the configuration written and checked; states can be read,
      nothing moves.
    * ``ACTIVE``: speed commands are accepted.
    * ``ERROR``: a fault stopped the motors; only an explicit operator release leaves it
      (``release()``, ``robchair run --release-stop``).
    * ``FINALIZED``: closed; the object is not used again.
    """

    UNCONFIGURED = "unconfigured"
    INACTIVE = "inactive"
    ACTIVE = "active"
    ERROR = "error"
    FINALIZED = "finalized"


@runtime_checkable
class MotorController(Protocol):
    """A dual-channel wheel motor controller in closed-loop speed mode.

    Units: speeds are motor-shaft RPM (before the gearbox); encoder counts are signed 32-bit,
    quadrature x4, (left, right); stamps are integer nanoseconds of the backend's clock.
    Errors are :class:`hw.errors.HardwareError` subclasses; every fault path stops the motors before
    it raises. Motion is only possible in the active state (see :class:`MotorControllerLifecycle`).
    """

    name: str

    def open(self) -> None:
        """Start a session and, when the controller may move the chair, activate it.

        Raises:
            DeviceDisconnectedError: the port cannot be opened.
            DeviceTimeoutError, ProtocolError: the device does not answer, or not as the protocol says.
            DeviceFaultError: a fault flag is set, or a stop latched earlier needs an operator release.
        """
        ...

    def close(self) -> None:
        """Command zero speeds (best effort) and end the session; idempotent, never raises."""
        ...

    def set_speeds_rpm(self, left_rpm: float, right_rpm: float) -> None:
        """Command motor-shaft speeds, RPM; also refreshes the controller's watchdog.

        Raises:
            CommandError: a speed is not finite or beyond the maximum (after stopping).
            DeviceStateError: a non-zero speed while not active.
            DeviceFaultError: a non-zero speed after a fault, before the operator released it.
            DeviceTimeoutError, ProtocolError, DeviceDisconnectedError: the link failed (after stopping).
        """
        ...

    def read_state(self) -> MotorState:
        """Encoder counts, speeds (RPM) and fault flags.

        Raises:
            DeviceFaultError: a fault flag or an implausible encoder change (after stopping).
            DeviceTimeoutError, ProtocolError, DeviceDisconnectedError: the link failed (after stopping).
        """
        ...

    def configure_pid(self, left: PIDConfig, right: PIDConfig) -> None:
        """Write the speed-loop gains (continuous units). Raises CommandError if a gain does not fit."""
        ...

    def emergency_stop(self) -> None:
        """Stop both motors now and latch the stop (Roboteq ``!EX``); confirmed by reading it back.

        Raises:
            DeviceFaultError: the controller did not latch the stop (the motors were commanded to zero).
            DeviceTimeoutError, ProtocolError, DeviceDisconnectedError: the link failed.
        """
        ...

    def release_stop(self) -> None:
        """Operator release of a latched stop (Roboteq ``!MG``); the controller may move again.

        Raises:
            DeviceFaultError: a fault flag is still set after the release.
        """
        ...


@runtime_checkable
class MotorControllerLifecycle(MotorController, Protocol):
    """The explicit lifecycle of a motor controller (ros2_control ``SystemInterface``).

    ``configure()`` unconfigured -> inactive; ``activate()`` inactive -> active (commands zero first);
    ``deactivate()`` active -> inactive (zero, then a latched stop); a fault moves to error, which only
    ``release()`` leaves (-> inactive); ``close()`` -> finalized. ``open()`` is ``configure()`` then
    ``activate()``. Motion is refused outside active with :class:`hw.errors.DeviceStateError`.
    """

    @property
    def state(self) -> LifecycleState: ...

    def configure(self) -> None: ...

    def activate(self) -> None: ...

    def deactivate(self) -> None: ...

    def release(self) -> None: ...


@runtime_checkable
class Ranger(Protocol):
    """One ultrasonic range sensor (SRF08 on I2C, SRF04 on trigger/echo pins).

    Units: metres and radians in :class:`RangeReading` (REP-117: ``+inf`` = no echo within range,
    NaN = invalid); ``stamp_ns`` is the time of the ping on the backend's :class:`Clock`.
    """

    name: str

    def open(self) -> None:
        """Connect and configure (e.g. the SRF08 range register).

        Raises:
            DeviceIOError: The bus or pins cannot be opened, or a transfer fails after the retries.
            DeviceTimeoutError: The device does not finish a ranging left over from before.
            CommandError: The configuration is invalid (address, gain, range).
        """
        ...

    def close(self) -> None:
        """Release the bus or pins (idempotent; a shared bus stays open). Does not raise."""
        ...

    def read(self) -> RangeReading:
        """Fire one ranging and return it; blocks for the ranging (up to 65 ms for an SRF08).

        Callers keep the firing interval the sensor needs (65 ms for an SRF08 and any sonar whose beam
        overlaps it; :class:`hw.sonar_array.SonarFiringGroup`).

        Raises:
            DeviceClosedError: Not open.
            DeviceTimeoutError: The ranging does not finish (device absent or hung).
            DeviceIOError: A bus transfer fails after the retries.
            ProtocolError: The device answers something impossible (e.g. a negative echo width).
        """
        ...


@runtime_checkable
class Servo(Protocol):
    """The hobby servo that pans a sonar array; angles in degrees, 0..180 with 90 = straight ahead.

    (Degrees, not radians, because the servo boards speak degrees; REP-103 angles are derived from
    them by the array's mount, ``assets/robchair.toml``.)
    """

    name: str

    def open(self) -> None:
        """Connect to the servo board or PWM daemon.

        Raises:
            HardwareError: The board or daemon cannot be reached (a serial or pigpio failure).
        """
        ...

    def close(self) -> None:
        """Release the board (idempotent). Does not raise."""
        ...

    def set_angle_deg(self, angle_deg: float) -> None:
        """Command an angle, degrees; returns once the board has acknowledged it (not once reached).

        Raises:
            DeviceClosedError: Not open.
            CommandError: The angle is not finite, or outside the limits with ``out_of_range="refuse"``
                (with ``"clamp"`` it is clamped to them).
            DeviceFaultError: The board refused the angle.
            DeviceTimeoutError: The board did not acknowledge in time.
            HardwareError: The board acknowledged a different angle.
        """
        ...

    def angle_deg(self) -> float:
        """The last commanded (acknowledged) angle, degrees. Does not raise."""
        ...


@runtime_checkable
class SonarArray(Protocol):
    """Three sonars, the outer ones at +-30 deg from the middle one, on a servo.

    Units: ranges in metres (REP-117: ``+inf`` = no echo, NaN = invalid or a failed sonar), the servo
    angle in degrees (90 = straight ahead), ``stamp_ns`` the first ping of the reading's cycle.
    """

    name: str

    def open(self) -> None:
        """Open the three sonars and the servo (all or none).

        Raises:
            HardwareError: Any of them fails to open (its error; the others are closed again).
        """
        ...

    def close(self) -> None:
        """Close the sonars and the servo (idempotent; a failure closing one is logged). Does not raise."""
        ...

    def read(self) -> SonarArrayReading:
        """The three ranges of one firing cycle; blocks for it (195 ms for the chair's SRF08 arrays).

        A failing sonar reads NaN and is counted; the others go on, so one dead sonar does not raise.

        Raises:
            DeviceClosedError: Not open.
        """
        ...

    def set_servo_deg(self, angle_deg: float) -> None:
        """Turn the array, degrees (see :class:`Servo`).

        Raises:
            DeviceClosedError: Not open.
            CommandError: The array has no servo, or the angle is not finite or outside the limits.
            HardwareError: The servo's own errors (see :meth:`Servo.set_angle_deg`).
        """
        ...


@runtime_checkable
class DepthCamera(Protocol):
    """A depth camera (the Kinect v2): organised point clouds in metres (see :class:`DepthFrame`)."""

    name: str

    def open(self) -> None:
        """Start the camera.

        Raises:
            HardwareError: The camera cannot be started.
        """
        ...

    def close(self) -> None:
        """Stop the camera (idempotent). Does not raise."""
        ...

    def read(self) -> DepthFrame:
        """The newest frame: points (H, W, 3) in metres in ``frame_id`` (x forward, y left, z up), NaN
        where a pixel has no return; ``stamp_ns`` is the exposure time on the backend's clock.

        Raises:
            DeviceClosedError: Not open.
            DeviceTimeoutError: A camera driver gets no frame in time (the simulated camera renders
                synchronously and does not time out).
        """
        ...


@runtime_checkable
class Joystick(Protocol):
    """The chair's joystick (an Arduino on a serial line): normalised axes, see :class:`JoystickReading`."""

    name: str

    def open(self) -> None:
        """Open the serial line.

        Raises:
            DeviceIOError: The port cannot be opened.
        """
        ...

    def close(self) -> None:
        """Close the line (idempotent). Does not raise."""
        ...

    def read(self) -> JoystickReading:
        """The latest axes in [-1, 1] (dead zone applied) and the dead-man button.

        A reading older than the joystick's staleness limit reads as centred with the dead-man button
        released, so a silent joystick never keeps the chair moving.

        Raises:
            DeviceClosedError: Not open.
            DeviceIOError: The serial line fails.
        """
        ...


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
