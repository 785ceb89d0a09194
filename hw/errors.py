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


class DeviceDisconnectedError(HardwareError, ConnectionError):
    """The link to a device went away (port unplugged, pty closed)."""


class CommandError(HardwareError, ValueError):
    """A command argument is invalid (non-finite, out of range); the message names it."""


class DeviceIOError(HardwareError, OSError):
    """A bus transfer to a device failed (I2C NACK, serial read error) and retries did not help."""


class DeviceStateError(HardwareError, RuntimeError):
    """A call the device's lifecycle state does not allow (motion while not active, a read-only session)."""
