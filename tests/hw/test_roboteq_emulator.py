"""The emulator against the user manual (V1.8/V2.0) on the points where it used to follow the driver.

Raw bytes over the pty (pyserial), no driver involved: the watchdog resume, the per-character echo,
``_`` as a line end, the firmware 2.x gain range, and the emulator versions of the late
acknowledgement / rejected ``!EX`` reproduction.
"""

from __future__ import annotations

import time

import pytest

from hw.errors import HardwareError
from hw.roboteq import codec
from hw.roboteq.driver import RoboteqMDC2230
from hw.roboteq.emulator import RoboteqEmulator, SyncedClock

TIMEOUT_S = 0.05


@pytest.fixture
def clock() -> SyncedClock:
    return SyncedClock()


@pytest.fixture
def emu(clock):
    with RoboteqEmulator(clock=clock) as e:
        yield e


def test_emulator_resumes_the_earlier_set_points_on_the_next_command_after_a_watchdog_trip(
    emu, clock
) -> None:
    import serial

    with serial.Serial(emu.device_path, timeout=0.5) as port:
        port.write(b"!S 1 300\r!S 2 300\r")
        _read_lines(port, 4)
        clock.advance(1.5)
        assert emu.setpoints_rpm == (0.0, 0.0) and emu.watchdog_trips == 1
        port.write(b"!S 1 50\r")
        _read_lines(port, 2)
    assert emu.setpoints_rpm == (50.0, 300.0)  # channel 2 resumed its earlier speed (manual)


def test_emulator_echoes_each_character_as_it_arrives_and_takes_underscore_as_a_line_end(emu) -> None:
    import serial

    with serial.Serial(emu.device_path, timeout=0.5) as port:
        port.write(b"?FI")
        assert port.read(3) == b"?FI"  # echoed before the command is complete
        port.write(b"D\r")
        lines = _read_lines(port, 2)
        assert lines == ["D", f"FID={emu.firmware.text}"]
        port.write(b"?FF_?FM 2_")
        lines = _read_lines(port, 2)
    # the echo is of the characters as typed; each '_' ended a command like a CR
    assert lines == ["?FF_?FM 2_FF=0", "FM=0"]


def test_emulator_accepts_gains_up_to_two_billion_on_firmware_2x(clock) -> None:
    import serial

    with RoboteqEmulator(clock=clock, firmware="Roboteq v2.0 MDC2230 01/01/2020", echo=False) as emu:
        with serial.Serial(emu.device_path, timeout=0.5) as port:
            port.write(b"^KP 1 2000000000\r^KP 1 2000000001\r")
            assert _read_lines(port, 2) == ["+", "-"]


def _read_lines(port, n: int) -> list[str]:
    data = b""
    while data.count(b"\r") < n:
        chunk = port.read(1) + port.read(port.in_waiting)  # what has arrived, not 64 bytes or the timeout
        assert chunk, f"no answer after {data!r}"
        data += chunk
    return codec.split_lines(data)[0]


def test_a_late_ack_and_a_rejected_ex_never_pass_for_a_latched_stop(emu, clock) -> None:
    drv = RoboteqMDC2230(emu.device_path, timeout_s=0.1, retries=2, clock=clock)
    drv.open()
    drv.set_speeds_rpm(400, 400)
    emu.inject(delay_s=0.25, delay_n=1)
    drv.set_speeds_rpm(400, 400)  # first try times out, the retry is answered; its late '+' follows
    end = time.monotonic() + 2.0
    while emu._pending and time.monotonic() < end:  # until the late '+' has been written
        time.sleep(0.005)
    assert not emu._pending
    emu.inject(reject=3)  # every try of !EX is corrupted in transit: the controller answers '-'
    with pytest.raises(HardwareError):
        drv.emergency_stop()
    assert emu.setpoints_rpm == (0.0, 0.0)  # zero was commanded before the error was raised
    drv.close()
