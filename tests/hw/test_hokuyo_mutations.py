"""The Hokuyo driver's open() against a stream another program left running (SCIP 2.0 emulator, pty).

The emulator runs in real time; waits are on conditions with a bound, never a fixed sleep.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

from hw.hokuyo.driver import HokuyoURG
from hw.hokuyo.emulator import HokuyoEmulator, Scene2D

WALL_X = 1.5
STREAM = "MD0044072501000"  # SCIP 2.0: MD, steps 44..725, cluster 01, interval 0, 000 scans = until QT


def _wait_for(cond, timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > end:
            return False
        time.sleep(0.01)
    return True


def test_open_stops_a_running_stream_with_qt_before_its_first_command_without_retrying() -> None:
    """SCIP 2.0 (Hokuyo "Communication Protocol Specification For SCIP2.0 Standard"): ``QT`` stops a
    running ``MD`` stream and switches the laser off; scans already sent stay in the input until read.
    With no retries allowed, open() only succeeds if its first command after the stale stream is ``QT``
    and every reply it parses answers its own command. The scan then shows the wall 1.5 m ahead."""
    emu = HokuyoEmulator(Scene2D(segments=(((WALL_X, -10.0), (WALL_X, 10.0)),)))
    emu.start()
    path = emu.device_path
    assert path is not None
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, f"SCIP2.0\n{STREAM}\n".encode())
            assert _wait_for(lambda: emu.scans_sent >= 3)  # scans pile up unread
        finally:
            os.close(fd)
        with HokuyoURG(path, mode="GD", retries=0) as laser:
            assert emu.received[:3] == ["SCIP2.0", STREAM, "QT"]
            assert laser.n_retries == 0
            scan = laser.read()
            assert laser.n_retries == 0
        ahead = np.abs(scan.angles()) < math.radians(10.0)
        assert np.all(np.abs(scan.ranges[ahead] * np.cos(scan.angles()[ahead]) - WALL_X) < 0.0015)
    finally:
        emu.stop()
