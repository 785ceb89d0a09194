"""What the Roboteq driver writes to the controller and what it reports back for diagnostics.

* :class:`RoboteqProtections`: the controller-side protections (``^MAC``/``^MDEC`` ramps, ``^ALIM``,
  ``^CLERD``), derived from the platform spec and the safety limits, so the controller bounds a
  runaway command by itself even when the host misbehaves.
* :class:`RoboteqDiagnostics`: counters and readings a runtime polls at a low rate (1 Hz is plenty)
  and turns into ``diagnostic_msgs/DiagnosticArray``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from hw.errors import CommandError
from hw.roboteq import codec

# The MDC2230's rated continuous current per channel (datasheet: 2 x 30 A).
MDC2230_RATED_AMPS = 30.0
# The controller ramps are set this much above what the safety layer asks for, so the software
# limits govern in normal driving and the controller's ramps only bound a runaway command.
RAMP_HEADROOM = 1.5


@dataclass(frozen=True)
class RoboteqProtections:
    """Controller-side protections written in ``configure()`` and read back before activation.

    Attributes:
        accel_rpm_s: ``^MAC`` acceleration ramp, motor RPM per second (0 bypasses the ramp).
        decel_rpm_s: ``^MDEC`` deceleration ramp, motor RPM per second.
        amps_limit_a: ``^ALIM`` motor current limit, A.
        loop_error_detection: ``^CLERD`` level: 0 off, 1 (250 ms, error > 100), 2 (500 ms, > 250),
            3 (1000 ms, > 500). The driver's fault logic relies on the loop-error flag (``?FM`` f3),
            so 0 is refused.
    """

    accel_rpm_s: float = 1000.0
    decel_rpm_s: float = 1000.0
    amps_limit_a: float = MDC2230_RATED_AMPS
    loop_error_detection: int = 2

    def __post_init__(self) -> None:
        for name in ("accel_rpm_s", "decel_rpm_s", "amps_limit_a"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise CommandError(f"RoboteqProtections.{name}={v!r}: expected a finite number > 0")
        if self.loop_error_detection not in (1, 2, 3):
            raise CommandError(
                f"RoboteqProtections.loop_error_detection={self.loop_error_detection!r}: expected 1, 2 "
                "or 3 (0 would disable the loop-error flag the driver stops on)"
            )
        for name, value in self.config_items().items():
            lo, hi = codec.CONFIG_RANGE[name]
            if not lo <= value <= hi:
                raise CommandError(f"RoboteqProtections: ^{name} {value} outside the manual's {lo}..{hi}")

    def config_items(self) -> dict[str, int]:
        """Per-channel configuration integers in the controller's units (0.1 RPM/s, 0.1 A)."""
        return {
            "MAC": round(self.accel_rpm_s * 10),
            "MDEC": round(self.decel_rpm_s * 10),
            "ALIM": round(self.amps_limit_a * 10),
            "CLERD": int(self.loop_error_detection),
        }

    @classmethod
    def from_spec(
        cls, spec: Any, limits: Any = None, amps_limit_a: float = MDC2230_RATED_AMPS
    ) -> RoboteqProtections:
        """Ramps from the safety limits, in motor RPM/s with :data:`RAMP_HEADROOM`.

        One wheel accelerates at most ``max_accel + max_yaw_accel * separation / 2`` (m/s^2) when
        both limits act; braking is assumed at ``brake_decel`` (plus the yaw share) by the stopping
        distance, so the controller must be able to decelerate at least that fast.

        Args:
            spec: a :class:`robchair.platform.spec.RobChairSpec` (wheel radius, separation, gear ratio).
            limits: a :class:`robchair.platform.safety.SafetyLimits` (default: its defaults).
            amps_limit_a: ``^ALIM``, A.
        """
        if limits is None:
            from robchair.platform.safety import SafetyLimits

            limits = SafetyLimits()
        half = spec.wheel_separation / 2.0
        to_motor_rpm_s = 60.0 / (2.0 * math.pi * spec.wheel_radius) * spec.gear_ratio
        accel = (limits.max_accel + limits.max_yaw_accel * half) * to_motor_rpm_s * RAMP_HEADROOM
        decel = (limits.brake_decel + limits.max_yaw_accel * half) * to_motor_rpm_s * RAMP_HEADROOM
        return cls(accel_rpm_s=round(accel, 1), decel_rpm_s=round(decel, 1), amps_limit_a=amps_limit_a)


@dataclass(frozen=True)
class RoboteqDiagnostics:
    """One diagnostics sample (see :meth:`hw.roboteq.driver.RoboteqMDC2230.read_diagnostics`).

    Attributes:
        stamp_ns: when the readings were taken, ns of the driver's clock.
        state: lifecycle state name (``"active"``, ``"error"``, ...).
        firmware: the ``?FID`` text.
        retries: transactions that had to be repeated since the session started.
        discarded_lines: received lines that answered nothing the driver asked (stale or unsolicited).
        watchdog_trips: host stalls longer than the serial watchdog (the controller stopped the motors).
        stop_reason: why the motors were stopped, or None.
        faults: set fault-flag names (``?FF``).
        status: set status-flag names (``?FS``).
        battery_v, internal_v: supply voltages, V (``?V``).
        motor_amps: motor currents (left, right), A (``?A``).
        temperatures_c: MCU and the two channel heatsinks, degrees C (``?T``).
    """

    stamp_ns: int
    state: str
    firmware: str
    retries: int
    discarded_lines: int
    watchdog_trips: int
    stop_reason: str | None
    faults: tuple[str, ...] = ()
    status: tuple[str, ...] = ()
    battery_v: float = math.nan
    internal_v: float = math.nan
    motor_amps: tuple[float, float] = (math.nan, math.nan)
    temperatures_c: tuple[float, ...] = field(default=(math.nan, math.nan, math.nan))

    def as_key_values(self) -> dict[str, str]:
        """Flat string key/values, as ``diagnostic_msgs/KeyValue`` wants them."""
        return {
            "state": self.state,
            "firmware": self.firmware,
            "retries": str(self.retries),
            "discarded_lines": str(self.discarded_lines),
            "watchdog_trips": str(self.watchdog_trips),
            "stop_reason": self.stop_reason or "",
            "faults": ",".join(self.faults),
            "status": ",".join(self.status),
            "battery_v": f"{self.battery_v:.1f}",
            "internal_v": f"{self.internal_v:.1f}",
            "motor_amps_left": f"{self.motor_amps[0]:.1f}",
            "motor_amps_right": f"{self.motor_amps[1]:.1f}",
            **{f"temperature_{n}_c": f"{t:.0f}" for n, t in zip(("mcu", "ch1", "ch2"), self.temperatures_c)},
        }
