"""A :class:`hw.interfaces.SonarArray` made of three :class:`Ranger` s and an optional :class:`Servo`.

Sonars 1, 2, 3 are left, middle, right (outer ones at +-30 deg, SPEC section 3). They are fired one
after the other, never together: their beams overlap by design, so one sonar would hear another's
ping. A sonar that fails (I/O error, timeout, protocol error) gives NaN for that reading while the
others go on; each failure is logged and counted in :attr:`RangerSonarArray.error_counts`, and a
sonar that has failed ``max_consecutive_errors`` reads in a row is reported at WARNING level once
per run of failures so a dead sonar is visible without flooding the log. A dead sonar is then only
retried on every ``retry_dead_every``-th read (NaN in between, counted in :attr:`skipped_counts`):
a missing SRF08 costs a whole busy-poll timeout per attempt, which would stall the control loop.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Any

from hw.clock import MonotonicClock
from hw.errors import CommandError, HardwareError
from hw.interfaces import Clock, Device, Ranger, Servo, SonarArrayReading

log = logging.getLogger(__name__)


class RangerSonarArray(Device):
    """Three rangers (left, middle, right) on a servo.

    Args:
        rangers: exactly three :class:`Ranger` s, sonar 1 (left) first.
        servo: the array's servo, or None for a fixed array (its angle is then ``fixed_angle_deg``).
        name: device name.
        clock: stamps the readings.
        fixed_angle_deg: servo angle reported when there is no servo.
        max_consecutive_errors: failures in a row after which a sonar is reported as dead.
        retry_dead_every: a dead sonar is tried again on every this-many-th read (1 = always).
    """

    def __init__(
        self,
        rangers: Sequence[Ranger],
        servo: Servo | None = None,
        *,
        name: str = "sonar_array",
        clock: Clock | None = None,
        fixed_angle_deg: float = 90.0,
        max_consecutive_errors: int = 5,
        retry_dead_every: int = 10,
    ) -> None:
        if max_consecutive_errors < 1 or retry_dead_every < 1:
            raise CommandError(
                f"{name}: max_consecutive_errors={max_consecutive_errors!r} and "
                f"retry_dead_every={retry_dead_every!r} must be >= 1"
            )
        if len(rangers) != 3:
            raise CommandError(f"{name}: rangers must be exactly 3 (left, middle, right), got {len(rangers)}")
        self.rangers = tuple(rangers)
        self.servo = servo
        self.name = name
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        self.fixed_angle_deg = fixed_angle_deg
        self.max_consecutive_errors = max_consecutive_errors
        self.error_counts = [0, 0, 0]
        self.consecutive_errors = [0, 0, 0]
        self.last_errors: list[BaseException | None] = [None, None, None]
        self.retry_dead_every = retry_dead_every
        self.skipped_counts = [0, 0, 0]
        self._skips_left = [0, 0, 0]

    def open(self) -> None:
        if self._is_open:
            return
        opened: list[Any] = []
        try:
            for dev in self._devices():
                dev.open()
                opened.append(dev)
        except BaseException:
            for dev in reversed(opened):
                dev.close()
            raise
        self._is_open = True

    def close(self) -> None:
        for dev in reversed(self._devices()):
            try:
                dev.close()
            except Exception as exc:  # closing the rest matters more
                log.warning("%s: closing %s failed: %s", self.name, getattr(dev, "name", dev), exc)
        self._is_open = False

    def _devices(self) -> list[Any]:
        return [*self.rangers, *([self.servo] if self.servo is not None else [])]

    def set_servo_deg(self, angle_deg: float) -> None:
        self._check_open()
        if self.servo is None:
            raise CommandError(f"{self.name}: this array has no servo; cannot turn to {angle_deg!r} deg")
        self.servo.set_angle_deg(angle_deg)

    def read(self) -> SonarArrayReading:
        """Fire sonars 1, 2, 3 in turn; a failing sonar reads NaN and the others go on."""
        self._check_open()
        stamp = self._clock.now_ns()
        ranges: list[float] = []
        for k, ranger in enumerate(self.rangers):
            if self._skips_left[k] > 0:  # dead: rest it instead of paying another timeout
                self._skips_left[k] -= 1
                self.skipped_counts[k] += 1
                ranges.append(math.nan)
                continue
            try:
                r = float(ranger.read().range_m)
            except (HardwareError, OSError) as exc:
                r = math.nan
                self.error_counts[k] += 1
                self.consecutive_errors[k] += 1
                self.last_errors[k] = exc
                level = (
                    logging.WARNING
                    if self.consecutive_errors[k] == self.max_consecutive_errors
                    else logging.INFO
                )
                log.log(
                    level,
                    "%s: sonar %d (%s) failed (%d in a row, %d total): %s",
                    self.name,
                    k + 1,
                    getattr(ranger, "name", "?"),
                    self.consecutive_errors[k],
                    self.error_counts[k],
                    exc,
                )
                if self.consecutive_errors[k] >= self.max_consecutive_errors:
                    self._skips_left[k] = self.retry_dead_every - 1
            else:
                if self.consecutive_errors[k] >= self.max_consecutive_errors:
                    log.warning("%s: sonar %d is back", self.name, k + 1)
                self.consecutive_errors[k] = 0
            ranges.append(r)
        angle = self.servo.angle_deg() if self.servo is not None else self.fixed_angle_deg
        return SonarArrayReading(
            stamp_ns=stamp, ranges_m=(ranges[0], ranges[1], ranges[2]), servo_angle_deg=angle
        )

    @property
    def dead(self) -> tuple[bool, bool, bool]:
        """Sonars that have failed at least ``max_consecutive_errors`` reads in a row."""
        d = [c >= self.max_consecutive_errors for c in self.consecutive_errors]
        return d[0], d[1], d[2]
