"""Hobby servo of a sonar array (180 deg travel): a :class:`hw.interfaces.Servo`.

Two ways to drive it:

* :class:`SerialServo`: through an Arduino, ASCII line protocol (LF-terminated)::

      host  -> board   "S <id> <angle_deg>\\n"   move servo <id> (0..15) to a whole-degree angle 0..180
      board -> host    "A <id> <angle_deg>\\n"   acknowledged: the board now commands that angle
      board -> host    "N <id> <reason>\\n"      refused (unknown servo, angle out of range)

  :class:`ArduinoServoEmulator` answers the board's side for tests.
* :class:`PwmServo`: a PWM output directly (:class:`PwmOutput`, e.g. :class:`PigpioPwm` on a
  Raspberry Pi): angle -> pulse width, linear from ``min_pulse_us`` at 0 deg to ``max_pulse_us`` at 180.

Both check the command first: a non-finite angle is always refused; an angle outside the limits
(0..180 deg unless narrowed) is clamped to the nearest limit (``out_of_range="clamp"``, logged) or
refused (``out_of_range="refuse"``) with :class:`hw.errors.CommandError`. A hobby servo reports no
position, so ``angle_deg()`` is the last angle the board acknowledged (or the PWM set).
"""

from __future__ import annotations

import logging
import math
from typing import Any, Literal, Protocol, runtime_checkable

from hw.clock import MonotonicClock
from hw.errors import CommandError, DeviceFaultError, DeviceTimeoutError, HardwareError
from hw.interfaces import Clock, Device
from hw.serial_lines import EmulatedLineBoard, LineTransport, decode_line, lines_until

log = logging.getLogger(__name__)

OutOfRange = Literal["clamp", "refuse"]


class _AngleCheck:
    """Limits and the clamp/refuse policy shared by both servos."""

    name: str

    def _init_limits(self, limits_deg: tuple[float, float], out_of_range: OutOfRange) -> None:
        lo, hi = (float(v) for v in limits_deg)
        if not (0.0 <= lo < hi <= 180.0):
            raise CommandError(f"{self.name}: limits_deg={limits_deg!r} must satisfy 0 <= low < high <= 180")
        if out_of_range not in ("clamp", "refuse"):
            raise CommandError(f"{self.name}: out_of_range={out_of_range!r} must be 'clamp' or 'refuse'")
        self.limits_deg = (lo, hi)
        self.out_of_range = out_of_range

    def _checked(self, angle_deg: float) -> float:
        a = float(angle_deg)
        if not math.isfinite(a):
            raise CommandError(f"{self.name}: angle_deg={angle_deg!r} is not finite")
        lo, hi = self.limits_deg
        if lo <= a <= hi:
            return a
        if self.out_of_range == "refuse":
            raise CommandError(f"{self.name}: angle_deg={a:g} is outside the limits {lo:g}..{hi:g} deg")
        clamped = min(max(a, lo), hi)
        log.info("%s: angle %.1f deg clamped to %.1f deg", self.name, a, clamped)
        return clamped


class SerialServo(Device, _AngleCheck):
    """A servo on an Arduino, driven with the module's line protocol.

    Args:
        transport: the board's serial link (shared; not closed here).
        servo_id: the board's servo number 0..15.
        name: device name.
        clock: time source for the acknowledge deadline.
        limits_deg: allowed travel (within 0..180).
        out_of_range: ``"clamp"`` or ``"refuse"`` angles outside the limits.
        initial_deg: angle commanded on ``open()`` so the state is known (None: none sent).
        reply_timeout_s: how long to wait for ``A``/``N``.
        retries: extra attempts after a timed-out command.
        poll_s: how long an empty ``readline`` is taken to have waited (see hw.srf04.ArduinoEchoPins).
    """

    def __init__(
        self,
        transport: LineTransport,
        servo_id: int = 0,
        *,
        name: str | None = None,
        clock: Clock | None = None,
        limits_deg: tuple[float, float] = (0.0, 180.0),
        out_of_range: OutOfRange = "clamp",
        initial_deg: float | None = 90.0,
        reply_timeout_s: float = 0.1,
        retries: int = 1,
        poll_s: float = 0.005,
    ) -> None:
        self.name = name or f"servo{servo_id}"
        if not (isinstance(servo_id, int) and 0 <= servo_id <= 15):
            raise CommandError(f"{self.name}: servo_id={servo_id!r} must be an integer 0..15")
        self._init_limits(limits_deg, out_of_range)
        self.transport = transport
        self.servo_id = servo_id
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        self.initial_deg = initial_deg
        self.reply_timeout_s = reply_timeout_s
        self.retries = retries
        self.poll_s = poll_s
        self._angle_deg = math.nan
        self.ignored_lines = 0

    def open(self) -> None:
        self._is_open = True
        if self.initial_deg is not None:
            try:
                self.set_angle_deg(self.initial_deg)
            except BaseException:
                self._is_open = False
                raise

    def angle_deg(self) -> float:
        """Last angle the board acknowledged (NaN before the first)."""
        self._check_open()
        return self._angle_deg

    def set_angle_deg(self, angle_deg: float) -> None:
        self._check_open()
        target = round(self._checked(angle_deg))  # the protocol carries whole degrees
        line = f"S {self.servo_id} {target}\n".encode("ascii")
        for attempt in range(self.retries + 1):
            self.transport.write(line)
            reply = self._await_reply()
            if reply is None:
                log.info("%s: no acknowledge for %r (attempt %d)", self.name, line, attempt + 1)
                continue
            kind, value = reply
            if kind == "N":
                raise DeviceFaultError(f"{self.name}: board refused angle {target} deg: {value}")
            if int(value) != target:
                raise HardwareError(f"{self.name}: board acknowledged {value} deg, not the {target} deg sent")
            self._angle_deg = float(target)
            return
        raise DeviceTimeoutError(
            f"{self.name}: no acknowledge within {self.reply_timeout_s * 1e3:.0f} ms"
            f" after {self.retries + 1} tries"
        )

    def _await_reply(self) -> tuple[str, str] | None:
        for raw in lines_until(self.transport, self._clock, self.reply_timeout_s, self.poll_s):
            text = decode_line(raw)
            parts = text.split(" ", 2) if text is not None else []
            if len(parts) == 3 and parts[0] in ("A", "N") and parts[1] == str(self.servo_id):
                if parts[0] == "N" or parts[2].isdigit():
                    return parts[0], parts[2]
            self.ignored_lines += 1
            log.debug("%s: ignored line %r", self.name, raw)
        return None


