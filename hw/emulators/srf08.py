"""SRF08 sonars on an emulated I2C bus: an object with the smbus2 methods the SRF08 driver uses.

:class:`SRF08Bus` stands in for ``smbus2.SMBus``: ``write_byte_data``, ``read_byte_data``,
``read_i2c_block_data`` and ``close`` with smbus2's signatures. It holds any number of SRF08s by
7-bit address and implements the device's register map (Devantech SRF08 technical specification):

======== =============================== ==================================
register read                            write
======== =============================== ==================================
0        software revision               command (0x50/0x51/0x52 ranging in
                                          inches / cm / microseconds;
                                          0xA0, 0xAA, 0xA5, new address)
1        light sensor                    maximum analogue gain (0..31)
2, 3     1st echo, high byte first       2: range register
4..35    echoes 2..17                    (not writable)
======== =============================== ==================================

Ranging: a ranging command makes the device busy for ``65 ms * (range_register + 1) / 256`` (65 ms
at the default 255 = 11 m; the listen time scales with the range setting, which is why lowering the
range register gives faster results). While busy it does not take part in I2C transfers; how that
looks to the host depends on the adapter, so :class:`BusyMode` offers both: ``FF`` (reads return 0xFF
because SDA floats high, writes are lost) and ``NACK`` (every transfer raises
``OSError(121, EREMOTEIO)`` as the Linux i2c-dev driver reports a missing acknowledge).
Writing a command to address 0 (general call) starts every device ranging.

The echoes come from a callable ``ranges(address, stamp_ns) -> metres`` (one float, or a sequence
for several echoes; NaN/inf = nothing), e.g. the simulator's sonar cones or a script. It is sampled
when the ranging starts. Echoes beyond the range setting (``(reg * 43 + 43) mm``) are not heard;
missing echoes read 0, as on the device.

Echoes of earlier pings (datasheet: "the second ranging may pick up a distant echo returning from the
previous ping"; fire every 65 ms or slower at the power-up gain). Every ping stays audible for
:data:`ECHO_WINDOW_S` (65 ms) to the devices of its acoustic group (``groups``; by default all devices
share one space, as the two arrays of a chair do). A ranging started inside that window also hears the
earlier ping's echoes: an echo of range r from a ping ``dt`` earlier arrives ``2 r / c - dt`` after the
new ping, so it reads as ``r - c dt / 2`` when that is above the device's blind zone and shorter than its
own first echo. Pings within the same instant (one slot of both arrays) read each other's echoes of the
same object at the object's range, which is what a bistatic echo gives. The emulator models this at
every gain: the datasheet gives no interval that is safe at a lower gain.

Fault injection: :meth:`SRF08Bus.inject_io_error` (one device answers every transfer with
``OSError(5, EIO)``, for N transfers or until cleared), :meth:`SRF08Bus.stick` (the device keeps
reporting one value whatever is in front of it). Not emulated: ANN mode (0x53-0x55) and the gain's
effect on echo detection (the gain register is stored and read back only by tests).
"""

from __future__ import annotations

import bisect
import enum
import errno
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from hw.errors import HardwareError, ProtocolError
from hw.interfaces import Clock

#: Speed of sound used to convert ranges to microsecond results, m/s.
SPEED_OF_SOUND_M_S = 343.0
#: Ranging time at the default range register (255), seconds.
FULL_RANGING_TIME_S = 0.065
#: How long the echoes of one ping stay audible, seconds (the datasheet's 65 ms firing interval).
ECHO_WINDOW_S = 0.065
#: Echoes closer than this are lost in the transducer's ring-down (SPEC table 5.1: 3 cm minimum).
BLIND_ZONE_M = 0.03
#: 7-bit addresses an SRF08 can take (8-bit 0xE0..0xFE).
SRF08_ADDRESSES = range(0x70, 0x80)

RangesFn = Callable[[int, int], "float | Sequence[float]"]


