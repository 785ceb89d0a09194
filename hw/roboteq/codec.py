"""Line codec of the Roboteq serial protocol (MDC2230 and the rest of the family): pure functions.

The controller speaks ASCII lines ended by a carriage return (CR, ``\\r``). Four command kinds:

* ``!NAME args`` runtime commands (``!S 1 500`` closed-loop speed, ``!G``, ``!EX``, ``!MG``),
  acknowledged with ``+`` (accepted) or ``-`` (rejected). Only these refresh the serial watchdog.
* ``?NAME [channel]`` runtime queries, answered ``NAME=v1:v2`` (all channels) or ``NAME=v``.
* ``^NAME args`` configuration writes, acknowledged ``+`` / ``-``.
* ``~NAME [channel]`` configuration reads, answered like queries.

With echo on (the factory default) the controller first sends the command text back, ending in CR.

Flag words are unsigned 16-bit on firmware 2.x (8-bit on 1.x); bit ``fN`` is ``1 << (N-1)``. Names
from the Roboteq Advanced Digital Motor Controller user manual (V1.8, 2017; V2.0, 2019):

* ``?FF`` fault flags: f1 overheat, f2 overvoltage, f3 undervoltage, f4 short circuit,
  f5 emergency stop, f6 sepex excitation / brushless sensor fault, f7 MOSFET failure,
  f8 default configuration loaded at startup.
* ``?FS`` status flags: f1 serial mode, f2 pulse mode, f3 analog mode, f4 power stage off,
  f5 stall detected, f6 at limit, f7 unused, f8 MicroBasic script running, f9 tuning mode.
* ``?FM`` runtime status flags per motor: f1 amps limit active, f2 motor stalled, f3 loop error
  detected, f4 safety stop active, f5 forward limit triggered, f6 reverse limit triggered,
  f7 amps trigger activated.

A bit the manual does not name (``?FF=256``, ``?FM=128``) is kept in ``unknown_bits`` of the decoded
flags; the driver treats it as a fault, because a newer firmware uses it for something it cannot
judge. A word outside 0..65535 is a :class:`hw.errors.ProtocolError`.

Other facts used here (same manuals): ``_`` is read by the controller as a carriage return;
``# C`` stops the telemetry a ``# nn`` or ``/"..."`` request started (no reply); ``^ECHOF 1``
turns the echo off; ``^MAC``/``^MDEC`` are in 0.1 RPM/s (0..500000), ``^ALIM`` in 0.1 A, ``^CLERD``
0 (off), 1 (250 ms and error > 100), 2 (500 ms, > 250), 3 (1000 ms, > 500); gains ``^KP/^KI/^KD``
are 0..255 (gain x10) on 1.x and 0..2,000,000,000 (gain x1,000,000) on 2.x.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from hw.errors import ProtocolError
from hw.interfaces import MotorFaults

CR = b"\r"
KINDS = ("!", "?", "^", "~")

# Names the codec knows; the emulator answers exactly these (anything else is answered "-").
RUNTIME_COMMANDS = ("G", "S", "EX", "MG")
QUERIES = ("FID", "C", "S", "V", "A", "T", "FF", "FS", "FM")
CONFIG = ("MMOD", "EPPR", "MXRPM", "KP", "KI", "KD", "RWD", "ECHOF", "MAC", "MDEC", "ALIM", "CLERD")
# Global (not per-channel) configuration items.
GLOBAL_CONFIG = ("RWD", "ECHOF")

# Ranges of the configuration items, from the manuals (V1.8/V2.0 command reference).
CONFIG_RANGE: dict[str, tuple[int, int]] = {
    "MMOD": (0, 5),
    "EPPR": (1, 5000),
    "MXRPM": (10, 65000),
    "RWD": (0, 65000),
    "ECHOF": (0, 1),
    "MAC": (0, 500000),
    "MDEC": (0, 500000),
    "ALIM": (10, 3000),
    "CLERD": (0, 3),
}
FLAG_WORD_MAX = 0xFFFF
LINE_ENDS = (b"\r", b"_")

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


def split_command_lines(buffer: bytes) -> tuple[list[str], bytes]:
    """Split what a host sent into command lines as the controller does: CR or ``_`` ends a line."""
    return split_lines(buffer.replace(b"_", CR))


def is_echo(line: str, command: Command) -> bool:
    """True if ``line`` is the controller echoing ``command`` back (spacing and case ignored)."""
    return " ".join(line.split()).upper() == command.text.upper()


# --- flag words -------------------------------------------------------------------------------

FAULT_BITS = (
    "overheat",
    "overvoltage",
    "undervoltage",
    "short_circuit",
    "emergency_stop",
    "sepex_excitation",
    "mosfet_failure",
    "startup_config",
)
STATUS_BITS = (
    "serial_mode",
    "pulse_mode",
    "analog_mode",
    "power_stage_off",
    "stall_detected",
    "at_limit",
    "unused",
    "script_running",
    "tuning_mode",
)
MOTOR_BITS = (
    "amps_limit",
    "motor_stall",
    "loop_error",
    "safety_stop",
    "forward_limit",
    "reverse_limit",
    "amps_trigger",
)


def _decode_bits(cls: type, names: tuple[str, ...], word: int, what: str) -> Any:
    if isinstance(word, bool) or not isinstance(word, int) or not 0 <= word <= FLAG_WORD_MAX:
        raise ProtocolError(f"{what} word {word!r} outside 0..{FLAG_WORD_MAX}")
    known = {n: bool(word >> i & 1) for i, n in enumerate(names)}
    return cls(**known, unknown_bits=word & ~((1 << len(names)) - 1))


def _encode_bits(flags: Any, names: tuple[str, ...]) -> int:
    word = int(flags.unknown_bits)
    for i, n in enumerate(names):
        if getattr(flags, n):
            word |= 1 << i
    return word


def unknown_bit_names(unknown_bits: int) -> list[str]:
    """``['f9', 'f12']`` for the bits of ``unknown_bits`` (the manual's 1-based numbering)."""
    return [f"f{i + 1}" for i in range(16) if unknown_bits >> i & 1]


def decode_fault_flags(word: int) -> MotorFaults:
    """``?FF`` word -> MotorFaults (bit order f1..f8 as in :data:`FAULT_BITS`; higher bits unknown)."""
    return _decode_bits(MotorFaults, FAULT_BITS, word, "fault flag (?FF)")  # type: ignore[no-any-return]


def encode_fault_flags(faults: MotorFaults) -> int:
    return _encode_bits(faults, FAULT_BITS)


@dataclass(frozen=True)
class StatusFlags:
    """``?FS`` status flags, bit order f1..f9; ``unknown_bits`` holds set bits the manual does not name."""

    serial_mode: bool = False
    pulse_mode: bool = False
    analog_mode: bool = False
    power_stage_off: bool = False
    stall_detected: bool = False
    at_limit: bool = False
    unused: bool = False
    script_running: bool = False
    tuning_mode: bool = False
    unknown_bits: int = 0

    def names(self) -> list[str]:
        return [n for n in STATUS_BITS if getattr(self, n)] + unknown_bit_names(self.unknown_bits)


@dataclass(frozen=True)
class MotorFlags:
    """``?FM`` runtime status flags of one motor, bit order f1..f7; ``unknown_bits`` as in StatusFlags."""

    amps_limit: bool = False
    motor_stall: bool = False
    loop_error: bool = False
    safety_stop: bool = False
    forward_limit: bool = False
    reverse_limit: bool = False
    amps_trigger: bool = False
    unknown_bits: int = 0

    @property
    def any_fault(self) -> bool:
        """Flags meaning the motor is not doing what it was told, or a bit the manual does not name
        (limits and the amps limit are informational)."""
        return self.motor_stall or self.loop_error or self.safety_stop or bool(self.unknown_bits)

    def names(self) -> list[str]:
        return [n for n in MOTOR_BITS if getattr(self, n)] + unknown_bit_names(self.unknown_bits)


def decode_status_flags(word: int) -> StatusFlags:
    return _decode_bits(StatusFlags, STATUS_BITS, word, "status flag (?FS)")  # type: ignore[no-any-return]


def encode_status_flags(flags: StatusFlags) -> int:
    return _encode_bits(flags, STATUS_BITS)


def decode_motor_flags(word: int) -> MotorFlags:
    return _decode_bits(MotorFlags, MOTOR_BITS, word, "motor flag (?FM)")  # type: ignore[no-any-return]


def encode_motor_flags(flags: MotorFlags) -> int:
    return _encode_bits(flags, MOTOR_BITS)


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
