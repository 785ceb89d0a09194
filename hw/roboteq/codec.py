"""Line codec of the Roboteq serial protocol (MDC2230 and the rest of the family): pure functions.

The controller speaks ASCII lines ended by a carriage return (CR, ``\\r``). Four command kinds:

* ``!NAME args`` runtime commands (``!S 1 500`` closed-loop speed, ``!G``, ``!EX``, ``!MG``),
  acknowledged with ``+`` (accepted) or ``-`` (rejected). Only these refresh the serial watchdog.
* ``?NAME [channel]`` runtime queries, answered ``NAME=v1:v2`` (all channels) or ``NAME=v``.
* ``^NAME args`` configuration writes, acknowledged ``+`` / ``-``.
* ``~NAME [channel]`` configuration reads, answered like queries.

With echo on (the factory default) the controller first sends the command text back, ending in CR.

Flag words (bit ``fN`` is ``1 << (N-1)``), from the Roboteq controllers user manual:

* ``?FF`` fault flags: f1 overheat, f2 overvoltage, f3 undervoltage, f4 short circuit,
  f5 emergency stop, f6 sepex excitation fault, f7 MOSFET failure, f8 startup configuration fault.
* ``?FS`` status flags: f1 serial mode, f2 pulse mode, f3 analog mode, f4 power stage off,
  f5 stall detected, f6 at limit, f7 unused, f8 MicroBasic script running, f9 tuning mode.
* ``?FM`` runtime status flags per motor: f1 amps limit active, f2 motor stall, f3 loop error
  detected, f4 safety stop active, f5 forward limit triggered, f6 reverse limit triggered,
  f7 amps trigger activated.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, fields
from typing import Any

from hw.errors import ProtocolError
from hw.interfaces import MotorFaults

CR = b"\r"
KINDS = ("!", "?", "^", "~")

# Names the codec knows; the emulator answers exactly these (anything else is answered "-").
RUNTIME_COMMANDS = ("G", "S", "EX", "MG")
QUERIES = ("FID", "C", "S", "V", "A", "FF", "FS", "FM")
CONFIG = ("MMOD", "EPPR", "MXRPM", "KP", "KI", "KD", "RWD", "ECHOF")

_NAME_RE = re.compile(r"^[A-Z][A-Z0-9]*$")
_VALUE_LINE_RE = re.compile(r"^([A-Z][A-Z0-9]*)=(.*)$")
_INT_RE = re.compile(r"^[+-]?\d+$")
_FID_RE = re.compile(r"v(\d+)\.(\d+)")

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1


@dataclass(frozen=True)
class Command:
    """One command line: kind (``! ? ^ ~``), upper-case name, integer arguments."""

    kind: str
    name: str
    args: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ProtocolError(f"command kind {self.kind!r} is not one of {KINDS}")
        if not _NAME_RE.match(self.name):
            raise ProtocolError(f"command name {self.name!r} must be upper-case letters/digits")
        for a in self.args:
            if isinstance(a, bool) or not isinstance(a, int):
                raise ProtocolError(f"command {self.kind}{self.name}: argument {a!r} is not an integer")

    @property
    def text(self) -> str:
        """The command as typed, without the CR (``!S 1 500``)."""
        return " ".join([f"{self.kind}{self.name}", *(str(a) for a in self.args)])

    def encode(self) -> bytes:
        """Bytes to write to the port, CR-terminated."""
        return self.text.encode("ascii") + CR

    @property
    def expects_value(self) -> bool:
        """True for queries and config reads (answer ``NAME=...``), False for ``+``/``-`` commands."""
        return self.kind in ("?", "~")

    @property
    def refreshes_watchdog(self) -> bool:
        """Only runtime (``!``) commands reset the controller's serial watchdog."""
        return self.kind == "!"


@dataclass(frozen=True)
class Ack:
    """``+``: the command was accepted."""


@dataclass(frozen=True)
class Nack:
    """``-``: the command was rejected (bad name, argument or state)."""


@dataclass(frozen=True)
class Value:
    """``NAME=v1:v2...``: an answer to a query or config read. ``raw`` keeps the text after ``=``."""

    name: str
    raw: str

    def ints(self) -> tuple[int, ...]:
        """The colon-separated fields as integers; ProtocolError if any is not an integer."""
        parts = self.raw.split(":")
        if not all(_INT_RE.match(p) for p in parts):
            raise ProtocolError(f"answer '{self.name}={self.raw}' is not a list of integers")
        return tuple(int(p) for p in parts)


Reply = Ack | Nack | Value


# --- command builders -------------------------------------------------------------------------


def _channel(ch: int) -> int:
    if ch not in (1, 2):
        raise ProtocolError(f"channel {ch!r} must be 1 or 2")
    return ch


def set_speed(channel: int, rpm: int) -> Command:
    """``!S cc rpm``: closed-loop speed set point in RPM."""
    return Command("!", "S", (_channel(channel), int(rpm)))


def go(channel: int, value: int) -> Command:
    """``!G cc v``: motor command -1000..1000 (relative to ``^MXRPM`` in closed-loop speed mode)."""
    if not -1000 <= value <= 1000:
        raise ProtocolError(f"!G value {value} outside -1000..1000")
    return Command("!", "G", (_channel(channel), int(value)))


def emergency_stop() -> Command:
    return Command("!", "EX")


def release_stop() -> Command:
    return Command("!", "MG")


def query(name: str, channel: int | None = None) -> Command:
    """``?NAME [cc]``."""
    return Command("?", name, () if channel is None else (_channel(channel),))


def set_config(name: str, *args: int) -> Command:
    """``^NAME args`` (``^KP 1 20``, ``^RWD 1000``)."""
    return Command("^", name, tuple(int(a) for a in args))


