"""`robchair hw check --laser` and `robchair hw emulate hokuyo`."""

from __future__ import annotations

import os
import subprocess
import sys

from hw.hokuyo.emulator import HokuyoEmulator, Scene2D
from robchair.cli import main


def test_hw_check_laser_reports_version_parameters_and_one_scan(capsys) -> None:
    with HokuyoEmulator(Scene2D(segments=(((2.0, -10.0), (2.0, 10.0)),))) as emu:
        rc = main(["hw", "check", "--laser", emu.device_path])
    out = capsys.readouterr().out
    assert rc == 0
    assert "laser: PROD SOKUIKI Sensor URG-04LX" in out
    assert "laser: PROT SCIP 2.0" in out
    assert "range 20-5600 mm, steps 44..725 (front 384, 1024 per turn), 600 rpm" in out
    assert "state 'Sensor works well.'" in out
    assert "scan 682 beams -119.5..119.9 deg every 0.3516 deg" in out
    assert "min 2.000 m" in out and "ahead 2.000 m" in out


def test_hw_check_laser_on_a_hung_sensor_is_one_line_and_exit_code_2(capsys) -> None:
    with HokuyoEmulator() as emu:
        emu.inject(stuck=True)
        rc = main(["hw", "check", "--laser", emu.device_path])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and "Hokuyo gave no valid answer to 'QT'" not in err[0]
    assert err[0].startswith("robchair hw: error: Hokuyo gave no valid answer to 'SCIP2.0'")


def test_hw_check_without_any_device_is_refused(capsys) -> None:
    assert main(["hw", "check"]) == 2
    assert "give --port (Roboteq) and/or --laser (Hokuyo)" in capsys.readouterr().err


def test_hw_emulate_hokuyo_prints_a_pty_path_the_driver_can_use() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "robchair.cli", "hw", "emulate", "hokuyo", "--duration", "20"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
    )
    try:
        assert proc.stdout is not None
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        from hw.hokuyo.driver import HokuyoURG

        with HokuyoURG(path, mode="GD") as laser:
            scan = laser.read()
        assert scan.n_beams == 682
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_hw_check_reads_the_roboteq_and_the_laser_together(capsys) -> None:
    from hw.clock import ManualClock
    from hw.roboteq.emulator import RoboteqEmulator

    with RoboteqEmulator(clock=ManualClock()) as motors, HokuyoEmulator() as laser:
        rc = main(["hw", "check", "--port", motors.device_path, "--laser", laser.device_path])
    out = capsys.readouterr().out
    assert rc == 0
    assert "roboteq: firmware" in out and "roboteq: fault flags none" in out
    assert "laser: PROD SOKUIKI Sensor URG-04LX" in out and "laser: scan 682 beams" in out
