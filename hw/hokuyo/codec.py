"""SCIP 2.0, the Hokuyo URG protocol: framing, checksums, character encodings, replies, scan data.

Facts used here, all from Hokuyo's "Communication Protocol Specification For SCIP2.0 Standard" and the
URG-04LX specification:

* A command is ASCII ending in LF (``VV``, ``PP``, ``II``, ``BM``, ``QT``, ``RS``, ``MDSSSSEEEECCSNN``,
  ``GDSSSSEEEECC``, optionally ``;tag`` of at most 16 characters, echoed back).
* A reply is a *block*: the echo of the command, a status line, any data lines, and an empty line
  (two LFs in a row end the block).
* Every line after the echo ends in one checksum character: the sum of the line's other bytes, lower
  6 bits, plus 0x30 (``00`` -> ``00P``, ``99`` -> ``99b``). In the ``NAME:value;`` lines of VV/PP/II the
  sum runs over ``NAME:value`` without the ``;`` (``DMIN:20;4``, ``AMIN:44;7``, ``SCAN:600;e``).
* Numbers in scan data are 6-bit characters (value + 0x30), most significant first: 2 characters for
  ranges up to 4095 mm (``MS``/``GS``), 3 characters up to 262143 mm (``MD``/``GD``), 4 for the
  24-bit millisecond time stamp (``1234`` -> ``CB``, ``5432`` -> ``1Dh``).
* Scan data lines hold at most 64 data characters plus the checksum; one value may be split across
  two lines, so the lines are joined (checksums removed) before decoding.
* Status ``00`` is success, ``99`` precedes each scan of an ``MD``/``MS`` stream; ``0A``..``0I`` are
  common errors; ``01``..``07`` name a bad measurement parameter; ``10`` (GD/GS) the laser is off;
  ``50``..``97`` hardware trouble (laser or motor malfunction). The status of ``SCIP2.0`` on a sensor
  still in SCIP 1.1 mode is the single character ``0`` (no checksum); on one already in SCIP 2.0 it is
  ``0E`` (command not defined), which is fine too.
* URG-04LX: steps 0..768 in a 1024-step revolution (ARES), measurable 44 (AMIN) .. 725 (AMAX), step
  384 (AFRT) points forward, 20 mm (DMIN) .. 5600 mm (DMAX, 4 m guaranteed), 600 rpm (SCAN).
  Ranges below DMIN are error codes, not distances.
* The URG turns counter-clockwise seen from above, so step ``s`` is at ``(s - AFRT) * 2 pi / ARES`` rad
  in REP-103 (0 forward, counter-clockwise positive).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hw.errors import DeviceFaultError, ProtocolError
from hw.interfaces import LaserScan

LF = b"\n"
#: Most data characters on one line of a scan reply (the checksum follows them).
DATA_LINE_CHARS = 64
#: Longest tag a measurement command may carry (echoed with it).
MAX_TAG_CHARS = 16
TIMESTAMP_CHARS = 4
TIMESTAMP_MODULO_MS = 1 << 24

STATUS_OK = "00"
STATUS_SCAN = "99"

COMMON_STATUS: dict[str, str] = {
    "0A": "unable to create transmission data or reply command internally",
    "0B": "buffer shortage or command repeated that is already processed",
    "0C": "command with insufficient parameters",
    "0D": "undefined control code",
    "0E": "command not defined",
    "0F": "command not defined for this model (denied)",
    "0G": "command tag exceeds 16 characters",
    "0H": "command tag contains a character that is not allowed",
    "0I": "sensor is in firmware update mode",
}

MEASURE_STATUS: dict[str, str] = {
    "01": "starting step has a non-numeric value",
    "02": "end step has a non-numeric value",
    "03": "cluster count has a non-numeric value",
    "04": "end step is out of range",
    "05": "end step is smaller than the starting step",
    "06": "scan interval has a non-numeric value",
    "07": "number of scans has a non-numeric value",
    "10": "laser is off (send BM first)",
    "98": "resumed after confirming normal laser operation",
}

BM_STATUS: dict[str, str] = {
    "01": "unable to switch the laser on (laser malfunction)",
    "02": "laser is already on",
}

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


class ChecksumError(ProtocolError):
    """A reply line failed its SCIP checksum (line noise): the transaction is retried."""


class StatusError(ProtocolError):
    """The sensor refused a command with an error status; the message names the status."""

    def __init__(self, command: str, status: str, meaning: str) -> None:
        super().__init__(f"Hokuyo answered {command!r} with status {status!r}: {meaning}")
        self.command = command
        self.status = status


class HardwareTroubleError(DeviceFaultError):
    """Status 50..97: the sensor reports a hardware malfunction (laser, motor)."""


# --------------------------------------------------------------------------------------------
# checksum and character encodings
# --------------------------------------------------------------------------------------------


def checksum(data: bytes) -> int:
    """SCIP checksum byte of ``data``: ``(sum of bytes & 0x3F) + 0x30``."""
    return (sum(data) & 0x3F) + 0x30


def with_checksum(payload: bytes) -> bytes:
    """``payload`` followed by its checksum character (no LF)."""
    return payload + bytes([checksum(payload)])


def verify_line(line: bytes, *, exclude_semicolon: bool = False) -> bytes:
    """The payload of a line whose last byte is its checksum (LF already removed).

    Args:
        line: ``payload + checksum``.
        exclude_semicolon: VV/PP/II lines: the payload ends in ``;``, which the specification's sum
            leaves out; a sum that includes it is accepted too, as some firmware sends it.

    Raises:
        ChecksumError: the line is empty or the checksum does not match.
    """
    if len(line) < 2:
        raise ChecksumError(f"line {line!r} is too short to carry a checksum")
    payload, got = line[:-1], line[-1]
    summed = payload[:-1] if exclude_semicolon and payload.endswith(b";") else payload
    if exclude_semicolon and checksum(payload) == got:
        return payload  # some firmware sums the ';' as well (Hokuyo's urg_library accepts both)
    if checksum(summed) != got:
        raise ChecksumError(
            f"checksum mismatch on line {line!r}: expected {chr(checksum(summed))!r}, got {chr(got)!r}"
        )
    return payload


def encode(value: int, n_chars: int) -> bytes:
    """``value`` as ``n_chars`` 6-bit characters (value + 0x30), most significant first.

    Raises:
        ProtocolError: the value is negative or needs more than ``6 * n_chars`` bits.
    """
    if not 0 <= value < (1 << (6 * n_chars)):
        raise ProtocolError(f"value {value} does not fit {n_chars}-character SCIP encoding")
    return bytes(((value >> (6 * (n_chars - 1 - k))) & 0x3F) + 0x30 for k in range(n_chars))


def decode(chars: bytes) -> int:
    """Integer of a run of 6-bit characters (``b"CB"`` -> 1234, ``b"1Dh"`` -> 5432).

    Raises:
        ProtocolError: a character lies outside 0x30..0x6F.
    """
    value = 0
    for c in chars:
        if not 0x30 <= c <= 0x6F:
            raise ProtocolError(f"byte 0x{c:02X} in {chars!r} is not a SCIP data character")
        value = (value << 6) | (c - 0x30)
    return value


def encode_array(values: Any, n_chars: int) -> bytes:
    """Many values, each as ``n_chars`` characters, concatenated (vectorised :func:`encode`)."""
    v = np.asarray(values, dtype=np.int64).reshape(-1)
    if v.size and (v.min() < 0 or v.max() >= (1 << (6 * n_chars))):
        raise ProtocolError(f"values outside 0..{(1 << (6 * n_chars)) - 1} for {n_chars}-character encoding")
    shifts = 6 * np.arange(n_chars - 1, -1, -1, dtype=np.int64)
    chars = ((v[:, None] >> shifts[None, :]) & 0x3F) + 0x30
    return chars.astype(np.uint8).tobytes()


def decode_array(data: bytes, n_chars: int) -> npt.NDArray[np.int64]:
    """Values of concatenated ``n_chars``-character groups (vectorised :func:`decode`).

    Raises:
        ProtocolError: the length is not a multiple of ``n_chars`` or a character is out of range.
    """
    if len(data) % n_chars:
        raise ProtocolError(f"{len(data)} data characters are not a multiple of {n_chars}")
    b = np.frombuffer(data, dtype=np.uint8).astype(np.int64)
    if b.size and (b.min() < 0x30 or b.max() > 0x6F):
        raise ProtocolError("scan data holds a byte outside the SCIP data characters 0x30..0x6F")
    groups = (b - 0x30).reshape(-1, n_chars)
    shifts = 6 * np.arange(n_chars - 1, -1, -1, dtype=np.int64)
    return (groups << shifts[None, :]).sum(axis=1)  # type: ignore[no-any-return]


def split_data_lines(data: bytes) -> list[bytes]:
    """Scan data as reply lines: at most 64 characters each, each followed by its checksum."""
    return [with_checksum(data[i : i + DATA_LINE_CHARS]) for i in range(0, len(data), DATA_LINE_CHARS)]


# --------------------------------------------------------------------------------------------
# commands
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# replies
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reply:
    """One reply block: the echo, the status (checksum verified) and the raw lines after it."""

    echo: str
    status: str
    lines: tuple[bytes, ...]


def parse_status(line: bytes) -> str:
    """The two-character status of a status line (``b"00P"`` -> ``"00"``), checksum verified.

    The single character ``0`` (SCIP 1.1 style, the answer of ``SCIP2.0`` switching modes) is also
    accepted and returned as ``"0"``.

    Raises:
        ChecksumError: the checksum does not match.
        ProtocolError: the line has another length.
    """
    if line in (b"0", b"E"):
        return line.decode()
    if len(line) != 3:
        raise ProtocolError(f"status line {line!r}: expected two status characters and a checksum")
    payload = verify_line(line)
    try:
        return payload.decode("ascii")
    except UnicodeDecodeError:  # pragma: no cover - verify_line already rejects most noise
        raise ProtocolError(f"status line {line!r} is not ASCII") from None


def parse_reply(block: list[bytes]) -> Reply:
    """A :class:`Reply` from the lines of one block (LFs removed, the final empty line excluded).

    Raises:
        ChecksumError / ProtocolError: the block is too short or its status line is damaged.
    """
    if len(block) < 2:
        raise ProtocolError(f"reply of {len(block)} line(s) {block!r}: expected an echo and a status")
    try:
        echo = block[0].decode("ascii")
    except UnicodeDecodeError:
        raise ChecksumError(f"echo line {block[0]!r} is not ASCII (line noise)") from None
    return Reply(echo, parse_status(block[1]), tuple(block[2:]))


def status_meaning(command: str, status: str) -> str:
    """Human-readable meaning of ``status`` for ``command`` (its first two letters)."""
    if status in COMMON_STATUS:
        return COMMON_STATUS[status]
    name = command[:2]
    if name == "BM" and status in BM_STATUS:
        return BM_STATUS[status]
    if name in ("MD", "MS", "GD", "GS") and status in MEASURE_STATUS:
        return MEASURE_STATUS[status]
    if status.isdigit() and 21 <= int(status) <= 49:
        return "processing stopped to verify an error"
    if status.isdigit() and 50 <= int(status) <= 97:
        return "hardware trouble (laser or motor malfunction)"
    return "unknown status"


def check_status(command: str, status: str, accept: tuple[str, ...] = (STATUS_OK,)) -> None:
    """Raise the right error unless ``status`` is one of ``accept``.

    Raises:
        HardwareTroubleError: status 50..97.
        StatusError: any other status not in ``accept``.
    """
    if status in accept:
        return
    meaning = status_meaning(command, status)
    if status.isdigit() and 50 <= int(status) <= 97:
        raise HardwareTroubleError(f"Hokuyo answered {command!r} with status {status!r}: {meaning}")
    raise StatusError(command, status, meaning)


def parse_info(lines: tuple[bytes, ...] | list[bytes]) -> dict[str, str]:
    """``NAME: value`` pairs of a VV/PP/II reply body (``NAME:value;C`` lines, checksums verified).

    Raises:
        ChecksumError: a line fails its checksum.
        ProtocolError: a line is not ``NAME:value;`` + checksum.
    """
    out: dict[str, str] = {}
    for line in lines:
        payload = verify_line(line, exclude_semicolon=True)
        text = payload.decode("ascii", errors="replace")
        if ":" not in text or not text.endswith(";"):
            raise ProtocolError(f"information line {line!r}: expected NAME:value;")
        name, value = text[:-1].split(":", 1)
        out[name] = value
    return out


def info_line(name: str, value: str) -> bytes:
    """One VV/PP/II line ``NAME:value;`` + checksum (of ``NAME:value``), without LF."""
    payload = f"{name}:{value}".encode("ascii")
    return payload + b";" + bytes([checksum(payload)])


@dataclass(frozen=True)
class SensorParams:
    """The ``PP`` answer: model, range limits and the step geometry.

    Attributes:
        model: ``MODL``.
        dmin_mm, dmax_mm: Range limits, mm.
        ares: Steps in a full revolution.
        amin, amax: First and last measurable step.
        afrt: Step pointing forward.
        scan_rpm: Motor speed, revolutions per minute.
    """

    model: str
    dmin_mm: int
    dmax_mm: int
    ares: int
    amin: int
    amax: int
    afrt: int
    scan_rpm: int

    @property
    def angle_increment(self) -> float:
        """Angle between steps, rad (2 pi / ARES)."""
        return 2.0 * math.pi / self.ares

    @property
    def scan_time(self) -> float:
        """Time of one revolution, s."""
        return 60.0 / self.scan_rpm

    @property
    def time_increment(self) -> float:
        """Time between two steps, s."""
        return self.scan_time / self.ares

    def step_angle(self, step: Any) -> Any:
        """Angle of ``step`` in REP-103, rad: ``(step - AFRT) * 2 pi / ARES``."""
        return (np.asarray(step, dtype=np.float64) - self.afrt) * self.angle_increment

    @classmethod
    def from_info(cls, info: dict[str, str]) -> SensorParams:
        """Parse and check a ``PP`` reply.

        Raises:
            ProtocolError: a field is missing, not an integer, or the geometry is inconsistent.
        """

        def num(key: str) -> int:
            raw = info.get(key)
            if raw is None:
                raise ProtocolError(f"PP reply has no {key} field (got {sorted(info)})")
            digits = re.match(r"\s*(\d+)", raw)
            if digits is None:
                raise ProtocolError(f"PP field {key}={raw!r} is not an integer")
            return int(digits[1])

        p = cls(
            model=info.get("MODL", ""),
            dmin_mm=num("DMIN"),
            dmax_mm=num("DMAX"),
            ares=num("ARES"),
            amin=num("AMIN"),
            amax=num("AMAX"),
            afrt=num("AFRT"),
            scan_rpm=num("SCAN"),
        )
        if not (0 < p.dmin_mm < p.dmax_mm and p.ares > 0 and p.scan_rpm > 0):
            raise ProtocolError(f"PP reply is inconsistent: {p}")
        if not p.amin <= p.afrt <= p.amax < p.ares:
            raise ProtocolError(f"PP reply steps AMIN {p.amin} <= AFRT {p.afrt} <= AMAX {p.amax} < ARES fail")
        return p


#: The URG-04LX's ``PP`` values (SCIP 2.0 mode).
URG_04LX = SensorParams(
    model="URG-04LX(Hokuyo Automatic Co.,Ltd.)",
    dmin_mm=20,
    dmax_mm=5600,
    ares=1024,
    amin=44,
    amax=725,
    afrt=384,
    scan_rpm=600,
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
