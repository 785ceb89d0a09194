"""A :class:`hw.interfaces.SonarArray` made of three :class:`Ranger` s and an optional :class:`Servo`.

Sonars 1, 2, 3 are left, middle, right (outer ones at +-30 deg, SPEC section 3). Their beams overlap by
design, so one sonar hears another's ping: sonars of one array are never fired within each other's
echo window, :data:`ECHO_WINDOW_S` = 65 ms (the SRF08 datasheet's firing interval at the power-up
gain; a ping fired sooner hears the distant echoes of the previous one). The two arrays of the chair are
fired in step by a :class:`SonarFiringGroup`: slot k (65 ms long) fires sonar k of every array at
once, so a whole cycle of six readings takes 3 x 65 ms = 195 ms (:attr:`SonarFiringGroup.cycle_time_s`),
each sonar is fired every 195 ms, and the first array's :meth:`RangerSonarArray.read` runs the cycle
while the other array's read returns the reading of that same cycle. Sonars of different arrays fired in
the same instant may hear each other's echo of the same object, which reads at about that object's
range (a bistatic echo), never a stale one. An array without a group fires its own three sonars one
slot each, with the same spacing.

A sonar that fails (I/O error, timeout, protocol error) gives NaN for that reading while the
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
from hw.interfaces import Clock, Device, Ranger, RangeReading, Servo, SonarArrayReading

log = logging.getLogger(__name__)

ECHO_WINDOW_S = 0.065
"""Shortest time between two pings of one array (and between two pings of one sonar), s: the SRF08
datasheet's "fire every 65 ms or slower" at the power-up gain."""


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
        self.group: SonarFiringGroup | None = None
        self._own_group: SonarFiringGroup | None = None

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
        """The three ranges of one firing cycle (see the module docstring); a failing sonar reads NaN.

        Blocks until the cycle is done: up to :attr:`SonarFiringGroup.cycle_time_s` (195 ms).
        """
        self._check_open()
        if self.group is None:
            if self._own_group is None:
                self._own_group = SonarFiringGroup([self], clock=self._clock, attach=False)
            return self._own_group.read(self)
        return self.group.read(self)

    def _servo_angle(self) -> float:
        return self.servo.angle_deg() if self.servo is not None else self.fixed_angle_deg

    def _start(self, k: int) -> Any:
        """Fire sonar ``k`` (0-based); returns what :meth:`_finish` needs to collect its range."""
        if self._skips_left[k] > 0:  # dead: rest it instead of paying another timeout
            self._skips_left[k] -= 1
            self.skipped_counts[k] += 1
            return None
        ranger = self.rangers[k]
        start, collect = getattr(ranger, "start_ranging", None), getattr(ranger, "collect", None)
        if start is None or collect is None:
            return ranger.read  # a ranger without a split ranging reads inside the slot
        try:
            stamp = start()
        except (HardwareError, OSError) as exc:
            return exc
        return lambda: collect(stamp)

    def _finish(self, k: int, started: Any) -> float:
        """Collect sonar ``k``'s range (NaN when skipped or failed, with the failure counted)."""
        if started is None:
            return math.nan
        try:
            if isinstance(started, BaseException):
                raise started
            reading: RangeReading = started()
            r = float(reading.range_m)
        except (HardwareError, OSError) as exc:
            self._failed(k, exc)
            return math.nan
        if self.consecutive_errors[k] >= self.max_consecutive_errors:
            log.warning("%s: sonar %d is back", self.name, k + 1)
        self.consecutive_errors[k] = 0
        return r

    def _failed(self, k: int, exc: BaseException) -> None:
        self.error_counts[k] += 1
        self.consecutive_errors[k] += 1
        self.last_errors[k] = exc
        level = logging.WARNING if self.consecutive_errors[k] == self.max_consecutive_errors else logging.INFO
        log.log(
            level,
            "%s: sonar %d (%s) failed (%d in a row, %d total): %s",
            self.name,
            k + 1,
            getattr(self.rangers[k], "name", "?"),
            self.consecutive_errors[k],
            self.error_counts[k],
            exc,
        )
        if self.consecutive_errors[k] >= self.max_consecutive_errors:
            self._skips_left[k] = self.retry_dead_every - 1

    @property
    def dead(self) -> tuple[bool, bool, bool]:
        """Sonars that have failed at least ``max_consecutive_errors`` reads in a row."""
        d = [c >= self.max_consecutive_errors for c in self.consecutive_errors]
        return d[0], d[1], d[2]


