"""The chair's Arduino joystick over serial: a :class:`hw.interfaces.Joystick` with a dead-man button.

Line protocol (ASCII, LF-terminated), streamed by the board at its own rate (e.g. 50 Hz)::

    "J <x> <y> <b> <cc>\\n"

* ``x``: forward axis, raw 10-bit ADC 0..1023 (512 = centre, larger = forward)
* ``y``: turn axis, 0..1023 (512 = centre, larger = turn left)
* ``b``: dead-man button, ``1`` held, ``0`` released
* ``cc``: checksum, two upper-case hex digits: the sum of the bytes of ``"J <x> <y> <b>"`` mod 256

A line that does not match exactly (fields, ranges, checksum) is rejected and counted; it never moves
the chair. :meth:`SerialJoystick.read` drains what has arrived and keeps the newest valid line; when
the newest valid line is older than ``stale_after_s`` (the board stopped talking, the cable came off)
the reading is a zero command with the dead-man released. A released dead-man always gives a zero
command. Axes are normalised to [-1, 1] with a small dead zone around the centre.
:class:`ArduinoJoystickEmulator` is the board's side for tests.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from hw.clock import MonotonicClock
from hw.errors import CommandError, DeviceIOError
from hw.interfaces import Clock, Device, JoystickReading
from hw.serial_lines import EmulatedLineBoard, LineTransport, decode_line

log = logging.getLogger(__name__)

ADC_MAX = 1023
ADC_CENTRE = 512


def checksum(body: str) -> str:
    """Two-hex-digit checksum of a line body (sum of its bytes mod 256)."""
    return f"{sum(body.encode('ascii')) % 256:02X}"


def format_line(x_raw: int, y_raw: int, deadman: bool) -> bytes:
    """The board's line for one sample (used by the emulator and by tests)."""
    body = f"J {x_raw} {y_raw} {1 if deadman else 0}"
    return f"{body} {checksum(body)}\n".encode("ascii")


@dataclass(frozen=True)
class RawSample:
    x_raw: int
    y_raw: int
    deadman: bool


def parse_line(raw: bytes) -> RawSample | None:
    """Parse one line; None when it is not a valid, checksummed joystick line."""
    text = decode_line(raw)
    if text is None:
        return None
    parts = text.split(" ")
    if len(parts) != 5 or parts[0] != "J":
        return None
    _, xs, ys, bs, cc = parts
    if not (xs.isdigit() and ys.isdigit() and bs in ("0", "1")):
        return None
    x, y = int(xs), int(ys)
    if x > ADC_MAX or y > ADC_MAX:
        return None
    if cc != checksum(f"J {xs} {ys} {bs}"):
        return None
    return RawSample(x, y, bs == "1")


class SerialJoystick(Device):
    """The Arduino joystick.

    Args:
        transport: the board's serial link (owned: closed with the joystick).
        name: device name.
        clock: time source (stamps and staleness).
        stale_after_s: a reading older than this gives a zero command with the dead-man released.
        deadzone: normalised axis values with magnitude below this read as 0.
        max_lines_per_read: bound on the lines drained by one ``read`` (a flooding board cannot
            stall the control loop).
    """

    def __init__(
        self,
        transport: LineTransport,
        *,
        name: str = "joystick",
        clock: Clock | None = None,
        stale_after_s: float = 0.2,
        deadzone: float = 0.05,
        max_lines_per_read: int = 200,
    ) -> None:
        if not (math.isfinite(stale_after_s) and stale_after_s > 0):
            raise CommandError(f"{name}: stale_after_s={stale_after_s!r} must be > 0")
        if not (0.0 <= deadzone < 1.0):
            raise CommandError(f"{name}: deadzone={deadzone!r} must be in [0, 1)")
        self.transport = transport
        self.name = name
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        self.stale_after_s = stale_after_s
        self.deadzone = deadzone
        self.max_lines_per_read = max_lines_per_read
        self._last: RawSample | None = None
        self._last_ns: int | None = None
        self.rejected_lines = 0
        self.stale_reads = 0

    def close(self) -> None:
        if self._is_open:
            self.transport.close()
        self._is_open = False

    def _axis(self, raw: int) -> float:
        v = (raw - ADC_CENTRE) / (ADC_MAX - ADC_CENTRE)
        v = min(1.0, max(-1.0, v))
        return 0.0 if abs(v) < self.deadzone else v

    def read(self) -> JoystickReading:
        """Newest valid sample as a command; zero with dead-man released when stale or released."""
        self._check_open()
        for _ in range(self.max_lines_per_read):
            try:
                if self.transport.in_waiting <= 0:
                    break
                raw = self.transport.readline()
            except OSError as exc:  # pyserial's SerialException is an OSError
                raise DeviceIOError(
                    getattr(exc, "errno", None), f"{self.name}: serial line failed: {exc}"
                ) from exc
            if not raw:
                break
            sample = parse_line(raw)
            if sample is None:
                self.rejected_lines += 1
                log.debug("%s: rejected line %r", self.name, raw)
                continue
            self._last = sample
            self._last_ns = self._clock.now_ns()
        now = self._clock.now_ns()
        if self._last is None or self._last_ns is None or now - self._last_ns > self.stale_after_s * 1e9:
            self.stale_reads += 1
            return JoystickReading(
                stamp_ns=now if self._last_ns is None else self._last_ns, forward=0.0, turn=0.0, deadman=False
            )
        s = self._last
        if not s.deadman:
            return JoystickReading(stamp_ns=self._last_ns, forward=0.0, turn=0.0, deadman=False)
        return JoystickReading(
            stamp_ns=self._last_ns, forward=self._axis(s.x_raw), turn=self._axis(s.y_raw), deadman=True
        )


class ArduinoJoystickEmulator(EmulatedLineBoard):
    """The joystick board as a :class:`hw.serial_lines.LineTransport`: call :meth:`emit` to stream."""

    def __init__(self) -> None:
        super().__init__()
        self.x_raw = ADC_CENTRE
        self.y_raw = ADC_CENTRE
        self.deadman = False

    def set(self, x_raw: int, y_raw: int, deadman: bool) -> None:
        self.x_raw, self.y_raw, self.deadman = x_raw, y_raw, deadman

    def emit(self, n: int = 1) -> None:
        """Send ``n`` samples of the current stick state, as the board's loop does."""
        for _ in range(n):
            self._send(format_line(self.x_raw, self.y_raw, self.deadman))

    def emit_raw(self, line: bytes) -> None:
        """Send arbitrary bytes (line noise, a cut line)."""
        self._send(line)
