"""Driver of the Hokuyo URG-04LX laser range finder over SCIP 2.0 (USB serial), a LaserScanner.

Session start (``open``), in the order the maintained URG libraries use:

1. ``QT`` and a drain until the line is quiet: a stream left running by a crashed program stops, and
   its scans in flight are not taken for answers;
2. ``SCIP2.0``: switches a sensor still in SCIP 1.1 mode (status ``0``); one already in SCIP 2.0
   answers ``0E`` (not defined), which is fine;
3. ``VV`` (vendor, product, firmware, protocol, serial number), ``PP`` (range limits and step
   geometry, checked for consistency), ``II`` (laser, motor and sensor state);
4. ``BM`` (laser on; ``02`` = already on is fine), then in ``mode="MD"`` the scan stream
   (``MD``/``MS`` with scans 00 = until ``QT``), in ``mode="GD"`` nothing more: each ``read``
   polls one scan with ``GD``/``GS``.

Reply integrity: each reply block must start with the echo of its command (measurement blocks with the
command's fields, an ``MD`` data echo differing only in its remaining-scan count); blocks that answer
something else are discarded and counted. Every line after the echo carries a SCIP checksum, verified
on every data line before a value is decoded; a failed checksum, a malformed block or a missing answer
is retried (the input drained first) up to ``retries`` times, then raised: :class:`DeviceTimeoutError`
when nothing came, :class:`ProtocolError` when something unusable did. In ``MD`` mode a damaged scan
is dropped and the next one awaited within the same budget; when several scans are waiting, the newest
is returned and the older ones counted in :attr:`HokuyoURG.n_dropped_scans`.

Faults: status 50..97 (laser or motor malfunction) raise :class:`DeviceFaultError`; a port that fails
(cable pulled) raises :class:`DeviceDisconnectedError`. ``close`` sends ``QT`` (laser off) on a
best-effort basis and never raises for a device that is gone.

Time: :attr:`LaserScan.stamp_ns` is the host clock when the scan's block was complete minus one scan
period (the first beam's approximate time); the sensor's own 24-bit millisecond counter is kept in
:attr:`HokuyoURG.last_timestamp_ms`.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any, TypeVar

from hw.errors import (
    CommandError,
    DeviceDisconnectedError,
    DeviceTimeoutError,
    HardwareError,
    ProtocolError,
)
from hw.hokuyo import codec, measurement
from hw.hokuyo.transport import BlockReader, SerialLike, open_serial_port
from hw.interfaces import Device, LaserScan

log = logging.getLogger(__name__)

T = TypeVar("T")

MODES = ("MD", "GD")


class HokuyoURG(Device):
    """A Hokuyo URG-04LX (or another SCIP 2.0 URG) as a :class:`hw.interfaces.LaserScanner`.

    Args:
        port: device path (``/dev/ttyACM0``, an emulator's pty) or an open serial-like object.
        baudrate: serial speed (ignored by the sensor over USB).
        mode: ``"MD"`` (the sensor streams every scan; ``read`` returns the newest) or ``"GD"`` (each
            ``read`` asks for one scan).
        encoding: 3 (``MD``/``GD``, ranges to 5.6 m) or 2 (``MS``/``GS``, ranges to 4.095 m, less data).
        start_step, end_step: scan window in sensor steps (default: ``AMIN``..``AMAX`` from ``PP``).
        cluster: steps merged into one value (1 = full resolution).
        timeout_s: deadline for one reply, s (a scan takes 0.1 s at 600 rpm).
        retries: extra attempts after a damaged or missing reply.
        clock: gives the stamps (default ``time.monotonic_ns``).
        frame_id: the scans' frame.
    """

    name = "hokuyo-urg"

    def __init__(
        self,
        port: str | SerialLike,
        *,
        baudrate: int = 115200,
        mode: str = "MD",
        encoding: int = 3,
        start_step: int | None = None,
        end_step: int | None = None,
        cluster: int = 1,
        timeout_s: float = 0.3,
        retries: int = 2,
        clock: Any = None,
        frame_id: str = "laser_link",
    ) -> None:
        if mode not in MODES:
            raise CommandError(f"mode={mode!r}: expected one of {MODES}")
        if encoding not in (2, 3):
            raise CommandError(f"encoding={encoding!r}: expected 2 (MS/GS) or 3 (MD/GD) characters")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise CommandError(f"timeout_s={timeout_s!r} must be a positive number of seconds")
        if retries < 0:
            raise CommandError(f"retries={retries!r} must be >= 0")
        if not 1 <= cluster <= 99:
            raise CommandError(f"cluster={cluster!r}: expected 1..99")
        self._port_arg = port
        self.baudrate = baudrate
        self.mode = mode
        self.encoding = encoding
        self._start_step = start_step
        self._end_step = end_step
        self.cluster = cluster
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self._clock = clock
        self.frame_id = frame_id
        self._port: SerialLike | None = None
        self._reader: BlockReader | None = None
        self._owns_port = False
        self.version: dict[str, str] = {}
        self.state: dict[str, str] = {}
        self.params: codec.SensorParams | None = None
        self.command: measurement.MeasureCommand | None = None
        self.last_timestamp_ms: int | None = None
        self._streaming = False
        # diagnostics
        self.n_retries = 0
        self.n_bad_blocks = 0
        self.n_foreign_blocks = 0
        self.n_dropped_scans = 0

    # --- lifecycle --------------------------------------------------------------------------

    def open(self) -> None:
        """Connect, identify (``SCIP2.0``, ``VV``, ``PP``, ``II``), switch the laser on, start scanning.

        Raises:
            DeviceDisconnectedError, DeviceTimeoutError, ProtocolError, DeviceFaultError: see
            :class:`hw.interfaces.LaserScanner`.
            CommandError: the requested scan window lies outside the sensor's ``AMIN``..``AMAX``.
        """
        if self._is_open:
            return
        if isinstance(self._port_arg, str):
            self._port = open_serial_port(self._port_arg, self.baudrate)
            self._owns_port = True
        else:
            self._port = self._port_arg
        self._reader = BlockReader(self._port)
        self._is_open = True
        try:
            self._io(self._port.write, b"QT\n")
            self._io(self._reader.discard, quiet_s=0.15, max_s=1.0)
            self._transact("SCIP2.0", accept=("0", "00", "0E"))
            self.version = self._transact("VV", parse=lambda r: codec.parse_info(r.lines))
            info = self._transact("PP", parse=lambda r: codec.parse_info(r.lines))
            self.params = codec.SensorParams.from_info(info)
            self.state = self._transact("II", parse=lambda r: codec.parse_info(r.lines))
            self.command = self._measure_command(self.params)
            log.info(
                "Hokuyo on %s: %s, firmware %s, %s",
                self._port_arg,
                self.version.get("PROD", "?"),
                self.version.get("FIRM", "?"),
                self.command.text(),
            )
            self._transact("BM", accept=("00", "02"))
            if self.mode == "MD":
                self._start_stream()
        except BaseException:
            self.close()
            raise

    def _measure_command(self, p: codec.SensorParams) -> measurement.MeasureCommand:
        start = p.amin if self._start_step is None else self._start_step
        end = p.amax if self._end_step is None else self._end_step
        if not p.amin <= start <= end <= p.amax:
            raise CommandError(
                f"scan window {start}..{end} lies outside the sensor's steps {p.amin}..{p.amax} (PP)"
            )
        return measurement.measure_command(
            stream=self.mode == "MD", n_chars=self.encoding, start=start, end=end, cluster=self.cluster
        )

    def _start_stream(self) -> None:
        assert self.command is not None
        self._transact(self.command.text(), accept=("00",))
        self._streaming = True

    def close(self) -> None:
        """``QT`` (laser off, stream stopped; best effort, waiting at most one reply deadline for the
        acknowledgement) and close the port if this driver opened it. Never raises for a lost device."""
        if not self._is_open:
            return
        self._is_open = False
        self._streaming = False
        if self._port is not None:
            retries, self.retries = self.retries, 0
            try:  # wait for the acknowledgement, so the laser is known to be off
                self._transact("QT", accept=("00",))
            except HardwareError as exc:  # a pulled cable or a hung sensor: nothing more to tell it
                log.debug("Hokuyo close: QT not acknowledged: %s", exc)
            finally:
                self.retries = retries
            if self._owns_port:
                try:
                    self._port.close()
                except Exception as exc:
                    log.debug("closing Hokuyo port: %s", exc)
        self._port = None
        self._reader = None

    # --- the LaserScanner interface ---------------------------------------------------------

    def read(self) -> LaserScan:
        """The next complete scan as a :class:`hw.interfaces.LaserScan` (REP-103 angles, REP-117 ranges).

        Raises:
            DeviceClosedError, DeviceTimeoutError, ProtocolError, DeviceDisconnectedError,
            DeviceFaultError: see :class:`hw.interfaces.LaserScanner`.
        """
        self._check_open()
        assert self.command is not None and self.params is not None
        if self.mode == "MD":
            raw = self._next_streamed_scan()
        else:
            cmd = self.command
            try:
                raw = self._transact(
                    cmd.text(), accept=("00",), parse=lambda r: measurement.parse_scan_reply(r, cmd)
                )
            except codec.StatusError as exc:
                if exc.status != "10":
                    raise
                # the laser went off (a reset, another program's QT): switch it on and ask again once
                log.warning("Hokuyo: laser was off; switching it on again")
                self._transact("BM", accept=("00", "02"))
                raw = self._transact(
                    cmd.text(), accept=("00",), parse=lambda r: measurement.parse_scan_reply(r, cmd)
                )
        self.last_timestamp_ms = raw.timestamp_ms
        stamp = self._now_ns() - round(self.params.scan_time * 1e9)
        return measurement.to_laser_scan(raw, self.params, stamp, self.frame_id)

    def reset(self) -> None:
        """``RS``: the sensor stops measuring, switches the laser off and restores its defaults; the
        driver then switches the laser on again and restarts its stream."""
        self._check_open()
        self._streaming = False
        self._transact("RS", accept=("00",))
        self._transact("BM", accept=("00", "02"))
        if self.mode == "MD":
            self._start_stream()

    # --- transactions -----------------------------------------------------------------------

    def _now_ns(self) -> int:
        return int(self._clock.now_ns()) if self._clock is not None else time.monotonic_ns()

    def _io(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a port operation; a failing port becomes DeviceDisconnectedError."""
        try:
            return fn(*args, **kwargs)
        except OSError as exc:  # pyserial's SerialException is an OSError
            raise DeviceDisconnectedError(f"Hokuyo port {self._port_arg!r} failed: {exc}") from exc

    def _transact(
        self,
        text: str,
        *,
        accept: tuple[str, ...] = ("00",),
        parse: Callable[[codec.Reply], T] | None = None,
    ) -> Any:
        """Send ``text``, await the block that echoes it, check its status, parse it; retry damage.

        Raises:
            StatusError / DeviceFaultError: the sensor refused the command (not retried).
            DeviceTimeoutError / ProtocolError: no usable answer after the retries.
        """
        assert self._port is not None and self._reader is not None
        problems: list[str] = []
        for attempt in range(self.retries + 1):
            if attempt:
                self.n_retries += 1
                self._io(self._reader.discard, quiet_s=0.02, max_s=self.timeout_s)
            self._io(self._port.write, text.encode("ascii") + codec.LF)
            deadline = time.monotonic() + self.timeout_s
            while True:
                block = self._io(self._reader.read_block, deadline)
                if block is None:
                    problems.append(f"timeout: no answer within {self.timeout_s} s")
                    break
                if block and block[0] != text.encode("ascii", errors="replace"):
                    if self._is_damaged_echo(block[0], text):
                        self.n_bad_blocks += 1
                        problems.append(f"garbled echo {block[0][:40]!r}")
                        break
                    self.n_foreign_blocks += 1  # e.g. a scan of a stream still in flight
                    log.debug("Hokuyo: discarded block %r while waiting for %s", block[0][:40], text)
                    continue
                try:
                    reply = codec.parse_reply(block)
                    if reply.status == codec.STATUS_SCAN and codec.STATUS_SCAN not in accept:
                        self.n_foreign_blocks += 1  # a scan of an earlier identical stream
                        continue
                    codec.check_status(text, reply.status, accept)
                    return parse(reply) if parse is not None else reply.status
                except (codec.StatusError, codec.HardwareTroubleError):
                    raise
                except ProtocolError as exc:
                    self.n_bad_blocks += 1
                    problems.append(f"damaged reply: {exc}")
                    break
        kinds = {p.split(":")[0] for p in problems}
        err: type[HardwareError] = DeviceTimeoutError if kinds == {"timeout"} else ProtocolError
        raise err(f"Hokuyo gave no valid answer to {text!r} in {len(problems)} tries: {problems}")

    @staticmethod
    def _is_damaged_echo(line: bytes, text: str) -> bool:
        """An echo of our command that line noise changed (same length, not clean ASCII or mostly equal)."""
        want = text.encode("ascii", errors="replace")
        if len(line) != len(want):
            return False
        same = sum(a == b for a, b in zip(line, want))
        return same >= len(want) // 2

    def _next_streamed_scan(self) -> measurement.RawScan:
        """The newest complete scan of the ``MD``/``MS`` stream (waiting for one if none is buffered)."""
        assert self._reader is not None and self.command is not None
        cmd = self.command
        problems: list[str] = []
        deadline = time.monotonic() + self.timeout_s
        latest: measurement.RawScan | None = None
        while True:
            block = self._io(self._reader.read_block, deadline if latest is None else 0.0)
            if block is None:
                if latest is not None:
                    return latest
                problems.append(f"timeout: no scan within {self.timeout_s} s")
                if len(problems) > self.retries:
                    break
                # restart the stream: the sensor may have stopped it (QT by another program, a reset)
                self.n_retries += 1
                self._restart_stream()
                deadline = time.monotonic() + self.timeout_s
                continue
            try:
                reply = codec.parse_reply(block)
            except ProtocolError as exc:
                self.n_bad_blocks += 1
                problems.append(f"damaged reply: {exc}")
                if len(problems) > self.retries:
                    break
                continue
            if not reply.echo.startswith(cmd.name):
                self.n_foreign_blocks += 1
                continue
            if reply.status == codec.STATUS_OK:  # the acknowledgement of (re)starting the stream
                continue
            codec.check_status(reply.echo, reply.status, (codec.STATUS_SCAN,))
            try:
                scan = measurement.parse_scan_reply(reply, cmd)
            except ProtocolError as exc:
                self.n_bad_blocks += 1
                self.n_retries += 1
                problems.append(f"damaged scan: {exc}")
                log.debug("Hokuyo: dropped a damaged scan: %s", exc)
                if len(problems) > self.retries:
                    break
                continue
            if latest is not None:
                self.n_dropped_scans += 1
            latest = scan
        if latest is not None:  # damage after a good scan only costs the newer ones
            return latest
        kinds = {p.split(":")[0] for p in problems}
        err: type[HardwareError] = DeviceTimeoutError if kinds == {"timeout"} else ProtocolError
        raise err(f"Hokuyo stream {cmd.text()!r} gave no valid scan in {len(problems)} tries: {problems}")

    def _restart_stream(self) -> None:
        assert self._port is not None and self._reader is not None and self.command is not None
        self._transact("QT", accept=("00",))  # scans still in flight come before its echo
        self._transact("BM", accept=("00", "02"))
        self._start_stream()
