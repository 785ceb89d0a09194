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
than the watchdog after non-zero speeds the driver commands zero on both channels before the new
speeds, and counts the trip (:attr:`RoboteqMDC2230.watchdog_trips`); a gap after zero speeds stops
nothing and is no trip (start-up, a stop).

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

The class is built in layers: :mod:`hw.roboteq.transactions` (port, retries, fault path),
:mod:`hw.roboteq.readings` (queries, diagnostics), :mod:`hw.roboteq.configuration` (writes and
read-back) and this module (lifecycle, session, motion).
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any

from hw.errors import (
    CommandError,
    DeviceFaultError,
    DeviceStateError,
    HardwareError,
)
from hw.interfaces import LifecycleState, MotorState, PIDConfig
from hw.roboteq import codec
from hw.roboteq.configuration import RoboteqConfiguration, check_watchdog_ms
from hw.roboteq.link import ReplyLink
from hw.roboteq.settings import RoboteqProtections
from hw.roboteq.transactions import RELEASE_HINT, SerialLike

log = logging.getLogger(__name__)

PLAUSIBILITY_SLACK_COUNTS = 8
# Firmware from which the speed loop drives a current loop (manual V2.1): the identified
# voltage-to-speed plant then does not describe what the speed gains act on.
CASCADED_LOOP_FIRMWARE = (2, 1)

S = LifecycleState


class RoboteqMDC2230(RoboteqConfiguration):
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
        check_watchdog_ms(watchdog_ms)
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
        self._moving = False  # the last speeds commanded were not both zero
        self.stop_acknowledged = False

    # --- lifecycle --------------------------------------------------------------------------

    @property
    def state(self) -> LifecycleState:
        """The lifecycle state (:class:`hw.interfaces.LifecycleState`)."""
        return self._state

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
        self._moving = left != 0 or right != 0

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
        self._moving = left != 0 or right != 0

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

    # --- checks -------------------------------------------------------------------------------

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

    def _after_stall(self) -> None:
        """After a host stall longer than the watchdog, zero both channels before anything else.

        A gap after zero speeds (start-up, a stop) is no trip: the watchdog stops nothing that moves.
        """
        if self._state is not S.ACTIVE or self._last_bang_ns is None or not self._moving:
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

    # --- transactions -------------------------------------------------------------------------

    def _zero(self) -> None:
        self._command(codec.set_speed(1, 0))
        self._command(codec.set_speed(2, 0))
        self._moving = False

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


_FF_ESTOP = 1 << codec.FAULT_BITS.index("emergency_stop")
_FF_STARTUP_CONFIG = 1 << codec.FAULT_BITS.index("startup_config")