class ArduinoServoEmulator(EmulatedLineBoard):
    """The board side of the servo protocol, as a :class:`hw.serial_lines.LineTransport`.

    Holds the commanded angle of each servo in :attr:`angles`. Fault injection: ``drop_replies``
    (swallow N acknowledges), ``refuse_next`` (answer N once with a reason).
    """

    def __init__(self, servo_ids: tuple[int, ...] = (0,)) -> None:
        super().__init__()
        self.angles: dict[int, int | None] = dict.fromkeys(servo_ids)
        self.drop_replies = 0
        self.refuse_next: str | None = None
        self.commands: list[tuple[int, int]] = []

    def _reply(self, line: str) -> None:
        if self.drop_replies > 0:
            self.drop_replies -= 1
            return
        self._send(line.encode("ascii") + b"\n")

    def _handle(self, line: str) -> None:
        parts = line.split()
        if len(parts) != 3 or parts[0] != "S" or not parts[1].isdigit():
            return
        sid = int(parts[1])
        if sid not in self.angles:
            self._reply(f"N {sid} no such servo")
            return
        if not parts[2].isdigit() or not 0 <= int(parts[2]) <= 180:
            self._reply(f"N {sid} angle out of range")
            return
        if self.refuse_next is not None:
            reason, self.refuse_next = self.refuse_next, None
            self._reply(f"N {sid} {reason}")
            return
        angle = int(parts[2])
        self.angles[sid] = angle
        self.commands.append((sid, angle))
        self._reply(f"A {sid} {angle}")


@runtime_checkable
class PwmOutput(Protocol):
    """A servo PWM output: 50 Hz frame, settable high time."""

    def set_pulse_width_us(self, width_us: float) -> None: ...

    def close(self) -> None: ...


class PwmServo(Device, _AngleCheck):
    """A servo driven by a PWM output; angle maps linearly onto the pulse width.

    Args:
        pwm: the output (owned: closed with the servo).
        min_pulse_us, max_pulse_us: pulse widths at 0 and 180 deg (typical hobby servo 500-2500 us;
            check the servo's datasheet).
    """

    def __init__(
        self,
        pwm: PwmOutput,
        *,
        name: str = "servo",
        limits_deg: tuple[float, float] = (0.0, 180.0),
        out_of_range: OutOfRange = "clamp",
        min_pulse_us: float = 500.0,
        max_pulse_us: float = 2500.0,
        initial_deg: float | None = 90.0,
    ) -> None:
        self.name = name
        self._init_limits(limits_deg, out_of_range)
        if not (0.0 < min_pulse_us < max_pulse_us <= 3000.0):
            raise CommandError(f"{name}: need 0 < min_pulse_us < max_pulse_us <= 3000 us")
        self.pwm = pwm
        self.min_pulse_us = min_pulse_us
        self.max_pulse_us = max_pulse_us
        self.initial_deg = initial_deg
        self._angle_deg = math.nan

    def open(self) -> None:
        self._is_open = True
        if self.initial_deg is not None:
            self.set_angle_deg(self.initial_deg)

    def close(self) -> None:
        if self._is_open:
            self.pwm.close()
        self._is_open = False

    def pulse_width_us(self, angle_deg: float) -> float:
        return self.min_pulse_us + (self.max_pulse_us - self.min_pulse_us) * angle_deg / 180.0

    def set_angle_deg(self, angle_deg: float) -> None:
        self._check_open()
        a = self._checked(angle_deg)
        self.pwm.set_pulse_width_us(self.pulse_width_us(a))
        self._angle_deg = a

    def angle_deg(self) -> float:
        self._check_open()
        return self._angle_deg


class PigpioPwm:
    """Servo pulses on a Raspberry Pi GPIO through pigpio (``set_servo_pulsewidth``; 0 = off)."""

    def __init__(self, gpio: int, host: str = "localhost") -> None:
        try:
            import pigpio
        except ImportError as exc:
            raise HardwareError("PigpioPwm needs the 'pigpio' package and a running pigpiod") from exc
        self._pi: Any = pigpio.pi(host)
        if not self._pi.connected:
            raise HardwareError(f"cannot connect to the pigpio daemon on {host!r} (is pigpiod running?)")
        self.gpio = gpio

    def set_pulse_width_us(self, width_us: float) -> None:
        self._pi.set_servo_pulsewidth(self.gpio, round(width_us))

    def close(self) -> None:
        self._pi.set_servo_pulsewidth(self.gpio, 0)  # stop the pulses: the servo goes limp
        self._pi.stop()
