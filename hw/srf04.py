"""Devantech SRF04 ultrasonic ranger (trigger/echo timing): a :class:`hw.interfaces.Ranger`.

Timing (Devantech SRF04 technical documentation): a 10 us high pulse on the trigger input starts a
ranging; the SRF04 sends its burst and raises the echo line, and lowers it when the echo returns, so
the echo pulse width is the flight time: ``range_cm = width_us / 58``. With nothing in range the
echo line drops anyway after about 36 ms. Readings follow REP-117 (``sensor_msgs/Range``):

* an echo beyond the rated :data:`MAX_RANGE_M` (3 m, a pulse over 17.4 ms), and the no-echo pulse
  (``no_echo_width_s`` = 30 ms or longer), read ``+inf``: no return within range. The SRF04's range is
  only rated to 3 m, so a 3.1-5.2 m value would be an echo the sensor does not promise to see again;
* an echo under the rated :data:`MIN_RANGE_M` (3 cm, a pulse under 174 us) reads NaN: invalid. Such a
  pulse is the transducer's ring-down or electrical crosstalk as often as a touching object, and the
  sensor cannot tell them apart; REP-117's ``-inf`` ("too close") would claim a detection, and the
  sonar fusion (:mod:`mapping.sonar`) refuses negative ranges.

No pulse at all means a disconnected sensor and raises :class:`hw.errors.DeviceTimeoutError`.

The SRF04 sits behind a small pin interface, :class:`EchoPins`, with two implementations:

* :class:`PigpioEchoPins`: a Raspberry Pi with the ``pigpio`` daemon (imported only when built);
  the echo edges are time-stamped by pigpio's microsecond tick.
* :class:`ArduinoEchoPins`: an Arduino times the pulse and reports it over serial, line protocol
  (ASCII, LF-terminated, one request in flight per board)::

      host  -> board   "T <id>\\n"            fire sonar <id> (0..15): 10 us trigger, then time the echo
      board -> host    "E <id> <width_us>\\n" the echo pulse width in whole microseconds; 0 when no
                                             pulse started within the board's 60 ms pulseIn timeout

  Lines that do not parse, or answer another sonar, are ignored and counted.
  :class:`ArduinoSRF04Emulator` speaks the board's side for tests.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from hw.clock import MonotonicClock
from hw.errors import CommandError, DeviceTimeoutError, HardwareError, ProtocolError
from hw.interfaces import Clock, Device, RangeReading
from hw.serial_lines import EmulatedLineBoard, LineTransport, decode_line, lines_until

log = logging.getLogger(__name__)

US_PER_CM = 58.0
TRIGGER_PULSE_US = 10
NO_ECHO_PULSE_S = 0.036  # the SRF04 drops its echo line after ~36 ms without an echo
MIN_RANGE_M = 0.03  # SPEC table 5.1
MAX_RANGE_M = 3.0
FIELD_OF_VIEW_RAD = math.radians(60.0)


@runtime_checkable
class EchoPins(Protocol):
    """Trigger and echo lines of one SRF04."""

    def trigger(self) -> None:
        """Send the 10 us trigger pulse."""
        ...

    def wait_echo_width_s(self, timeout_s: float) -> float | None:
        """Width of the echo pulse that follows the trigger, seconds; None if none within ``timeout_s``."""
        ...

    def close(self) -> None: ...


class SRF04(Device):
    """One SRF04 behind an :class:`EchoPins`.

    Args:
        pins: the trigger/echo interface (owned: closed with the device).
        name: device name.
        clock: time source (pacing and stamps).
        min_cycle_s: minimum time between two triggers, so the previous ping's echoes have faded.
        no_echo_width_s: echo pulses this long or longer mean "nothing in range".
        timeout_s: how long to wait for the echo pulse to finish before declaring the sensor silent.
    """

    def __init__(
        self,
        pins: EchoPins,
        *,
        name: str = "srf04",
        clock: Clock | None = None,
        min_cycle_s: float = 0.05,
        no_echo_width_s: float = 0.030,
        timeout_s: float = 0.070,
    ) -> None:
        if not (0.0 < no_echo_width_s < timeout_s):
            raise CommandError(
                f"{name}: need 0 < no_echo_width_s ({no_echo_width_s!r}) < timeout_s ({timeout_s!r})"
            )
        self.pins = pins
        self.name = name
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        self.min_cycle_s = min_cycle_s
        self.no_echo_width_s = no_echo_width_s
        self.timeout_s = timeout_s
        self._last_trigger_ns: int | None = None

    def close(self) -> None:
        if self._is_open:
            self.pins.close()
        self._is_open = False

    def read(self) -> RangeReading:
        """Trigger, time the echo, convert: ``+inf`` beyond the range or without an echo, NaN under it.

        Raises:
            DeviceClosedError: The device is not open.
            DeviceTimeoutError: No echo pulse within ``timeout_s`` (sensor silent).
            ProtocolError: The pin interface reported a negative or non-finite width.
        """
        self._check_open()
        if self._last_trigger_ns is not None:
            self._clock.sleep_until_ns(self._last_trigger_ns + round(self.min_cycle_s * 1e9))
        stamp = self._clock.now_ns()
        self._last_trigger_ns = stamp
        self.pins.trigger()
        width = self.pins.wait_echo_width_s(self.timeout_s)
        if width is None:
            raise DeviceTimeoutError(
                f"{self.name}: no echo pulse within {self.timeout_s * 1e3:.0f} ms of the trigger "
                "(sensor unpowered or disconnected?)"
            )
        if not (math.isfinite(width) and width >= 0.0):
            raise ProtocolError(f"{self.name}: echo width {width!r} s is not a finite value >= 0")
        range_m = width * 1e6 / US_PER_CM / 100.0
        if width >= self.no_echo_width_s or range_m > MAX_RANGE_M:
            range_m = math.inf
        elif range_m < MIN_RANGE_M:
            range_m = math.nan
        return RangeReading(
            stamp_ns=stamp,
            range_m=range_m,
            min_range_m=MIN_RANGE_M,
            max_range_m=MAX_RANGE_M,
            field_of_view_rad=FIELD_OF_VIEW_RAD,
        )


# --- Raspberry Pi (pigpio) -----------------------------------------------------------------------------


class PigpioEchoPins:
    """SRF04 on two Raspberry Pi GPIOs through the pigpio daemon (``sudo pigpiod``).

    The trigger uses ``gpio_trigger`` (a 10 us pulse timed by the daemon); the echo edges come from a
    pigpio callback with the daemon's microsecond tick, so Python's scheduling does not enter the width.
    """

    def __init__(self, trigger_gpio: int, echo_gpio: int, host: str = "localhost") -> None:
        try:
            import pigpio
        except ImportError as exc:
            raise HardwareError("PigpioEchoPins needs the 'pigpio' package and a running pigpiod") from exc
        self._pigpio: Any = pigpio
        self._pi: Any = pigpio.pi(host)
        if not self._pi.connected:
            raise HardwareError(f"cannot connect to the pigpio daemon on {host!r} (is pigpiod running?)")
        self.trigger_gpio = trigger_gpio
        self.echo_gpio = echo_gpio
        self._pi.set_mode(trigger_gpio, pigpio.OUTPUT)
        self._pi.write(trigger_gpio, 0)
        self._pi.set_mode(echo_gpio, pigpio.INPUT)
        self._rise_tick: int | None = None
        self._width_us: int | None = None
        self._done = threading.Event()
        self._cb = self._pi.callback(echo_gpio, pigpio.EITHER_EDGE, self._edge)

    def _edge(self, gpio: int, level: int, tick: int) -> None:
        if level == 1:
            self._rise_tick = tick
        elif level == 0 and self._rise_tick is not None:
            self._width_us = self._pigpio.tickDiff(self._rise_tick, tick)
            self._done.set()

    def trigger(self) -> None:
        self._rise_tick = None
        self._width_us = None
        self._done.clear()
        self._pi.gpio_trigger(self.trigger_gpio, TRIGGER_PULSE_US, 1)

    def wait_echo_width_s(self, timeout_s: float) -> float | None:
        if not self._done.wait(timeout_s) or self._width_us is None:
            return None
        return self._width_us / 1e6

    def close(self) -> None:
        self._cb.cancel()
        self._pi.stop()


# --- Arduino over serial ------------------------------------------------------------------------------


class ArduinoEchoPins:
    """One SRF04 on an Arduino that times echo pulses and reports them over serial (module protocol).

    Args:
        transport: the board's serial link (shared by every sonar on the board; not closed here).
        sonar_id: the board's sonar number, 0..15.
        clock: time source for the reply deadline.
        poll_s: how long one empty ``readline`` is taken to have waited (a real port blocks for its
            own timeout; with a manual clock this advances simulated time).
    """

    def __init__(
        self, transport: LineTransport, sonar_id: int, clock: Clock | None = None, poll_s: float = 0.005
    ):
        if not (isinstance(sonar_id, int) and 0 <= sonar_id <= 15):
            raise CommandError(f"sonar_id={sonar_id!r} must be an integer 0..15")
        self.transport = transport
        self.sonar_id = sonar_id
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        self.poll_s = poll_s
        self.ignored_lines = 0

    def trigger(self) -> None:
        self.transport.write(f"T {self.sonar_id}\n".encode("ascii"))

    def wait_echo_width_s(self, timeout_s: float) -> float | None:
        for raw in lines_until(self.transport, self._clock, timeout_s, self.poll_s):
            width_us = self._parse(raw)
            if width_us is None:
                continue
            return None if width_us == 0 else width_us / 1e6
        return None

    def _parse(self, raw: bytes) -> int | None:
        text = decode_line(raw)
        parts = text.split(" ") if text is not None else []
        if len(parts) == 3 and parts[0] == "E" and parts[1].isdigit() and parts[2].isdigit():
            if int(parts[1]) == self.sonar_id:
                return int(parts[2])
        self.ignored_lines += 1
        log.debug("SRF04 board: ignored line %r while waiting for sonar %d", raw, self.sonar_id)
        return None

    def close(self) -> None:
        """The transport is shared by the board's sonars; its owner closes it."""


