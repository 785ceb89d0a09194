"""Two :class:`hw.interfaces.Clock` implementations: the machine's monotonic clock and a manual one.

Drivers take a clock so that tests can run them against emulators in simulated time: with a
:class:`ManualClock`, ``sleep_until_ns`` jumps the time forward instead of sleeping, so a driver
waiting 65 ms for an SRF08 ranging returns at once and the emulator sees exactly 65 ms pass.
"""

from __future__ import annotations

import math
import threading
import time

from hw.errors import HardwareError


class MonotonicClock:
    """Wall time from ``time.monotonic_ns``; ``sleep_until_ns`` really sleeps."""

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep_until_ns(self, t_ns: int) -> None:
        delay = (t_ns - time.monotonic_ns()) / 1e9
        if delay > 0:
            time.sleep(delay)


class ManualClock:
    """Simulated time that moves only when asked: by ``advance`` or by a ``sleep_until_ns``."""

    def __init__(self, start_ns: int = 0) -> None:
        self._t_ns = int(start_ns)
        self._lock = threading.Lock()  # emulator threads may read it while a test advances it

    def now_ns(self) -> int:
        with self._lock:
            return self._t_ns

    def advance(self, seconds: float) -> None:
        """Move time forward by ``seconds`` (finite, >= 0)."""
        if not (math.isfinite(seconds) and seconds >= 0.0):
            raise HardwareError(f"ManualClock.advance: seconds must be finite and >= 0, got {seconds!r}")
        with self._lock:
            self._t_ns += round(seconds * 1e9)

    def sleep_until_ns(self, t_ns: int) -> None:
        with self._lock:
            self._t_ns = max(self._t_ns, int(t_ns))