class BusyMode(enum.Enum):
    """How a ranging SRF08 looks to the host (see module docstring)."""

    FF = "ff"
    NACK = "nack"


def ranging_time_s(range_register: int) -> float:
    """Listen time of one ranging for a range-register value (65 ms at 255)."""
    return FULL_RANGING_TIME_S * (int(range_register) + 1) / 256.0


def max_range_m(range_register: int) -> float:
    """Maximum range for a range-register value: ``(reg * 43 mm) + 43 mm``."""
    return (int(range_register) * 43 + 43) / 1000.0


@dataclass
class EmulatedSRF08:
    """Register state of one emulated SRF08."""

    address: int
    software_revision: int = 11
    light: int = 0x80
    gain: int = 31
    range_register: int = 255
    busy_mode: BusyMode = BusyMode.FF
    echoes: list[int] = field(default_factory=lambda: [0] * 17)
    busy_until_ns: int = -1
    pending: tuple[int, list[float]] | None = None  # (command, ranges sampled at the ping)
    address_sequence: int = 0  # how many of 0xA0, 0xAA, 0xA5 have arrived in order
    io_errors_left: int = 0  # < 0: forever
    stuck_value: int | None = None
    rangings: int = 0
    stale: list[float] = field(default_factory=list)  # echoes of earlier pings this ranging hears


