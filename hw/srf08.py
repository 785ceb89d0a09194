"""Devantech SRF08 ultrasonic ranger over I2C (smbus2): a :class:`hw.interfaces.Ranger`.

Protocol facts (Devantech SRF08 technical specification):

* 7-bit addresses 0x70..0x7F (the datasheet's 8-bit 0xE0..0xFE; shipped at 0xE0 = 0x70).
* Write 0x51 to register 0 to range with the result in centimetres (0x50 inches, 0x52 microseconds).
* A ranging takes 65 ms at the default range; while ranging the SRF08 ignores the bus. A host sees
  that either as reads of 0xFF (SDA floating high: "read the software revision at register 0 until it
  is not 255") or, on Linux i2c-dev, as ``OSError`` (EREMOTEIO, no acknowledge). Both mean "busy".
* Registers 2 and 3 hold the first echo, high byte first; 0 means no echo.
* Register 1 (write) is the maximum analogue gain 0..31; register 2 (write) is the range register,
  ``range = reg * 43 mm + 43 mm`` (255 = 11.008 m, 24 = 1.075 m). Both reset to defaults at power-up.
  Shortening the range shortens the listen time; we model it as ``65 ms * (reg + 1) / 256``.
* Timing and gain. At the power-up settings the datasheet says to fire each SRF08 every 65 ms or
  slower; a ranging started sooner "may pick up a distant echo returning from the previous ping", and
  firing faster needs a lower maximum gain (register 1; the gain ramps from 94 to the register's
  :data:`ANALOGUE_GAIN` over the first ~390 mm of a ranging). The datasheet gives no interval that is
  safe at a lower gain, so this driver keeps the gain the device has (31 = 1025 after power-up unless
  ``gain`` is passed) and :data:`ECHO_WINDOW_S` = 65 ms is the firing interval every caller keeps:
  a sonar is fired at most every 65 ms, and no sonar whose beam overlaps it within 65 ms of its ping
  (:class:`hw.sonar_array.SonarFiringGroup`, which fires one sonar of each array per 65 ms slot: six
  sonars in 3 x 65 = 195 ms). The range register only shortens the wait for the result.
* Readings (REP-117): a ranging with no echo (result 0) is ``+inf``; a result under the 3 cm minimum
  is an echo inside the transducer's ring-down and reads NaN (invalid).
* Address change: write 0xA0, 0xAA, 0xA5 and then the new 8-bit address to register 0, as four
  separate transfers, with only that one sonar on the bus: :func:`change_address` (guarded).

Transport: any object with smbus2's ``write_byte_data``, ``read_byte_data``, ``read_i2c_block_data``
and ``close`` (an ``smbus2.SMBus`` or :class:`hw.emulators.srf08.SRF08Bus`). Pass a bus number to
have the driver open ``smbus2.SMBus(n)`` itself (imported only then); a bus object passed in is
shared (six sonars on one bus) and is not closed by the driver.
"""

from __future__ import annotations

import errno
import logging
import math
from collections.abc import Iterable
from typing import Any, Literal

from hw.clock import MonotonicClock
from hw.errors import CommandError, DeviceIOError, DeviceTimeoutError, HardwareError
from hw.interfaces import Clock, Device, RangeReading

log = logging.getLogger(__name__)

SRF08_ADDRESSES = range(0x70, 0x80)
DEFAULT_ADDRESS = 0x70
REG_COMMAND = 0
REG_REVISION = 0
REG_GAIN = 1
REG_RANGE = 2
REG_ECHO1 = 2
CMD_RANGE_INCHES = 0x50
CMD_RANGE_CM = 0x51
CMD_RANGE_US = 0x52
ADDRESS_SEQUENCE = (0xA0, 0xAA, 0xA5)
BUSY = 0xFF
DEFAULT_RANGE_REGISTER = 255
FULL_RANGING_TIME_S = 0.065
ECHO_WINDOW_S = 0.065  # datasheet: fire every 65 ms or slower (at the power-up gain)
#: Maximum analogue gain for each gain-register value 0..31 (datasheet table; 31 is the power-up value).
ANALOGUE_GAIN = (
    94, 97, 100, 103, 107, 110, 114, 118, 123, 128, 133, 139, 145, 152, 159, 168,
    177, 187, 199, 212, 227, 245, 265, 288, 317, 352, 395, 450, 524, 626, 777, 1025,
)  # fmt: skip
MIN_RANGE_M = 0.03  # SPEC table 5.1: 3 cm
RATED_MAX_RANGE_M = 6.0  # SPEC table 5.1 / datasheet: detects objects up to about 6 m
FIELD_OF_VIEW_RAD = math.radians(60.0)  # SPEC table 5.1: ~60 deg (the measured model is in mapping.sonar)
#: errno values a Linux I2C adapter reports for a device that does not acknowledge (busy or absent).
NACK_ERRNOS = frozenset({errno.EREMOTEIO, errno.ENXIO, errno.EAGAIN, errno.ETIMEDOUT})


