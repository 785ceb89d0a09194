"""Differential-drive kinematics and encoder odometry of the RobChair Storm.

The chain, all functions of :class:`robchair.platform.spec.RobChairSpec`::

    (v, w) body twist  <->  wheel angular speeds (rad/s)  <->  motor shaft RPM (x gear_ratio = 29)
                       <->  encoder counts (PPR x 4 quadrature, x 29 when the encoder is on the motor)

Conventions: REP-103 (x forward, y left, z up; positive w turns left). Left/right wheel order is
always (left, right), matching Roboteq channels (1, 2). The maximum speed follows from the maximum motor
speed: 1000 RPM / 29 x 2 pi / 60 x 0.172 m = 0.621 m/s.

Odometry integrates encoder count *deltas* exactly along circular arcs (the pose update is exact when
the two wheels turn at constant speeds during the interval) and is immune to wrap-around of the
controller's signed 32-bit counters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robchair.platform.errors import RobChairError
from robchair.platform.spec import RobChairSpec, load_spec

RPM_TO_RAD_S = 2.0 * math.pi / 60.0
INT32_MIN = -(2**31)
INT32_SPAN = 2**32


class KinematicsError(RobChairError, ValueError):
    """A kinematic quantity was invalid (non-finite speed, bad counter value)."""


@dataclass(frozen=True)
class Pose2D:
    """Planar pose of ``base_link`` in the odometry frame: x, y in m, theta in rad (wrapped to (-pi, pi])."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


def wrap_int32(value: int) -> int:
    """Reduce any integer to the signed 32-bit range, as a wrapping hardware counter does."""
    return (int(value) - INT32_MIN) % INT32_SPAN + INT32_MIN


def int32_delta(new: int, old: int) -> int:
    """Signed count difference ``new - old`` of two 32-bit counter readings, correct across a wrap.

    Valid as long as the true change between readings is below 2**31 counts in magnitude (at 1000 RPM
    and 4000 counts per motor revolution that is more than 8 hours between readings).
    """
    return (int(new) - int(old) - INT32_MIN) % INT32_SPAN + INT32_MIN


