"""Hokuyo URG-04LX laser range finder: SCIP 2.0 codec, serial transport, driver and pty emulator."""

from hw.hokuyo.codec import URG_04LX, SensorParams

__all__ = ["URG_04LX", "HokuyoEmulator", "HokuyoURG", "Scene2D", "SensorParams"]


def __getattr__(name: str) -> object:
    # The driver and emulator are imported lazily so `import hw.hokuyo` stays light.
    if name == "HokuyoURG":
        from hw.hokuyo.driver import HokuyoURG

        return HokuyoURG
    if name in ("HokuyoEmulator", "Scene2D"):
        from hw.hokuyo import emulator

        return getattr(emulator, name)
    raise AttributeError(name)
