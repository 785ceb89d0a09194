"""A Hokuyo URG-04LX on a pseudo-terminal: SCIP 2.0 byte for byte, ranges from a 2D scene.

The emulator opens a pty (``os.openpty``, raw mode) and a background thread answers on the master side
what the sensor answers on its USB serial port: the echo, the status with its checksum, the
``NAME:value;`` lines of ``VV``/``PP``/``II``, and scans as 2- or 3-character data lines of at most 64
characters with a checksum each, every block ended by an empty line. The real driver
(:class:`hw.hokuyo.driver.HokuyoURG`) is pointed at :attr:`HokuyoEmulator.device_path` unchanged.

Behaviour modelled after the SCIP 2.0 specification: the sensor powers up in SCIP 1.1 mode (only
``SCIP2.0`` is understood, other commands get the SCIP 1.1 status ``E``) unless ``scip2=True``;
``BM`` switches the laser on (``02`` when already on); ``GD``/``GS`` answer ``10`` while the laser is
off and otherwise wait for the next complete revolution (one scan every 100 ms at 600 rpm); ``MD``/
``MS`` switch the laser on, acknowledge with ``00`` and then send one ``99`` block per revolution
(every ``interval + 1`` revolutions) with the remaining-scan count in the echo, until the count is
reached (then the laser goes off) or ``QT``; ``RS`` stops everything and switches the laser off.

Ranges come from a :class:`Scene2D` (segments and circles in the sensor frame, x forward, y left) or
from any function of the beam angles (rad, REP-103) returning metres. A beam with nothing within
DMAX reads error code 0 ("object possibly at 22 m"); one nearer than DMIN reads code 19
("non-measurable distance"); in 2-character mode a range above 4095 mm reads code 16.

Fault injection (:meth:`HokuyoEmulator.inject`): replace a data line by line noise (``garble``),
change one data character but not its checksum (``bad_checksum``), hold replies back
(``delay_s``/``delay_n``), stop answering altogether (``stuck``), report hardware trouble in every
status (``hardware_status``); :meth:`unplug` closes the pty as a pulled cable does.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hw.errors import HardwareError, ProtocolError
from hw.hokuyo import codec, measurement
from hw.pty_link import PtyServer

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_VERSION", "HokuyoEmulator", "Scene2D"]

IDLE_WAKE_S = 0.01

DEFAULT_VERSION: dict[str, str] = {
    "VEND": "Hokuyo Automatic Co.,Ltd.",
    "PROD": "SOKUIKI Sensor URG-04LX",
    "FIRM": "3.4.03(17/Dec./2007)",
    "PROT": "SCIP 2.0",
    "SERI": "H0000000",
}

RangeFunction = Callable[[npt.NDArray[np.float64]], Any]


@dataclass(frozen=True)
class Scene2D:
    """A flat world around the sensor: line segments and circles in the sensor frame (m).

    Attributes:
        segments: ``((x1, y1), (x2, y2))`` pairs.
        circles: ``((cx, cy), radius)`` pairs.
    """

    segments: tuple[tuple[tuple[float, float], tuple[float, float]], ...] = ()
    circles: tuple[tuple[tuple[float, float], float], ...] = ()

    def ranges(self, angles: Any) -> npt.NDArray[np.float64]:
        """Distance (m) from the origin along each angle to the first hit; ``inf`` for none."""
        a = np.asarray(angles, dtype=np.float64)
        d = np.stack([np.cos(a), np.sin(a)], axis=-1)  # (N, 2)
        best = np.full(a.shape, np.inf)
        if self.segments:
            seg = np.asarray(self.segments, dtype=np.float64)  # (S, 2, 2)
            p, q = seg[:, 0, :], seg[:, 1, :]
            e = q - p  # (S, 2)
            # origin + t d = p + u e  ->  t d - u e = p ; solve with 2D cross products
            den = d[:, None, 0] * (-e[None, :, 1]) - d[:, None, 1] * (-e[None, :, 0])  # (N, S)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (p[None, :, 0] * (-e[None, :, 1]) - p[None, :, 1] * (-e[None, :, 0])) / den
                u = (d[:, None, 0] * p[None, :, 1] - d[:, None, 1] * p[None, :, 0]) / den
            ok = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
            best = np.minimum(best, np.where(ok, t, np.inf).min(axis=1))
        for (cx, cy), r in self.circles:
            b = d[:, 0] * cx + d[:, 1] * cy
            disc = b * b - (cx * cx + cy * cy - r * r)
            with np.errstate(invalid="ignore"):
                s = np.sqrt(disc)
            t_near, t_far = b - s, b + s
            t = np.where(t_near > 0, t_near, np.where(t_far > 0, t_far, np.inf))
            best = np.minimum(best, np.where(disc >= 0, t, np.inf))
        return best


def room_scene(half_width: float = 2.0, front: float = 3.0, back: float = 1.0) -> Scene2D:
    """A rectangular room around the sensor with a round pillar ahead on the left (a demo scene)."""
    x0, x1, y0, y1 = -back, front, -half_width, half_width
    return Scene2D(
        segments=(((x0, y0), (x1, y0)), ((x1, y0), (x1, y1)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0))),
        circles=(((1.5, 0.8), 0.2),),
    )


@dataclass
class _Faults:
    garble: int = 0
    bad_checksum: int = 0
    delay_n: int = 0
    delay_s: float = 0.0
    stuck: bool = False
    hardware_status: str | None = None


@dataclass
class _Stream:
    command: measurement.MeasureCommand
    remaining: int  # scans still to send; -1 = until QT
    next_rev: int  # revolution index of the next scan to send
    every: int


@dataclass
class _Pending:
    command: measurement.MeasureCommand
    rev: int


class HokuyoEmulator(PtyServer):
    """An emulated URG-04LX answering SCIP 2.0 on a pty.

    Args:
        scene: a :class:`Scene2D`, a function of the beam angles (rad) returning ranges (m), or None
            (:func:`room_scene`).
        params: the ``PP`` values (default the URG-04LX's).
        version: the ``VV`` values.
        scip2: start in SCIP 2.0 mode (default: SCIP 1.1, as a URG-04LX with older firmware powers up).
        noise_std_m: Gaussian range noise (0 = exact ranges, rounded to mm).
        seed: seed of the noise generator.
    """

    name = "hokuyo-emulator"
    idle_wake_s = IDLE_WAKE_S

    def __init__(
        self,
        scene: Scene2D | RangeFunction | None = None,
        *,
        params: codec.SensorParams = codec.URG_04LX,
        version: dict[str, str] | None = None,
        scip2: bool = False,
        noise_std_m: float = 0.0,
        seed: int = 0,
    ) -> None:
        if not (math.isfinite(noise_std_m) and noise_std_m >= 0):
            raise HardwareError(f"HokuyoEmulator: noise_std_m must be >= 0, got {noise_std_m!r}")
        super().__init__()
        self.scene = scene if scene is not None else room_scene()
        self.params = params
        self.version = dict(DEFAULT_VERSION if version is None else version)
        self.scip2 = scip2
        self.noise_std_m = float(noise_std_m)
        self._rng = np.random.default_rng(seed)
        self.laser_on = False
        self.faults = _Faults()
        self.received: list[str] = []
        self.scans_sent = 0
        self._rx = b""
        self._t0 = time.monotonic()
        self._stream: _Stream | None = None
        self._pending: list[_Pending] = []
        self._delayed: list[tuple[float, bytes]] = []
        self._sent_rev = -1

    # --- ranges ---------------------------------------------------------------------------------

    def values_for(self, command: measurement.MeasureCommand) -> npt.NDArray[np.int64]:
        """The raw values (mm or error codes) the sensor would send for ``command`` now."""
        p = self.params
        cluster = max(command.cluster, 1)
        steps = np.arange(command.start, command.end + 1)
        angles = p.step_angle(steps)
        fn = self.scene.ranges if isinstance(self.scene, Scene2D) else self.scene
        r = np.asarray(fn(angles), dtype=np.float64).reshape(-1)
        if r.shape != angles.shape:
            raise HardwareError(f"scene returned {r.shape[0]} ranges for {angles.shape[0]} beams")
        if self.noise_std_m > 0:
            r = r + self.noise_std_m * self._rng.standard_normal(r.shape)
        with np.errstate(invalid="ignore"):
            mm = np.where(np.isfinite(r), np.round(r * 1000.0), np.inf)
        values = np.where(mm > p.dmax_mm, 0, np.where(mm < p.dmin_mm, 19, mm))
        values = np.nan_to_num(values, nan=18).astype(np.int64)
        dead = (steps < p.amin) | (steps > p.amax)  # outside the measurable window: no light back
        values[dead] = 1
        if command.n_chars == 2:
            values = np.where(values > 4095, 16, values)
        if cluster > 1:  # the sensor reports the smallest valid range of each cluster
            n = command.n_values
            pad = np.full(n * cluster - values.size, -1, dtype=np.int64)
            groups = np.concatenate([values, pad]).reshape(n, cluster)
            valid = np.where(groups >= p.dmin_mm, groups, np.iinfo(np.int64).max)
            mins = valid.min(axis=1)
            values = np.where(mins == np.iinfo(np.int64).max, groups[:, 0], mins)
        return values

    # --- fault injection ------------------------------------------------------------------------

    def inject(
        self,
        *,
        garble: int = 0,
        bad_checksum: int = 0,
        delay_s: float = 0.0,
        delay_n: int = 0,
        stuck: bool | None = None,
        hardware_status: str | None = None,
    ) -> None:
        """Damage, delay or stop the next replies.

        Args:
            garble: the next N replies with data lines get one line replaced by line noise.
            bad_checksum: the next N such replies get one data character changed, checksum kept.
            delay_s, delay_n: hold the next ``delay_n`` replies back ``delay_s`` real seconds.
            stuck: True: answer nothing (a hung sensor) until set False again.
            hardware_status: answer every command with this status (e.g. ``"50"``: laser
                malfunction); ``""`` clears it.
        """
        with self._lock:
            self.faults.garble += garble
            self.faults.bad_checksum += bad_checksum
            if delay_n:
                self.faults.delay_n += delay_n
                self.faults.delay_s = float(delay_s)
            if stuck is not None:
                self.faults.stuck = stuck
            if hardware_status is not None:
                self.faults.hardware_status = hardware_status or None

    # --- lifecycle ------------------------------------------------------------------------------

    def _on_start(self) -> None:
        self._t0 = time.monotonic()
        log.info("Hokuyo emulator on %s", self.device_path)

    # --- time -----------------------------------------------------------------------------------

    def _revolution(self, t: float | None = None) -> int:
        """Index of the revolution in progress (revolution k ends at (k + 1) * scan_time)."""
        t = time.monotonic() if t is None else t
        return int((t - self._t0) / self.params.scan_time)

    def _timestamp_ms(self) -> int:
        return int((time.monotonic() - self._t0) * 1000.0) % measurement.TIMESTAMP_MODULO_MS

    # --- serving --------------------------------------------------------------------------------

    def _on_wake(self, data: bytes) -> None:
        if data:
            self._rx += data.replace(b"\r", b"\n")
            while b"\n" in self._rx:
                line, self._rx = self._rx.split(b"\n", 1)
                if line.strip():
                    self._handle(line.decode("ascii", errors="replace").strip())
        self._tick()

    def _tick(self) -> None:
        """Send what falls due: scans of finished revolutions, delayed replies."""
        rev_done = self._revolution() - 1  # the last completed revolution
        if not self.faults.stuck:
            for pend in [p for p in self._pending if p.rev <= rev_done]:
                self._pending.remove(pend)
                self._send_scan(pend.command, codec.STATUS_OK)
            s = self._stream
            if s is not None and s.next_rev <= rev_done:
                remaining = max(s.remaining - 1, 0) if s.remaining > 0 else 0
                self._send_scan(s.command.with_remaining(remaining), codec.STATUS_SCAN)
                s.next_rev = rev_done + s.every
                if s.remaining > 0:
                    s.remaining -= 1
                    if s.remaining == 0:
                        self._stream = None
                        self.laser_on = False
        now = time.monotonic()
        due = [d for d in self._delayed if d[0] <= now]
        self._delayed = [d for d in self._delayed if d[0] > now]
        for _, data in due:
            self._write(data)

    def _send_block(self, lines: list[bytes], *, data_from: int | None = None) -> None:
        """Send one reply block; ``data_from`` is the index of the first line that faults may damage."""
        if self.faults.stuck:
            return
        lines = list(lines)
        if data_from is not None and data_from < len(lines):
            k = data_from + (len(lines) - data_from) // 2  # a line in the middle of the data
            if self.faults.garble > 0:
                self.faults.garble -= 1
                lines[k] = bytes(0x80 | (b ^ 0x2A) for b in lines[k])
            elif self.faults.bad_checksum > 0:
                self.faults.bad_checksum -= 1
                line = bytearray(lines[k])
                line[0] = 0x30 + ((line[0] - 0x30 + 1) & 0x3F)  # still a data character
                lines[k] = bytes(line)
        data = b"".join(line + codec.LF for line in lines) + codec.LF
        if self.faults.delay_n > 0:
            self.faults.delay_n -= 1
            self._delayed.append((time.monotonic() + self.faults.delay_s, data))
            return
        self._write(data)

    def _status_block(self, echo: str, status: str, body: list[bytes] | None = None) -> None:
        if self.faults.hardware_status is not None:
            status, body = self.faults.hardware_status, None
        self._send_block(
            [echo.encode("ascii", errors="replace"), codec.with_checksum(status.encode()), *(body or [])],
            data_from=2,
        )

    def _send_scan(self, command: measurement.MeasureCommand, status: str) -> None:
        values = self.values_for(command)
        lines = measurement.scan_reply_lines(command, status, self._timestamp_ms(), values)
        self.scans_sent += 1
        self._send_block(lines, data_from=3)

    def _handle(self, line: str) -> None:
        self.received.append(line)
        if self.faults.stuck:
            return
        if not self.scip2:
            if line == "SCIP2.0":
                self.scip2 = True
                self._send_block([b"SCIP2.0", b"0"])
            else:
                self._send_block([line.encode("ascii", errors="replace"), b"E"])
            return
        name = line[:2]
        if line == "SCIP2.0":
            self._status_block(line, "0E")
        elif line == "VV":
            self._status_block(line, "00", [codec.info_line(k, v) for k, v in self.version.items()])
        elif line == "PP":
            p = self.params
            pp = {
                "MODL": p.model,
                "DMIN": str(p.dmin_mm),
                "DMAX": str(p.dmax_mm),
                "ARES": str(p.ares),
                "AMIN": str(p.amin),
                "AMAX": str(p.amax),
                "AFRT": str(p.afrt),
                "SCAN": str(p.scan_rpm),
            }
            self._status_block(line, "00", [codec.info_line(k, v) for k, v in pp.items()])
        elif line == "II":
            ii = {
                "MODL": self.params.model,
                "LASR": "ON" if self.laser_on else "OFF",
                "SCSP": f"Initial({self.params.scan_rpm}[rpm])",
                "MESM": "Measuring by Normal Mode",
                "SBPS": "USB only",
                "TIME": f"{self._timestamp_ms():06X}",
                "STAT": "Sensor works well." if self.faults.hardware_status is None else "Laser malfunction.",
            }
            self._status_block(line, "00", [codec.info_line(k, v) for k, v in ii.items()])
        elif line == "BM":
            status = "02" if self.laser_on else "00"
            self.laser_on = True
            self._status_block(line, status)
        elif line == "QT":
            self._stream = None
            self._pending.clear()
            self.laser_on = False
            self._status_block(line, "00")
        elif line == "RS":
            self._stream = None
            self._pending.clear()
            self.laser_on = False
            self._status_block(line, "00")
        elif name in ("MD", "MS", "GD", "GS"):
            self._measure(line)
        else:
            self._status_block(line, "0E")

    def _measure(self, line: str) -> None:
        try:
            cmd = measurement.parse_measure_command(line)
        except ProtocolError as exc:
            field_status = {"start": "01", "end": "02", "cluster": "03", "interval": "06", "scans": "07"}
            status = next((v for k, v in field_status.items() if f"field {k} " in str(exc)), "0C")
            self._status_block(line, status)
            return
        p = self.params
        if len(cmd.tag) > measurement.MAX_TAG_CHARS:
            self._status_block(line, "0G")
            return
        if cmd.end < cmd.start:
            self._status_block(line, "05")
            return
        if cmd.end > p.amin + p.amax - 1:  # steps 0..768 on the URG-04LX (44..725 measurable)
            self._status_block(line, "04")
            return
        if self.faults.hardware_status is not None:
            self._status_block(line, self.faults.hardware_status)
            return
        if cmd.stream:
            self.laser_on = True
            self._status_block(line, "00")
            rev = self._revolution()
            self._stream = _Stream(cmd, cmd.scans if cmd.scans > 0 else -1, rev, cmd.interval + 1)
        else:
            if not self.laser_on:
                self._status_block(line, "10")
                return
            # the reply carries the next complete revolution
            self._pending.append(_Pending(cmd, self._revolution()))
