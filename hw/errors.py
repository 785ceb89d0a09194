"""Error root of the hardware package."""


class HardwareError(Exception):
    """Root of every error the hardware layer raises on purpose."""


class DeviceClosedError(HardwareError, RuntimeError):
    """A device was used before open() or after close()."""


class DeviceTimeoutError(HardwareError, TimeoutError):
    """A device did not answer within its deadline."""


class ProtocolError(HardwareError, ValueError):
    """A device answered something the protocol does not allow."""


class DeviceFaultError(HardwareError):
    """A device reported a fault (the motors have already been commanded to stop)."""
