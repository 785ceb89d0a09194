"""Hardware-abstraction layer: device interfaces, real drivers, and protocol emulators."""

from hw.errors import HardwareError

__all__ = ["HardwareError"]
