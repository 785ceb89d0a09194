"""Roboteq MDC2230 dual-channel motor controller: line codec, pyserial driver and pty emulator."""

from hw.roboteq.codec import FirmwareId, MotorFlags, StatusFlags

__all__ = ["FirmwareId", "MotorFlags", "RoboteqEmulator", "RoboteqMDC2230", "StatusFlags"]


def __getattr__(name: str) -> object:
    # The driver and emulator are imported lazily so `import hw.roboteq` stays light.
    if name == "RoboteqMDC2230":
        from hw.roboteq.driver import RoboteqMDC2230

        return RoboteqMDC2230
    if name == "RoboteqEmulator":
        from hw.roboteq.emulator import RoboteqEmulator

        return RoboteqEmulator
    raise AttributeError(name)
