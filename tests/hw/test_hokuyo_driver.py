"""The real Hokuyo driver, unchanged, against the SCIP 2.0 emulator over a pseudo-terminal.

The emulator runs in real time (one scan per 100 ms revolution), so each test reads only a few scans.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from hw.errors import (
    CommandError,
    DeviceClosedError,
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceTimeoutError,
    ProtocolError,
)
from hw.hokuyo.codec import URG_04LX
from hw.hokuyo.driver import HokuyoURG
from hw.hokuyo.emulator import HokuyoEmulator, Scene2D
from hw.interfaces import LaserScanner

WALL_X = 1.5
WALL = Scene2D(segments=(((WALL_X, -10.0), (WALL_X, 10.0)),))


@pytest.fixture
def emu():
    e = HokuyoEmulator(WALL)
    e.start()
    yield e
    e.stop()


def _wait_for(cond, timeout_s: float = 5.0) -> bool:
    """Poll ``cond`` every 10 ms until it holds (True) or ``timeout_s`` of real time passed (False)."""
    import time

    end = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > end:
            return False
        time.sleep(0.01)
    return True


def _check_wall(scan, wall_x=WALL_X, reach_m=5.6):
    a = scan.angles()
    facing = np.cos(a) > wall_x / (reach_m - 0.001)  # beams that meet the wall within reach
    x = scan.ranges[facing] * np.cos(a[facing])
    assert np.all(np.abs(x - wall_x) < 0.0015)  # rounding to whole mm, projected
    assert np.isposinf(scan.ranges[~facing & (np.abs(a) > math.pi / 2)]).all()


def test_open_reads_version_parameters_and_state(emu):
    with HokuyoURG(emu.device_path) as laser:
        assert isinstance(laser, LaserScanner)
        assert laser.version["PROD"] == "SOKUIKI Sensor URG-04LX"
        assert laser.version["PROT"] == "SCIP 2.0"
        assert laser.params == URG_04LX
        assert laser.state["STAT"] == "Sensor works well."
        assert laser.command is not None and laser.command.text() == "MD0044072501000"
    # a crashed program's stream is stopped first; a sensor in SCIP 1.1 mode is switched
    assert emu.received[:6] == ["QT", "SCIP2.0", "VV", "PP", "II", "BM"]
    assert emu.received[-1] == "QT"  # close switches the laser off
    assert not emu.laser_on


@pytest.mark.parametrize(("mode", "encoding"), [("MD", 3), ("MD", 2), ("GD", 3), ("GD", 2)])
def test_scan_of_a_wall_gives_its_distance_on_every_beam(emu, mode, encoding):
    with HokuyoURG(emu.device_path, mode=mode, encoding=encoding) as laser:
        scan = laser.read()
    assert scan.n_beams == 682
    assert scan.ranges.dtype == np.float32
    assert scan.angle_min == pytest.approx((44 - 384) * 2 * math.pi / 1024)
    assert scan.angle_max == pytest.approx((725 - 384) * 2 * math.pi / 1024)
    assert scan.scan_time == pytest.approx(0.1)
    assert scan.ranges[384 - 44] == pytest.approx(WALL_X)  # step 384 points straight ahead
    _check_wall(scan, reach_m=5.6 if encoding == 3 else 4.095)


def test_two_character_mode_reads_beyond_4095_mm_as_no_return():
    with HokuyoEmulator(Scene2D(segments=(((4.5, -1.0), (4.5, 1.0)),)), scip2=True) as emu:
        with HokuyoURG(emu.device_path, mode="GD", encoding=2) as laser:
            scan2 = laser.read()
        with HokuyoURG(emu.device_path, mode="GD", encoding=3) as laser:
            scan3 = laser.read()
    front = 384 - 44
    assert np.isposinf(scan2.ranges[front])
    assert scan3.ranges[front] == pytest.approx(4.5)


def test_a_garbled_scan_is_dropped_and_the_next_one_returned(emu):
    with HokuyoURG(emu.device_path) as laser:
        laser.read()
        emu.inject(garble=1)
        scans = [laser.read(), laser.read()]  # the damaged one is among the next two revolutions
        assert laser.n_bad_blocks == 1
    for scan in scans:
        _check_wall(scan)


def test_a_bad_checksum_in_gd_mode_is_retried(emu):
    with HokuyoURG(emu.device_path, mode="GD") as laser:
        emu.inject(bad_checksum=1)
        scan = laser.read()
        assert laser.n_retries == 1 and laser.n_bad_blocks == 1
    _check_wall(scan)


def test_persistent_bad_checksums_raise_a_protocol_error_naming_them(emu):
    with HokuyoURG(emu.device_path, mode="GD", retries=2) as laser:
        emu.inject(bad_checksum=10)
        with pytest.raises(ProtocolError, match="checksum mismatch"):
            laser.read()
        assert laser.n_bad_blocks == 3


def test_a_delayed_reply_is_waited_for_again(emu):
    with HokuyoURG(emu.device_path, mode="GD", timeout_s=0.3) as laser:
        emu.inject(delay_s=0.5, delay_n=1)
        scan = laser.read()
        assert laser.n_retries >= 1
    _check_wall(scan)


def test_unplugged_sensor_raises_a_clear_disconnected_error(emu):
    laser = HokuyoURG(emu.device_path)
    laser.open()
    laser.read()
    emu.unplug()
    with pytest.raises(DeviceDisconnectedError, match="Hokuyo port"):
        for _ in range(3):  # what was already buffered may still come out first
            laser.read()
    laser.close()  # never raises for a device that is gone
    assert not laser.is_open


def test_stuck_sensor_raises_a_timeout(emu):
    with HokuyoURG(emu.device_path, mode="GD", timeout_s=0.25, retries=1) as laser:
        emu.inject(stuck=True)
        with pytest.raises(DeviceTimeoutError, match="no answer"):
            laser.read()


def test_silent_port_fails_open_with_a_timeout():
    with HokuyoEmulator(WALL) as emu:
        emu.inject(stuck=True)
        with pytest.raises(DeviceTimeoutError, match=r"'SCIP2\.0'"):
            HokuyoURG(emu.device_path, timeout_s=0.1, retries=1).open()


def test_hardware_trouble_status_is_a_fault(emu):
    with HokuyoURG(emu.device_path, mode="GD") as laser:
        emu.inject(hardware_status="50")
        with pytest.raises(DeviceFaultError, match="status '50'"):
            laser.read()


def test_stream_left_running_by_another_program_is_stopped_on_open(emu):
    fd = os.open(emu.device_path, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, b"SCIP2.0\nMD0044072501000\n")
        assert _wait_for(lambda: emu.scans_sent >= 3)  # scans pile up unread
    finally:
        os.close(fd)
    with HokuyoURG(emu.device_path, mode="GD") as laser:
        scan = laser.read()
    _check_wall(scan)


def test_md_returns_the_newest_scan_when_several_wait(emu):
    with HokuyoURG(emu.device_path) as laser:
        laser.read()
        sent = emu.scans_sent
        assert _wait_for(lambda: emu.scans_sent >= sent + 4)  # four revolutions wait unread
        laser.read()
        assert laser.n_dropped_scans >= 2


def test_reset_restarts_the_stream(emu):
    with HokuyoURG(emu.device_path) as laser:
        laser.read()
        laser.reset()
        _check_wall(laser.read())
    assert "RS" in emu.received


def test_window_outside_the_sensor_steps_is_refused(emu):
    with pytest.raises(CommandError, match=r"outside the sensor's steps 44\.\.725"):
        HokuyoURG(emu.device_path, start_step=10, end_step=700).open()


def test_closed_driver_refuses_to_read(emu):
    laser = HokuyoURG(emu.device_path)
    with pytest.raises(DeviceClosedError):
        laser.read()


def test_stuck_stream_is_restarted_then_reported_as_a_timeout(emu):
    with HokuyoURG(emu.device_path, timeout_s=0.2, retries=1) as laser:
        laser.read()
        emu.inject(stuck=True)
        with pytest.raises(DeviceTimeoutError, match="no valid answer to 'QT'"):
            laser.read()


def test_laser_switched_off_behind_the_drivers_back_is_switched_on_again(emu):
    with HokuyoURG(emu.device_path, mode="GD") as laser:
        laser.read()
        fd = os.open(emu.device_path, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, b"QT\n")
        finally:
            os.close(fd)
        import time

        t_end = time.monotonic() + 2.0
        while emu.laser_on and time.monotonic() < t_end:
            time.sleep(0.01)
        assert not emu.laser_on
        _check_wall(laser.read())
        assert emu.laser_on


def test_emulator_scene_may_be_a_function_of_the_beam_angles():
    with HokuyoEmulator(lambda a: 1.0 + 0.1 * np.abs(a), scip2=True) as emu:
        with HokuyoURG(emu.device_path, mode="GD") as laser:
            scan = laser.read()
    np.testing.assert_allclose(scan.ranges, 1.0 + 0.1 * np.abs(scan.angles()), atol=0.0006)


def test_emulator_in_scip11_mode_answers_only_the_switch():
    with HokuyoEmulator(WALL) as emu:
        fd = os.open(emu.device_path, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, b"VV\n")
            import select

            got = b""
            while not got.endswith(b"\n\n") and select.select([fd], [], [], 2.0)[0]:
                got += os.read(fd, 100)
            assert got == b"VV\nE\n\n"
        finally:
            os.close(fd)