def get_config(name: str, channel: int | None = None) -> Command:
    """``~NAME [cc]``."""
    return Command("~", name, () if channel is None else (_channel(channel),))


def parse_command(line: str) -> Command:
    """Parse a command line as the controller would (used by the emulator). Case-insensitive."""
    text = line.strip()
    if not text or text[0] not in KINDS:
        raise ProtocolError(f"command line {line!r} does not start with one of {KINDS}")
    parts = text[1:].split()
    if not parts:
        raise ProtocolError(f"command line {line!r} has no name")
    name = parts[0].upper()
    args: list[int] = []
    for p in parts[1:]:
        if not _INT_RE.match(p):
            raise ProtocolError(f"command line {line!r}: argument {p!r} is not an integer")
        args.append(int(p))
    return Command(text[0], name, tuple(args))


# --- replies ----------------------------------------------------------------------------------


def format_value(name: str, *values: int | str) -> str:
    """``NAME=v1:v2`` (no CR)."""
    return f"{name}=" + ":".join(str(v) for v in values)


def parse_reply_line(line: str) -> Reply:
    """Parse one received line (CR removed) into Ack, Nack or Value; ProtocolError otherwise.

    Echo lines are not replies: callers compare a line with the command text before calling this.
    """
    text = line.strip()
    if text == "+":
        return Ack()
    if text == "-":
        return Nack()
    m = _VALUE_LINE_RE.match(text)
    if m is None:
        raise ProtocolError(f"reply line {line!r} is neither '+', '-' nor NAME=value")
    return Value(m.group(1), m.group(2))


def split_lines(buffer: bytes) -> tuple[list[str], bytes]:
    """Split a byte buffer on CR (LF tolerated and dropped); return complete lines and the rest.

    Non-ASCII bytes (line noise) are kept as U+FFFD so the line fails to parse instead of vanishing.
    """
    *complete, rest = buffer.replace(b"\n", b"").split(CR)
    return [c.decode("ascii", errors="replace") for c in complete], rest


def is_echo(line: str, command: Command) -> bool:
    """True if ``line`` is the controller echoing ``command`` back (spacing and case ignored)."""
    return " ".join(line.split()).upper() == command.text.upper()


# --- flag words -------------------------------------------------------------------------------


def _decode_bits(cls: type, word: int, what: str) -> object:
    names = [f.name for f in fields(cls)]
    if word < 0 or word >= 1 << len(names):
        raise ProtocolError(f"{what} word {word} outside 0..{(1 << len(names)) - 1}")
    return cls(**{n: bool(word >> i & 1) for i, n in enumerate(names)})


def _encode_bits(flags: Any) -> int:
    word = 0
    for i, f in enumerate(fields(flags)):
        if getattr(flags, f.name):
            word |= 1 << i
    return word


def decode_fault_flags(word: int) -> MotorFaults:
    """``?FF`` word -> MotorFaults (field order in MotorFaults is the bit order f1..f8)."""
    return _decode_bits(MotorFaults, word, "fault flag (?FF)")  # type: ignore[return-value]


def encode_fault_flags(faults: MotorFaults) -> int:
    return _encode_bits(faults)


@dataclass(frozen=True)
class StatusFlags:
    """``?FS`` status flags, bit order f1..f9."""

    serial_mode: bool = False
    pulse_mode: bool = False
    analog_mode: bool = False
    power_stage_off: bool = False
    stall_detected: bool = False
    at_limit: bool = False
    unused: bool = False
    script_running: bool = False
    tuning_mode: bool = False

    def names(self) -> list[str]:
        return [f.name for f in fields(self) if getattr(self, f.name)]


@dataclass(frozen=True)
class MotorFlags:
    """``?FM`` runtime status flags of one motor, bit order f1..f7."""

    amps_limit: bool = False
    motor_stall: bool = False
    loop_error: bool = False
    safety_stop: bool = False
    forward_limit: bool = False
    reverse_limit: bool = False
    amps_trigger: bool = False

    @property
    def any_fault(self) -> bool:
        """Flags that mean the motor is not doing what it was told (limits are informational)."""
        return self.motor_stall or self.loop_error or self.safety_stop

    def names(self) -> list[str]:
        return [f.name for f in fields(self) if getattr(self, f.name)]


def decode_status_flags(word: int) -> StatusFlags:
    return _decode_bits(StatusFlags, word, "status flag (?FS)")  # type: ignore[return-value]


def encode_status_flags(flags: StatusFlags) -> int:
    return _encode_bits(flags)


def decode_motor_flags(word: int) -> MotorFlags:
    return _decode_bits(MotorFlags, word, "motor flag (?FM)")  # type: ignore[return-value]


def encode_motor_flags(flags: MotorFlags) -> int:
    return _encode_bits(flags)


# --- firmware id ------------------------------------------------------------------------------


@dataclass(frozen=True)
class FirmwareId:
    """``?FID`` answer, e.g. ``Roboteq v1.3 MDC2230 07/24/2013``."""

    text: str
    major: int
    minor: int


def parse_firmware_id(text: str) -> FirmwareId:
    """Find the ``vMAJOR.MINOR`` version in a firmware id; ProtocolError if there is none."""
    m = _FID_RE.search(text)
    if m is None:
        raise ProtocolError(f"firmware id {text!r} carries no 'vMAJOR.MINOR' version")
    return FirmwareId(text.strip(), int(m.group(1)), int(m.group(2)))


def wrap_int32(value: int) -> int:
    """Wrap an integer to signed 32 bits, as the controller's encoder counter does."""
    return (value - INT32_MIN) % (1 << 32) + INT32_MIN
