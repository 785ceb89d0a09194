"""What the Roboteq driver writes to the controller, and the read-back that confirms it.

:class:`RoboteqConfiguration` holds the configuration side of
:class:`hw.roboteq.driver.RoboteqMDC2230`: closed-loop speed mode, encoder PPR, max RPM, the
protections (:class:`hw.roboteq.settings.RoboteqProtections`), the PID gains in the firmware's units
and the serial watchdog. Every value written is remembered and
read back (``~NAME``) before activation; a difference refuses to activate.
"""

from __future__ import annotations

import math

from hw.errors import CommandError, DeviceClosedError, DeviceFaultError, DeviceStateError
from hw.interfaces import PIDConfig
from hw.roboteq import codec
from hw.roboteq.readings import RoboteqReadings
from hw.roboteq.settings import RoboteqProtections


class RoboteqConfiguration(RoboteqReadings):
    """Configuration writes and read-back (the state they use is set by the driver)."""

    name: str
    encoder_ppr: int
    max_rpm: int
    watchdog_ms: int
    protections: RoboteqProtections | None
    _pid: tuple[PIDConfig, PIDConfig] | None
    _written: dict[str, tuple[int, ...]]

    def set_watchdog_ms(self, watchdog_ms: int) -> None:
        """Write ``^RWD`` (1..65000 ms) and read it back; the runtime sets it from its cycle.

        Raises:
            CommandError: 0 or out of range (the watchdog must stay armed).
            DeviceStateError: read-only session.
            DeviceFaultError: the value read back differs.
        """
        check_watchdog_ms(watchdog_ms)
        self._check_open()
        if not self._writable:
            raise DeviceStateError(f"{self.name}: read-only session: ^RWD is not written")
        self._command(codec.set_config("RWD", watchdog_ms))
        self.watchdog_ms = watchdog_ms
        self._written["RWD"] = (watchdog_ms,)
        self._verify_configuration(["RWD"])

    def configure_pid(self, left: PIDConfig, right: PIDConfig) -> None:
        """Write ``^KP/^KI/^KD`` per channel in the firmware's units and read them back.

        Raises:
            CommandError: a gain does not fit the firmware (nothing is written then).
            DeviceStateError: read-only session.
            ProtocolError: a write was rejected; DeviceFaultError: the values read back differ.
        """
        self._check_open()
        if not self._writable:
            raise DeviceStateError(f"{self.name}: read-only session: gains are not written")
        encoded = [self.firmware_gains(cfg) for cfg in (left, right)]  # validate both before writing
        for i, name in enumerate(("KP", "KI", "KD")):
            for cc in (1, 2):
                self._command(codec.set_config(name, cc, encoded[cc - 1][i]))
            self._written[name] = (encoded[0][i], encoded[1][i])
        self._verify_configuration(["KP", "KI", "KD"])

    def firmware_gains(self, cfg: PIDConfig) -> tuple[int, int, int]:
        """The ``^KP/^KI/^KD`` integers for ``cfg`` on this controller's firmware.

        The multiplier is the control module's (:data:`hw.roboteq.gains.FIRMWARE_MULTIPLIER`: x10
        on 1.x, x1,000,000 on 2.x); the range is the manual's (:data:`hw.roboteq.FIRMWARE_RANGE`:
        0..255 on 1.x, 0..2,000,000,000 on 2.x). CommandError if a gain does not fit.
        """
        from hw.roboteq.gains import FIRMWARE_MULTIPLIER, FIRMWARE_RANGE

        if self.firmware is None:
            raise DeviceClosedError(f"{self.name}: firmware unknown until configure() has probed ?FID")
        major = self.firmware.major
        if major not in FIRMWARE_MULTIPLIER or major not in FIRMWARE_RANGE:
            raise CommandError(
                f"firmware {self.firmware.text!r}: no known gain encoding for major version {major}"
            )
        mult, (lo, hi) = FIRMWARE_MULTIPLIER[major], FIRMWARE_RANGE[major]
        out = []
        for label, g in (("kp", cfg.kp), ("ki", cfg.ki), ("kd", cfg.kd)):
            q = round(g * mult) if math.isfinite(g) else None
            if q is None or not lo <= q <= hi:
                raise CommandError(
                    f"PID {label}={g!r} does not fit firmware {major}.x (x{mult} must lie in {lo}..{hi})"
                )
            out.append(int(q))
        return out[0], out[1], out[2]

    def _write_configuration(self) -> None:
        if self.protections is None:
            from robchair.platform.spec import load_spec

            self.protections = RoboteqProtections.from_spec(load_spec())
        items: dict[str, int] = {"MMOD": 1, "EPPR": self.encoder_ppr, "MXRPM": self.max_rpm}
        items.update(self.protections.config_items())
        for name, value in items.items():
            for cc in (1, 2):
                self._command(codec.set_config(name, cc, value))
            self._written[name] = (value, value)
        if self._pid is not None:
            self.configure_pid(*self._pid)
        self._command(codec.set_config("RWD", self.watchdog_ms))
        self._written["RWD"] = (self.watchdog_ms,)

    def _verify_configuration(self, names: list[str] | None = None) -> None:
        diffs = []
        for name in names if names is not None else list(self._written):
            got = self.read_config(name)
            if got != self._written[name]:
                want = ":".join(map(str, self._written[name]))
                diffs.append(f"{name}={':'.join(map(str, got))} (written {want})")
        if diffs:
            raise DeviceFaultError(
                f"Roboteq configuration read back differs from what was written: {', '.join(diffs)}; "
                "the controller is not activated"
            )


def check_watchdog_ms(watchdog_ms: object) -> None:
    """Refuse a watchdog period that is not an integer in 1..65000 ms (CommandError)."""
    if isinstance(watchdog_ms, bool) or not isinstance(watchdog_ms, int) or not 1 <= watchdog_ms <= 65000:
        raise CommandError(
            f"watchdog_ms={watchdog_ms!r}: the serial watchdog must stay armed (1..65000 ms; 0 is refused)"
        )