class ArduinoSRF04Emulator(EmulatedLineBoard):
    """The Arduino side of the SRF04 line protocol, as a :class:`LineTransport` for tests and demos.

    Args:
        ranges: ``ranges(sonar_id, stamp_ns)`` -> metres; NaN/inf = nothing (a 36 ms echo pulse).
        clock: stamps passed to ``ranges``.
        sonar_ids: the sonars wired to the board; a request for another id reports width 0 (no pulse).
    """

    def __init__(self, ranges: Callable[[int, int], float], clock: Clock, sonar_ids: tuple[int, ...] = (0,)):
        super().__init__()
        self.ranges = ranges
        self.clock = clock
        self.sonar_ids = set(sonar_ids)
        self.drop_replies = 0
        self.garble_replies = 0
        self.wrong_id_replies = 0
        self.requests: list[int] = []

    # board behaviour ------------------------------------------------------------------------------------
    def _handle(self, line: str) -> None:
        parts = line.split()
        if len(parts) != 2 or parts[0] != "T" or not parts[1].isdigit():
            return  # the sketch ignores what it does not understand
        sid = int(parts[1])
        self.requests.append(sid)
        if sid not in self.sonar_ids:
            width = 0
        else:
            r = float(self.ranges(sid, self.clock.now_ns()))
            in_range = math.isfinite(r) and 0.0 < r <= MAX_RANGE_M
            width = round(r * 100.0 * US_PER_CM) if in_range else round(NO_ECHO_PULSE_S * 1e6)
        if self.drop_replies > 0:
            self.drop_replies -= 1
            return
        if self.garble_replies > 0:
            self.garble_replies -= 1
            self._send(b"E\xff" + str(width).encode() + b"\x00\n")
            return
        if self.wrong_id_replies > 0:
            self.wrong_id_replies -= 1
            self._send(f"E {sid + 1} 1234\n".encode())
        self._send(f"E {sid} {width}\n".encode())
