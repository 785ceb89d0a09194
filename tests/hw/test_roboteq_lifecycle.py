"""Lifecycle, diagnostics and fault rehearsal of the Roboteq driver against the emulator.

Motor time is a SyncedClock the test advances; reply deadlines are real time and short.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import pytest

from hw.errors import (
    CommandError,
    DeviceClosedError,
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceStateError,
    HardwareError,
)
from hw.interfaces import LifecycleState, MotorControllerLifecycle, MotorFaults, PIDConfig
from hw.roboteq.driver import RoboteqMDC2230
from hw.roboteq.emulator import INJECT_KINDS, RoboteqEmulator, SyncedClock
from hw.roboteq.settings import RoboteqProtections
from robchair.cli import main
from robchair.platform.spec import load_spec

TIMEOUT_S = 0.05
S = LifecycleState


@pytest.fixture
def clock() -> SyncedClock:
    return SyncedClock()


@pytest.fixture
def emu(clock):
    with RoboteqEmulator(clock=clock) as e:
        yield e


def make(emu, clock, **kw) -> RoboteqMDC2230:
    return RoboteqMDC2230(emu.device_path, timeout_s=TIMEOUT_S, retries=2, clock=clock, **kw)


def test_lifecycle_walks_from_unconfigured_to_finalized_and_moves_only_when_active(emu, clock) -> None:
    drv = make(emu, clock)
    assert isinstance(drv, MotorControllerLifecycle)
    assert drv.state is S.UNCONFIGURED
    with pytest.raises(DeviceClosedError):
        drv.set_speeds_rpm(100, 100)

    drv.configure()
    assert drv.state is S.INACTIVE
    with pytest.raises(DeviceStateError, match="activate"):
        drv.set_speeds_rpm(100, 100)
    drv.set_speeds_rpm(0, 0)  # zero is always allowed
    assert drv.read_state().encoder_counts == (0, 0)  # states are readable while inactive
    assert emu.setpoints_rpm == (0.0, 0.0)

    drv.activate()
    assert drv.state is S.ACTIVE
    drv.set_speeds_rpm(100, 100)
    assert emu.setpoints_rpm == (100.0, 100.0)
    clock.advance(0.1)

    emu.raise_fault(MotorFaults(overheat=True))
    with pytest.raises(DeviceFaultError, match="overheat"):
        drv.read_state()
    assert drv.state is S.ERROR
    assert emu.setpoints_rpm == (0.0, 0.0) and emu.estop
    with pytest.raises(DeviceFaultError, match="--release-stop"):
        drv.set_speeds_rpm(100, 100)
    with pytest.raises(DeviceStateError, match="--release-stop"):
        drv.activate()
    with pytest.raises(DeviceFaultError, match="overheat"):  # the cause is still there
        drv.release()
    assert drv.state is S.ERROR

    emu.clear_faults()
    drv.release()
    assert drv.state is S.INACTIVE and not emu.estop
    with pytest.raises(DeviceStateError):
        drv.set_speeds_rpm(100, 100)
    assert emu.setpoints_rpm == (0.0, 0.0)

    drv.activate()
    assert drv.state is S.ACTIVE
    drv.set_speeds_rpm(50, -50)
    assert emu.setpoints_rpm == (50.0, -50.0)

    drv.deactivate()  # zero, then a latched stop
    assert drv.state is S.INACTIVE
    assert emu.setpoints_rpm == (0.0, 0.0) and emu.estop
    drv.activate()  # releases its own stop
    drv.set_speeds_rpm(20, 20)
    assert emu.setpoints_rpm == (20.0, 20.0)

    drv.close()
    assert drv.state is S.FINALIZED
    assert emu.setpoints_rpm == (0.0, 0.0)
    with pytest.raises(DeviceClosedError):
        drv.set_speeds_rpm(100, 100)


def test_emergency_stop_is_read_back_and_needs_a_release(emu, clock) -> None:
    drv = make(emu, clock)
    drv.open()
    drv.set_speeds_rpm(200, 200)
    drv.emergency_stop()
    assert emu.estop and drv.state is S.ERROR
    assert "?FF" in [t for _, t in emu.received][-2:]
    drv.release_stop()
    assert drv.state is S.ACTIVE and not emu.estop
    drv.close()


def test_configure_writes_the_protections_from_the_spec_and_reads_them_back(emu, clock) -> None:
    spec = load_spec()
    prot = RoboteqProtections.from_spec(spec)
    # one wheel at max_accel 0.5 + max_yaw_accel 1.5 * 0.29 m, r = 0.172 m, 1:29, headroom 1.5
    assert prot.accel_rpm_s == pytest.approx(0.935 / 0.172 * 60 / (2 * math.pi) * 29 * 1.5, abs=0.1)
    drv = make(emu, clock, protections=prot)
    drv.open()
    items = prot.config_items()
    for name in ("MAC", "MDEC", "ALIM", "CLERD"):
        assert drv.read_config(name) == (items[name], items[name])
    drv.close()


def test_a_lost_encoder_trips_the_loop_error_detection_the_driver_configured(emu, clock) -> None:
    drv = make(emu, clock)  # ^CLERD 2: 500 ms with an error above 250 RPM
    drv.open()
    for _ in range(10):
        drv.set_speeds_rpm(400, 400)
        drv.read_state()
        clock.advance(0.05)
    emu.disconnect_encoder(1)
    with pytest.raises(DeviceFaultError, match="loop_error"):
        for _ in range(40):
            drv.set_speeds_rpm(400, 400)
            clock.advance(0.05)
            drv.read_state()
    assert [s.reason for s in emu.stops][:1] == ["loop_error"]
    assert emu.setpoints_rpm == (0.0, 0.0)
    drv.close()


def test_loop_error_detection_cannot_be_switched_off() -> None:
    with pytest.raises(CommandError, match="loop-error"):
        RoboteqProtections(loop_error_detection=0)


def test_diagnostics_report_counters_voltages_amps_and_temperatures(emu, clock) -> None:
    drv = make(emu, clock)
    drv.open()
    emu.inject(drop=1)
    drv.set_speeds_rpm(100, 100)
    emu.emit("A=55:60")
    time.sleep(0.01)
    d = drv.read_diagnostics()
    assert d.state == "active" and d.retries == 1 and d.discarded_lines >= 1
    assert d.battery_v == pytest.approx(24.0) and d.internal_v == pytest.approx(23.7)
    assert len(d.temperatures_c) == 3 and all(20 < t < 60 for t in d.temperatures_c)
    kv = d.as_key_values()
    assert kv["retries"] == "1" and kv["battery_v"] == "24.0"
    assert drv.counters()["retries"] == 1
    drv.close()


def test_an_unknown_status_bit_found_by_the_diagnostics_poll_stops_the_motors(emu, clock) -> None:
    drv = make(emu, clock)
    drv.open()
    drv.set_speeds_rpm(100, 100)
    assert drv.read_diagnostics().status == ("serial_mode",)
    emu.status_unknown_bits = 1 << 10
    with pytest.raises(DeviceFaultError, match="f11"):
        drv.read_diagnostics()
    assert emu.setpoints_rpm == (0.0, 0.0) and drv.state is S.ERROR
    drv.close()


def test_watchdog_can_be_set_by_the_runtime_and_zero_is_refused(emu, clock) -> None:
    drv = make(emu, clock)
    drv.open()
    drv.set_watchdog_ms(250)
    assert emu.rwd_ms == 250 and drv.read_config("RWD") == (250,)
    with pytest.raises(CommandError, match="armed"):
        drv.set_watchdog_ms(0)
    drv.close()


def test_firmware_2_1_and_later_warns_that_the_gain_design_holds_for_1x_and_2_0_only(clock, caplog) -> None:
    with RoboteqEmulator(clock=clock, firmware="Roboteq v2.1 MDC2230 03/01/2021") as emu:
        drv = make(emu, clock)
        drv.open()
        assert drv.firmware_warning is not None and "1.x and 2.0 only" in drv.firmware_warning
        drv.close()
    assert any("current loop" in r.getMessage() for r in caplog.records)


def test_firmware_2x_gains_follow_the_manuals_range_of_two_billion(clock) -> None:
    with RoboteqEmulator(clock=clock, firmware="Roboteq v2.0 MDC2230 01/01/2020") as emu:
        drv = make(emu, clock)
        drv.open()
        assert drv.firmware_gains(PIDConfig(2000.0, 0.0, 0.0)) == (2_000_000_000, 0, 0)
        with pytest.raises(CommandError, match="2000000000"):
            drv.firmware_gains(PIDConfig(2000.001, 0.0, 0.0))
        drv.close()


# --- fault rehearsal: each injected kind is handled --------------------------------------------


def drive(drv, clock, seconds=0.3, rpm=200.0):
    for _ in range(round(seconds * 20)):
        drv.set_speeds_rpm(rpm, rpm)
        drv.read_state()
        clock.advance(0.05)


@pytest.mark.parametrize(
    ("kind", "error", "match"),
    [
        ("late-ack", None, None),
        ("rejected", None, None),
        ("unsolicited", None, None),
        ("garble", None, None),
        ("reboot", DeviceFaultError, "restart"),
        ("unknown-flag", DeviceFaultError, "f9"),
        ("stall", DeviceFaultError, "motor_stall"),
        ("unplug", DeviceDisconnectedError, "unplugged"),
    ],
)
def test_each_rehearsed_fault_is_ridden_out_or_stops_the_motors_first(emu, clock, kind, error, match) -> None:
    assert kind in INJECT_KINDS
    drv = make(emu, clock, watchdog_ms=1000)
    drv.open()
    drive(drv, clock)
    emu.inject_kind(kind)
    time.sleep(0.06)  # real time for telemetry or a late answer to arrive
    if error is None:
        drive(drv, clock, seconds=0.5)
        assert emu.setpoints_rpm == (200.0, 200.0)
        if kind == "unsolicited":
            assert drv.discarded_lines >= 1
            assert not emu._telemetry  # the driver sent "# C" again
        else:
            assert drv.n_retries >= 1
    else:
        with pytest.raises(error, match=match):
            drive(drv, clock, seconds=0.5)
        assert drv.state is S.ERROR
        if kind != "unplug":
            assert emu.setpoints_rpm == (0.0, 0.0)
        else:
            clock.advance(1.5)  # the controller's own watchdog stops it
            assert emu.setpoints_rpm == (0.0, 0.0)
    drv.close()


def test_hw_emulate_rehearses_the_injected_faults_and_announces_them() -> None:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "robchair.cli", "hw", "emulate", "roboteq", "--duration", "30"]
    cmd += ["--inject", "unknown-flag", "--inject-after", "0.3"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout is not None
        path = proc.stdout.readline().strip()
        drv = RoboteqMDC2230(path, timeout_s=0.2)
        drv.open()
        with pytest.raises(DeviceFaultError, match="f9"):
            for _ in range(200):
                drv.set_speeds_rpm(100, 100)
                drv.read_state()
                time.sleep(0.05)
        drv.close()
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
    assert "fault rehearsal: injected unknown-flag" in err


def test_hw_emulate_refuses_an_unknown_fault_kind_in_one_line(capsys) -> None:
    assert main(["hw", "emulate", "roboteq", "--inject", "late-ack,meteor"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "meteor" in err


def test_a_read_only_session_cannot_be_activated_or_released(emu, clock) -> None:
    drv = make(emu, clock, configure=False)
    drv.open()
    assert drv.state is S.INACTIVE and drv.read_only
    for call in (drv.activate, drv.release):
        with pytest.raises(DeviceStateError, match="read-only"):
            call()
    emu.raise_fault(MotorFaults(overheat=True))
    with pytest.raises(HardwareError):
        drv.read_state()
    assert not emu.estop  # a read-only session never latches
    drv.close()
