"""SCIP 2.0, the Hokuyo URG protocol: framing, checksums, character encodings, replies, sensor parameters.

Measurement commands and scan data build on this in :mod:`hw.hokuyo.measurement`.

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

LF = b"\n"

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