def check_address(address: int, what: str = "address") -> int:
    """Validate a 7-bit SRF08 address (0x70..0x7F) and return it."""
    if isinstance(address, bool) or not isinstance(address, int):
        raise CommandError(f"{what}={address!r} must be an int 7-bit SRF08 address (0x70..0x7F)")
    if address not in SRF08_ADDRESSES:
        hint = (
            f" (that is the 8-bit form of 0x{address >> 1:02X})" if address in range(0xE0, 0x100, 2) else ""
        )
        raise CommandError(f"{what}=0x{address:02X} is not an SRF08 7-bit address (0x70..0x7F){hint}")
    return address


def range_register_for(max_range_m: float) -> int:
    """Smallest range-register value whose range ``(reg * 43 + 43) mm`` covers ``max_range_m``."""
    if not (math.isfinite(max_range_m) and 0.043 <= max_range_m <= 11.008):
        raise CommandError(f"max_range_m={max_range_m!r} must be within 0.043..11.008 m")
    return max(0, math.ceil((max_range_m * 1000.0 - 43.0) / 43.0 - 1e-9))


def range_for_register(reg: int) -> float:
    """Range in metres of a range-register value."""
    return (reg * 43 + 43) / 1000.0


def ranging_time_for_register(reg: int) -> float:
    """Modelled listen time of one ranging, seconds (65 ms at 255)."""
    return FULL_RANGING_TIME_S * (reg + 1) / 256.0


def open_bus(bus_number: int) -> Any:
    """Open ``smbus2.SMBus(bus_number)`` (imported here); OSError becomes DeviceIOError naming the bus."""
    try:
        import smbus2
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise HardwareError("the SRF08 driver needs 'smbus2' for a real I2C bus: pip install smbus2") from exc
    try:
        return smbus2.SMBus(bus_number)
    except OSError as exc:
        raise DeviceIOError(exc.errno, f"cannot open I2C bus {bus_number}: {exc.strerror}") from exc


_open_smbus = open_bus  # older name, still used by hw.registry / robchair.commands.hw


