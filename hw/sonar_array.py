"""A :class:`hw.interfaces.SonarArray` made of three :class:`Ranger` s and an optional :class:`Servo`.

Sonars 1, 2, 3 are left, middle, right (outer ones at +-30 deg, SPEC section 3). Their beams overlap by
design, so one sonar hears another's ping: sonars of one array are never fired within each other's
echo window, :data:`ECHO_WINDOW_S` = 65 ms (the SRF08 datasheet's firing interval at the power-up
gain; a ping fired sooner hears the distant echoes of the previous one). The two arrays of the chair are
fired in step by a :class:`SonarFiringGroup`: slot k (65 ms long) fires sonar k of every array at
once, so each sonar is fired at most every 3 x 65 ms = 195 ms (:attr:`SonarFiringGroup.cycle_time_s`).
A read fires the next slot when it is due and returns every sonar's latest range: a loop at 10 Hz gets
one fresh sonar per array per cycle and a whole fresh array every 300 ms. Sonars of different arrays
fired in the same instant may hear each other's echo of the same object, which reads at about that
object's range (a bistatic echo), never a stale one. An array without a group schedules its own three
sonars the same way.

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
        try:
            self._scheduler().prime(self)  # fire each sonar once now, so no read has to wait for three
        except BaseException:
            self.close()
            raise

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
        """Each sonar's latest range (see :class:`SonarFiringGroup`); a failing sonar reads NaN.

        Fires the next slot when it is due and blocks for its ranging (:meth:`open` has fired each
        sonar once already, blocking 2 x 65 ms plus a ranging).
        """
        self._check_open()
        return self._scheduler().read(self)

    def _scheduler(self) -> SonarFiringGroup:
        if self.group is not None:
            return self.group
        if self._own_group is None:
            self._own_group = SonarFiringGroup([self], clock=self._clock, attach=False)
        return self._own_group

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

    Slot k fires sonar k of every array at once and collects them; slots go k = 0, 1, 2, 0, ... and a
    slot never starts sooner than ``echo_window_s`` after the previous one, so no two pings of one
    array are closer than 65 ms and each sonar is fired at most every :attr:`cycle_time_s` = 3 x 65 ms
    = 195 ms.

    :meth:`read` does not wait for a slot: it fires the next slot when one is due (blocking only for
    that slot's ranging, 11.9 ms at a 2 m range setting) and returns each sonar's latest range, stamped
    with the oldest ping among the three. The first read of an array blocks until all three of its
    sonars have been fired once (:meth:`RangerSonarArray.open` does that). So a loop that reads every
    65 ms or slower refreshes one sonar of each
    array per read and a whole array every three reads (300 ms at 10 Hz, 195 ms at the fastest).

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
        self._window_ns = round(self.echo_window_s * 1e9)
        self._clock: Clock = clock if clock is not None else self.arrays[0]._clock
        self._last_slot_ns: int | None = None
        self._next = 0
        self._ranges = {id(a): [math.nan] * 3 for a in self.arrays}
        self._stamps: dict[int, list[int | None]] = {id(a): [None] * 3 for a in self.arrays}
        self.slots = 0
        if attach:
            for a in self.arrays:
                a.group = self

    @property
    def cycle_time_s(self) -> float:
        """Shortest time between two firings of one sonar, and for a whole set of readings, s (195 ms)."""
        return 3 * self.echo_window_s

    @property
    def cycles(self) -> int:
        """Complete cycles (three slots) fired so far."""
        return self.slots // 3

    def prime(self, array: RangerSonarArray) -> None:
        """Fire slots (waiting for each) until every sonar of ``array`` has been fired once."""
        while any(t is None for t in self._stamps[id(array)]):
            self._fire(wait=True)

    def read(self, array: RangerSonarArray) -> SonarArrayReading:
        """``array``'s latest three ranges, after firing the next slot if it is due (see the class)."""
        stamps = self._stamps[id(array)]
        if any(t is None for t in stamps):
            self.prime(array)
        else:
            self._fire(wait=False)
        r = self._ranges[id(array)]
        return SonarArrayReading(
            stamp_ns=min(t for t in stamps if t is not None),
            ranges_m=(r[0], r[1], r[2]),
            servo_angle_deg=array._servo_angle(),
        )

    def _fire(self, wait: bool) -> None:
        """Fire and collect the next slot; when it is not due yet, wait for it or (``wait=False``) skip."""
        if self._last_slot_ns is not None:
            due = self._last_slot_ns + self._window_ns
            if self._clock.now_ns() < due:
                if not wait:
                    return
                self._clock.sleep_until_ns(due)
        k = self._next
        slot = self._clock.now_ns()
        self._last_slot_ns = slot
        started = [(a, a._start(k)) for a in self.arrays if a.is_open]
        for a, st in started:
            self._ranges[id(a)][k] = a._finish(k, st)
            self._stamps[id(a)][k] = slot
        self._next = (k + 1) % 3
        self.slots += 1
