"""Roboteq MDC2230 dual-channel motor controller: line codec, pyserial driver and pty emulator."""

from hw.roboteq.codec import FirmwareId, MotorFlags, StatusFlags
from hw.roboteq.settings import RoboteqDiagnostics, RoboteqProtections

__all__ = [
    "FirmwareId",
    "MotorFlags",
    "RoboteqDiagnostics",
    "RoboteqEmulator",
    "RoboteqMDC2230",
    "RoboteqProtections",
    "StatusFlags",
]


def __getattr__(name: str) -> object:
    # The driver and emulator are imported lazily so `import hw.roboteq` stays light.
    if name == "RoboteqMDC2230":
        from hw.roboteq.driver import RoboteqMDC2230

        return RoboteqMDC2230
    if name == "RoboteqEmulator":
        from hw.roboteq.emulator import RoboteqEmulator

        return RoboteqEmulator
    raise AttributeError(name)