class SRF08(Device):
    """One SRF08 on an I2C bus.

    Args:
        bus: an smbus2-shaped object (shared, not closed here) or an I2C bus number (opened on
            ``open()`` via smbus2, closed on ``close()``).
        address: 7-bit address 0x70..0x7F.
        name: device name for logs and errors.
        clock: time source; tests pass :class:`hw.clock.ManualClock`.
        wait: ``"poll"`` reads register 0 every ``poll_interval_s`` until it stops reading 0xFF /
            raising; ``"sleep"`` first waits the modelled ranging time, then polls (usually once).
        gain: maximum analogue gain 0..31 written on ``open()`` (None: leave the power-up default 31).
        max_range_m: range setting written on ``open()`` (None: power-up default 11 m).
        poll_interval_s: pause between two busy polls.
        timeout_s: give up waiting for one ranging after this long (DeviceTimeoutError).
        retries: extra attempts for a transfer that fails with an I/O error (not a busy NACK).
    """

    def __init__(
        self,
        bus: Any,
        address: int = DEFAULT_ADDRESS,
        *,
        name: str | None = None,
        clock: Clock | None = None,
        wait: Literal["poll", "sleep"] = "poll",
        gain: int | None = None,
        max_range_m: float | None = None,
        poll_interval_s: float = 0.005,
        timeout_s: float = 0.25,
        retries: int = 2,
    ) -> None:
        self.address = check_address(address)
        self.name = name or f"srf08@0x{address:02X}"
        if wait not in ("poll", "sleep"):
            raise CommandError(f"wait={wait!r} must be 'poll' or 'sleep'")
        if gain is not None and not (isinstance(gain, int) and 0 <= gain <= 31):
            raise CommandError(f"gain={gain!r} must be an integer 0..31")
        self._range_register = (
            DEFAULT_RANGE_REGISTER if max_range_m is None else range_register_for(max_range_m)
        )
        self._write_range = max_range_m is not None
        self._gain = gain
        self._bus_arg = bus
        self._bus: Any = None
        self._owns_bus = isinstance(bus, int)
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        self.wait = wait
        self.poll_interval_s = poll_interval_s
        self.timeout_s = timeout_s
        self.retries = retries
        self.software_revision: int | None = None
        self.busy_polls = 0  # polls that found the device busy, over the device's life
        self._uncollected = False  # a ranging was started and its result not read yet

    # --- lifecycle ---------------------------------------------------------------------------------

    def open(self) -> None:
        if self._is_open:
            return
        self._bus = open_bus(self._bus_arg) if self._owns_bus else self._bus_arg
        self._is_open = True
        try:
            # a ranging left over from before us would make the first reads busy: wait it out
            self.software_revision = self._wait_ready(self._clock.now_ns())
            if self._gain is not None:
                self._write(REG_GAIN, self._gain)
            if self._write_range:
                self._write(REG_RANGE, self._range_register)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        if self._owns_bus and self._bus is not None:
            self._bus.close()
        self._bus = None
        self._is_open = False

    # --- configuration -------------------------------------------------------------------------------

    @property
    def max_range_m(self) -> float:
        return range_for_register(self._range_register)

    @property
    def ranging_time_s(self) -> float:
        return ranging_time_for_register(self._range_register)

    def set_gain(self, gain: int) -> None:
        """Write the maximum analogue gain (register 1), 0..31 (31 = 1025, the power-up default)."""
        self._check_open()
        if isinstance(gain, bool) or not isinstance(gain, int) or not 0 <= gain <= 31:
            raise CommandError(f"{self.name}: gain={gain!r} must be an integer 0..31")
        self._write(REG_GAIN, gain)
        self._gain = gain

    def set_max_range_m(self, max_range_m: float) -> None:
        """Write the range register (register 2) for the smallest range covering ``max_range_m``."""
        self._check_open()
        reg = range_register_for(max_range_m)
        self._write(REG_RANGE, reg)
        self._range_register = reg

    # --- ranging -----------------------------------------------------------------------------------------

    def start_ranging(self, command: int = CMD_RANGE_CM) -> int:
        """Send a ranging command; returns the time stamp (ns) of the ping.

        If an earlier ranging was never collected (a timeout, or no ``read_range_cm``), the device may
        still be busy and would silently drop the command (or NACK it): wait until it is idle first.
        """
        self._check_open()
        if self._uncollected:
            self._wait_ready(self._clock.now_ns(), settle=False)
        stamp = self._clock.now_ns()
        self._write(REG_COMMAND, command)
        self._uncollected = True
        return stamp

    def read_range_cm(self) -> int:
        """Wait until the current ranging completes and return the first echo (0 = no echo)."""
        self._check_open()
        self._wait_ready(self._clock.now_ns())
        hi, lo = self._transfer(lambda: self._bus.read_i2c_block_data(self.address, REG_ECHO1, 2))
        value = (int(hi) << 8) | int(lo)
        self._uncollected = False
        if value == 0xFFFF:
            # SDA floating high: the device went busy again or dropped off between poll and read
            raise DeviceIOError(
                errno.EIO, f"{self.name}: echo registers read 0xFFFF (no device driving the bus)"
            )
        return value

    def read(self) -> RangeReading:
        """One ranging in centimetres (see :meth:`collect` for the values)."""
        stamp = self.start_ranging(CMD_RANGE_CM)
        return self.collect(stamp)

    def collect(self, stamp_ns: int) -> RangeReading:
        """Wait for the ranging started at ``stamp_ns`` (:meth:`start_ranging`, in centimetres) and read it.

        ``range_m`` is ``+inf`` without an echo (result 0: nothing within the range setting, REP-117)
        and NaN for a result under :data:`MIN_RANGE_M` (an echo inside the ring-down: invalid).

        Raises:
            DeviceTimeoutError: The ranging does not finish within ``timeout_s``.
            DeviceIOError: A transfer fails after the retries, or the echo reads 0xFFFF.
        """
        value = self.read_range_cm()
        if value == 0:
            range_m = math.inf
        elif value / 100.0 < MIN_RANGE_M:
            range_m = math.nan
        else:
            range_m = value / 100.0
        return RangeReading(
            stamp_ns=stamp_ns,
            range_m=range_m,
            min_range_m=MIN_RANGE_M,
            max_range_m=min(self.max_range_m, RATED_MAX_RANGE_M),
            field_of_view_rad=FIELD_OF_VIEW_RAD,
        )

    # --- internals ---------------------------------------------------------------------------------------

    def _transfer(self, fn: Any) -> Any:
        """Run one bus transfer, retrying I/O errors ``retries`` times; errors become DeviceIOError."""
        last: OSError | None = None
        for _ in range(self.retries + 1):
            try:
                return fn()
            except OSError as exc:
                last = exc
                log.debug("%s: transfer failed (%s), retrying", self.name, exc)
        assert last is not None
        raise DeviceIOError(
            last.errno, f"{self.name}: I2C transfer failed after {self.retries + 1} attempts: {last}"
        ) from last

    def _write(self, register: int, value: int) -> None:
        self._transfer(lambda: self._bus.write_byte_data(self.address, register, value))

    def _wait_ready(self, start_ns: int, settle: bool = True) -> int:
        """Poll register 0 until the device answers something other than 0xFF; returns that value.

        A NACK-type ``OSError`` counts as busy. Other OSErrors are I/O faults: they are retried
        ``retries`` times in a row and then raised as DeviceIOError. With ``wait="sleep"`` and
        ``settle``, the modelled ranging time is slept first.
        """
        if self.wait == "sleep" and settle:
            self._clock.sleep_until_ns(start_ns + round(self.ranging_time_s * 1e9))
        deadline = start_ns + round(self.timeout_s * 1e9)
        io_failures = 0
        while True:
            try:
                value = int(self._bus.read_byte_data(self.address, REG_REVISION))
                io_failures = 0
                if value != BUSY:
                    return value
            except OSError as exc:
                if exc.errno not in NACK_ERRNOS:
                    io_failures += 1
                    if io_failures > self.retries:
                        raise DeviceIOError(
                            exc.errno, f"{self.name}: I/O error while polling register 0: {exc}"
                        ) from exc
            self.busy_polls += 1
            now = self._clock.now_ns()
            if now >= deadline:
                raise DeviceTimeoutError(
                    f"{self.name}: still busy {self.timeout_s * 1e3:.0f} ms after the ranging started"
                    " (register 0 reads 0xFF or is not acknowledged): device absent, wrong address,"
                    " or not finishing its ranging"
                )
            self._clock.sleep_until_ns(min(now + round(self.poll_interval_s * 1e9), deadline))


