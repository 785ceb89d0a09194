"""A Roboteq MDC2230 on a pseudo-terminal: same command set, same framing, motors through the plant.

The emulator opens a pty (``os.openpty``, raw mode), and a background thread answers what arrives on
the master side as the controller does on its serial port (Roboteq user manual V1.8/V2.0): echo of
each character as it arrives (when on; ``^ECHOF 1`` turns it off), CR or ``_`` ending a command,
``+``/``-`` acknowledgements, ``NAME=v1:v2`` answers with CR line ends, ``# C`` stopping telemetry.
The real driver (:class:`hw.roboteq.driver.RoboteqMDC2230`) is pointed at
:attr:`RoboteqEmulator.device_path` unchanged.

Each channel runs the identified second-order plant (:class:`robchair.platform.control.DiscretePlant`, command
RPM in, shaft RPM out) under the discrete PID (:class:`robchair.platform.control.DiscretePID`) at the
controller rate, with the gains the driver wrote (``^KP/^KI/^KD`` in firmware units). Encoder ticks are
counted quadrature x4 into a signed 32-bit counter. The serial watchdog (``^RWD`` ms) stops both
motors when no ``!`` command arrived within the period; as the manual says, the motors resume their
earlier set points on the next valid command (so a host must command zero after a stall).
The set point reaches the PID through the ``^MAC``/``^MDEC`` ramps (0.1 RPM/s; power-on 1000 RPM/s);
``^CLERD`` stops a channel whose speed error stays above the level's threshold for its time (?FM
f3, :meth:`RoboteqEmulator.disconnect_encoder` provokes it); ``^ALIM`` is stored, not modelled.
Gains are 0..255 on 1.x and 0..2,000,000,000 on 2.x, as in the manual.

Time: by default motor time follows ``time.monotonic_ns`` (the real elapsed time); pass any
:class:`hw.interfaces.Clock` (e.g. :class:`hw.clock.ManualClock`) to step simulated time instead, so tests run
simulated seconds in milliseconds. Reply delays are always real time, because the driver's deadline is.

Fault injection: :meth:`RoboteqEmulator.inject` drops, garbles or delays the next N replies;
:meth:`raise_fault` sets ``?FF`` flags (which also stops the motors, as the controller does);
:meth:`disconnect` closes the pty as an unplugged cable would; :meth:`inject_kind` applies one of
:data:`INJECT_KINDS` (what ``robchair hw emulate roboteq --inject`` rehearses):

* ``late-ack``: the next reply comes 0.25 s late (after the driver's deadline);
* ``rejected``: the next ``!``/``^`` command is answered ``-`` and not executed (corrupted in transit);
* ``unsolicited``: telemetry ``C=123456:-99`` every 50 ms until ``# C``, as a ``TELS`` script would;
* ``reboot``: the controller restarts: counters 0, echo on, configuration from power-on, ``?FF`` f8;
* ``unknown-flag``: ``?FF`` bit f9, which the V1.8/V2.0 manuals do not name;
* ``garble``: the next reply is line noise;
* ``unplug``: the pty closes;
* ``stall``: motor 1 stalls (``?FM`` f2, ``?FS`` f5) and stops until commanded to zero.
"""

from __future__ import annotations

import collections
import logging
import math
import time
from typing import Any

from hw.clock import ManualClock, MonotonicClock
from hw.errors import HardwareError, ProtocolError
from hw.interfaces import Clock, MotorFaults
from hw.pty_link import PtyServer
from hw.roboteq import codec
from hw.roboteq.emulated_commands import EmulatedCommandSet
from hw.roboteq.emulated_motors import StopEvent
from robchair.platform.spec import RobChairSpec

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_FIRMWARE", "ManualClock", "RoboteqEmulator", "StopEvent", "SyncedClock"]

IDLE_WAKE_S = 0.02
DEFAULT_FIRMWARE = "Roboteq v1.3 MDC2230 07/24/2013"
INJECT_KINDS = ("late-ack", "rejected", "unsolicited", "reboot", "unknown-flag", "garble", "unplug", "stall")
LATE_ACK_S = 0.25
TELEMETRY_PERIOD_S = 0.05


class SyncedClock(ManualClock):
    """A :class:`hw.clock.ManualClock` that brings its followers (emulators) up to date on each move.

    Stepping an emulated controller through a long jump of simulated time (1.5 s = 1500 controller
    steps) takes real milliseconds. With a plain ManualClock the emulator catches up when the next
    command arrives, i.e. inside the driver's reply deadline; with this clock the catch-up happens in
    ``advance``/``sleep_until_ns`` (the caller's thread), where the real controller's time passes too.
    """

    def __init__(self, start_ns: int = 0) -> None:
        super().__init__(start_ns)
        self.followers: list[Any] = []

    def advance(self, seconds: float) -> None:
        super().advance(seconds)
        for f in self.followers:
            f.sync()

    def sleep_until_ns(self, t_ns: int) -> None:
        super().sleep_until_ns(t_ns)
        for f in self.followers:
            f.sync()


