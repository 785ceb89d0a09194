"""Driver of the Roboteq MDC2230 dual-channel motor controller over a serial line (pyserial).

Transport: 115200 8N1 on a serial port, the USB CDC-ACM device (``/dev/ttyACM0``), or a pty (the
emulator) — or any object with ``write(bytes)``, ``read(n) -> bytes`` (returning what is there within
its own short timeout), ``close()`` and ``reset_input_buffer()``.

Lifecycle (ros2_control ``SystemInterface``, :class:`hw.interfaces.LifecycleState`):

* ``configure()``: open the port and start the session as the Clearpath and Roboteq-Inc drivers do:
  command zero on both channels first (a controller left driving by a crashed program stops), stop
  auto-sent telemetry (``# C``), set the echo state explicitly (``^ECHOF``), flush, identify the
  controller (``?FID``), then write the configuration: closed-loop speed mode, encoder PPR, max RPM,
  ramps, amps limit, loop-error detection, gains, serial watchdog. -> inactive.
* ``activate()``: read the configuration back and refuse if it differs from what was written;
  refuse if a fault or a stop latched by someone else is set (the message names
  ``--release-stop``); command zero; -> active. Only then are non-zero speeds accepted.
* ``deactivate()``: zero, then ``!EX``; -> inactive. ``activate()`` releases that stop itself.
* any fault: zero speeds and ``!EX`` first, then -> error and raise. Only :meth:`release` (the
  operator's decision: ``robchair run --release-stop``) leaves error, -> inactive.
* ``close()``: zero (best effort), close the port; -> finalized.
* ``open()`` (the :class:`hw.interfaces.Device` call) is ``configure()`` then, unless the session is
  read-only (``configure=False``), ``activate()``. A read-only session never moves a motor and
  never latches anything: its fault path only commands zero.

Reply integrity. One command at a time; the input is flushed before each command (lines found then
are stale: discarded and counted). With echo on (the default here) a reply belongs to a command only
after that command's echo: a ``+`` or ``-`` before it answers an earlier command. Queries are
answered by their own name (``?C`` by ``C=``) with the expected number of fields; ``!``/``^`` by
``+``/``-``. Anything else is discarded and counted, never taken as an answer. A ``-``, a garbled or
malformed line, or no answer within ``timeout_s`` is retried up to ``retries`` times; then the
motors are stopped and the error raised. :meth:`emergency_stop` reads ``?FF`` back and raises if the
controller did not latch.

Plausibility. The encoder change between two reads may not exceed what the motor can turn:
``max_rpm * (1 + plausibility_margin)`` for the elapsed time, in counts (quadrature x4 of
``encoder_ppr``; on the wheel side of the gearbox divided by ``gear_ratio``), plus
``PLAUSIBILITY_SLACK_COUNTS``. A larger jump (a controller restart resets the counters) is a fault,
as is the "default configuration loaded at startup" flag appearing during a session.

Watchdog. The controller's serial watchdog (``^RWD``) is always armed (0 is refused) and only ``!``
commands refresh it, so speeds must be sent every cycle. When it trips, the controller keeps the
last set points and resumes them on the next valid command (manual): after any host stall longer
than the watchdog the driver commands zero on both channels before the new speeds, and counts the
trip (:attr:`RoboteqMDC2230.watchdog_trips`).

Where this differs from the reference drivers, and why:

* Clearpath ``roboteq_driver`` (ROS 1) downloads a MicroBasic script that streams feedback at
  10/50 Hz and turns the echo off. Here nothing runs on the controller and every value is polled
  and paired with its query: a stream cannot be told apart from a stale or foreign line, and a
  script in the controller is a second program to keep in step with the host. The cost is four
  transactions per cycle instead of one stream.
* Echo: both Clearpath and Roboteq-Inc's driver send ``^ECHOF 1``. Here the echo is set on
  (``^ECHOF 0``) by default, because over an ordered serial link the echo is what ties a ``+`` or
  ``-`` to its command; ``echo=False`` gives their behaviour (pairing by flush and reply kind).
* Husarion's Panther interface talks CANopen (PDOs, SDOs, heartbeat), so its replies are paired by
  the bus; it escalates only after several consecutive read/write errors. Here any failure that
  outlives ``retries`` immediate retries stops the chair: a seated person, no second E-stop loop.
* Panther and ros2_control leave the error state through ``on_error``/re-configure; here only an
  explicit operator release (``release()``, ``--release-stop``) leaves it, and the configuration
  is read back before every activation (neither reference reads it back).
* Neither reference checks encoder plausibility or restarts; a restart here is a fault (counters
  reset, "default configuration loaded", or the plausibility bound).
* Clearpath's ``!EX`` is fire-and-forget; here the latch is read back from ``?FF``.

One thread talks to a driver (the runtime loop); it holds no lock of its own.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any, NoReturn, Protocol

from hw.errors import (
    CommandError,
    DeviceClosedError,
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceStateError,
    DeviceTimeoutError,
    HardwareError,
    ProtocolError,
)
from hw.interfaces import Device, LifecycleState, MotorFaults, MotorState, PIDConfig
from hw.roboteq import codec
from hw.roboteq.link import ReplyLink
from hw.roboteq.settings import RoboteqDiagnostics, RoboteqProtections

log = logging.getLogger(__name__)

RELEASE_HINT = "release it with `robchair run --release-stop` (driver: release())"
PLAUSIBILITY_SLACK_COUNTS = 8
# Firmware from which the speed loop drives a current loop (manual V2.1): the identified
# voltage-to-speed plant then does not describe what the speed gains act on.
CASCADED_LOOP_FIRMWARE = (2, 1)

S = LifecycleState


class SerialLike(Protocol):
    def write(self, data: bytes) -> int | None: ...

    def read(self, size: int = 1) -> bytes: ...

    def close(self) -> None: ...

    def reset_input_buffer(self) -> None: ...


class RoboteqMDC2230(Device):
    """A Roboteq MDC2230 in closed-loop speed mode, one channel per wheel (1 = left, 2 = right).

    Args:
        port: device path (``/dev/ttyACM0``, a pty path) or an open serial-like object.
        baudrate: serial speed (115200 8N1 is the controller's default).
        timeout_s: deadline for one reply, seconds.
        retries: extra attempts after a ``-``, a garbled or malformed line or a timeout.
        watchdog_ms: ``^RWD`` period; 1..65000 ms (0, which disables it, is refused).
        encoder_ppr: ``^EPPR`` pulses per revolution of the encoder.
        max_rpm: ``^MXRPM``, the motor speed that ``!G 1000`` means; also the limit of ``!S``.
        pid: gains per channel (left, right) in the control module's units, written in
            ``configure()`` after conversion to the firmware's units; None leaves the gains alone.
        clock: gives ``MotorState.stamp_ns`` and times host stalls (default ``time.monotonic_ns``).
        configure: write the configuration (False: a read-only session, as ``robchair hw check``:
            nothing is written but zero speeds, and it never becomes active).
        release_on_open: in ``open()``, release a stop latched by an earlier session (``!MG``).
            Off by default: releasing a stop is the operator's decision (``--release-stop``).
        check_motor_flags: also query ``?FM`` in :meth:`read_state` and stop on a motor stall, a
            closed-loop error or a safety stop.
        protections: ramps, amps limit, loop-error detection (default: from the platform spec).
        echo: the echo state to set (True: ``^ECHOF 0``, replies paired after the echo; False:
            ``^ECHOF 1``, paired by flushing and by reply kind). A read-only session detects it.
        encoder_on: ``"motor"`` (before the gearbox) or ``"wheel"``, for the plausibility bound.
        gear_ratio: motor turns per wheel turn, for the plausibility bound.
        plausibility_margin: fraction above ``max_rpm`` an encoder may still move (overshoot).
    """

    name = "roboteq-mdc2230"

    def __init__(
        self,
        port: str | SerialLike,
        *,
        baudrate: int = 115200,
        timeout_s: float = 0.1,
        retries: int = 2,
        watchdog_ms: int = 1000,
        encoder_ppr: int = 1000,
        max_rpm: int = 1000,
        pid: tuple[PIDConfig, PIDConfig] | None = None,
        clock: Any = None,
        configure: bool = True,
        release_on_open: bool = False,
        check_motor_flags: bool = True,
        protections: RoboteqProtections | None = None,
        echo: bool = True,
        encoder_on: str = "motor",
        gear_ratio: float = 29.0,
        plausibility_margin: float = 0.5,
    ) -> None:
        _check_watchdog(watchdog_ms)
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise CommandError(f"timeout_s={timeout_s!r} must be a positive number of seconds")
        if retries < 0:
            raise CommandError(f"retries={retries!r} must be >= 0")
        if not 1 <= encoder_ppr <= 5000:
            raise CommandError(f"encoder_ppr={encoder_ppr!r} outside 1..5000")
        if not 10 <= max_rpm <= 65000:
            raise CommandError(f"max_rpm={max_rpm!r} outside 10..65000")
        if encoder_on not in ("motor", "wheel"):
            raise CommandError(f"encoder_on={encoder_on!r}: expected 'motor' or 'wheel'")
        if not (math.isfinite(gear_ratio) and gear_ratio > 0):
            raise CommandError(f"gear_ratio={gear_ratio!r} must be > 0")
        if not (math.isfinite(plausibility_margin) and plausibility_margin >= 0):
            raise CommandError(f"plausibility_margin={plausibility_margin!r} must be >= 0")
        self._port_arg = port
        self.baudrate = baudrate
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.watchdog_ms = watchdog_ms
        self.encoder_ppr = encoder_ppr
        self.max_rpm = max_rpm
        self._pid = pid
        self._clock = clock
        self._writable = configure
        self._release_on_open = release_on_open
        self.check_motor_flags = check_motor_flags
        self.protections = protections
        self._echo_wanted = echo
        ticks = 4.0 * encoder_ppr / (gear_ratio if encoder_on == "wheel" else 1.0)
        self._max_counts_per_s = max_rpm * (1.0 + plausibility_margin) / 60.0 * ticks
        self.plausibility_margin = plausibility_margin
        self._port: SerialLike | None = None
        self._owns_port = False
        self._state = S.UNCONFIGURED
        self._dead = False  # the port failed: nothing more is written, nothing more is logged
        self._identified = False  # ?FID answered: it is a Roboteq, stop commands may be sent
        self._self_latched = False  # the latched stop is this driver's own deactivate()
        self._startup_config_at_start = False
        self._written: dict[str, tuple[int, ...]] = {}
        self._last: tuple[int, tuple[int, ...]] | None = None  # (stamp_ns, counts) of the last read
        self._last_bang_ns: int | None = None
        self._link: ReplyLink | None = None
        self.firmware: codec.FirmwareId | None = None
        self.firmware_warning: str | None = None
        self.stop_reason: str | None = None
        self.n_retries = 0
        self._discarded_before = 0
        self.watchdog_trips = 0
        self.stop_acknowledged = False

    # --- lifecycle --------------------------------------------------------------------------

    @property
    def state(self) -> LifecycleState:
        """The lifecycle state (:class:`hw.interfaces.LifecycleState`)."""
        return self._state

    @property
    def discarded_lines(self) -> int:
        """Received lines that answered nothing the driver asked (stale, unsolicited, other echoes)."""
        return self._link.discarded_lines if self._link is not None else self._discarded_before

    @property
    def read_only(self) -> bool:
        """True for a ``configure=False`` session: it never moves a motor and never latches a stop."""
        return not self._writable

    def open(self) -> None:
        """``configure()``, then ``activate()`` unless read-only (and ``!MG`` first with ``release_on_open``).

        Raises:
            DeviceDisconnectedError, DeviceTimeoutError, ProtocolError, DeviceFaultError: see
            :meth:`configure` and :meth:`activate`; the port is closed again before raising.
        """
        if self._state in (S.INACTIVE, S.ACTIVE):
            return
        try:
            self.configure()
            if self._writable:
                if self._release_on_open and self.read_faults_word() & _FF_ESTOP:
                    self.release()
                self.activate()
        except BaseException:
            self.close()
            raise

    def configure(self) -> None:
        """Open the port, start the session, identify the controller, write the configuration.

        unconfigured -> inactive.

        Raises:
            DeviceStateError: not unconfigured.
            DeviceDisconnectedError: the port cannot be opened or failed.
            DeviceTimeoutError: nothing answered ``?FID``.
            ProtocolError: bytes came back that are not a Roboteq reply (wrong device or baud
                rate), or a configuration write was rejected.
            CommandError: a gain does not fit the firmware's range.
        """
        if self._state is not S.UNCONFIGURED:
            raise DeviceStateError(
                f"{self.name}: configure() needs the unconfigured state, not {self._state.value}"
            )
        self._open_port()
        self._link = ReplyLink(self._port, self.timeout_s)
        self._is_open = True
        self._state = S.INACTIVE
        self.stop_reason = None
        try:
            self._start_session()
            if self._writable:
                self._write_configuration()
        except BaseException:
            self.close()
            self._state = S.UNCONFIGURED  # ros2_control: a failed configure stays unconfigured
            raise

    def activate(self) -> None:
        """Check the configuration and the fault flags, command zero; inactive -> active.

        Raises:
            DeviceStateError: read-only session, or not inactive (in error: release() first).
            DeviceFaultError: the configuration read back differs from what was written, a fault
                flag is set, or a stop latched before the driver opened the port (the message names
                ``--release-stop``).
        """
        self._check_open()
        if not self._writable:
            raise DeviceStateError(
                f"{self.name}: read-only session (configure=False): motion is never allowed; open the "
                "controller with configure=True to drive"
            )
        if self._state is S.ACTIVE:
            return
        if self._state is not S.INACTIVE:
            raise DeviceStateError(
                f"{self.name}: activate() needs the inactive state, not {self._state.value}"
                + (f" ({self.stop_reason}); {RELEASE_HINT}" if self._state is S.ERROR else "")
            )
        self._verify_configuration()
        word = self.read_faults_word()
        if word & _FF_ESTOP and self._self_latched:
            self._command(codec.release_stop())
            self._self_latched = False
            word = self.read_faults_word()
        faults = codec.decode_fault_flags(word)
        if faults.emergency_stop:
            raise DeviceFaultError(
                f"{self.name}: an emergency stop is latched (by an earlier run or the stop input, "
                f"?FF={word}); {RELEASE_HINT}"
            )
        other = [n for n in faults.names() if n != "startup_config" or not self._startup_config_at_start]
        if other:
            raise DeviceFaultError(
                f"{self.name}: fault flags {other} (?FF={word}); the chair cannot be activated"
            )
        self._zero()
        self._last_bang_ns = self._now_ns()
        self._last = (self._now_ns(), self._ints(codec.query("C"), 2))
        self._state = S.ACTIVE

    def deactivate(self) -> None:
        """Zero both channels, then latch ``!EX``; active -> inactive (``activate()`` releases it).

        Raises:
            DeviceFaultError: the controller did not latch the stop (after commanding zero).
        """
        self._check_open()
        if self._state is not S.ACTIVE:
            return
        self._zero()
        self._latch_and_confirm()
        self._self_latched = True
        self._state = S.INACTIVE

    def release(self) -> None:
        """Operator release (``!MG``) of a latched stop; error (or inactive) -> inactive.

        Raises:
            DeviceFaultError: fault flags other than the released stop are still set.
            DeviceStateError: read-only session (it never latches, so it never releases).
        """
        self._check_open()
        if not self._writable:
            raise DeviceStateError(f"{self.name}: read-only session: it never latches, so it never releases")
        self._command(codec.release_stop())
        self._self_latched = False
        word = self.read_faults_word()
        faults = codec.decode_fault_flags(word)
        remaining = [n for n in faults.names() if n != "startup_config" or not self._startup_config_at_start]
        if remaining:
            self._state = S.ERROR
            raise DeviceFaultError(
                f"{self.name}: still faulted after the release: {remaining} (?FF={word}); fix the cause "
                "(power, temperature, wiring), then release again"
            )
        self.stop_reason = None
        self._state = S.INACTIVE

    def release_stop(self) -> None:
        """``release()`` then ``activate()``: the operator's release, back to driving (one call)."""
        self.release()
        self.activate()

    def close(self) -> None:
        """Command zero speeds (best effort, unless the port failed) and close; -> finalized."""
        if self._state in (S.UNCONFIGURED, S.FINALIZED) and self._port is None:
            self._state = S.FINALIZED if self._state is S.FINALIZED else self._state
            return
        if not self._dead and self._port is not None and self._identified:
            try:
                self._zero()
            except HardwareError as exc:
                log.debug("Roboteq close: %s", exc)
        self._is_open = False
        if self._owns_port and self._port is not None:
            try:
                self._port.close()
            except Exception as exc:
                log.debug("closing Roboteq port: %s", exc)
        self._port = None
        if self._link is not None:
            self._discarded_before = self._link.discarded_lines
        self._link = None
        self._state = S.FINALIZED

    def set_watchdog_ms(self, watchdog_ms: int) -> None:
        """Write ``^RWD`` (1..65000 ms) and read it back; the runtime sets it from its cycle.

        Raises:
            CommandError: 0 or out of range (the watchdog must stay armed).
            DeviceStateError: read-only session.
            DeviceFaultError: the value read back differs.
        """
        _check_watchdog(watchdog_ms)
        self._check_open()
        if not self._writable:
            raise DeviceStateError(f"{self.name}: read-only session: ^RWD is not written")
        self._command(codec.set_config("RWD", watchdog_ms))
        self.watchdog_ms = watchdog_ms
        self._written["RWD"] = (watchdog_ms,)
        self._verify_configuration(["RWD"])

    # --- the MotorController interface ------------------------------------------------------

    def set_speeds_rpm(self, left_rpm: float, right_rpm: float) -> None:
        """``!S 1 left`` and ``!S 2 right`` (closed-loop motor RPM, rounded). Refreshes the watchdog.

        Zero is accepted in any open state; non-zero only when active.

        Raises:
            CommandError: a speed is not finite or beyond ``max_rpm`` (the motors are stopped first).
            DeviceStateError: a non-zero speed while not active (read-only, inactive).
            DeviceFaultError: a non-zero speed in the error state (the message names the release).
            DeviceTimeoutError, ProtocolError, DeviceDisconnectedError: the link failed (after stopping).
        """
        self._check_open()
        for label, v in (("left_rpm", left_rpm), ("right_rpm", right_rpm)):
            if not math.isfinite(v) or abs(v) > self.max_rpm:
                self._fail(CommandError(f"{label}={v!r} is not a finite speed within +-{self.max_rpm} RPM"))
        left, right = round(left_rpm), round(right_rpm)
        self._check_motion(left != 0 or right != 0)
        self._after_stall()
        self._command(codec.set_speed(1, left))
        self._command(codec.set_speed(2, right))

    def set_commands(self, left: int, right: int) -> None:
        """``!G 1 left`` and ``!G 2 right``: motor commands -1000..1000 (a fraction of ``^MXRPM``).

        Raises: as :meth:`set_speeds_rpm`.
        """
        self._check_open()
        for label, v in (("left", left), ("right", right)):
            if isinstance(v, bool) or not isinstance(v, int) or not -1000 <= v <= 1000:
                self._fail(CommandError(f"!G {label}={v!r} is not an integer in -1000..1000"))
        self._check_motion(left != 0 or right != 0)
        self._after_stall()
        self._command(codec.go(1, left))
        self._command(codec.go(2, right))

    def read_state(self) -> MotorState:
        """``?C``, ``?S``, ``?FF`` (and ``?FM`` with ``check_motor_flags``), checked.

        Raises:
            DeviceFaultError: a fault flag (an unknown bit included), a motor stall / loop error /
                safety stop, a controller restart, or an implausible encoder change (after stopping).
            DeviceTimeoutError, ProtocolError, DeviceDisconnectedError: the link failed (after stopping).
        """
        self._check_open()
        counts = self._ints(codec.query("C"), 2)
        stamp = self._now_ns()
        speeds = self._ints(codec.query("S"), 2)
        faults = self.read_faults()
        if self.check_motor_flags:
            for side, flags in zip(("left", "right"), self.read_motor_flags()):
                if flags.any_fault:
                    self._fail(DeviceFaultError(f"Roboteq {side} motor flags {flags.names()} (?FM)"))
        self._check_plausible(stamp, (counts[0], counts[1]))
        return MotorState(stamp, (counts[0], counts[1]), (float(speeds[0]), float(speeds[1])), faults)

    def read_encoder_counts(self) -> tuple[int, int]:
        """``?C`` (signed 32-bit, quadrature x4) without the plausibility check (for inspection)."""
        self._check_open()
        a, b = self._ints(codec.query("C"), 2)
        return a, b

    def read_speeds_rpm(self) -> tuple[float, float]:
        """``?S``: measured motor speeds, RPM."""
        self._check_open()
        a, b = self._ints(codec.query("S"), 2)
        return float(a), float(b)

    def read_faults_word(self) -> int:
        """The raw ``?FF`` word (0..65535), without acting on it."""
        self._check_open()
        (word,) = self._ints(codec.query("FF"), 1, validate=_flag_word)
        return word

    def read_faults(self) -> MotorFaults:
        """``?FF`` decoded; a set flag (an unknown bit included) stops the motors, then raises.

        A controller that restarted during the session (the "default configuration loaded at
        startup" flag appears) is a fault too.

        Raises:
            DeviceFaultError: after stopping. Read-only sessions only command zero (no ``!EX``).
        """
        word = self.read_faults_word()
        faults = codec.decode_fault_flags(word)
        names = faults.names()
        if faults.startup_config and self._startup_config_at_start:
            names.remove("startup_config")
        if faults.startup_config and not self._startup_config_at_start:
            self._fail(
                DeviceFaultError(
                    f"Roboteq restarted during the session (?FF={word}: default configuration loaded at "
                    "startup); its configuration is lost: close and open again"
                )
            )
        if names:
            self._fail(DeviceFaultError(f"Roboteq reports fault flags {names} (?FF={word})" + self._hint()))
        return faults

    def read_status(self) -> codec.StatusFlags:
        """``?FS`` decoded (no action is taken on it)."""
        self._check_open()
        (word,) = self._ints(codec.query("FS"), 1, validate=_flag_word)
        return codec.decode_status_flags(word)

    def read_motor_flags(self) -> tuple[codec.MotorFlags, codec.MotorFlags]:
        """``?FM`` for both motors, decoded (no action is taken on them)."""
        self._check_open()
        a, b = self._ints(codec.query("FM"), 2, validate=_flag_word)
        return codec.decode_motor_flags(a), codec.decode_motor_flags(b)

    def read_voltages(self) -> tuple[float, float, float]:
        """(internal V, battery V, 5 V output V) from ``?V``."""
        self._check_open()
        internal, battery, five_mv = self._ints(codec.query("V"), 3)
        return internal / 10.0, battery / 10.0, five_mv / 1000.0

    def read_amps(self) -> tuple[float, float]:
        """Motor currents (left, right), A, from ``?A``."""
        self._check_open()
        a, b = self._ints(codec.query("A"), 2)
        return a / 10.0, b / 10.0

    def read_temperatures(self) -> tuple[float, float, float]:
        """(MCU, channel 1 heatsink, channel 2 heatsink), degrees C, from ``?T``."""
        self._check_open()
        t = self._ints(codec.query("T"), 3)
        return float(t[0]), float(t[1]), float(t[2])

    def read_config(self, name: str) -> tuple[int, ...]:
        """``~NAME``: a configuration value for every channel (or the one global value)."""
        self._check_open()
        n = 1 if name in codec.GLOBAL_CONFIG else 2
        return self._ints(codec.get_config(name), n)

    def counters(self) -> dict[str, int]:
        """Retries, discarded lines and watchdog trips since the session started (no I/O)."""
        return {
            "retries": self.n_retries,
            "discarded_lines": self.discarded_lines,
            "watchdog_trips": self.watchdog_trips,
        }

    def read_diagnostics(self) -> RoboteqDiagnostics:
        """Counters plus ``?V``, ``?A``, ``?T``, ``?FS``, ``?FF`` (five transactions: poll at about 1 Hz).

        ``?FF``/``?FM`` are acted on by :meth:`read_state` every cycle; ``?FS`` (the controller's
        mode) only here, at the diagnostics rate: a status bit the manual does not name stops.

        Raises:
            DeviceFaultError: ``?FS`` has a bit the manual does not name (after stopping).
            DeviceTimeoutError, ProtocolError, DeviceDisconnectedError: the link failed (after stopping).
        """
        self._check_open()
        status = self.read_status()
        if status.unknown_bits and self._state is not S.ERROR:
            self._fail(
                DeviceFaultError(
                    f"Roboteq status flags {status.names()} (?FS): a bit the manual does not name"
                )
            )
        internal, battery, _ = self.read_voltages()
        amps = self.read_amps()
        temps = self.read_temperatures()
        faults = codec.decode_fault_flags(self.read_faults_word())
        return RoboteqDiagnostics(
            stamp_ns=self._now_ns(),
            state=self._state.value,
            firmware=self.firmware.text if self.firmware else "",
            retries=self.n_retries,
            discarded_lines=self.discarded_lines,
            watchdog_trips=self.watchdog_trips,
            stop_reason=self.stop_reason,
            faults=tuple(faults.names()),
            status=tuple(status.names()),
            battery_v=battery,
            internal_v=internal,
            motor_amps=amps,
            temperatures_c=temps,
        )

    def configure_pid(self, left: PIDConfig, right: PIDConfig) -> None:
        """Write ``^KP/^KI/^KD`` per channel in the firmware's units and read them back.

        Raises:
            CommandError: a gain does not fit the firmware (nothing is written then).
            DeviceStateError: read-only session.
            ProtocolError: a write was rejected; DeviceFaultError: the values read back differ.
        """
        self._check_open()
        if not self._writable:
            raise DeviceStateError(f"{self.name}: read-only session: gains are not written")
        encoded = [self.firmware_gains(cfg) for cfg in (left, right)]  # validate both before writing
        for i, name in enumerate(("KP", "KI", "KD")):
            for cc in (1, 2):
                self._command(codec.set_config(name, cc, encoded[cc - 1][i]))
            self._written[name] = (encoded[0][i], encoded[1][i])
        self._verify_configuration(["KP", "KI", "KD"])

    def firmware_gains(self, cfg: PIDConfig) -> tuple[int, int, int]:
        """The ``^KP/^KI/^KD`` integers for ``cfg`` on this controller's firmware.

        The multiplier is the control module's (:data:`hw.roboteq.gains.FIRMWARE_MULTIPLIER`: x10
        on 1.x, x1,000,000 on 2.x); the range is the manual's (:data:`hw.roboteq.FIRMWARE_RANGE`:
        0..255 on 1.x, 0..2,000,000,000 on 2.x). CommandError if a gain does not fit.
        """
        from hw.roboteq.gains import FIRMWARE_MULTIPLIER, FIRMWARE_RANGE

        if self.firmware is None:
            raise DeviceClosedError(f"{self.name}: firmware unknown until configure() has probed ?FID")
        major = self.firmware.major
        if major not in FIRMWARE_MULTIPLIER or major not in FIRMWARE_RANGE:
            raise CommandError(
                f"firmware {self.firmware.text!r}: no known gain encoding for major version {major}"
            )
        mult, (lo, hi) = FIRMWARE_MULTIPLIER[major], FIRMWARE_RANGE[major]
        out = []
        for label, g in (("kp", cfg.kp), ("ki", cfg.ki), ("kd", cfg.kd)):
            q = round(g * mult) if math.isfinite(g) else None
            if q is None or not lo <= q <= hi:
                raise CommandError(
                    f"PID {label}={g!r} does not fit firmware {major}.x (x{mult} must lie in {lo}..{hi})"
                )
            out.append(int(q))
        return out[0], out[1], out[2]

    def emergency_stop(self) -> None:
        """``!EX``, confirmed by reading ``?FF`` back; the motors stay stopped until released.

        In a read-only session only zero speeds are sent (it never latches anything).

        Raises:
            DeviceFaultError: the controller did not latch the stop (zero was commanded first).
            DeviceTimeoutError, ProtocolError, DeviceDisconnectedError: the link failed.
        """
        self._check_open()
        if not self._writable:
            self._zero()
            return
        self._latch_and_confirm()
        self.stop_reason = self.stop_reason or "emergency stop requested"
        self._state = S.ERROR

    # --- session ------------------------------------------------------------------------------

    def _open_port(self) -> None:
        if not isinstance(self._port_arg, str):
            self._port = self._port_arg
            return
        try:
            import serial
        except ImportError as exc:  # pragma: no cover - pyserial is a dependency
            raise HardwareError("the Roboteq driver needs pyserial: pip install pyserial") from exc
        try:
            self._port = serial.Serial(
                self._port_arg,
                baudrate=self.baudrate,
                bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE,
                stopbits=serial.STOPBITS_ONE,
                timeout=0.005,
                write_timeout=self.timeout_s,
            )
        except (serial.SerialException, OSError) as exc:
            self._state = S.UNCONFIGURED
            raise DeviceDisconnectedError(f"cannot open Roboteq port {self._port_arg!r}: {exc}") from exc
        self._owns_port = True

    def _start_session(self) -> None:
        # zero first, without waiting: a controller left driving stops before anything else
        self._write_raw(codec.set_speed(1, 0).encode() + codec.set_speed(2, 0).encode() + b"# C" + codec.CR)
        time.sleep(min(0.02, self.timeout_s))
        self._flush()
        fid = self._transact(codec.query("FID"), expected=None, probing=True)
        assert isinstance(fid, codec.Value)
        self.firmware = codec.parse_firmware_id(fid.raw)
        self._identified = True
        log.info("Roboteq on %s: %s", self._port_arg, self.firmware.text)
        if (self.firmware.major, self.firmware.minor) >= CASCADED_LOOP_FIRMWARE:
            self.firmware_warning = (
                f"firmware {self.firmware.major}.{self.firmware.minor} runs the speed loop into a current "
                "loop: the identified voltage-to-speed plant and its PID design hold for 1.x and 2.0 only"
            )
            log.warning("Roboteq: %s", self.firmware_warning)
        if self._writable:
            self._command(codec.set_config("ECHOF", 0 if self._echo_wanted else 1))
            assert self._link is not None
            self._link.echo = self._echo_wanted
        self._zero()  # acknowledged this time
        assert self._link is not None
        self._link.discarded_lines = 0  # the answers to the unacknowledged first zeros are not news
        self._link.stop_telemetry = True
        word = self.read_faults_word()
        self._startup_config_at_start = bool(word & _FF_STARTUP_CONFIG)

    def _write_configuration(self) -> None:
        if self.protections is None:
            from robchair.spec import load_spec

            self.protections = RoboteqProtections.from_spec(load_spec())
        items: dict[str, int] = {"MMOD": 1, "EPPR": self.encoder_ppr, "MXRPM": self.max_rpm}
        items.update(self.protections.config_items())
        for name, value in items.items():
            for cc in (1, 2):
                self._command(codec.set_config(name, cc, value))
            self._written[name] = (value, value)
        if self._pid is not None:
            self.configure_pid(*self._pid)
        self._command(codec.set_config("RWD", self.watchdog_ms))
        self._written["RWD"] = (self.watchdog_ms,)

    def _verify_configuration(self, names: list[str] | None = None) -> None:
        diffs = []
        for name in names if names is not None else list(self._written):
            got = self.read_config(name)
            if got != self._written[name]:
                want = ":".join(map(str, self._written[name]))
                diffs.append(f"{name}={':'.join(map(str, got))} (written {want})")
        if diffs:
            raise DeviceFaultError(
                f"Roboteq configuration read back differs from what was written: {', '.join(diffs)}; "
                "the controller is not activated"
            )

    # --- checks -------------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._state in (S.UNCONFIGURED, S.FINALIZED) or self._port is None:
            raise DeviceClosedError(
                f"{self.name} is closed ({self._state.value}): call open() (or configure()) first"
            )
        if self._dead:
            raise DeviceDisconnectedError(
                f"Roboteq port {self._port_arg!r} is gone ({self.stop_reason}); close and open again"
            )

    def _check_motion(self, moving: bool) -> None:
        if not moving or self._state is S.ACTIVE:
            return
        if self._state is S.ERROR:
            raise DeviceFaultError(f"Roboteq is stopped after a fault ({self.stop_reason}); {RELEASE_HINT}")
        if not self._writable:
            raise DeviceStateError(
                f"{self.name}: read-only session (configure=False): motion is never allowed"
            )
        raise DeviceStateError(
            f"{self.name} is {self._state.value}: call activate() before commanding motion"
        )

    def _hint(self) -> str:
        return f"; {RELEASE_HINT}" if self._writable else ""

    def _after_stall(self) -> None:
        """After a host stall longer than the watchdog, zero both channels before anything else."""
        if self._state is not S.ACTIVE or self._last_bang_ns is None:
            return
        gap_ms = (self._now_ns() - self._last_bang_ns) / 1e6
        if gap_ms > self.watchdog_ms:
            self.watchdog_trips += 1
            log.warning(
                "Roboteq: no speed command for %.0f ms (watchdog %d ms): the controller stopped the motors; "
                "commanding zero before resuming", gap_ms, self.watchdog_ms,
            )  # fmt: skip
            self._zero()

    def _check_plausible(self, stamp: int, counts: tuple[int, int]) -> None:
        last, self._last = self._last, (stamp, counts)
        if last is None:
            return
        dt = max(0.0, (stamp - last[0]) / 1e9)
        limit = self._max_counts_per_s * dt + PLAUSIBILITY_SLACK_COUNTS
        for side, now, before in zip(("left", "right"), counts, last[1]):
            delta = codec.wrap_int32(now - before)
            if abs(delta) > limit:
                self._last = None
                self._fail(
                    DeviceFaultError(
                        f"Roboteq {side} encoder changed by {delta} counts in {dt:.3f} s, more than the "
                        f"{limit:.0f} the motor can turn (max_rpm {self.max_rpm} + "
                        f"{self.plausibility_margin:.0%}): a controller restart or a counter fault"
                    )
                )

    def _now_ns(self) -> int:
        return int(self._clock.now_ns()) if self._clock is not None else time.monotonic_ns()

    # --- transactions -------------------------------------------------------------------------

    def _zero(self) -> None:
        self._command(codec.set_speed(1, 0))
        self._command(codec.set_speed(2, 0))

    def _latch_and_confirm(self) -> None:
        self._command(codec.emergency_stop())
        word = self.read_faults_word()
        if not word & _FF_ESTOP:
            self._fail(
                DeviceFaultError(
                    f"Roboteq acknowledged !EX but does not report the stop latched (?FF={word}); zero "
                    "speeds were commanded"
                )
            )

    def _ints(
        self, cmd: codec.Command, n: int | None, validate: Callable[[tuple[int, ...]], None] | None = None
    ) -> tuple[int, ...]:
        def check(values: tuple[int, ...]) -> None:
            if n is not None and len(values) != n:
                raise ProtocolError(f"expected {n} values")
            if validate is not None:
                validate(values)

        reply = self._transact(cmd, expected=check)
        assert isinstance(reply, codec.Value)
        return reply.ints()

    def _command(self, cmd: codec.Command) -> None:
        self._transact(cmd, expected=None)

    def _transact(
        self,
        cmd: codec.Command,
        expected: Callable[[tuple[int, ...]], None] | None,
        probing: bool = False,
    ) -> codec.Reply:
        """Send ``cmd`` and return its reply, retrying; on final failure stop the motors and raise."""
        link = self._link
        assert link is not None
        problems: list[str] = []
        link.rx_bytes = 0
        for attempt in range(self.retries + 1):
            if attempt:
                self.n_retries += 1
            try:
                outcome = link.attempt(cmd, expected)
            except OSError as exc:  # pyserial's SerialException is an IOError
                self._port_failed(exc)
            if isinstance(outcome, str):
                problems.append(outcome)
                log.debug("Roboteq %s: %s (attempt %d)", cmd.text, outcome, attempt + 1)
                continue
            if cmd.kind == "!":
                self._last_bang_ns = self._now_ns()
            return outcome
        kinds = {p.split(":")[0] for p in problems}
        if probing and link.rx_bytes and kinds <= {"timeout", "garbled", "unattributed"}:
            self._fail(
                ProtocolError(
                    f"{self._port_arg!r} received {link.rx_bytes} bytes that are not a Roboteq reply to "
                    f"{cmd.text!r} (wrong device or baud rate? {self.baudrate} 8N1 expected): {problems[-1]}"
                )
            )
        err_cls: type[HardwareError] = DeviceTimeoutError if kinds == {"timeout"} else ProtocolError
        self._fail(
            err_cls(f"Roboteq gave no valid answer to {cmd.text!r} in {len(problems)} tries: {problems}")
        )

    def _write_raw(self, data: bytes) -> None:
        assert self._link is not None
        try:
            self._link.write(data)
        except OSError as exc:
            self._port_failed(exc)

    def _flush(self) -> None:
        assert self._link is not None
        try:
            self._link.flush()
        except OSError as exc:
            self._port_failed(exc)

    # --- fault path ---------------------------------------------------------------------------

    def _port_failed(self, exc: BaseException) -> NoReturn:
        self._fail(DeviceDisconnectedError(f"Roboteq port {self._port_arg!r} failed (unplugged?): {exc}"))

    def _best_effort_stop(self) -> bool:
        """Write zero speeds (and ``!EX`` unless read-only) and wait one deadline for the acks.

        Nothing is written to a device that never identified itself as a Roboteq.
        """
        if self._link is None or self._dead or not self._identified:
            return False
        cmds = [codec.set_speed(1, 0), codec.set_speed(2, 0)]
        if self._writable:
            cmds.append(codec.emergency_stop())
        try:
            assert self._link is not None
            self.stop_acknowledged = self._link.send_stop(cmds)
            return True
        except Exception as exc:
            log.debug("Roboteq: could not send the stop commands: %s", exc)
            return False

    def _fail(self, exc: HardwareError) -> NoReturn:
        """Stop the motors first (zero speeds, ``!EX`` unless read-only), then -> error and raise."""
        if isinstance(exc, DeviceDisconnectedError):
            self._dead = True
            sent = False
        else:
            sent = self._best_effort_stop()
        self.stop_reason = str(exc)
        if self._state in (S.INACTIVE, S.ACTIVE):
            self._state = S.ERROR
        if self._identified:
            how = (
                "stop sent" if sent else "stop could NOT be sent: the controller's watchdog stops the motors"
            )
            log.error("Roboteq stop (%s): %s", how, exc)
        raise exc


_FF_ESTOP = 1 << codec.FAULT_BITS.index("emergency_stop")
_FF_STARTUP_CONFIG = 1 << codec.FAULT_BITS.index("startup_config")


def _flag_word(values: tuple[int, ...]) -> None:
    for v in values:
        if not 0 <= v <= codec.FLAG_WORD_MAX:
            raise ProtocolError(f"flag word {v} outside 0..{codec.FLAG_WORD_MAX}")


def _check_watchdog(watchdog_ms: object) -> None:
    if isinstance(watchdog_ms, bool) or not isinstance(watchdog_ms, int) or not 1 <= watchdog_ms <= 65000:
        raise CommandError(
            f"watchdog_ms={watchdog_ms!r}: the serial watchdog must stay armed (1..65000 ms; 0 is refused)"
        )
