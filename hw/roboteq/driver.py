"""Driver of the Roboteq MDC2230 dual-channel motor controller over a serial line (pyserial).

Transport: 115200 8N1 on a serial port, the USB CDC-ACM device (``/dev/ttyACM0``), or a pty (the
emulator) — or any object with ``write(bytes)``, ``read(n) -> bytes`` (returning what is there within
its own short timeout), ``close()`` and ``reset_input_buffer()``.

Protocol handling (see :mod:`hw.roboteq.codec`):

* one command at a time; replies are read line by line on CR until a deadline;
* the echo of the command is recognised and skipped, so echo on or off both work;
* ``+`` acknowledges ``!``/``^`` commands; ``NAME=v1:v2`` answers are routed by name, and any other
  well-formed line (unsolicited output, a late answer to an earlier query) is ignored;
* ``-``, a garbled line, or no answer before the deadline is retried up to ``retries`` times.

Safety. The controller's serial watchdog (``^RWD``) is always armed: the driver refuses 0. **Only
``!`` commands refresh that watchdog** — queries (``?``) and configuration (``^``/``~``) do not — so a
caller must send :meth:`RoboteqMDC2230.set_speeds_rpm` at least once per watchdog period even when
the speeds do not change; if the caller stalls, the controller stops the motors by itself.
Every fault path (no answer after the retries, garbled beyond the retries, port gone, a fault flag
in ``?FF``, a stall / closed-loop error / safety stop in ``?FM``, a non-finite or out-of-range speed)
first writes zero speeds and ``!EX`` (best effort, waiting one deadline for the acks), records the reason in
:attr:`RoboteqMDC2230.stop_reason`, and then raises a :class:`hw.errors.HardwareError` subclass.
After that, non-zero speed commands are refused until :meth:`release_stop` succeeds.

One thread talks to a driver (the runtime loop); it holds no lock of its own.
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any, NoReturn, Protocol

from hw.errors import (
    CommandError,
    DeviceClosedError,
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceTimeoutError,
    HardwareError,
    ProtocolError,
)
from hw.interfaces import Device, MotorFaults, MotorState, PIDConfig
from hw.roboteq import codec

log = logging.getLogger(__name__)


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
        retries: extra attempts after a ``-``, a garbled line or a timeout.
        watchdog_ms: ``^RWD`` period; 1..65000 ms (0, which disables it, is refused).
        encoder_ppr: ``^EPPR`` pulses per revolution of the encoder.
        max_rpm: ``^MXRPM``, the motor speed that ``!G 1000`` means; also the limit of ``!S``.
        pid: gains per channel (left, right) in the control module's units, written in ``open()``
            after conversion to the firmware's units; None leaves the controller's gains alone.
        clock: gives ``MotorState.stamp_ns`` (default ``time.monotonic_ns``).
        configure: write the configuration in ``open()`` (False only probes ``?FID``: for read-only
            checks such as ``robchair hw check``).
        release_on_open: send ``!MG`` in ``open()``, leaving an emergency stop latched by an earlier
            session (the controller holds ``!EX`` until released). Off by default: releasing a stop
            is the operator's decision.
        check_motor_flags: also query ``?FM`` in :meth:`read_state` and treat a motor stall, a
            closed-loop error (e.g. a broken encoder) or a safety stop as a fault.
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
    ) -> None:
        if not isinstance(watchdog_ms, int) or not 1 <= watchdog_ms <= 65000:
            raise CommandError(
                f"watchdog_ms={watchdog_ms!r}: the serial watchdog must stay armed "
                "(1..65000 ms; 0 is refused)"
            )
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise CommandError(f"timeout_s={timeout_s!r} must be a positive number of seconds")
        if retries < 0:
            raise CommandError(f"retries={retries!r} must be >= 0")
        if not 1 <= encoder_ppr <= 5000:
            raise CommandError(f"encoder_ppr={encoder_ppr!r} outside 1..5000")
        if not 10 <= max_rpm <= 65000:
            raise CommandError(f"max_rpm={max_rpm!r} outside 10..65000")
        self._port_arg = port
        self.baudrate = baudrate
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.watchdog_ms = watchdog_ms
        self.encoder_ppr = encoder_ppr
        self.max_rpm = max_rpm
        self._pid = pid
        self._clock = clock
        self._configure_on_open = configure
        self._release_on_open = release_on_open
        self.check_motor_flags = check_motor_flags
        self._port: SerialLike | None = None
        self._owns_port = False
        self._rx = b""
        self.firmware: codec.FirmwareId | None = None
        self.stop_reason: str | None = None
        self.n_retries = 0  # attempts that had to be repeated (for diagnostics)
        self.stop_acknowledged = False  # the last fault-path stop was acknowledged by the controller

    # --- lifecycle --------------------------------------------------------------------------

    def open(self) -> None:
        """Open the port, probe ``?FID``, configure closed-loop speed mode, PPR, max RPM, PID, watchdog."""
        if self._is_open:
            return
        if isinstance(self._port_arg, str):
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
                raise DeviceDisconnectedError(f"cannot open Roboteq port {self._port_arg!r}: {exc}") from exc
            self._owns_port = True
        else:
            self._port = self._port_arg
        self._is_open = True
        self.stop_reason = None
        try:
            self._port.reset_input_buffer()
            fid = self._transact(codec.query("FID"))
            assert isinstance(fid, codec.Value)
            self.firmware = codec.parse_firmware_id(fid.raw)
            log.info("Roboteq on %s: %s", self._port_arg, self.firmware.text)
            if self._configure_on_open:
                self._configure()
            if self._release_on_open:
                self.release_stop()
        except BaseException:
            self.close()
            raise

    def _configure(self) -> None:
        for cc in (1, 2):
            self._command(codec.set_config("MMOD", cc, 1))  # 1 = closed-loop speed
            self._command(codec.set_config("EPPR", cc, self.encoder_ppr))
            self._command(codec.set_config("MXRPM", cc, self.max_rpm))
        if self._pid is not None:
            self.configure_pid(*self._pid)
        self._command(codec.set_config("RWD", self.watchdog_ms))

    def close(self) -> None:
        """Command zero speeds (best effort) and close the port if this driver opened it."""
        if not self._is_open:
            return
        if self.stop_reason is None:
            try:  # a normal close: zero speeds, acknowledged, so they are applied before the port goes
                self._command(codec.set_speed(1, 0))
                self._command(codec.set_speed(2, 0))
            except HardwareError as exc:  # _fail already sent !EX and logged; closing goes on
                log.warning("Roboteq close: %s", exc)
        self._is_open = False
        if self._owns_port and self._port is not None:
            try:
                self._port.close()
            except Exception as exc:
                log.debug("closing Roboteq port: %s", exc)
        self._port = None

    # --- the MotorController interface ------------------------------------------------------

    def set_speeds_rpm(self, left_rpm: float, right_rpm: float) -> None:
        """``!S 1 left`` and ``!S 2 right`` (closed-loop RPM, rounded). Refreshes the watchdog.

        Raises:
            CommandError: a speed is not finite or beyond ``max_rpm`` (the motors are stopped first).
            DeviceFaultError: the driver is in a stopped state after a fault and a speed is non-zero.
        """
        self._check_open()
        for label, v in (("left_rpm", left_rpm), ("right_rpm", right_rpm)):
            if not math.isfinite(v) or abs(v) > self.max_rpm:
                self._fail(CommandError(f"{label}={v!r} is not a finite speed within +-{self.max_rpm} RPM"))
        if self.stop_reason is not None and (round(left_rpm) != 0 or round(right_rpm) != 0):
            raise DeviceFaultError(
                f"Roboteq is stopped after a fault ({self.stop_reason}); call release_stop() first"
            )
        self._command(codec.set_speed(1, round(left_rpm)))
        self._command(codec.set_speed(2, round(right_rpm)))

    def set_commands(self, left: int, right: int) -> None:
        """``!G 1 left`` and ``!G 2 right``: motor commands -1000..1000 (in closed-loop speed mode a
        fraction of ``^MXRPM``; in open loop a fraction of full power). Refreshes the watchdog."""
        self._check_open()
        for label, v in (("left", left), ("right", right)):
            if isinstance(v, bool) or not isinstance(v, int) or not -1000 <= v <= 1000:
                self._fail(CommandError(f"!G {label}={v!r} is not an integer in -1000..1000"))
        if self.stop_reason is not None and (left != 0 or right != 0):
            raise DeviceFaultError(
                f"Roboteq is stopped after a fault ({self.stop_reason}); call release_stop() first"
            )
        self._command(codec.go(1, left))
        self._command(codec.go(2, right))

    def read_state(self) -> MotorState:
        """``?C``, ``?S``, ``?FF`` (and ``?FM`` with ``check_motor_flags``).

        A set fault flag, or a motor flag meaning the motor is not following (stall, closed-loop
        error, safety stop), stops the motors and raises DeviceFaultError.
        """
        self._check_open()
        counts = self._ints(codec.query("C"), 2)
        speeds = self._ints(codec.query("S"), 2)
        faults = self.read_faults()
        if self.check_motor_flags:
            for side, flags in zip(("left", "right"), self.read_motor_flags()):
                if flags.any_fault:
                    self._fail(DeviceFaultError(f"Roboteq {side} motor flags {flags.names()} (?FM)"))
        stamp = self._clock.now_ns() if self._clock is not None else time.monotonic_ns()
        return MotorState(stamp, (counts[0], counts[1]), (float(speeds[0]), float(speeds[1])), faults)

    def read_faults(self) -> MotorFaults:
        """``?FF`` decoded; raises DeviceFaultError (after stopping) if any flag is set."""
        (word,) = self._ints(codec.query("FF"), 1)
        faults = codec.decode_fault_flags(word)
        if faults.any:
            self._fail(DeviceFaultError(f"Roboteq reports fault flags {faults.names()} (?FF={word})"))
        return faults

    def read_status(self) -> codec.StatusFlags:
        (word,) = self._ints(codec.query("FS"), 1)
        return codec.decode_status_flags(word)

    def read_motor_flags(self) -> tuple[codec.MotorFlags, codec.MotorFlags]:
        a, b = self._ints(codec.query("FM"), 2)
        return codec.decode_motor_flags(a), codec.decode_motor_flags(b)

    def read_voltages(self) -> tuple[float, float, float]:
        """(internal V, battery V, 5 V output V) from ``?V``."""
        internal, battery, five_mv = self._ints(codec.query("V"), 3)
        return internal / 10.0, battery / 10.0, five_mv / 1000.0

    def read_amps(self) -> tuple[float, float]:
        a, b = self._ints(codec.query("A"), 2)
        return a / 10.0, b / 10.0

    def read_config(self, name: str) -> tuple[int, ...]:
        """``~NAME``: a configuration value for every channel (or the one global value)."""
        return self._ints(codec.get_config(name), None)

    def configure_pid(self, left: PIDConfig, right: PIDConfig) -> None:
        """Write ``^KP/^KI/^KD`` per channel in the firmware's units (x10 on 1.x, x1e6 on 2.x)."""
        self._check_open()
        encoded = [self.firmware_gains(cfg) for cfg in (left, right)]  # validate both before writing
        for cc, (kp, ki, kd) in zip((1, 2), encoded):
            self._command(codec.set_config("KP", cc, kp))
            self._command(codec.set_config("KI", cc, ki))
            self._command(codec.set_config("KD", cc, kd))

    def firmware_gains(self, cfg: PIDConfig) -> tuple[int, int, int]:
        """The ``^KP/^KI/^KD`` integers for ``cfg`` on this controller's firmware.

        Uses the control module's encoding (:data:`robchair.control.FIRMWARE_MULTIPLIER`: gain x10 on
        1.x, x1,000,000 on 2.x, :data:`robchair.control.FIRMWARE_RANGE`); CommandError if a gain does
        not fit.
        """
        from robchair.control import FIRMWARE_MULTIPLIER, FIRMWARE_RANGE

        if self.firmware is None:
            raise DeviceClosedError(f"{self.name}: firmware unknown until open() has probed ?FID")
        major = self.firmware.major
        if major not in FIRMWARE_MULTIPLIER:
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
        """``!EX``: stop both motors now (the controller holds them until ``!MG``)."""
        self._check_open()
        self.stop_reason = self.stop_reason or "emergency_stop requested"
        self._command(codec.emergency_stop())

    def release_stop(self) -> None:
        """``!MG``: leave the emergency stop; speed commands are accepted again."""
        self._check_open()
        self._command(codec.release_stop())
        self.stop_reason = None

    # --- transactions -----------------------------------------------------------------------

    def _ints(self, cmd: codec.Command, n: int | None) -> tuple[int, ...]:
        reply = self._transact(cmd)
        assert isinstance(reply, codec.Value)
        values = reply.ints()  # validated inside _transact, so this cannot raise here
        if n is not None and len(values) != n:
            self._fail(ProtocolError(f"{cmd.text}: expected {n} values, got {reply.name}={reply.raw}"))
        return values

    def _command(self, cmd: codec.Command) -> None:
        self._transact(cmd)

    def _transact(self, cmd: codec.Command) -> codec.Reply:
        """Send ``cmd`` and return its reply, retrying; on final failure stop the motors and raise."""
        assert self._port is not None
        problems: list[str] = []
        for attempt in range(self.retries + 1):
            if attempt:
                self.n_retries += 1
                self._drain()
            try:
                self._port.write(cmd.encode())
                outcome = self._await_reply(cmd)
            except OSError as exc:  # pyserial's SerialException is an IOError
                self._fail(DeviceDisconnectedError(f"Roboteq port {self._port_arg!r} failed: {exc}"))
            if isinstance(outcome, str):
                problems.append(outcome)
                log.debug("Roboteq %s: %s (attempt %d)", cmd.text, outcome, attempt + 1)
                continue
            return outcome
        kinds = {p.split(":")[0] for p in problems}
        err_cls: type[HardwareError] = DeviceTimeoutError if kinds == {"timeout"} else ProtocolError
        self._fail(
            err_cls(f"Roboteq gave no valid answer to {cmd.text!r} in {len(problems)} tries: {problems}")
        )

    def _await_reply(self, cmd: codec.Command) -> codec.Reply | str:
        """Read lines until the reply to ``cmd``; a str describes why this attempt failed."""
        assert self._port is not None
        deadline = time.monotonic() + self.timeout_s
        while True:
            lines, self._rx = codec.split_lines(self._rx)
            for line in lines:
                if not line.strip() or codec.is_echo(line, cmd):
                    continue
                try:
                    reply = codec.parse_reply_line(line)
                except ProtocolError:
                    return f"garbled: {line!r}"
                if isinstance(reply, codec.Nack):
                    return "rejected: '-'"
                if cmd.expects_value:
                    if isinstance(reply, codec.Value) and reply.name == cmd.name:
                        if cmd.name == "FID":
                            return reply
                        try:
                            reply.ints()
                        except ProtocolError:
                            return f"garbled: {line!r}"
                        return reply
                elif isinstance(reply, codec.Ack):
                    return reply
                log.debug("Roboteq: ignored unsolicited line %r while waiting for %s", line, cmd.text)
            if time.monotonic() >= deadline:
                return f"timeout: no answer within {self.timeout_s} s"
            # read(1) returns as soon as a byte is there (or after the port's short timeout); then
            # take whatever else is already buffered
            chunk = self._port.read(max(1, int(getattr(self._port, "in_waiting", 0) or 0)))
            if chunk:
                self._rx += chunk

    def _drain(self) -> None:
        """Forget buffered input, so a late answer to a failed attempt cannot be taken for the next."""
        self._rx = b""
        assert self._port is not None
        try:
            self._port.reset_input_buffer()
        except OSError as exc:
            self._fail(DeviceDisconnectedError(f"Roboteq port {self._port_arg!r} failed: {exc}"))

    # --- fault path -------------------------------------------------------------------------

    def _best_effort_stop(self, emergency: bool) -> bool:
        """Write zero speeds (and ``!EX``) without waiting for answers; True if the writes went out."""
        if self._port is None:
            return False
        cmds = [codec.set_speed(1, 0), codec.set_speed(2, 0)]
        if emergency:
            cmds.append(codec.emergency_stop())
        try:
            self._rx = b""
            self._port.write(b"".join(c.encode() for c in cmds))
            # Wait (one deadline) for the acknowledgements, so the stop is known to have arrived
            # before the error is raised; missing acks do not matter beyond the log line.
            acks, deadline = 0, time.monotonic() + self.timeout_s
            while acks < len(cmds) and time.monotonic() < deadline:
                chunk = self._port.read(max(1, int(getattr(self._port, "in_waiting", 0) or 0)))
                lines, self._rx = codec.split_lines(self._rx + chunk)
                acks += sum(1 for line in lines if line.strip() == "+")
            self.stop_acknowledged = acks == len(cmds)
            return True
        except Exception as exc:
            log.error("Roboteq: could not send the stop commands: %s", exc)
            return False

    def _fail(self, exc: HardwareError) -> NoReturn:
        """Stop the motors first (zero speeds + ``!EX``), remember why, then raise ``exc``."""
        sent = self._best_effort_stop(emergency=True)
        self.stop_reason = str(exc)
        log.error("Roboteq stop (%s): %s", "stop sent" if sent else "stop could NOT be sent", exc)
        raise exc
