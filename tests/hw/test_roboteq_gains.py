"""Roboteq gain encoding: register integers <-> continuous gains per firmware (SPEC erratum 8)."""

from __future__ import annotations

import control as ct
import numpy as np
import pytest

from hw.roboteq.gains import (
    FIRMWARE_RANGE,
    GAIN_EQUIVALENCE_NOTE,
    decode_gain,
    encode_gain,
    gain_equivalence_holds,
    gains_from_roboteq,
    roboteq_gains,
)
from robchair.platform.control import ControlError, SecondOrderPlant, design_pid, identify_from_step_metrics

MOTORS = {"motor 1": (0.1365, 0.3975, 0.10), "motor 2": (0.1524, 0.3590, 0.12)}


def test_roboteq_firmware_1_and_2_encodings_of_motor_1():
    d = design_pid(identify_from_step_metrics(*MOTORS["motor 1"]).plant)
    g1 = roboteq_gains(d, 1)
    assert (g1.kp, g1.ki, g1.kd) == (round(d.kp * 10), round(d.ki * 10), round(d.kd * 10)) == (14, 37, 3)
    g2 = roboteq_gains(d, 2)
    assert (g2.kp, g2.ki, g2.kd) == (round(d.kp * 1e6), round(d.ki * 1e6), round(d.kd * 1e6))
    assert gains_from_roboteq(g1.kp, g1.ki, g1.kd, 1) == pytest.approx((1.4, 3.7, 0.3))
    assert gains_from_roboteq(g2.kp, g2.ki, g2.kd, 2) == pytest.approx((d.kp, d.ki, d.kd), abs=5e-7)


def test_quantised_gains_poles_are_recomputed_and_close_to_the_design():
    for name in MOTORS:
        d = design_pid(identify_from_step_metrics(*MOTORS[name]).plant)
        g2 = roboteq_gains(d, 2)
        assert g2.max_pole_shift < 2e-3  # 1e-6 gain resolution (the double pole splits as sqrt)
    g1 = roboteq_gains(design_pid(identify_from_step_metrics(*MOTORS["motor 1"]).plant), 1)
    # motor 1 on firmware 1.x: KP 14, KI 37, KD 3 -> the PID 0.3 s + 1.4 + 3.7 / s
    expected = np.sort_complex(
        np.asarray(ct.poles(ct.feedback(ct.tf([0.3, 1.4, 3.7], [1, 0]) * g1.quantised.plant.tf(), 1)))
    )
    np.testing.assert_allclose(np.sort_complex(g1.quantised.achieved_poles), expected, rtol=1e-9)
    assert g1.max_pole_shift < 0.1  # 0.1 resolution of firmware 1.x still keeps motor 1 within 10 %
    # motor 2 on firmware 1.x: K_d = 0.249 rounds to 0.2, which moves the poles by up to 96 %
    g1_m2 = roboteq_gains(design_pid(identify_from_step_metrics(*MOTORS["motor 2"]).plant), 1)
    assert (g1_m2.kp, g1_m2.ki, g1_m2.kd) == (11, 32, 2)
    assert 0.5 < g1_m2.max_pole_shift < 1.0
    assert np.all(g1_m2.quantised.achieved_poles.real < 0)


def test_gain_outside_firmware_range_is_refused():
    d = design_pid(SecondOrderPlant(2.0, 0.5), omega_w=20.0)
    with pytest.raises(ControlError, match=r"firmware 1\.x cannot hold"):
        roboteq_gains(d, 1)
    with pytest.raises(ControlError, match="firmware_major = 3"):
        roboteq_gains(d, 3)


def test_firmware_2_register_range_ends_at_two_billion_as_the_manual_says():
    assert FIRMWARE_RANGE[2] == (0, 2_000_000_000)
    assert encode_gain(2000.0, 2) == 2_000_000_000
    with pytest.raises(ControlError, match=r"0\.\.2000000000"):
        encode_gain(2000.001, 2)  # 2,000,001,000 fits int32 but not the manual's range
    with pytest.raises(ControlError, match="register 2147483647"):
        decode_gain(2**31 - 1, 2)


def test_register_and_gain_round_trip_on_both_firmwares():
    for major, g in ((1, 1.4), (1, 25.5), (2, 0.249123), (2, 1999.999999)):
        assert decode_gain(encode_gain(g, major), major) == pytest.approx(g, abs=1e-9)
    with pytest.raises(ControlError, match="not a finite gain"):
        encode_gain(float("nan"), 1, "kd")
    with pytest.raises(ControlError, match="register 256"):
        decode_gain(256, 1)


def test_gain_equivalence_holds_only_for_firmware_1_and_2_0():
    assert gain_equivalence_holds(1, 8) and gain_equivalence_holds(2, 0)
    assert not gain_equivalence_holds(2, 1) and not gain_equivalence_holds(2, 3)
    assert "1.x and 2.0 only" in GAIN_EQUIVALENCE_NOTE