class RoboteqEmulator(EmulatedCommandSet, PtyServer):
    """An emulated MDC2230 answering on a pty.

    Args:
        spec: a :class:`robchair.platform.spec.RobChairSpec` (default: ``load_spec()``); its motor step
            responses give the two plants, its PPR and max RPM the power-on configuration.
        firmware: the ``?FID`` answer; its ``vMAJOR.`` decides the firmware gain units.
        echo: echo each command line back (the controller's default) or not.
        clock: motor time source; None for real elapsed time.
        rate_hz: controller loop rate (the PID and plant step).
        battery_v: reported battery voltage (``?V``).
    """

    name = "roboteq-emulator"
    idle_wake_s = IDLE_WAKE_S

    def __init__(
        self,
        spec: RobChairSpec | None = None,
        *,
        firmware: str = DEFAULT_FIRMWARE,
        echo: bool = True,
        clock: Clock | None = None,
        rate_hz: float = 1000.0,
        battery_v: float = 24.0,
    ) -> None:
        from robchair.platform import control
        from robchair.platform.spec import load_spec

        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise HardwareError(f"RoboteqEmulator: rate_hz must be > 0, got {rate_hz!r}")
        super().__init__()
        self.spec = spec if spec is not None else load_spec()
        self.firmware = codec.parse_firmware_id(firmware)
        self.echo = echo
        self.clock: Clock = clock if clock is not None else MonotonicClock()
        self.dt = 1.0 / rate_hz
        self._dt_ns = round(self.dt * 1e9)
        self.battery_v = battery_v
        self._control = control
        self._rx = b""
        self._pending: list[tuple[float, bytes]] = []  # (monotonic due time, bytes) for delayed replies
        # global configuration
        self.rwd_ms = 1000
        self.estop = False
        self.faults = MotorFaults()
        self.motor_flags = [0, 0]
        self.status_unknown_bits = 0  # ?FS bits above f9, as a newer firmware might set
        # fault injection counters
        self._drop = 0
        self._garble = 0
        self._delay_n = 0
        self._delay_s = 0.0
        self._reject = 0
        self._wd_tripped = False  # the watchdog stopped the motors; set points kept for the resume
        self._telemetry: list[str] = []
        self._telemetry_due = 0.0
        self._telemetry_period = TELEMETRY_PERIOD_S
        # observation
        # (arrival time on the emulator's clock in ns, command line) of everything received; bounded for
        # long interactive sessions. Arrival, not motor time: the motors advance in 1 ms ticks, so a line
        # read just after an event outside would otherwise carry a stamp from before it
        self.received: collections.deque[tuple[int, str]] = collections.deque(maxlen=100_000)
        self.stops: list[StopEvent] = []
        self.watchdog_trips = 0
        self._channels = [self._make_channel(i) for i in range(2)]  # slow the first time (PID design)
        self._t_ns = self.clock.now_ns()  # motor time starts once the channels exist
        self._last_bang_ns = self._t_ns
        if isinstance(self.clock, SyncedClock):
            self.clock.followers.append(self)

    # --- fault injection --------------------------------------------------------------------

    def inject(
        self, *, drop: int = 0, garble: int = 0, delay_s: float = 0.0, delay_n: int = 0, reject: int = 0
    ) -> None:
        """Drop, garble, or delay (by ``delay_s`` real seconds) the next replies; answer the next
        ``reject`` ``!``/``^`` commands ``-`` without executing them (a command corrupted in transit)."""
        with self._lock:
            self._drop += drop
            self._garble += garble
            self._reject += reject
            if delay_n:
                self._delay_n += delay_n
                self._delay_s = float(delay_s)

    def raise_fault(self, faults: MotorFaults) -> None:
        """Set the ``?FF`` flags; any fault stops the motors, as the controller does."""
        with self._lock:
            self._sync()
            self.faults = faults
            if faults.any:
                self._stop_all("fault")

    def emit(self, line: str) -> None:
        """Send a line the host did not ask for (telemetry, a script's print), CR-terminated."""
        with self._lock:
            self._write(line.encode("ascii") + codec.CR)

    def set_fault_word(self, word: int) -> None:
        """Set the raw ``?FF`` word (0..65535, unknown bits included); a set flag stops the motors."""
        self.raise_fault(codec.decode_fault_flags(word))

    def start_telemetry(self, line: str, period_s: float = TELEMETRY_PERIOD_S) -> None:
        """Send ``line`` every ``period_s`` until the host sends ``# C`` (as ``# nn`` telemetry does)."""
        with self._lock:
            self._telemetry = [line]
            self._telemetry_period = float(period_s)
            self._telemetry_due = time.monotonic()

    def reboot(self) -> None:
        """Restart as after a power glitch: counters 0, motors stopped, no stop latched, echo on,
        configuration as at power-on (RAM settings lost), ``?FF`` f8 (default configuration loaded)."""
        with self._lock:
            self._sync()
            self._channels = [self._make_channel(i) for i in range(2)]
            self.rwd_ms, self.echo, self.estop, self._wd_tripped = 1000, True, False, False
            self.motor_flags = [0, 0]
            self.faults = MotorFaults(startup_config=True)
            self._pending.clear()
            self._telemetry = []
            self.stops.append(StopEvent(self._t_ns, "reboot"))

    def inject_kind(self, kind: str) -> None:
        """Apply one fault of :data:`INJECT_KINDS` (see the module docstring)."""
        if kind not in INJECT_KINDS:
            raise HardwareError(f"fault kind {kind!r}: expected one of {', '.join(INJECT_KINDS)}")
        if kind == "late-ack":
            self.inject(delay_n=1, delay_s=LATE_ACK_S)
        elif kind == "rejected":
            self.inject(reject=1)
        elif kind == "unsolicited":
            self.start_telemetry("C=123456:-99")
        elif kind == "reboot":
            self.reboot()
        elif kind == "unknown-flag":
            self.set_fault_word(codec.encode_fault_flags(self.faults) | 1 << 8)
        elif kind == "garble":
            self.inject(garble=1)
        elif kind == "unplug":
            self.disconnect()
        else:  # stall
            with self._lock:
                self._sync()
                self.motor_flags[0] |= 1 << codec.MOTOR_BITS.index("motor_stall")
                self._channels[0].setpoint_rpm = 0.0
                self.stops.append(StopEvent(self._t_ns, "stall"))

    def set_motor_flags(self, channel: int, flags: codec.MotorFlags) -> None:
        """Set the ``?FM`` flags of one channel (loop error, stall, ...)."""
        with self._lock:
            self.motor_flags[channel - 1] = codec.encode_motor_flags(flags)

    def clear_faults(self) -> None:
        with self._lock:
            self.faults = MotorFaults()

    def disconnect(self) -> None:
        """Close the pty (both ends) as if the cable were pulled; the thread stops."""
        self.unplug()

    def _on_start(self) -> None:
        log.info("Roboteq emulator on %s (%s, echo %s)", self.device_path, self.firmware.text, self.echo)

    # --- serving ----------------------------------------------------------------------------

    def _wait_s(self) -> float:
        # Motor state is stepped lazily (on each command, query and clock move), so the thread
        # only needs to wake for input, for a delayed reply falling due, and every 20 ms to keep
        # the real-time catch-up (done inside a reply) short.
        wait = IDLE_WAKE_S if not self._telemetry else min(IDLE_WAKE_S, self._telemetry_period / 2)
        if self._pending:
            wait = max(0.0, min(wait, min(p[0] for p in self._pending) - time.monotonic()))
        return wait

    def _on_wake(self, data: bytes) -> None:
        self._sync()
        self._flush_pending()
        self._send_telemetry()
        if not data:
            return
        if self.echo:  # the controller echoes each character as it arrives
            self._write(data.replace(b"\n", b""))
        self._rx += data
        lines, self._rx = codec.split_command_lines(self._rx)
        for line in lines:
            self._handle_line(line)

    def _send_telemetry(self) -> None:
        now = time.monotonic()
        if self._telemetry and now >= self._telemetry_due:
            self._telemetry_due = now + self._telemetry_period
            for line in self._telemetry:
                self._write(line.encode("ascii") + codec.CR)

    def _flush_pending(self) -> None:
        now = time.monotonic()
        due = [p for p in self._pending if p[0] <= now]
        self._pending = [p for p in self._pending if p[0] > now]
        for _, data in due:
            self._write(data)

    def _reply(self, text: str) -> None:
        data = text.encode("ascii") + codec.CR
        if self._drop > 0:
            self._drop -= 1
            log.debug("emulator: dropped reply %r", text)
            return
        if self._garble > 0:
            self._garble -= 1
            # line noise: every character replaced by a non-ASCII byte keeps the length and the CR
            data = bytes(0x80 | (b ^ 0x2A) for b in data[:-1]) + codec.CR
        if self._delay_n > 0:
            self._delay_n -= 1
            self._pending.append((time.monotonic() + self._delay_s, data))
            return
        self._write(data)

    def _handle_line(self, line: str) -> None:
        if not line.strip():
            return
        self.received.append((self.clock.now_ns(), line.strip()))
        if line.strip().startswith("#"):
            if line.strip()[1:].strip().upper() == "C":
                self._telemetry = []  # "# C": stop the automatic sending; no reply
            return
        try:
            cmd = codec.parse_command(line)
        except ProtocolError:
            self._reply("-")
            return
        if self._reject > 0 and cmd.kind in ("!", "^"):
            self._reject -= 1
            self._reply("-")
            return
        if cmd.refreshes_watchdog:
            self._last_bang_ns = self._t_ns
        try:
            answer = self._execute(cmd)
        except (ProtocolError, KeyError, IndexError, ValueError, TypeError):
            answer = "-"
        self._reply(answer)