def wrap_angle(theta: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    w = math.remainder(theta, 2.0 * math.pi)
    return math.pi if w == -math.pi else w


class DiffDrive:
    """Conversions between body twist, wheel speeds, motor RPM and encoder counts.

    Args:
        spec: The platform spec; ``None`` loads the default ``assets/robchair.toml``.
    """

    def __init__(self, spec: RobChairSpec | None = None) -> None:
        self.spec = spec if spec is not None else load_spec()
        self.r = self.spec.wheel_radius
        self.b = self.spec.wheel_separation
        self.gear_ratio = self.spec.gear_ratio
        self.counts_per_wheel_rev = self.spec.counts_per_wheel_rev
        self.counts_per_wheel_rad = self.counts_per_wheel_rev / (2.0 * math.pi)

    # -- limits ------------------------------------------------------------------------------------
    @property
    def max_wheel_speed(self) -> float:
        """Largest wheel angular speed, rad/s (max motor RPM through the gearbox)."""
        return self.spec.max_motor_rpm * RPM_TO_RAD_S / self.gear_ratio

    @property
    def max_speed(self) -> float:
        """Largest straight-line speed, m/s (about 0.62 m/s for 1000 RPM / 29 and r = 0.172 m)."""
        return self.max_wheel_speed * self.r

    @property
    def max_yaw_rate(self) -> float:
        """Largest spin-in-place rate, rad/s (wheels at +-max speed)."""
        return 2.0 * self.max_speed / self.b

    # -- twist <-> wheels --------------------------------------------------------------------------
    def wheel_speeds(self, v: float, w: float) -> tuple[float, float]:
        """Wheel angular speeds (left, right), rad/s, for body speed ``v`` m/s and yaw rate ``w`` rad/s."""
        _finite(v=v, w=w)
        half = 0.5 * self.b * w
        return ((v - half) / self.r, (v + half) / self.r)

    def twist(self, wl: float, wr: float) -> tuple[float, float]:
        """Body twist (v m/s, w rad/s) from wheel angular speeds (left, right) in rad/s."""
        _finite(wl=wl, wr=wr)
        return (0.5 * self.r * (wl + wr), self.r * (wr - wl) / self.b)

    # -- wheels <-> motor RPM ----------------------------------------------------------------------
    def wheel_to_rpm(self, wheel_rad_s: float) -> float:
        """Motor shaft RPM for a wheel angular speed (rad/s): through the 1:gear_ratio gearbox."""
        return wheel_rad_s * self.gear_ratio / RPM_TO_RAD_S

    def rpm_to_wheel(self, rpm: float) -> float:
        """Wheel angular speed (rad/s) for a motor shaft speed in RPM."""
        return rpm * RPM_TO_RAD_S / self.gear_ratio

    def motor_rpm(self, v: float, w: float) -> tuple[float, float]:
        """Motor shaft speeds (left_rpm, right_rpm) for body twist (v, w)."""
        wl, wr = self.wheel_speeds(v, w)
        return (self.wheel_to_rpm(wl), self.wheel_to_rpm(wr))

    def twist_from_rpm(self, left_rpm: float, right_rpm: float) -> tuple[float, float]:
        """Body twist (v, w) from motor shaft speeds in RPM."""
        return self.twist(self.rpm_to_wheel(left_rpm), self.rpm_to_wheel(right_rpm))

    def limit(self, v: float, w: float) -> tuple[float, float]:
        """Scale (v, w) down uniformly so neither motor exceeds ``max_motor_rpm``, exactly.

        The scaling keeps the ratio w / v, so the chair follows the same curve, only slower. The
        guarantee holds for the floating-point result: ``motor_rpm(*limit(v, w))`` never exceeds the cap
        by even one rounding step (the scale ``cap / peak`` alone can give 1000.0000000000002 RPM, which
        a motor driver checking its range must refuse), because the scale is lowered by one ulp until the
        recomputed RPMs fit.

        Raises:
            KinematicsError: ``v`` or ``w`` is not finite.
        """
        cap = self.spec.max_motor_rpm
        peak = self._peak_rpm(v, w)
        if peak <= cap:
            return (v, w)
        k = cap / peak
        while self._peak_rpm(v * k, w * k) > cap:  # a few rounding steps at most; k = 0 always fits
            k = math.nextafter(k, 0.0)
        return (v * k, w * k)

    def _peak_rpm(self, v: float, w: float) -> float:
        left, right = self.motor_rpm(v, w)
        return max(abs(left), abs(right))

    # -- wheels <-> encoder counts -----------------------------------------------------------------
    def wheel_angle_to_counts(self, angle_rad: float) -> float:
        """Encoder counts (not rounded) for a wheel rotation in rad."""
        return angle_rad * self.counts_per_wheel_rad

    def counts_to_wheel_angle(self, counts: float) -> float:
        """Wheel rotation (rad) for a number of encoder counts."""
        return counts / self.counts_per_wheel_rad

    def counts_to_distance(self, counts: float) -> float:
        """Distance (m) travelled by a wheel's contact point for a number of encoder counts."""
        return self.counts_to_wheel_angle(counts) * self.r

    def counts_for_motion(self, v: float, w: float, dt: float) -> tuple[float, float]:
        """Encoder count increments (left, right), not rounded, for twist (v, w) held for ``dt`` s."""
        wl, wr = self.wheel_speeds(v, w)
        return (self.wheel_angle_to_counts(wl * dt), self.wheel_angle_to_counts(wr * dt))


class Odometry:
    """Dead reckoning from the two encoder counters.

    Call :meth:`update` with the raw signed 32-bit counter readings (left, right). The first call only
    latches the counters (the pose stays where :meth:`reset` put it); later calls integrate the deltas.
    Counters may wrap from 2**31 - 1 to -2**31 (and back) between readings.

    The pose update for wheel arc lengths d_l, d_r is the exact circular arc: with
    d = (d_l + d_r) / 2 and dtheta = (d_r - d_l) / b the chord has length d sinc(dtheta / 2) and points
    along theta + dtheta / 2. Straight motion (dtheta = 0) is the limit of the same formula.

    Args:
        spec: The platform spec; ``None`` loads the default.
        pose: Initial pose.
    """

    def __init__(self, spec: RobChairSpec | None = None, pose: Pose2D | None = None) -> None:
        self.drive = DiffDrive(spec)
        self._pose = pose if pose is not None else Pose2D()
        self._last: tuple[int, int] | None = None
        self.distance = 0.0  # total path length of base_link, m (signed: reversing subtracts)

    @property
    def pose(self) -> Pose2D:
        return self._pose

    def reset(self, pose: Pose2D | None = None) -> None:
        """Set the pose (default the origin) and forget the latched counters."""
        self._pose = pose if pose is not None else Pose2D()
        self._last = None
        self.distance = 0.0

    def update(self, counts_left: int, counts_right: int) -> Pose2D:
        """Integrate new counter readings and return the pose.

        Args:
            counts_left: Left (channel 1) counter, signed 32-bit (any int is reduced modulo 2**32).
            counts_right: Right (channel 2) counter.

        Raises:
            KinematicsError: A count is not an integer.
        """
        for name, c in (("counts_left", counts_left), ("counts_right", counts_right)):
            if isinstance(c, bool) or not isinstance(c, int | np.integer):
                raise KinematicsError(f"{name} = {c!r}: expected an integer encoder count")
        now = (wrap_int32(int(counts_left)), wrap_int32(int(counts_right)))
        if self._last is None:
            self._last = now
            return self._pose
        dl_counts = int32_delta(now[0], self._last[0])
        dr_counts = int32_delta(now[1], self._last[1])
        self._last = now
        self._pose = integrate_arc(
            self._pose,
            self.drive.counts_to_distance(dl_counts),
            self.drive.counts_to_distance(dr_counts),
            self.drive.b,
        )
        self.distance += 0.5 * (
            self.drive.counts_to_distance(dl_counts) + self.drive.counts_to_distance(dr_counts)
        )
        return self._pose


def integrate_arc(pose: Pose2D, d_left: float, d_right: float, wheel_separation: float) -> Pose2D:
    """Move ``pose`` along the exact arc driven by wheel arc lengths ``d_left``, ``d_right`` (m)."""
    d = 0.5 * (d_left + d_right)
    dth = (d_right - d_left) / wheel_separation
    half = 0.5 * dth
    chord = d * (math.sin(half) / half if half != 0.0 else 1.0)
    heading = pose.theta + half
    return Pose2D(
        x=pose.x + chord * math.cos(heading),
        y=pose.y + chord * math.sin(heading),
        theta=wrap_angle(pose.theta + dth),
    )


def _finite(**values: float) -> None:
    for name, v in values.items():
        if not math.isfinite(v):
            raise KinematicsError(f"{name} = {v!r}: expected a finite number")
