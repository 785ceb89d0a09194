"""A Roboteq MDC2230 on a pseudo-terminal: same command set, same framing, motors through the plant.

The emulator opens a pty (``os.openpty``, raw mode), and a background thread answers what arrives on
the master side as the controller does on its serial port (Roboteq user manual V1.8/V2.0): echo of
each character as it arrives (when on; ``^ECHOF 1`` turns it off), CR or ``_`` ending a command,
``+``/``-`` acknowledgements, ``NAME=v1:v2`` answers with CR line ends, ``# C`` stopping telemetry.
The real driver (:class:`hw.roboteq.driver.RoboteqMDC2230`) is pointed at
:attr:`RoboteqEmulator.device_path` unchanged.

Each channel runs the identified second-order plant (:class:`robchair.control.DiscretePlant`, command
RPM in, shaft RPM out) under the discrete PID (:class:`robchair.control.DiscretePID`) at the
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
import contextlib
import functools
import logging
import math
import os
import select
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from hw.clock import ManualClock, MonotonicClock
from hw.errors import HardwareError, ProtocolError
from hw.interfaces import Clock, MotorFaults
from hw.roboteq import codec
from hw.roboteq.gains import FIRMWARE_RANGE, gains_from_roboteq
from robchair.spec import RobChairSpec

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_FIRMWARE", "ManualClock", "RoboteqEmulator", "StopEvent", "SyncedClock"]

IDLE_WAKE_S = 0.02
DEFAULT_FIRMWARE = "Roboteq v1.3 MDC2230 07/24/2013"
INJECT_KINDS = ("late-ack", "rejected", "unsolicited", "reboot", "unknown-flag", "garble", "unplug", "stall")
LATE_ACK_S = 0.25
TELEMETRY_PERIOD_S = 0.05
# Power-on values of the per-channel configuration items the driver writes (manual defaults).
POWER_ON_CONFIG = {"MAC": 10000, "MDEC": 10000, "ALIM": 300, "CLERD": 0}


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


@dataclass
class StopEvent:
    """A moment the emulated controller stopped the motors, and why."""

    t_ns: int
    reason: str  # "command" (!S/!G 0 on both), "emergency_stop", "watchdog", "fault"


@dataclass
class _Channel:
    pid: Any
    plant: Any
    gains_fw: list[int]  # [KP, KI, KD] in firmware units
    setpoint_rpm: float = 0.0
    command: float = 0.0  # PID output (command RPM into the plant)
    speed_rpm: float = 0.0
    ramp_rpm: float = 0.0  # the set point after the ^MAC/^MDEC ramp
    ticks: float = 0.0  # unwrapped encoder position, ticks (float keeps the fraction)
    config: dict[str, int] = field(default_factory=dict)
    encoder_lost: bool = False  # the encoder came off: the loop sees 0 RPM and no counts
    loop_error_s: float = 0.0  # how long the loop error has exceeded the ^CLERD threshold
    loop_stopped: bool = False  # ^CLERD tripped: the channel is off until commanded to 0


# ^CLERD level -> (seconds, RPM error) from the manual ("1: 250ms and Error > 100", ...)
LOOP_ERROR_DETECTION = {1: (0.25, 100.0), 2: (0.5, 250.0), 3: (1.0, 500.0)}


@functools.lru_cache(maxsize=16)
def _plant_and_default_gains(
    t_r: float, t_p: float, M_p: float, firmware_major: int
) -> tuple[Any, tuple[int, int, int]]:
    """Identified plant and the firmware gains of the SPEC 5 design (cached: the design is slow)."""
    from hw.roboteq.gains import roboteq_gains
    from robchair import control as c

    plant = c.identify_from_step_metrics(t_r, t_p, M_p).plant
    fw = roboteq_gains(c.design_pid(plant), firmware_major)
    return plant, (fw.kp, fw.ki, fw.kd)


class RoboteqEmulator:
    """An emulated MDC2230 answering on a pty.

    Args:
        spec: a :class:`robchair.spec.RobChairSpec` (default: ``load_spec()``); its motor step
            responses give the two plants, its PPR and max RPM the power-on configuration.
        firmware: the ``?FID`` answer; its ``vMAJOR.`` decides the firmware gain units.
        echo: echo each command line back (the controller's default) or not.
        clock: motor time source; None for real elapsed time.
        rate_hz: controller loop rate (the PID and plant step).
        battery_v: reported battery voltage (``?V``).
    """

    name = "roboteq-emulator"

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
        from robchair import control
        from robchair.spec import load_spec

        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise HardwareError(f"RoboteqEmulator: rate_hz must be > 0, got {rate_hz!r}")
        self.spec = spec if spec is not None else load_spec()
        self.firmware = codec.parse_firmware_id(firmware)
        self.echo = echo
        self.clock: Clock = clock if clock is not None else MonotonicClock()
        self.dt = 1.0 / rate_hz
        self._dt_ns = round(self.dt * 1e9)
        self.battery_v = battery_v
        self._control = control
        self._lock = threading.RLock()
        self._thread: threading.Thread | None = None
        self._running = False
        self._master: int | None = None
        self._slave: int | None = None
        self.device_path: str | None = None
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
        # (motor time, command line) of everything received; bounded for long interactive sessions
        self.received: collections.deque[tuple[int, str]] = collections.deque(maxlen=100_000)
        self.stops: list[StopEvent] = []
        self.watchdog_trips = 0
        self.disconnected = False
        self._channels = [self._make_channel(i) for i in range(2)]  # slow the first time (PID design)
        self._t_ns = self.clock.now_ns()  # motor time starts once the channels exist
        self._last_bang_ns = self._t_ns
        if isinstance(self.clock, SyncedClock):
            self.clock.followers.append(self)

    # --- plant ------------------------------------------------------------------------------

    def _make_channel(self, index: int) -> _Channel:
        c = self._control
        step = self.spec.step_for_channel(index + 1)
        plant, gains = _plant_and_default_gains(step.t_r, step.t_p, step.M_p, self.firmware.major)
        ch = _Channel(pid=None, plant=c.DiscretePlant(plant, self.dt), gains_fw=list(gains))
        ch.config = {
            "MMOD": 1,
            "EPPR": int(self.spec.encoder_ppr),
            "MXRPM": int(self.spec.max_motor_rpm),
            **POWER_ON_CONFIG,
        }
        self._rebuild_pid(ch)
        return ch

    def _rebuild_pid(self, ch: _Channel) -> None:
        g_p, g_i, g_d = ch.gains_fw
        kp, ki, kd = gains_from_roboteq(g_p, g_i, g_d, firmware_major=self.firmware.major)
        mx = float(ch.config["MXRPM"])
        integral = ch.pid.integral if ch.pid is not None else 0.0
        ch.pid = self._control.DiscretePID(kp, ki, kd, self.dt, u_min=-mx, u_max=mx)
        ch.pid.integral = integral  # new gains must not make a running motor jump

    def _ticks_per_motor_rev(self, ch: _Channel) -> float:
        # quadrature x4; an encoder on the wheel turns gear_ratio times slower than the motor.
        # Speeds (!S, ?S) are motor-shaft RPM here whatever encoder_on says (the spec's default is
        # "motor", where the controller's encoder RPM is the motor RPM).
        per_rev = 4.0 * ch.config["EPPR"]
        if getattr(self.spec, "encoder_on", "motor") == "wheel":
            per_rev /= float(self.spec.gear_ratio)
        return per_rev

    def _sync(self) -> None:
        """Advance both channels to the clock's time in controller steps (call with the lock held)."""
        now = self.clock.now_ns()
        while self._t_ns + self._dt_ns <= now:
            self._t_ns += self._dt_ns
            if (
                self.rwd_ms > 0
                and not self._wd_tripped
                and self._t_ns - self._last_bang_ns > self.rwd_ms * 1_000_000
                and any(ch.setpoint_rpm != 0.0 for ch in self._channels)
            ):
                self.watchdog_trips += 1
                self._wd_tripped = True
                self.stops.append(StopEvent(self._t_ns, "watchdog"))
            for ch in self._channels:
                target = 0.0 if self._wd_tripped else ch.setpoint_rpm
                if self.estop or self.faults.any:
                    ch.ramp_rpm = 0.0  # the power stage is off: no ramp
                else:
                    ch.ramp_rpm = self._ramp(ch, target)
                target = ch.ramp_rpm
                measured = 0.0 if ch.encoder_lost else ch.speed_rpm
                self._detect_loop_error(ch, target, measured)
                if ch.loop_stopped:
                    u = 0.0
                elif ch.config["MMOD"] == 1:
                    u = ch.pid.update(target, measured)
                else:  # open loop: the set point is the plant command
                    u = target
                ch.command = float(u)
                ch.speed_rpm = float(ch.plant.step(ch.command))
                if not ch.encoder_lost:
                    ch.ticks += ch.speed_rpm / 60.0 * self.dt * self._ticks_per_motor_rev(ch)

    def _detect_loop_error(self, ch: _Channel, target: float, measured: float) -> None:
        """``^CLERD``: an error above the level's threshold for its time stops the channel (?FM f3)."""
        level = LOOP_ERROR_DETECTION.get(ch.config["CLERD"])
        if level is None or ch.loop_stopped or ch.config["MMOD"] != 1:
            ch.loop_error_s = 0.0
            return
        seconds, rpm = level
        ch.loop_error_s = ch.loop_error_s + self.dt if abs(target - measured) > rpm else 0.0
        if ch.loop_error_s >= seconds:
            index = self._channels.index(ch)
            self.motor_flags[index] |= 1 << codec.MOTOR_BITS.index("loop_error")
            ch.loop_stopped = True
            self.stops.append(StopEvent(self._t_ns, "loop_error"))

    def disconnect_encoder(self, channel: int) -> None:
        """The encoder of ``channel`` comes off: no counts, 0 RPM seen by the loop."""
        with self._lock:
            self._sync()
            self._channels[channel - 1].encoder_lost = True

    def _ramp(self, ch: _Channel, target: float) -> float:
        """Move the ramped set point towards ``target`` at ``^MAC`` (speeding up) or ``^MDEC``
        (slowing down), in 0.1 RPM/s; 0 bypasses the ramp (manual)."""
        now = ch.ramp_rpm
        speeding_up = abs(target) > abs(now) and (now == 0.0 or (target > 0) == (now > 0))
        rate = ch.config["MAC" if speeding_up else "MDEC"] / 10.0
        if rate <= 0:
            return target
        step = rate * self.dt
        return now + max(-step, min(step, target - now))

    def _stop_all(self, reason: str) -> None:
        for ch in self._channels:
            ch.setpoint_rpm = 0.0
        self.stops.append(StopEvent(self._t_ns, reason))

    # --- observation (thread-safe, synced to the clock) ---------------------------------------

    def sync(self) -> None:
        """Advance the motors to the clock's current time now (thread-safe)."""
        with self._lock:
            self._sync()

    @property
    def setpoints_rpm(self) -> tuple[float, float]:
        """The set points the motors follow now (zero while the watchdog holds them)."""
        with self._lock:
            self._sync()
            if self._wd_tripped:
                return (0.0, 0.0)
            return (self._channels[0].setpoint_rpm, self._channels[1].setpoint_rpm)

    @property
    def speeds_rpm(self) -> tuple[float, float]:
        with self._lock:
            self._sync()
            return (self._channels[0].speed_rpm, self._channels[1].speed_rpm)

    @property
    def encoder_counts(self) -> tuple[int, int]:
        with self._lock:
            self._sync()
            return tuple(codec.wrap_int32(math.floor(ch.ticks)) for ch in self._channels)  # type: ignore[return-value]

    def set_encoder_counts(self, left: int, right: int) -> None:
        """Preset the counters (to test 32-bit wrap-around)."""
        with self._lock:
            self._channels[0].ticks = float(left)
            self._channels[1].ticks = float(right)

    def config(self, name: str, channel: int) -> int:
        with self._lock:
            ch = self._channels[channel - 1]
            if name in ("KP", "KI", "KD"):
                return ch.gains_fw[("KP", "KI", "KD").index(name)]
            return ch.config[name]

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

    def clear_faults(self) -> None:
        with self._lock:
            self.faults = MotorFaults()

    def disconnect(self) -> None:
        """Close the pty (both ends) as if the cable were pulled; the thread stops."""
        with self._lock:
            self.disconnected = True
            self._running = False
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None

    # --- lifecycle --------------------------------------------------------------------------

    def start(self) -> str:
        """Open the pty, start answering, return the device path (the pty's slave side)."""
        import termios
        import tty

        if self._thread is not None:
            raise HardwareError("RoboteqEmulator.start: already started")
        master, slave = os.openpty()
        # raw mode on the slave: no line discipline echo, no CR/LF translation, bytes as sent
        tty.setraw(slave, termios.TCSANOW)
        self._master, self._slave = master, slave
        self.device_path = os.ttyname(slave)
        self._running = True
        self._thread = threading.Thread(target=self._serve, name="roboteq-emulator", daemon=True)
        self._thread.start()
        log.info("Roboteq emulator on %s (%s, echo %s)", self.device_path, self.firmware.text, self.echo)
        return self.device_path

    def stop(self) -> None:
        """Stop the thread and close the pty (idempotent)."""
        self._running = False
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        if not self.disconnected:
            self.disconnect()
            self.disconnected = False

    def __enter__(self) -> RoboteqEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- serving ----------------------------------------------------------------------------

    def _serve(self) -> None:
        while self._running:
            master = self._master
            if master is None:
                break
            # Motor state is stepped lazily (on each command, query and clock move), so the thread
            # only needs to wake for input, for a delayed reply falling due, and every 20 ms to keep
            # the real-time catch-up (done inside a reply) short.
            wait = IDLE_WAKE_S if not self._telemetry else min(IDLE_WAKE_S, self._telemetry_period / 2)
            if self._pending:
                wait = max(0.0, min(wait, min(p[0] for p in self._pending) - time.monotonic()))
            try:
                ready, _, _ = select.select([master], [], [], wait)
            except (OSError, ValueError):
                break
            with self._lock:
                if not self._running or self._master is None:
                    break
                self._sync()
                self._flush_pending()
                self._send_telemetry()
                if ready:
                    try:
                        data = os.read(master, 4096)
                    except OSError:
                        data = b""
                    if not data:
                        continue
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

    def _write(self, data: bytes) -> None:
        if self._master is None:
            return
        with contextlib.suppress(OSError):
            os.write(self._master, data)

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
        self.received.append((self._t_ns, line.strip()))
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

    def _execute(self, cmd: codec.Command) -> str:
        prefix = {"!": "bang", "?": "query", "^": "set", "~": "get"}[cmd.kind]
        handler = getattr(self, f"_cmd_{prefix}_{cmd.name}", None)
        if handler is None:
            return "-"
        if cmd.kind == "!":
            # a valid runtime command after a watchdog trip: the motors resume their earlier set points
            self._wd_tripped = False
        return str(handler(*cmd.args))

    # runtime commands -----------------------------------------------------------------------

    def _ch(self, cc: int) -> _Channel:
        if cc not in (1, 2):
            raise ValueError(cc)
        return self._channels[cc - 1]

    def _set_point(self, cc: int, rpm: float) -> str:
        ch = self._ch(cc)
        if self.estop or self.faults.any:
            ch.setpoint_rpm = 0.0
            return "+"
        mx = ch.config["MXRPM"]
        moving = any(c.setpoint_rpm != 0.0 for c in self._channels)
        ch.setpoint_rpm = max(-mx, min(mx, float(rpm)))
        if rpm == 0:  # manual: f2, f3 and f4 of ?FM clear when the motor command returns to 0
            self.motor_flags[cc - 1] &= ~0b1110
            if ch.loop_stopped:
                ch.loop_stopped, ch.loop_error_s = False, 0.0
                ch.pid.integral = 0.0
        if moving and all(c.setpoint_rpm == 0.0 for c in self._channels):
            self.stops.append(StopEvent(self._t_ns, "command"))
        return "+"

    def _cmd_bang_S(self, cc: int, rpm: int) -> str:
        return self._set_point(cc, rpm)

    def _cmd_bang_G(self, cc: int, value: int) -> str:
        if not -1000 <= value <= 1000:
            return "-"
        return self._set_point(cc, value / 1000.0 * self._ch(cc).config["MXRPM"])

    def _cmd_bang_EX(self) -> str:
        self.estop = True
        self._stop_all("emergency_stop")
        return "+"

    def _cmd_bang_MG(self) -> str:
        self.estop = False
        return "+"

    # queries --------------------------------------------------------------------------------

    def _per_channel(self, name: str, values: list[int], args: tuple[int, ...]) -> str:
        if args:
            self._ch(args[0])  # validates the channel
            return codec.format_value(name, values[args[0] - 1])
        return codec.format_value(name, *values)

    def _cmd_query_FID(self) -> str:
        return codec.format_value("FID", self.firmware.text)

    def _cmd_query_C(self, *args: int) -> str:
        counts = [codec.wrap_int32(math.floor(ch.ticks)) for ch in self._channels]
        return self._per_channel("C", counts, args)

    def _cmd_query_S(self, *args: int) -> str:
        return self._per_channel("S", [round(ch.speed_rpm) for ch in self._channels], args)

    def _cmd_query_A(self, *args: int) -> str:
        # Motor current in tenths of an amp. Model: current follows the PID's effort beyond the
        # current speed (torque to accelerate) plus a no-load share proportional to speed.
        amps = [abs(ch.command - ch.speed_rpm) * 0.02 + abs(ch.speed_rpm) * 0.002 for ch in self._channels]
        return self._per_channel("A", [round(a * 10) for a in amps], args)

    def _cmd_query_V(self, *args: int) -> str:
        # internal volts x10 : battery volts x10 : 5 V output in millivolts
        values = [round(self.battery_v * 10) - 3, round(self.battery_v * 10), 4980]
        if args:
            if args[0] not in (1, 2, 3):
                raise ValueError(args[0])
            return codec.format_value("V", values[args[0] - 1])
        return codec.format_value("V", *values)

    def _cmd_query_FF(self) -> str:
        faults = self.faults
        if self.estop and not faults.emergency_stop:
            faults = MotorFaults(**{**faults.__dict__, "emergency_stop": True})
        return codec.format_value("FF", codec.encode_fault_flags(faults))

    def _cmd_query_T(self, *args: int) -> str:
        # MCU, channel 1 and channel 2 heatsink temperatures, degrees C (warming with the motor current)
        heat = [abs(ch.command - ch.speed_rpm) * 0.01 for ch in self._channels]
        values = [31, 28 + round(heat[0]), 28 + round(heat[1])]
        if args:
            if args[0] not in (1, 2, 3):
                raise ValueError(args[0])
            return codec.format_value("T", values[args[0] - 1])
        return codec.format_value("T", *values)

    def _cmd_query_FS(self) -> str:
        stall = any(w & 2 for w in self.motor_flags)
        flags = codec.StatusFlags(
            serial_mode=True,
            power_stage_off=self.estop or self.faults.any,
            stall_detected=stall,
            unknown_bits=self.status_unknown_bits,
        )
        return codec.format_value("FS", codec.encode_status_flags(flags))

    def _cmd_query_FM(self, *args: int) -> str:
        return self._per_channel("FM", list(self.motor_flags), args)

    def set_motor_flags(self, channel: int, flags: codec.MotorFlags) -> None:
        """Set the ``?FM`` flags of one channel (loop error, stall, ...)."""
        with self._lock:
            self.motor_flags[channel - 1] = codec.encode_motor_flags(flags)

    # configuration --------------------------------------------------------------------------

    _PER_CHANNEL_CONFIG = ("MMOD", "EPPR", "MXRPM", "KP", "KI", "KD", "MAC", "MDEC", "ALIM", "CLERD")

    def _cmd_set_config(self, name: str, *args: int) -> str:
        if name == "RWD":
            (ms,) = args
            if not 0 <= ms <= 65000:
                return "-"
            self.rwd_ms = ms
            return "+"
        if name == "ECHOF":
            (off,) = args
            if off not in (0, 1):
                return "-"
            self.echo = off == 0
            return "+"
        cc, value = args
        ch = self._ch(cc)
        gain_range = FIRMWARE_RANGE[self.firmware.major]
        lo, hi = codec.CONFIG_RANGE.get(name, gain_range)
        if name == "MMOD":
            lo, hi = 0, 1  # open loop and closed-loop speed are what this emulator models
        if not lo <= value <= hi:
            return "-"
        if name in ("KP", "KI", "KD"):
            ch.gains_fw[("KP", "KI", "KD").index(name)] = value
            self._rebuild_pid(ch)
        else:
            ch.config[name] = value
            if name == "MXRPM":
                self._rebuild_pid(ch)
        return "+"

    def _cmd_get_config(self, name: str, *args: int) -> str:
        if name == "RWD":
            return codec.format_value("RWD", self.rwd_ms)
        if name == "ECHOF":
            return codec.format_value("ECHOF", 0 if self.echo else 1)
        if name not in self._PER_CHANNEL_CONFIG:
            return "-"
        values = [self.config(name, i) for i in (1, 2)]
        return self._per_channel(name, values, args)


def _bind_config_handlers() -> None:
    """Route ``^NAME``/``~NAME`` to the two generic config handlers and ``?NAME`` to its query."""
    for name in codec.CONFIG:

        def setter(self: RoboteqEmulator, *args: int, _n: str = name) -> str:
            return self._cmd_set_config(_n, *args)

        def getter(self: RoboteqEmulator, *args: int, _n: str = name) -> str:
            return self._cmd_get_config(_n, *args)

        setattr(RoboteqEmulator, f"_cmd_set_{name}", setter)
        setattr(RoboteqEmulator, f"_cmd_get_{name}", getter)


_bind_config_handlers()
