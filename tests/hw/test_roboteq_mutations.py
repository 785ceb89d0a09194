"""The Roboteq driver's units and limits against hand values from the manual and the spec.

The controller here is :class:`tests.hw.test_roboteq_manual.ManualRoboteq` (written from the Roboteq
Advanced Digital Motor Controller user manual, not from the emulator or the driver), with currents that
are not zero and a configuration that differs from what the driver writes, so a unit error on either
side of the wire shows.
"""

from __future__ import annotations

import math

import pytest

from hw.errors import CommandError
from hw.roboteq.driver import RoboteqMDC2230
from tests.hw.test_roboteq_manual import ManualRoboteq, opened


class LoadedRoboteq(ManualRoboteq):
    """A :class:`ManualRoboteq` whose motors draw current: ``?A`` answers ``A=125:-38``.

    Manual, ``?A`` (Read Motor Amps): one value per channel in 0.1 A, so 12.5 A and -3.8 A.
    """

    def _execute(self, line: str) -> str:
        if line.upper().startswith("?A"):
            return "A=125:-38"
        return super()._execute(line)


@pytest.fixture
def fake():
    with LoadedRoboteq() as f:
        # not what the driver writes: the read-back below must come from the driver's own writes
        f.config.update({"MAC": [1, 1], "MDEC": [1, 1], "ALIM": [10, 10], "CLERD": [0, 0]})
        yield f


def test_voltages_are_read_in_tenths_of_a_volt_and_the_5v_output_in_millivolts(fake) -> None:
    """Manual, ``?V`` (Read Volts): ``V=241:244:4980`` is 24.1 V internal, 24.4 V battery and 4.980 V on
    the 5 V output (the first two in 0.1 V, the third in mV). ``ManualRoboteq`` answers exactly that."""
    drv = opened(fake)
    assert drv.read_voltages() == pytest.approx((24.1, 24.4, 4.98), abs=1e-9)
    drv.close()


def test_motor_currents_are_read_in_tenths_of_an_amp(fake) -> None:
    """Manual, ``?A`` (Read Motor Amps) in 0.1 A: ``A=125:-38`` is 12.5 A left and -3.8 A right."""
    drv = opened(fake)
    assert drv.read_amps() == pytest.approx((12.5, -3.8), abs=1e-9)
    drv.close()


def test_open_writes_the_protections_in_the_controllers_units(fake) -> None:
    """Hand values (spec: wheel radius 0.172 m, separation 0.58 m, gear 29; safety defaults: max_accel
    0.5 m/s^2, max_yaw_accel 1.5 rad/s^2, brake_decel 0.8 m/s^2; the ramps 1.5x above them):

    * one wheel's acceleration (0.5 + 1.5 * 0.29) m/s^2 = 0.935 m/s^2 is
      0.935 * 60 / (2 pi 0.172) * 29 = 1505.4 motor RPM/s, times 1.5 = 2258.1 RPM/s; ``^MAC`` is in
      0.1 RPM/s (manual): 22581;
    * braking (0.8 + 0.435) m/s^2 = 1.235 m/s^2 gives 2982.6 RPM/s: ``^MDEC`` 29826;
    * ``^ALIM`` is in 0.1 A (manual): the MDC2230's 30 A rating (datasheet, 2 x 30 A) is 300;
    * ``^CLERD`` 2 is the manual's "500 ms at error > 250" detection level.
    """
    drv = opened(fake)
    cfg = fake.config
    for name, want in (("MAC", 22581), ("MDEC", 29826)):
        assert all(abs(v - want) <= 1 for v in cfg[name]), (name, cfg[name])
    assert cfg["ALIM"] == [300, 300]
    assert cfg["CLERD"] == [2, 2]
    assert cfg["MXRPM"] == [1000, 1000]  # spec: max_motor_rpm = 1000
    drv.close()


def test_speeds_up_to_the_maximum_are_written_and_just_above_are_refused(fake) -> None:
    """Spec: ``max_motor_rpm = 1000``. +-1000 RPM is written as ``!S 1 1000`` / ``!S 2 -1000``; 1000.6
    (which would round to 1001) and 1001 RPM are refused before anything reaches the controller."""
    drv = opened(fake)
    drv.set_speeds_rpm(1000.0, -1000.0)
    assert fake.received[-2:] == ["!S 1 1000", "!S 2 -1000"]
    for bad in (1000.6, 1001.0, -1001.0):
        drv.release_stop()
        n = len(fake.received)
        with pytest.raises(CommandError, match="1000 RPM"):
            drv.set_speeds_rpm(bad, 0.0)
        assert not any(line.startswith("!S 1 100") for line in fake.received[n:])
        assert fake.effective == (0, 0)  # refused after stopping
    drv.close()


def test_the_driver_refuses_a_maximum_outside_the_manuals_mxrpm_range() -> None:
    """Manual, ``^MXRPM``: 10 to 65000 RPM."""
    for bad in (9, 65001):
        with pytest.raises(CommandError, match="max_rpm"):
            RoboteqMDC2230("/dev/null", max_rpm=bad)
    assert math.isfinite(RoboteqMDC2230("/dev/null", max_rpm=10).max_rpm)
