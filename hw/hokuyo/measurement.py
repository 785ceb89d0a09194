"""SCIP 2.0 measurement: the ``MD``/``MS``/``GD``/``GS`` commands, scan data, and scans as LaserScan.

Facts (SCIP 2.0 specification, URG-04LX specification; framing and checksums in
:mod:`hw.hokuyo.codec`):

* ``MDSSSSEEEECCSNN`` / ``GDSSSSEEEECC``: start and end step (4 digits), cluster count (2), for ``M?``
  the scan interval (1) and the number of scans (2, 00 = until ``QT``), then optionally ``;tag``
  (at most 16 characters, echoed). ``?D`` sends 3-character values, ``?S`` 2-character ones.
* A scan reply: echo, status (``00`` for ``G?``, ``99`` for each scan of an ``M?`` stream, whose echo
  carries the number of scans still to come), the 4-character millisecond time stamp (24 bits) with
  its checksum, then data lines of at most 64 characters plus a checksum each; a value may be split
  across two lines.
* Values below DMIN (20 mm on the URG-04LX) are error codes, not ranges.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hw.errors import ProtocolError
from hw.hokuyo.codec import (
    LF,
    Reply,
    SensorParams,
    decode,
    decode_array,
    encode,
    encode_array,
    verify_line,
    with_checksum,
)
from hw.interfaces import LaserScan

#: Most data characters on one line of a scan reply (the checksum follows them).
DATA_LINE_CHARS = 64
#: Longest tag a measurement command may carry (echoed with it).
MAX_TAG_CHARS = 16
TIMESTAMP_CHARS = 4
TIMESTAMP_MODULO_MS = 1 << 24

#: URG-04LX error codes that come in place of a range (values below DMIN = 20 mm).
ERROR_CODES: dict[int, str] = {
    0: "possibility of detected object at 22 m",
    **{k: "reflected light has low intensity" for k in range(1, 6)},
    6: "possibility of detected object at 5.7 m",
    7: "distance data on the preceding and succeeding steps have errors",
    8: "others",
    9: "the same step had an error in the last two scans",
    **{k: "others" for k in range(10, 16)},
    16: "possibility of detected object in the range 4096 mm",
    17: "others",
    18: "unspecified",
    19: "non-measurable distance",
}
#: Error codes that mean "nothing measurable out there" (far or too dark): ``+inf`` under REP-117.
#: Every other code is an invalid measurement: ``NaN``.
NO_RETURN_CODES = frozenset({0, 1, 2, 3, 4, 5, 6, 16})


def split_data_lines(data: bytes) -> list[bytes]:
    """Scan data as reply lines: at most 64 characters each, each followed by its checksum."""
    return [with_checksum(data[i : i + DATA_LINE_CHARS]) for i in range(0, len(data), DATA_LINE_CHARS)]


@dataclass(frozen=True)
class MeasureCommand:
    """An ``MD``/``MS`` (stream) or ``GD``/``GS`` (one scan) request.

    Attributes:
        stream: True for ``M?`` (scans pushed until done or ``QT``), False for ``G?`` (one scan).
        n_chars: 3 for ``?D`` (ranges to 262 m), 2 for ``?S`` (ranges to 4095 mm).
        start, end: First and last step (inclusive).
        cluster: Steps merged into one value (00 and 01 both mean 1).
        interval: ``M?`` only: scans skipped between two sent ones.
        scans: ``M?`` only: number of scans to send (0 = until ``QT``); in a data reply's echo, the
            number still to come.
        tag: Optional string echoed with the command (at most 16 characters).
    """

    stream: bool
    n_chars: int
    start: int
    end: int
    cluster: int = 1
    interval: int = 0
    scans: int = 0
    tag: str = ""

    @property
    def name(self) -> str:
        return ("M" if self.stream else "G") + ("D" if self.n_chars == 3 else "S")

    @property
    def n_values(self) -> int:
        """Values in one scan: one per cluster of steps, a last partial cluster counting as one."""
        return -(-(self.end - self.start + 1) // max(self.cluster, 1))

    def text(self) -> str:
        """The command as sent, without LF."""
        s = f"{self.name}{self.start:04d}{self.end:04d}{self.cluster:02d}"
        if self.stream:
            s += f"{self.interval:01d}{self.scans:02d}"
        return s + (f";{self.tag}" if self.tag else "")

    def encode(self) -> bytes:
        return self.text().encode("ascii") + LF

    def with_remaining(self, scans: int) -> MeasureCommand:
        """The same command with the remaining-scan count a data reply echoes."""
        return MeasureCommand(
            self.stream, self.n_chars, self.start, self.end, self.cluster, self.interval, scans, self.tag
        )


def measure_command(
    *,
    stream: bool,
    n_chars: int = 3,
    start: int,
    end: int,
    cluster: int = 1,
    interval: int = 0,
    scans: int = 0,
    tag: str = "",
) -> MeasureCommand:
    """A validated :class:`MeasureCommand`.

    Raises:
        ProtocolError: a field does not fit its digits, ``end < start``, or the tag is too long or not
            printable ASCII without ``;``.
    """
    if n_chars not in (2, 3):
        raise ProtocolError(f"n_chars={n_chars}: SCIP scan data uses 2 (MS/GS) or 3 (MD/GD) characters")
    if not (0 <= start <= 9999 and 0 <= end <= 9999 and start <= end):
        raise ProtocolError(f"steps {start}..{end}: expected 0 <= start <= end <= 9999")
    if not 0 <= cluster <= 99:
        raise ProtocolError(f"cluster={cluster}: expected 0..99")
    if not (0 <= interval <= 9 and 0 <= scans <= 99):
        raise ProtocolError(f"interval={interval}, scans={scans}: expected 0..9 and 0..99")
    if len(tag) > MAX_TAG_CHARS or not all(0x20 <= ord(c) < 0x7F and c != ";" for c in tag):
        raise ProtocolError(f"tag {tag!r}: at most {MAX_TAG_CHARS} printable ASCII characters, no ';'")
    return MeasureCommand(
        stream, n_chars, start, end, cluster, interval if stream else 0, scans if stream else 0, tag
    )


def parse_measure_command(text: str) -> MeasureCommand:
    """The :class:`MeasureCommand` of a command line or of its echo.

    Raises:
        ProtocolError: not a well-formed ``MD``/``MS``/``GD``/``GS`` command (the status the sensor
            would answer is in the message: parameters that are not digits).
    """
    head, _, tag = text.partition(";")
    kind, enc = head[:1], head[1:2]
    if kind not in ("M", "G") or enc not in ("D", "S") or len(head) != (15 if kind == "M" else 12):
        raise ProtocolError(f"{text!r} is not an MD/MS/GD/GS command")
    spans = {"start": (2, 6), "end": (6, 10), "cluster": (10, 12)}
    if kind == "M":
        spans |= {"interval": (12, 13), "scans": (13, 15)}
    fields: dict[str, int] = {}
    for k, (a, b) in spans.items():
        if not head[a:b].isdigit():
            raise ProtocolError(f"{text!r}: field {k} = {head[a:b]!r} is not numeric")
        fields[k] = int(head[a:b])
    return MeasureCommand(
        stream=kind == "M",
        n_chars=3 if enc == "D" else 2,
        start=fields["start"],
        end=fields["end"],
        cluster=fields["cluster"],
        interval=fields.get("interval", 0),
        scans=fields.get("scans", 0),
        tag=tag,
    )


def parse_timestamp(line: bytes) -> int:
    """Millisecond time stamp (24 bits, wraps) of a scan's first data line, checksum verified.

    Raises:
        ChecksumError / ProtocolError: damaged or not four characters.
    """
    payload = verify_line(line)
    if len(payload) != TIMESTAMP_CHARS:
        raise ProtocolError(f"time stamp line {line!r}: expected {TIMESTAMP_CHARS} characters + checksum")
    return decode(payload)


def parse_scan_data(
    lines: tuple[bytes, ...] | list[bytes], n_chars: int, n_values: int
) -> npt.NDArray[np.int64]:
    """Raw values (mm or error codes) of a scan's data lines (after the time stamp).

    Every line's checksum is verified before anything is decoded.

    Raises:
        ChecksumError: a line fails its checksum.
        ProtocolError: a line is longer than 64 characters, or the count is not ``n_values``.
    """
    parts = []
    for line in lines:
        payload = verify_line(line)
        if len(payload) > DATA_LINE_CHARS:
            raise ProtocolError(f"scan data line of {len(payload)} characters: at most {DATA_LINE_CHARS}")
        parts.append(payload)
    values = decode_array(b"".join(parts), n_chars)
    if values.size != n_values:
        raise ProtocolError(f"scan holds {values.size} values, expected {n_values}")
    return values


def ranges_from_mm(values: Any, params: SensorParams) -> npt.NDArray[np.float32]:
    """Ranges in m under REP-117 from raw values (mm, or error codes below DMIN).

    A value in [DMIN, DMAX] is a range; above DMAX (possible in 3-character mode) is ``+inf``;
    a code in :data:`NO_RETURN_CODES` is ``+inf`` (nothing measurable); any other value below DMIN
    is ``NaN`` (the sensor flagged the beam as invalid).
    """
    v = np.asarray(values, dtype=np.int64)
    out = v.astype(np.float32) / np.float32(1000.0)
    low = v < params.dmin_mm
    no_return = np.isin(v, np.fromiter(NO_RETURN_CODES, dtype=np.int64)) & low
    out[low] = np.nan
    out[no_return | (v > params.dmax_mm)] = np.inf
    return out


@dataclass(frozen=True)
class RawScan:
    """One decoded scan as the sensor sent it (before unit conversion)."""

    command: MeasureCommand
    timestamp_ms: int
    values: npt.NDArray[np.int64]


def parse_scan_reply(reply: Reply, expected: MeasureCommand) -> RawScan:
    """A :class:`RawScan` from a ``GD``/``GS`` reply (status 00) or an ``MD``/``MS`` data reply (99).

    The echo must be ``expected`` (an ``MD`` data echo may differ only in its remaining-scan count).

    Raises:
        ChecksumError / ProtocolError: wrong echo, damaged lines, wrong value count.
    """
    try:
        echoed = parse_measure_command(reply.echo)
    except ProtocolError:
        raise ProtocolError(f"reply echo {reply.echo!r} does not answer {expected.text()!r}") from None
    if echoed.with_remaining(expected.scans) != expected:
        raise ProtocolError(f"reply echo {reply.echo!r} does not answer {expected.text()!r}")
    if not reply.lines:
        raise ProtocolError(f"scan reply to {expected.text()!r} has no time stamp line")
    ts = parse_timestamp(reply.lines[0])
    values = parse_scan_data(reply.lines[1:], expected.n_chars, expected.n_values)
    return RawScan(echoed, ts, values)


def scan_reply_lines(command: MeasureCommand, status: str, timestamp_ms: int, values: Any) -> list[bytes]:
    """The lines (no LFs) of a scan reply: echo, status, time stamp, data lines (used by the emulator)."""
    data = encode_array(values, command.n_chars)
    return [
        command.text().encode("ascii"),
        with_checksum(status.encode("ascii")),
        with_checksum(encode(timestamp_ms % TIMESTAMP_MODULO_MS, TIMESTAMP_CHARS)),
        *split_data_lines(data),
    ]


def to_laser_scan(
    raw: RawScan, params: SensorParams, stamp_ns: int, frame_id: str = "laser_link"
) -> LaserScan:
    """A :class:`hw.interfaces.LaserScan` (REP-103 angles, REP-117 ranges) from a decoded scan.

    With clustering, a value stands for ``cluster`` steps and its angle is the middle of them.
    """
    cmd = raw.command
    cluster = max(cmd.cluster, 1)
    inc = params.angle_increment * cluster
    first = params.step_angle(cmd.start + 0.5 * (cluster - 1))
    n = raw.values.size
    return LaserScan(
        stamp_ns=int(stamp_ns),
        angle_min=float(first),
        angle_max=float(first + inc * (n - 1)),
        angle_increment=float(inc),
        time_increment=float(params.time_increment * cluster),
        scan_time=float(params.scan_time),
        range_min=params.dmin_mm / 1000.0,
        range_max=params.dmax_mm / 1000.0,
        ranges=ranges_from_mm(raw.values, params),
        frame_id=frame_id,
    )
