"""`robchair hw check` and `robchair hw emulate roboteq` against the emulator."""

from __future__ import annotations

import io
import os
import subprocess
import sys

import pytest

from hw.clock import ManualClock
from hw.emulators.srf08 import SRF08Bus
from hw.interfaces import MotorFaults
from hw.roboteq.driver import RoboteqMDC2230
from hw.roboteq.emulator import RoboteqEmulator
from robchair.cli import main
from robchair.commands.hw import hw_check


def test_hw_check_prints_firmware_config_counts_and_voltages(capsys) -> None:
    clock = ManualClock()
    with RoboteqEmulator(clock=clock) as emu:
        emu.set_encoder_counts(1234, -567)
        rc = main(["hw", "check", "--port", emu.device_path])
        sent = [t for _, t in emu.received]
    out = capsys.readouterr().out
    assert rc == 0
    assert "firmware 'Roboteq v1.3 MDC2230 07/24/2013' (major 1)" in out
    assert "encoder counts 1234 -567" in out
    assert "battery 24.0 V" in out
    assert "MMOD = 1:1" in out and "RWD = 1000" in out
    assert not any(t.startswith("^") for t in sent)  # a check writes no configuration


def test_hw_check_reports_a_fault_flag_with_exit_code_1() -> None:
    clock = ManualClock()
    out = io.StringIO()
    with RoboteqEmulator(clock=clock) as emu:
        emu.raise_fault(MotorFaults(undervoltage=True))
        with RoboteqMDC2230(emu.device_path, configure=False, timeout_s=0.05) as drv:
            assert hw_check(drv, out=out) == 1
    assert "undervoltage" in out.getvalue()


def test_hw_check_lists_sonar_addresses_and_ranges_on_the_bus() -> None:
    clock = ManualClock()
    bus = SRF08Bus(clock, lambda addr, _t: 0.5 if addr == 0x70 else float("nan"), addresses=(0x70, 0x74))
    out = io.StringIO()
    with RoboteqEmulator(clock=clock) as emu, RoboteqMDC2230(emu.device_path, configure=False) as drv:
        rc = hw_check(drv, bus, out=out, clock=clock)
    text = out.getvalue()
    assert rc == 0
    assert "2 SRF08 found at ['0x70', '0x74']" in text
    assert "sonar 0x70: revision 11, range 0.50 m" in text
    assert "sonar 0x74: revision 11, range no echo" in text


def test_hw_check_on_a_missing_port_fails_with_one_line(capsys) -> None:
    assert main(["hw", "check", "--port", "/dev/no-such-roboteq"]) == 2
    assert "/dev/no-such-roboteq" in capsys.readouterr().err


def test_hw_check_with_a_missing_i2c_bus_fails_with_one_line_naming_it(capsys) -> None:
    with RoboteqEmulator(clock=ManualClock()) as emu:
        assert main(["hw", "check", "--port", emu.device_path, "--i2c", "97"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "97" in err


def test_hw_emulate_roboteq_prints_a_device_path_the_driver_can_use() -> None:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "robchair.cli", "hw", "emulate", "roboteq", "--no-echo", "--duration", "30"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        with RoboteqMDC2230(path, timeout_s=0.2) as drv:
            assert drv.firmware is not None and drv.firmware.major == 1
            drv.set_speeds_rpm(100, -100)
            assert drv.read_config("MMOD") == (1, 1)
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.hardware
def test_real_roboteq_answers_the_check() -> None:
    port = os.environ.get("ROBCHAIR_ROBOTEQ_PORT", "/dev/ttyACM0")
    assert main(["hw", "check", "--port", port]) == 0
