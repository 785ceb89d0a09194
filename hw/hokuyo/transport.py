"""Byte transport of the Hokuyo driver: a serial port (USB CDC-ACM ``/dev/ttyACM0``, or a pty) read
as SCIP reply blocks (lines ending in LF, a block ending in an empty line).

The URG-04LX enumerates as a USB modem; its baud rate setting is ignored over USB (19200 and 115200
both work) and only matters on its RS-232 connector. Any object with pyserial's ``write``,
``read(n)`` (returning what arrived within its own short timeout), ``in_waiting``,
``reset_input_buffer`` and ``close`` can stand in for the port.
"""

from __future__ import annotations

import time
from typing import Protocol

from hw.errors import DeviceDisconnectedError, HardwareError

BLOCK_END = b"\n\n"


class SerialLike(Protocol):
    def write(self, data: bytes) -> int | None: ...

    def read(self, size: int = 1) -> bytes: ...

    @property
    def in_waiting(self) -> int: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


def open_serial_port(path: str, baudrate: int = 115200, write_timeout_s: float = 0.5) -> SerialLike:
    """Open ``path`` 8N1 with a 5 ms read timeout (``read`` returns what is there).

    Raises:
        DeviceDisconnectedError: the port does not exist or cannot be opened.
    """
    try:
        import serial
    except ImportError as exc:  # pragma: no cover - pyserial is a dependency
        raise HardwareError("the Hokuyo driver needs pyserial: pip install pyserial") from exc
    try:
        port: SerialLike = serial.Serial(
            path, baudrate=baudrate, timeout=0.005, write_timeout=write_timeout_s
        )
    except (serial.SerialException, OSError) as exc:
        raise DeviceDisconnectedError(f"cannot open Hokuyo port {path!r}: {exc}") from exc
    return port


class BlockReader:
    """Splits what a port sends into reply blocks, keeping any partial block for the next call."""

    def __init__(self, port: SerialLike) -> None:
        self.port = port
        self._rx = b""

    @property
    def buffered(self) -> int:
        return len(self._rx)

    def has_block(self) -> bool:
        return BLOCK_END in self._rx

    def pump(self) -> int:
        """Read whatever the port holds now (at most the port's short timeout); bytes read.

        Raises:
            OSError: the port failed (pyserial's SerialException is an OSError).
        """
        chunk = self.port.read(max(1, int(self.port.in_waiting or 0)))
        self._rx += chunk
        return len(chunk)

    def read_block(self, deadline: float) -> list[bytes] | None:
        """The lines of the next complete block (LFs removed, the empty end line excluded), or None
        when ``deadline`` (``time.monotonic()``) passes first. A deadline in the past still takes a
        block that is already buffered or waiting in the port.

        Raises:
            OSError: the port failed.
        """
        while True:
            if BLOCK_END in self._rx:
                block, self._rx = self._rx.split(BLOCK_END, 1)
                # a block never starts with a blank line: stray LFs before it are separators
                return block.lstrip(b"\n").split(b"\n")
            got = self.pump()
            if not got and time.monotonic() >= deadline:
                return None

    def discard(self, quiet_s: float = 0.0, max_s: float = 0.5) -> int:
        """Drop buffered input, then keep reading until the port stayed quiet for ``quiet_s`` (so the
        rest of a reply in flight is dropped too), at most ``max_s``. Returns the bytes dropped.

        Raises:
            OSError: the port failed.
        """
        dropped = len(self._rx)
        self._rx = b""
        self.port.reset_input_buffer()
        if quiet_s <= 0:
            return dropped
        t_end = time.monotonic() + max_s
        last = time.monotonic()
        while time.monotonic() < t_end:
            n = self.pump()
            if n:
                dropped += n
                self._rx = b""
                last = time.monotonic()
            elif time.monotonic() - last >= quiet_s:
                break
        self._rx = b""
        return dropped
