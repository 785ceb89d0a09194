"""One command, one reply, retried; when it fails for good, the motors stop first and the error follows.

:class:`RoboteqTransactions` is the part of :class:`hw.roboteq.driver.RoboteqMDC2230` that talks to
the port: it opens it (pyserial, 115200 8N1, or any object with the same methods), sends each command
through the :class:`hw.roboteq.link.ReplyLink` that pairs replies with commands, retries a ``-``, a
garbled or malformed line or a timeout up to ``retries`` times, and on final failure takes the fault
path: zero speeds and ``!EX`` (only zero in a read-only session), the error state, then the raise. A
port that failed (unplugged) is never written again.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, NoReturn, Protocol

from hw.errors import (
    DeviceClosedError,
    DeviceDisconnectedError,
    DeviceTimeoutError,
    HardwareError,
    ProtocolError,
)
from hw.interfaces import Device, LifecycleState
from hw.roboteq import codec
from hw.roboteq.link import ReplyLink

log = logging.getLogger(__name__)

S = LifecycleState

RELEASE_HINT = "release it with `robchair run --release-stop` (driver: release())"


class SerialLike(Protocol):
    def write(self, data: bytes) -> int | None: ...

    def read(self, size: int = 1) -> bytes: ...

    def close(self) -> None: ...

    def reset_input_buffer(self) -> None: ...


class RoboteqTransactions(Device):
    """Port, transactions and fault path of the Roboteq driver (the state is set by the driver).

    Attributes:
        retries: extra attempts after a ``-``, a garbled or malformed line or a timeout.
        n_retries: retries made since the session started.
        stop_reason: why the motors were last stopped by the fault path (None after a release).
        stop_acknowledged: the controller acknowledged the fault path's stop commands.
    """

    _port_arg: str | SerialLike
    _port: SerialLike | None
    _owns_port: bool
    _link: ReplyLink | None
    _state: LifecycleState
    _clock: Any
    _dead: bool
    _identified: bool
    _writable: bool
    _last_bang_ns: int | None
    baudrate: int
    timeout_s: float
    retries: int
    n_retries: int
    stop_reason: str | None
    stop_acknowledged: bool

    def _check_open(self) -> None:
        if self._state in (S.UNCONFIGURED, S.FINALIZED) or self._port is None:
            raise DeviceClosedError(
                f"{self.name} is closed ({self._state.value}): call open() (or configure()) first"
            )
        if self._dead:
            raise DeviceDisconnectedError(
                f"Roboteq port {self._port_arg!r} is gone ({self.stop_reason}); close and open again"
            )

    def _now_ns(self) -> int:
        return int(self._clock.now_ns()) if self._clock is not None else time.monotonic_ns()

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

    def _command(self, cmd: codec.Command) -> None:
        self._transact(cmd, expected=None)

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