class SonarFiringGroup:
    """Fires the sonars of several arrays in step, one slot of :data:`ECHO_WINDOW_S` per sonar index.

    Slot k fires sonar k of every array at once and collects them; the next slot starts no sooner than
    ``echo_window_s`` after this one, across cycles too, so no two pings of one array (nor two pings of
    one sonar) are ever closer than ``echo_window_s``. One cycle (three slots) takes
    :attr:`cycle_time_s` = 3 x 65 ms = 195 ms at the default. Each array's :meth:`read` returns the
    reading of the latest cycle that array has not yet returned, running a new cycle when there is none.

    Args:
        arrays: The arrays (each :class:`RangerSonarArray`; attached to this group unless ``attach`` is
            False).
        clock: Time source for the slots (default: the first array's clock).
        echo_window_s: Slot length, s; the SRF08 datasheet allows nothing shorter than 65 ms at the
            power-up gain and names no interval for a lower one, so shorter windows are refused.
        attach: Set each array's ``group`` to this group.

    Raises:
        CommandError: No arrays, an array twice, or an echo window under 65 ms.
    """

    def __init__(
        self,
        arrays: Sequence[RangerSonarArray],
        *,
        clock: Clock | None = None,
        echo_window_s: float = ECHO_WINDOW_S,
        attach: bool = True,
    ) -> None:
        if not arrays or len({id(a) for a in arrays}) != len(arrays):
            raise CommandError(f"a sonar firing group needs distinct arrays, got {len(arrays)}")
        if not (math.isfinite(echo_window_s) and echo_window_s >= ECHO_WINDOW_S):
            raise CommandError(
                f"echo_window_s={echo_window_s!r}: the SRF08 datasheet allows firing no faster than every "
                f"{ECHO_WINDOW_S * 1e3:.0f} ms at the power-up gain and names no shorter safe interval"
            )
        self.arrays = tuple(arrays)
        self.echo_window_s = float(echo_window_s)
        self._clock: Clock = clock if clock is not None else self.arrays[0]._clock
        self._last_slot_ns: int | None = None
        self._unread: dict[int, SonarArrayReading] = {}
        self.cycles = 0
        if attach:
            for a in self.arrays:
                a.group = self

    @property
    def cycle_time_s(self) -> float:
        """Time between two firings of one sonar, and for one full set of readings, s (195 ms)."""
        return 3 * self.echo_window_s

    def read(self, array: RangerSonarArray) -> SonarArrayReading:
        """The reading of ``array`` from the latest cycle it has not returned yet (runs one if needed)."""
        reading = self._unread.pop(id(array), None)
        if reading is None:
            self._unread = self._cycle()
            reading = self._unread.pop(id(array))
        return reading

    def _cycle(self) -> dict[int, SonarArrayReading]:
        window_ns = round(self.echo_window_s * 1e9)
        ranges = {id(a): [math.nan] * 3 for a in self.arrays}
        stamp: int | None = None
        for k in range(3):
            if self._last_slot_ns is not None:
                self._clock.sleep_until_ns(self._last_slot_ns + window_ns)
            slot = self._clock.now_ns()
            stamp = slot if stamp is None else stamp
            self._last_slot_ns = slot
            started = [(a, a._start(k)) for a in self.arrays if a.is_open]
            for a, st in started:
                ranges[id(a)][k] = a._finish(k, st)
        self.cycles += 1
        assert stamp is not None
        return {
            id(a): SonarArrayReading(
                stamp_ns=stamp,
                ranges_m=(ranges[id(a)][0], ranges[id(a)][1], ranges[id(a)][2]),
                servo_angle_deg=a._servo_angle(),
            )
            for a in self.arrays
        }