class SRF08Bus:
    """An emulated I2C bus with SRF08 devices; smbus2-compatible for the methods the driver uses.

    Args:
        clock: time source for ranging durations (a :class:`hw.clock.ManualClock` in tests).
        ranges: ``ranges(address, stamp_ns)`` -> range(s) in metres; NaN or inf = no echo.
        addresses: 7-bit addresses of the devices present initially.
        busy_mode: default :class:`BusyMode` of the devices.
        groups: sets of addresses that hear each other's pings (e.g. one per array when the arrays are
            acoustically apart); None: every device hears every other.
    """

    def __init__(
        self,
        clock: Clock,
        ranges: RangesFn,
        addresses: Sequence[int] = (0x70,),
        busy_mode: BusyMode = BusyMode.FF,
        groups: Sequence[Sequence[int]] | None = None,
    ) -> None:
        self.clock = clock
        self.ranges = ranges
        self.groups = None if groups is None else [frozenset(g) for g in groups]
        self.pings: list[tuple[int, int, list[float]]] = []  # (stamp_ns, address, ranges) of recent pings
        self.stale_echoes = 0  # rangings that read an earlier ping's echo
        self.devices: dict[int, EmulatedSRF08] = {}
        self.closed = False
        self.transfers = 0
        for a in addresses:
            self.add_device(a, busy_mode=busy_mode)

    # --- set-up and fault injection -------------------------------------------------------------

    def add_device(self, address: int, busy_mode: BusyMode = BusyMode.FF) -> EmulatedSRF08:
        if address not in SRF08_ADDRESSES:
            raise HardwareError(f"address=0x{address:02X} is not an SRF08 address (0x70..0x7F)")
        if address in self.devices:
            raise HardwareError(f"address=0x{address:02X} is already taken on the emulated bus")
        dev = EmulatedSRF08(address=address, busy_mode=busy_mode)
        self.devices[address] = dev
        return dev

    def inject_io_error(self, address: int, count: int = -1) -> None:
        """Make the device at ``address`` fail its next ``count`` transfers with EIO (-1: until cleared)."""
        self._dev(address).io_errors_left = count

    def clear_faults(self, address: int) -> None:
        dev = self._dev(address)
        dev.io_errors_left = 0
        dev.stuck_value = None

    def stick(self, address: int, value: int | None) -> None:
        """Make every ranging of ``address`` report ``value`` (in the command's units); None unsticks."""
        self._dev(address).stuck_value = value

    def _dev(self, address: int) -> EmulatedSRF08:
        try:
            return self.devices[address]
        except KeyError:
            raise HardwareError(f"no emulated SRF08 at 0x{address:02X}") from None

    # --- bus behaviour -----------------------------------------------------------------------------

    def _access(self, address: int) -> EmulatedSRF08 | None:
        """The device a transfer reaches, or None when it is ranging in FF mode (SDA floats high)."""
        if self.closed:
            raise OSError(errno.EBADF, "emulated I2C bus is closed")
        self.transfers += 1
        dev = self.devices.get(address)
        if dev is None:
            raise OSError(errno.EREMOTEIO, f"no device acknowledges address 0x{address:02X}")
        if dev.io_errors_left != 0:
            if dev.io_errors_left > 0:
                dev.io_errors_left -= 1
            raise OSError(errno.EIO, f"I/O error talking to 0x{address:02X} (injected)")
        self._finish_if_done(dev)
        if self.clock.now_ns() < dev.busy_until_ns:
            if dev.busy_mode is BusyMode.NACK:
                raise OSError(errno.EREMOTEIO, f"0x{address:02X} does not acknowledge while ranging")
            return None
        return dev

    def _finish_if_done(self, dev: EmulatedSRF08) -> None:
        if dev.pending is None or self.clock.now_ns() < dev.busy_until_ns:
            return
        command, ranges = dev.pending
        dev.pending = None
        limit = max_range_m(dev.range_register)
        heard = sorted(r for r in ranges if math.isfinite(r) and 0.0 < r <= limit)
        ghosts = [r for r in dev.stale if r <= limit and (not heard or r < heard[0])]
        if ghosts:
            self.stale_echoes += 1
            heard = sorted([*heard, *ghosts])
        values = [self._encode(command, r) for r in heard[:17]]
        if dev.stuck_value is not None:
            values = [dev.stuck_value]
        dev.echoes = [*values, *([0] * (17 - len(values)))]

    @staticmethod
    def _encode(command: int, r_m: float) -> int:
        if command == 0x50:
            v = round(r_m / 0.0254)
        elif command == 0x51:
            v = round(r_m * 100.0)
        else:
            v = round(2.0 * r_m / SPEED_OF_SOUND_M_S * 1e6)
        return min(max(v, 0), 0xFFFF)

    def _start_ranging(self, dev: EmulatedSRF08, command: int) -> None:
        now = self.clock.now_ns()
        sample = self.ranges(dev.address, now)
        try:
            ranges = [float(v) for v in sample]  # type: ignore[union-attr]
        except TypeError:  # a single range (float, numpy scalar)
            ranges = [float(sample)]  # type: ignore[arg-type]
        dev.pending = (command, ranges)
        dev.stale = self._stale_echoes(dev.address, now)
        self.pings = [p for p in self.pings if now - p[0] < round(ECHO_WINDOW_S * 1e9)]
        self.pings.append((now, dev.address, ranges))
        dev.busy_until_ns = now + round(ranging_time_s(dev.range_register) * 1e9)
        dev.rangings += 1

    def _hears(self, a: int, b: int) -> bool:
        return self.groups is None or any(a in g and b in g for g in self.groups)

    def _stale_echoes(self, address: int, now: int) -> list[float]:
        """Ranges at which echoes of earlier pings in the window arrive after a ping at ``now``."""
        out = []
        for stamp, other, ranges in self.pings:
            dt = (now - stamp) / 1e9
            if not (0.0 <= dt < ECHO_WINDOW_S and self._hears(address, other)):
                continue
            for r in ranges:
                if math.isfinite(r) and r > 0.0 and (dt > 0.0 or other != address):
                    ghost = r - SPEED_OF_SOUND_M_S * dt / 2.0
                    if ghost >= BLIND_ZONE_M:
                        out.append(ghost)
        return out

    def _command(self, dev: EmulatedSRF08, value: int) -> None:
        if value in (0x50, 0x51, 0x52):
            dev.address_sequence = 0
            self._start_ranging(dev, value)
        elif value in (0x53, 0x54, 0x55):
            raise ProtocolError(f"SRF08 emulator: ANN mode command 0x{value:02X} is not emulated")
        elif value == 0xA0:
            dev.address_sequence = 1
        elif value == 0xAA and dev.address_sequence == 1:
            dev.address_sequence = 2
        elif value == 0xA5 and dev.address_sequence == 2:
            dev.address_sequence = 3
        elif dev.address_sequence == 3 and value in range(0xE0, 0x100, 2):
            new = value >> 1
            dev.address_sequence = 0
            if new != dev.address:
                if new in self.devices:  # two devices on one address: the bus would be garbage
                    raise HardwareError(f"emulated address change to 0x{new:02X} collides with a device")
                del self.devices[dev.address]
                dev.address = new
                self.devices[new] = dev
        else:
            dev.address_sequence = 0  # anything else breaks the sequence; the device ignores it

    # --- smbus2 methods ------------------------------------------------------------------------------

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        if not 0 <= value <= 0xFF:
            raise ValueError(f"value={value!r} is not a byte")
        if i2c_addr == 0x00:  # general call: every device that is listening obeys
            if register == 0 and value in (0x50, 0x51, 0x52):
                for each in list(self.devices.values()):
                    if each.io_errors_left == 0 and self.clock.now_ns() >= each.busy_until_ns:
                        self._finish_if_done(each)
                        self._start_ranging(each, value)
            self.transfers += 1
            return
        dev = self._access(i2c_addr)
        if dev is None:
            return  # lost while ranging
        if register == 0:
            self._command(dev, value)
        elif register == 1:
            dev.gain = value
        elif register == 2:
            dev.range_register = value
        # other locations are read-only; the device ignores writes to them

    def _register(self, dev: EmulatedSRF08, register: int) -> int:
        if register == 0:
            return dev.software_revision
        if register == 1:
            return dev.light
        if 2 <= register <= 35:
            echo = dev.echoes[(register - 2) // 2]
            return (echo >> 8) & 0xFF if register % 2 == 0 else echo & 0xFF
        return 0

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        dev = self._access(i2c_addr)
        if dev is None:
            return 0xFF
        return self._register(dev, register)

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        if not 1 <= length <= 32:
            raise ValueError(f"length={length!r} must be 1..32 (SMBus block limit)")
        dev = self._access(i2c_addr)
        if dev is None:
            return [0xFF] * length
        return [self._register(dev, register + k) for k in range(length)]

    def close(self) -> None:
        self.closed = True


class ScriptedRanges:
    """A ``ranges`` callable from a script: piecewise-constant ranges per address over time.

    Args:
        keyframes: ``[(t_s, {address: range_m, ...}), ...]`` with increasing times (seconds of the
            bus clock). From each keyframe on, its ranges hold until the next keyframe; an address a
            keyframe does not name hears nothing (NaN) during it, as does every address before the
            first keyframe.
    """

    def __init__(self, keyframes: Sequence[tuple[float, dict[int, float]]]) -> None:
        times: list[int] = []
        for k, (t_s, ranges) in enumerate(keyframes):
            if not math.isfinite(t_s):
                raise HardwareError(f"keyframes[{k}]: t_s={t_s!r} is not finite")
            t_ns = round(t_s * 1e9)
            if times and t_ns <= times[-1]:
                raise HardwareError(f"keyframes[{k}]: t_s={t_s!r} does not come after the previous keyframe")
            for a, r in ranges.items():
                if a not in SRF08_ADDRESSES:
                    raise HardwareError(f"keyframes[{k}]: address=0x{a:02X} is not an SRF08 address")
                if not (math.isnan(r) or r > 0.0):
                    raise HardwareError(f"keyframes[{k}]: range {r!r} m for 0x{a:02X} must be > 0 or NaN")
            times.append(t_ns)
        self._times = times
        self._frames = [dict(r) for _, r in keyframes]

    def __call__(self, address: int, stamp_ns: int) -> float:
        idx = bisect.bisect_right(self._times, stamp_ns) - 1
        if idx < 0:
            return math.nan
        return self._frames[idx].get(address, math.nan)
