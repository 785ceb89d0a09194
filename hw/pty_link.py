"""The pseudo-terminal side of an emulated serial device: open, serve on a thread, unplug, stop.

A device emulator (:class:`hw.roboteq.emulator.RoboteqEmulator`, :class:`hw.hokuyo.emulator.HokuyoEmulator`)
subclasses :class:`PtyServer` and implements only its protocol: :meth:`PtyServer._on_wake` gets the bytes
the host wrote (``b""`` when the thread woke for time alone) and answers through :meth:`PtyServer._write`.
The real driver opens :attr:`PtyServer.device_path` (the pty's slave side, raw mode) as it would open the
device's serial port.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import threading
from typing import Self

from hw.errors import HardwareError

log = logging.getLogger(__name__)

__all__ = ["PtyServer"]


class PtyServer:
    """A pty and the thread that answers on its master side.

    Subclasses call ``super().__init__()`` first, then implement :meth:`_on_wake` (and may override
    :meth:`_wait_s` and :meth:`_on_start`). Every call of :meth:`_on_wake` holds :attr:`_lock`, the
    re-entrant lock the subclass also takes for its public methods.

    Attributes:
        device_path: the slave side's path (e.g. ``/dev/pts/7``) once started, else None.
        unplugged: True after :meth:`unplug` (the pty closed as a pulled cable does).
    """

    name = "pty-device"
    idle_wake_s = 0.02

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._thread: threading.Thread | None = None
        self._running = False
        self._master: int | None = None
        self._slave: int | None = None
        self.device_path: str | None = None
        self.unplugged = False

    # --- hooks ----------------------------------------------------------------------------------

    def _on_wake(self, data: bytes) -> None:
        """Handle ``data`` from the host (``b""``: nothing arrived) and send what falls due."""
        raise NotImplementedError

    def _wait_s(self) -> float:
        """How long the thread may sleep waiting for input (s); default :attr:`idle_wake_s`."""
        return self.idle_wake_s

    def _on_start(self) -> None:
        """Called just before the thread starts, with :attr:`device_path` set."""

    # --- lifecycle ------------------------------------------------------------------------------

    def start(self) -> str:
        """Open the pty, start answering, return the device path (the pty's slave side).

        Raises:
            HardwareError: already started.
        """
        import termios
        import tty

        if self._thread is not None:
            raise HardwareError(f"{type(self).__name__}.start: already started")
        master, slave = os.openpty()
        # raw mode on the slave: no line discipline echo, no CR/LF translation, bytes as sent
        tty.setraw(slave, termios.TCSANOW)
        self._master, self._slave = master, slave
        self.device_path = os.ttyname(slave)
        self._on_start()
        self._running = True
        self._thread = threading.Thread(target=self._serve, name=self.name, daemon=True)
        self._thread.start()
        return self.device_path

    def unplug(self) -> None:
        """Close the pty (both ends) as a pulled cable does; the thread stops."""
        with self._lock:
            self.unplugged = True
            self._running = False
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None

    def stop(self) -> None:
        """Stop the thread and close the pty (idempotent)."""
        self._running = False
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        if not self.unplugged:
            self.unplug()
            self.unplugged = False

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- serving --------------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        """Send ``data`` to the host; nothing once unplugged."""
        if self._master is None:
            return
        with contextlib.suppress(OSError):
            os.write(self._master, data)

    def _serve(self) -> None:
        while self._running:
            master = self._master
            if master is None:
                break
            try:
                ready, _, _ = select.select([master], [], [], self._wait_s())
            except (OSError, ValueError):
                break
            with self._lock:
                if not self._running or self._master is None:
                    break
                data = b""
                if ready:
                    try:
                        data = os.read(master, 4096)
                    except OSError:
                        data = b""
                self._on_wake(data)
