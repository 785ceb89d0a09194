"""What the Roboteq driver reads from the controller: counts, speeds, flags, voltages, diagnostics.

:class:`RoboteqReadings` holds the queries of :class:`hw.roboteq.driver.RoboteqMDC2230` (``?C``,
``?S``, ``?FF``, ``?FS``, ``?FM``, ``?V``, ``?A``, ``?T``, ``~NAME``) and the diagnostics sample built
from them. Only :meth:`RoboteqReadings.read_faults` and :meth:`RoboteqReadings.read_diagnostics` act on
what they read (through the fault path); the others only decode.
"""

from __future__ import annotations

from hw.errors import DeviceFaultError, ProtocolError
from hw.interfaces import LifecycleState, MotorFaults
from hw.roboteq import codec
from hw.roboteq.settings import RoboteqDiagnostics
from hw.roboteq.transactions import RELEASE_HINT, RoboteqTransactions

S = LifecycleState


class RoboteqReadings(RoboteqTransactions):
    """The controller's readings (the state they depend on is set by the driver).

    Attributes:
        firmware: the ``?FID`` answer, parsed (None until configured).
        watchdog_trips: host stalls longer than the serial watchdog seen since the port was opened.
    """

    firmware: codec.FirmwareId | None
    watchdog_trips: int
    _startup_config_at_start: bool
    _discarded_before: int

    @property
    def discarded_lines(self) -> int:
        """Received lines that answered nothing the driver asked (stale, unsolicited, other echoes)."""
        return self._link.discarded_lines if self._link is not None else self._discarded_before

    def read_encoder_counts(self) -> tuple[int, int]:
        """``?C`` (signed 32-bit, quadrature x4) without the plausibility check (for inspection)."""
        self._check_open()
        a, b = self._ints(codec.query("C"), 2)
        return a, b

    def read_speeds_rpm(self) -> tuple[float, float]:
        """``?S``: measured motor speeds, RPM."""
        self._check_open()
        a, b = self._ints(codec.query("S"), 2)
        return float(a), float(b)

    def read_faults_word(self) -> int:
        """The raw ``?FF`` word (0..65535), without acting on it."""
        self._check_open()
        (word,) = self._ints(codec.query("FF"), 1, validate=_flag_word)
        return word

    def read_faults(self) -> MotorFaults:
        """``?FF`` decoded; a set flag (an unknown bit included) stops the motors, then raises.

        A controller that restarted during the session (the "default configuration loaded at
        startup" flag appears) is a fault too.

        Raises:
            DeviceFaultError: after stopping. Read-only sessions only command zero (no ``!EX``).
        """
        word = self.read_faults_word()
        faults = codec.decode_fault_flags(word)
        names = faults.names()
        if faults.startup_config and self._startup_config_at_start:
            names.remove("startup_config")
        if faults.startup_config and not self._startup_config_at_start:
            self._fail(
                DeviceFaultError(
                    f"Roboteq restarted during the session (?FF={word}: default configuration loaded at "
                    "startup); its configuration is lost: close and open again"
                )
            )
        if names:
            self._fail(DeviceFaultError(f"Roboteq reports fault flags {names} (?FF={word})" + self._hint()))
        return faults

    def read_status(self) -> codec.StatusFlags:
        """``?FS`` decoded (no action is taken on it)."""
        self._check_open()
        (word,) = self._ints(codec.query("FS"), 1, validate=_flag_word)
        return codec.decode_status_flags(word)

    def read_motor_flags(self) -> tuple[codec.MotorFlags, codec.MotorFlags]:
        """``?FM`` for both motors, decoded (no action is taken on them)."""
        self._check_open()
        a, b = self._ints(codec.query("FM"), 2, validate=_flag_word)
        return codec.decode_motor_flags(a), codec.decode_motor_flags(b)

    def read_voltages(self) -> tuple[float, float, float]:
        """(internal V, battery V, 5 V output V) from ``?V``."""
        self._check_open()
        internal, battery, five_mv = self._ints(codec.query("V"), 3)
        return internal / 10.0, battery / 10.0, five_mv / 1000.0

    def read_amps(self) -> tuple[float, float]:
        """Motor currents (left, right), A, from ``?A``."""
        self._check_open()
        a, b = self._ints(codec.query("A"), 2)
        return a / 10.0, b / 10.0

    def read_temperatures(self) -> tuple[float, float, float]:
        """(MCU, channel 1 heatsink, channel 2 heatsink), degrees C, from ``?T``."""
        self._check_open()
        t = self._ints(codec.query("T"), 3)
        return float(t[0]), float(t[1]), float(t[2])

    def read_config(self, name: str) -> tuple[int, ...]:
        """``~NAME``: a configuration value for every channel (or the one global value)."""
        self._check_open()
        n = 1 if name in codec.GLOBAL_CONFIG else 2
        return self._ints(codec.get_config(name), n)

    def counters(self) -> dict[str, int]:
        """Retries, discarded lines and watchdog trips since the session started (no I/O)."""
        return {
            "retries": self.n_retries,
            "discarded_lines": self.discarded_lines,
            "watchdog_trips": self.watchdog_trips,
        }

    def read_diagnostics(self) -> RoboteqDiagnostics:
        """Counters plus ``?V``, ``?A``, ``?T``, ``?FS``, ``?FF`` (five transactions: poll at about 1 Hz).

        ``?FF``/``?FM`` are acted on by :meth:`read_state` every cycle; ``?FS`` (the controller's
        mode) only here, at the diagnostics rate: a status bit the manual does not name stops.

        Raises:
            DeviceFaultError: ``?FS`` has a bit the manual does not name (after stopping).
            DeviceTimeoutError, ProtocolError, DeviceDisconnectedError: the link failed (after stopping).
        """
        self._check_open()
        status = self.read_status()
        if status.unknown_bits and self._state is not S.ERROR:
            self._fail(
                DeviceFaultError(
                    f"Roboteq status flags {status.names()} (?FS): a bit the manual does not name"
                )
            )
        internal, battery, _ = self.read_voltages()
        amps = self.read_amps()
        temps = self.read_temperatures()
        faults = codec.decode_fault_flags(self.read_faults_word())
        return RoboteqDiagnostics(
            stamp_ns=self._now_ns(),
            state=self._state.value,
            firmware=self.firmware.text if self.firmware else "",
            retries=self.n_retries,
            discarded_lines=self.discarded_lines,
            watchdog_trips=self.watchdog_trips,
            stop_reason=self.stop_reason,
            faults=tuple(faults.names()),
            status=tuple(status.names()),
            battery_v=battery,
            internal_v=internal,
            motor_amps=amps,
            temperatures_c=temps,
        )

    def _hint(self) -> str:
        return f"; {RELEASE_HINT}" if self._writable else ""


def _flag_word(values: tuple[int, ...]) -> None:
    for v in values:
        if not 0 <= v <= codec.FLAG_WORD_MAX:
            raise ProtocolError(f"flag word {v} outside 0..{codec.FLAG_WORD_MAX}")