def scan(bus: Any, addresses: Iterable[int] = SRF08_ADDRESSES) -> dict[int, int]:
    """Find SRF08s on a bus: ``{address: software revision}`` of every address that answers register 0.

    A device that reads 0xFF (ranging, or nothing driving SDA) is left out.
    """
    found: dict[int, int] = {}
    for a in addresses:
        try:
            v = int(bus.read_byte_data(a, REG_REVISION))
        except OSError:
            continue
        if v != BUSY:
            found[a] = v
    return found


def change_address(bus: Any, old: int, new: int, *, confirm: bool = False) -> None:
    """Give the SRF08 at ``old`` the address ``new`` (7-bit): writes 0xA0, 0xAA, 0xA5, ``new << 1``.

    Guarded tool function. The datasheet requires that only the one sonar is on the bus; the new
    address must be free and the device must answer at ``old``. Afterwards the device is checked at
    ``new``.

    Raises:
        CommandError: ``confirm`` is not True, an address is invalid, equal, or ``new`` is taken.
        DeviceIOError: the device does not answer at ``old`` or, afterwards, at ``new``.
    """
    old = check_address(old, "old")
    new = check_address(new, "new")
    if new == old:
        raise CommandError(f"new=0x{new:02X} equals old: nothing to change")
    if confirm is not True:
        raise CommandError(
            f"refusing to change SRF08 address 0x{old:02X} -> 0x{new:02X} without confirm=True "
            "(only that one sonar may be on the bus)"
        )
    present = scan(bus, (old, new))
    if new in present:
        raise CommandError(f"new=0x{new:02X} already answers on the bus: pick a free address")
    if old not in present:
        raise DeviceIOError(errno.ENXIO, f"no SRF08 answers at old=0x{old:02X}")
    for value in (*ADDRESS_SEQUENCE, new << 1):
        try:
            bus.write_byte_data(old, REG_COMMAND, value)
        except OSError as exc:
            raise DeviceIOError(
                exc.errno, f"address change 0x{old:02X} -> 0x{new:02X} failed writing 0x{value:02X}: {exc}"
            ) from exc
    if new not in scan(bus, (new,)):
        raise DeviceIOError(errno.ENXIO, f"after the address change nothing answers at new=0x{new:02X}")
    log.info("SRF08 at 0x%02X now answers at 0x%02X", old, new)
