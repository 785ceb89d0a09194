"""Line-oriented serial links to the Arduino boards (SRF04 echo timer, servo, joystick).

The drivers talk to a *transport*: anything with pyserial's ``write``, ``readline``, ``in_waiting``
and ``close``. A real port is opened by :func:`open_serial` (pyserial imported only then); tests use
the emulators next to each driver, which answer the same ASCII line protocols byte for byte.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol, runtime_checkable

from hw.errors import DeviceIOError, HardwareError
from hw.interfaces import Clock


@runtime_checkable
class LineTransport(Protocol):
    """The subset of ``serial.Serial`` the line drivers use."""

    @property
    def in_waiting(self) -> int: ...

    def write(self, data: bytes) -> int | None: ...

    def readline(self) -> bytes: ...

    def close(self) -> None: ...


def open_serial(port: str, baudrate: int = 115200, timeout_s: float = 0.05) -> LineTransport:
    """Open a serial port as a :class:`LineTransport` (8N1; ``readline`` times out after ``timeout_s``)."""
    try:
        import serial
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise HardwareError("serial devices need 'pyserial': pip install pyserial") from exc
    try:
        port_obj: LineTransport = serial.Serial(port, baudrate=baudrate, timeout=timeout_s)
    except (OSError, serial.SerialException) as exc:
        raise DeviceIOError(getattr(exc, "errno", None), f"cannot open serial port {port!r}: {exc}") from exc
    return port_obj


def decode_line(raw: bytes) -> str | None:
    """ASCII line without its CR/LF, or None when it is not clean printable ASCII (line noise)."""
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        return None
    text = text.rstrip("\r\n")
    if not text.isprintable():
        return None
    return text


def lines_until(transport: LineTransport, clock: Clock, timeout_s: float, poll_s: float) -> Iterator[bytes]:
    """Yield the raw lines ``transport`` delivers until ``timeout_s`` of ``clock`` time has passed.

    When nothing is waiting, sleeps ``poll_s`` on ``clock`` (simulated time in tests) before asking
    again; the deadline is checked before every read, so a caller that keeps rejecting lines still
    stops on time. The caller parses each line and returns (or breaks) on the one it waits for.
    """
    deadline = clock.now_ns() + round(timeout_s * 1e9)
    while True:
        before = clock.now_ns()
        if before >= deadline:
            return
        raw = transport.readline()
        if not raw:
            clock.sleep_until_ns(before + round(poll_s * 1e9))
            continue
        yield raw


class EmulatedLineBoard:
    """The serial side of an emulated Arduino board, as a :class:`LineTransport`.

    Host writes are split into LF-terminated ASCII lines and handed to :meth:`_handle`; the board's
    answers are queued with :meth:`_send` and handed back one line per ``readline`` (``b""`` when
    nothing is waiting, like a pyserial read that times out). Subclasses implement the protocol.
    """

    def __init__(self) -> None:
        self._rx = b""
        self._tx: list[bytes] = []
        self.closed = False

    @property
    def in_waiting(self) -> int:
        return sum(len(b) for b in self._tx)

    def write(self, data: bytes) -> int:
        self._check_open()
        self._rx += data
        while b"\n" in self._rx:
            line, self._rx = self._rx.split(b"\n", 1)
            self._handle(line.decode("ascii", "replace").strip())
        return len(data)

    def readline(self) -> bytes:
        self._check_open()
        return self._tx.pop(0) if self._tx else b""

    def close(self) -> None:
        self.closed = True

    def _check_open(self) -> None:
        if self.closed:
            raise OSError("emulated serial port is closed")

    def _send(self, raw: bytes) -> None:
        """Queue raw bytes (normally one line with its LF) for the host to read."""
        self._tx.append(raw)

    def _handle(self, line: str) -> None:
        """React to one host line (default: a board that ignores what the host sends)."""
