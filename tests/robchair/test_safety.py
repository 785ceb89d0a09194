"""The safety layer: every stop reason, the limits, the stopping distance, the stop log."""

from __future__ import annotations

import logging
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from robchair.platform.errors import ConfigError
from robchair.platform.kinematics import DiffDrive
from robchair.platform.safety import (
    SafetyDecision,
    SafetyInputs,
    SafetyLayer,
    SafetyLimits,
    StopReason,
    StopRecord,
)
from robchair.platform.spec import load_spec

DT = 0.1
# max_wheel_accel above what the body limits give a wheel (0.5 + 1.5 x 0.29 m/s^2): the body limits act
LIM = SafetyLimits(max_speed=0.6, max_yaw_rate=2.0, max_accel=0.5, max_yaw_accel=1.5, brake_decel=0.8,
                   reaction_time_s=0.3, margin_m=0.15, stale_after_s=0.5, max_wheel_accel=1.0)  # fmt: skip


def cruising(v: float = 0.4) -> SafetyLayer:
    """A layer whose last output is (v, 0), as after a long acceleration."""
    s = SafetyLayer(LIM)
    s._v = v
    return s


def test_stopping_distance_is_margin_plus_reaction_plus_braking() -> None:
    # 0.15 + 0.4 * 0.3 + 0.16 / 1.6 = 0.15 + 0.12 + 0.10
    assert LIM.stopping_distance(0.4) == pytest.approx(0.37)
    assert LIM.stopping_distance(-0.4) == pytest.approx(0.37)
    assert LIM.stopping_distance(0.0) == pytest.approx(0.15)


@given(st.floats(0, 2), st.floats(0, 2))
def test_stopping_distance_grows_with_speed(a: float, b: float) -> None:
    lo, hi = sorted((a, b))
    assert LIM.stopping_distance(lo) <= LIM.stopping_distance(hi)


@pytest.mark.parametrize(
    ("inputs", "reason"),
    [
        (SafetyInputs(driver_fault="Roboteq timeout"), StopReason.DRIVER_FAULT),
        (SafetyInputs(deadline_missed=True), StopReason.DEADLINE_MISSED),
        (SafetyInputs(stale_sensors=("sonar_array_left",)), StopReason.STALE_SENSOR),
        (SafetyInputs(deadman=False), StopReason.DEADMAN_RELEASED),
        (SafetyInputs(sonar_distance_m=0.36), StopReason.OBSTACLE_SONAR),
        (SafetyInputs(map_distance_m=0.36), StopReason.OBSTACLE_MAP),
    ],
)
def test_each_stop_reason_stops_and_is_logged_once(inputs: SafetyInputs, reason: StopReason) -> None:
    s = cruising(0.4)
    d = s.filter(0.4, 0.3, inputs, DT)
    assert (d.v, d.w, d.stop) == (0.0, 0.0, reason)
    s.filter(0.4, 0.3, inputs, DT)  # the same reason persisting is not logged again
    assert [r.reason for r in s.stops] == [reason]


def test_obstacle_just_beyond_the_stopping_distance_does_not_stop() -> None:
    s = cruising(0.4)
    d = s.filter(0.4, 0.0, SafetyInputs(sonar_distance_m=0.38, map_distance_m=0.38), DT)
    assert d.stop is None and d.v == pytest.approx(0.4)


def test_the_faster_of_wanted_and_current_speed_sets_the_stopping_distance() -> None:
    # standing still, wanting 0.6 m/s: d_stop(0.6) = 0.15 + 0.18 + 0.225 = 0.555
    s = SafetyLayer(LIM)
    assert s.filter(0.6, 0.0, SafetyInputs(sonar_distance_m=0.55), DT).stop is StopReason.OBSTACLE_SONAR
    assert SafetyLayer(LIM).filter(0.6, 0.0, SafetyInputs(sonar_distance_m=0.56), DT).stop is None


def test_reversing_or_turning_in_place_ignores_obstacles_ahead() -> None:
    s = SafetyLayer(LIM)
    assert s.filter(-0.2, 0.0, SafetyInputs(sonar_distance_m=0.05), DT).stop is None
    assert SafetyLayer(LIM).filter(0.0, 1.0, SafetyInputs(map_distance_m=0.05), DT).stop is None


def test_driver_fault_is_latched_until_reset() -> None:
    s = SafetyLayer(LIM)
    s.filter(0.2, 0.0, SafetyInputs(driver_fault="fault flags ['overheat']"), DT)
    d = s.filter(0.2, 0.0, SafetyInputs(), DT)
    assert d.stop is StopReason.DRIVER_FAULT and "overheat" in d.detail
    s.reset()
    assert s.filter(0.05, 0.0, SafetyInputs(), DT).stop is None


def test_non_finite_command_is_a_latched_fault() -> None:
    s = SafetyLayer(LIM)
    d = s.filter(math.nan, 0.0, SafetyInputs(), DT)
    assert d.stop is StopReason.DRIVER_FAULT and "non-finite" in d.detail
    assert s.filter(0.1, 0.0, SafetyInputs(), DT).stop is StopReason.DRIVER_FAULT


def test_precedence_fault_over_deadline_over_stale_over_deadman_over_obstacle() -> None:
    every = SafetyInputs(driver_fault="x", deadline_missed=True, stale_sensors=("s",), deadman=False,
                         sonar_distance_m=0.0, map_distance_m=0.0)  # fmt: skip
    assert cruising().filter(0.4, 0, every, DT).stop is StopReason.DRIVER_FAULT
    every2 = SafetyInputs(deadline_missed=True, stale_sensors=("s",), deadman=False, sonar_distance_m=0.0)
    assert cruising().filter(0.4, 0, every2, DT).stop is StopReason.DEADLINE_MISSED
    every3 = SafetyInputs(stale_sensors=("s",), deadman=False, sonar_distance_m=0.0)
    assert cruising().filter(0.4, 0, every3, DT).stop is StopReason.STALE_SENSOR
    every4 = SafetyInputs(deadman=False, sonar_distance_m=0.0)
    assert cruising().filter(0.4, 0, every4, DT).stop is StopReason.DEADMAN_RELEASED


def test_a_new_reason_after_another_is_logged_and_clearing_ends_the_stop() -> None:
    s = cruising(0.4)
    s.filter(0.4, 0, SafetyInputs(stamp_ns=1, deadline_missed=True), DT)
    s.filter(0.4, 0, SafetyInputs(stamp_ns=2, sonar_distance_m=0.1), DT)
    d = s.filter(0.4, 0, SafetyInputs(stamp_ns=3), DT)
    assert d.stop is None
    s.filter(0.4, 0, SafetyInputs(stamp_ns=4, sonar_distance_m=0.1), DT)
    assert [(r.stamp_ns, r.reason) for r in s.stops] == [
        (1, StopReason.DEADLINE_MISSED),
        (2, StopReason.OBSTACLE_SONAR),
        (4, StopReason.OBSTACLE_SONAR),
    ]


def test_acceleration_is_limited_per_cycle() -> None:
    s = SafetyLayer(LIM)
    outs = [s.filter(0.6, 0.0, SafetyInputs(), DT).v for _ in range(4)]
    assert outs == pytest.approx([0.05, 0.10, 0.15, 0.20])
    s2 = SafetyLayer(LIM)
    assert s2.filter(0.0, 2.0, SafetyInputs(), DT).w == pytest.approx(0.15)


def test_speed_and_yaw_rate_are_capped_and_their_sum_keeps_the_wheels_within_limits() -> None:
    s = SafetyLayer(LIM)
    s._v = 0.6  # already at full speed: no acceleration limit in the way
    d = s.filter(5.0, 0.0, SafetyInputs(), DT)
    assert d.v == pytest.approx(0.6) and d.limited
    s._v, s._w = 0.3, 1.0
    d = s.filter(0.6, 2.0, SafetyInputs(), DT)  # load 2: scaled to half
    assert (d.v, d.w) == pytest.approx((0.3, 1.0))


@given(st.floats(-3, 3), st.floats(-8, 8), st.floats(-0.62, 0.62), st.floats(-2.1, 2.1))
def test_the_output_never_makes_a_wheel_exceed_the_platform_limit(v, w, v0, w0) -> None:
    spec = load_spec()
    lim = SafetyLimits.from_spec(spec)
    dd = DiffDrive(spec)
    s = SafetyLayer(lim)
    s._v, s._w = v0, w0
    d = s.filter(v, w, SafetyInputs(), DT)
    left, right = dd.motor_rpm(d.v, d.w)
    assert max(abs(left), abs(right)) <= spec.max_motor_rpm * (1 + 1e-9)
    if abs(v0) / lim.max_speed + abs(w0) / lim.max_yaw_rate <= 1.0:
        # from a state within the wheel limits, the speed changes by at most max_accel * dt
        assert abs(d.v - v0) <= lim.max_accel * DT + 1e-12


def test_limits_from_spec_use_the_platform_maximum_and_reject_faster_caps() -> None:
    spec = load_spec()
    lim = SafetyLimits.from_spec(spec)
    assert lim.max_speed == pytest.approx(1000 / 29 * 2 * math.pi / 60 * 0.172)
    assert lim.max_yaw_rate == pytest.approx(2 * lim.max_speed / 0.58)
    with pytest.raises(
        ConfigError, match=r"^safety\.max_speed = 1\.0: expected a finite number <= the platform max"
    ):
        SafetyLimits.from_spec(spec, max_speed=1.0)
    with pytest.raises(
        ConfigError, match=r"^safety\.top_speed: unknown key \(value 0\.1\); expected one of brake_"
    ):
        SafetyLimits.from_spec(spec, top_speed=0.1)
    with pytest.raises(ConfigError, match=r"^safety\.margin_m = 'wide': expected a finite number > 0$"):
        SafetyLimits.from_spec(spec, margin_m="wide")  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, math.nan])
def test_non_positive_or_non_finite_limit_is_a_config_error(bad: float) -> None:
    with pytest.raises(ConfigError, match=r"^safety\.max_accel = .*: expected a finite number > 0$"):
        SafetyLimits(max_accel=bad)


def test_a_layer_asked_for_info_logs_each_new_stop_at_info_and_not_as_a_warning(caplog) -> None:
    """The Gymnasium envs and benchmarks log stops at INFO (they count them in ``info["safety"]``);
    a chair keeps WARNING. One stop, one record at the asked level (the module docstring's rule)."""
    s = SafetyLayer(LIM, log_level=logging.INFO)
    s._v = 0.4
    with caplog.at_level(logging.DEBUG, logger="robchair.platform.safety"):
        s.filter(0.4, 0.0, SafetyInputs(sonar_distance_m=0.2), DT)
        s.filter(0.4, 0.0, SafetyInputs(sonar_distance_m=0.2), DT)
    assert [r.levelno for r in caplog.records] == [logging.INFO]
    assert SafetyLayer(LIM).log_level == logging.WARNING


def test_the_navigation_env_logs_safety_stops_at_info() -> None:
    """``bench env`` and training loops must not get one WARNING line per stop on stderr."""
    import gymnasium

    import sim.envs  # noqa: F401  (registers the ids)

    env = gymnasium.make("RobChair/Navigation-v1")
    try:
        assert env.unwrapped.runtime.safety.log_level == logging.INFO
    finally:
        env.close()


def test_each_stop_is_recorded_and_logged_with_its_reason_and_a_detail_an_operator_can_read(caplog) -> None:
    """The stop log (module docstring): one ``safety stop: <reason> (<detail>)`` line and one
    :class:`StopRecord` per new stop. The details name what stopped the chair: the stale sensors in
    the order given, and for an obstacle its distance and the stopping distance, hand computed for
    0.4 m/s as 0.15 + 0.4 x 0.3 + 0.4^2 / 1.6 = 0.37 m."""
    cases = [
        (SafetyInputs(stamp_ns=11, deadline_missed=True), StopReason.DEADLINE_MISSED,
         "the previous control cycle overran its period"),
        (SafetyInputs(stamp_ns=12, stale_sensors=("sonar_array_left", "depth_camera")),
         StopReason.STALE_SENSOR,
         "no fresh data from sonar_array_left, depth_camera"),
        (SafetyInputs(stamp_ns=13, deadman=False), StopReason.DEADMAN_RELEASED,
         "joystick dead-man button released"),
        (SafetyInputs(stamp_ns=14, sonar_distance_m=0.2), StopReason.OBSTACLE_SONAR,
         "obstacle at 0.20 m ahead < stopping distance 0.37 m"),
    ]  # fmt: skip
    for inputs, reason, detail in cases:
        s = cruising(0.4)
        caplog.clear()
        with caplog.at_level(logging.DEBUG, logger="robchair.platform.safety"):
            d = s.filter(0.4, 0.0, inputs, DT)
        assert (d.v, d.w, d.stop, d.detail) == (0.0, 0.0, reason, detail)
        assert s.stops == [StopRecord(inputs.stamp_ns, reason, detail)]
        assert [(r.levelno, r.getMessage()) for r in caplog.records] == [
            (logging.WARNING, f"safety stop: {reason.value} ({detail})")
        ]


def test_a_stop_found_at_write_time_is_recorded_and_the_next_command_ramps_up_from_rest() -> None:
    """``stop_now`` (module docstring: stops found when the command is written, e.g. the controller
    watchdog) returns (0, 0) with its reason and detail and records it with its stamp; the chair is then
    at rest, so the next command is ramped from 0: 0.5 m/s^2 x 0.1 s = 0.05 m/s."""
    s = cruising(0.4)
    d = s.stop_now(7, StopReason.CONTROLLER_WATCHDOG, "no command for 0.6 s")
    assert d == SafetyDecision(0.0, 0.0, StopReason.CONTROLLER_WATCHDOG, "no command for 0.6 s")
    assert s.stops == [StopRecord(7, StopReason.CONTROLLER_WATCHDOG, "no command for 0.6 s")]
    after = s.filter(0.6, 0.0, SafetyInputs(stamp_ns=8), DT)
    assert after.stop is None and after.v == pytest.approx(0.05, abs=1e-12)


def test_reset_forgets_the_last_output_so_the_next_command_ramps_up_from_rest() -> None:
    """``reset`` (docstring: forgets the latched fault and the last output): a layer that was at
    (0.4 m/s, 0.5 rad/s) then ramps from (0, 0) by the body limits, 0.5 x 0.1 = 0.05 m/s and
    1.5 x 0.1 = 0.15 rad/s (the wheel step 0.05 + 0.15 x 0.29 = 0.0935 m/s is under 1.0 x 0.1)."""
    s = SafetyLayer(LIM)
    s._v, s._w = 0.4, 0.5
    s.reset()
    d = s.filter(0.6, 2.0, SafetyInputs(), DT)
    assert (d.v, d.w) == pytest.approx((0.05, 0.15), abs=1e-12)
    assert d.limited and d.stop is None


def test_a_chair_still_rolling_forward_is_stopped_by_an_obstacle_even_when_asked_to_reverse() -> None:
    """Module docstring: obstacle stops apply while the wanted *or current* speed is forward. At
    0.4 m/s the stopping distance is 0.37 m (hand value above), so an obstacle at 0.2 m stops a chair
    asked for -0.1 m/s; a chair at rest asked to stay at rest is not stopped by one at 0.05 m."""
    assert cruising(0.4).filter(-0.1, 0.0, SafetyInputs(sonar_distance_m=0.2), DT).stop is (
        StopReason.OBSTACLE_SONAR
    )
    assert SafetyLayer(LIM).filter(0.0, 0.0, SafetyInputs(sonar_distance_m=0.05), DT).stop is None


def test_an_infinite_distance_means_nothing_seen_and_a_pressed_deadman_drives() -> None:
    """SafetyInputs: a fused sonar range of +inf (no echo) and a map with no occupied cell ahead are no
    obstacle; ``deadman=True`` (pressed) and ``None`` (no joystick) let the chair drive at 0.4 m/s."""
    for inputs in (
        SafetyInputs(sonar_distance_m=math.inf, map_distance_m=math.inf),
        SafetyInputs(deadman=True),
        SafetyInputs(deadman=None),
    ):
        d = cruising(0.4).filter(0.4, 0.0, inputs, DT)
        assert d.stop is None and d.v == pytest.approx(0.4, abs=1e-12)


def test_reversing_and_turning_right_are_capped_from_below() -> None:
    """The caps are on |v| and |w| (SafetyLimits): at full reverse speed (-0.6 m/s) a -5 m/s command
    stays at -0.6 m/s; turning right at -2.0 rad/s, a -9 rad/s command stays at -2.0 rad/s."""
    s = SafetyLayer(LIM)
    s._v = -0.6
    assert s.filter(-5.0, 0.0, SafetyInputs(), DT).v == pytest.approx(-0.6, abs=1e-12)
    s = SafetyLayer(LIM)
    s._w = -2.0
    assert s.filter(0.0, -9.0, SafetyInputs(), DT).w == pytest.approx(-2.0, abs=1e-12)


def test_a_command_the_ramp_shortens_is_reported_as_limited_and_one_within_every_limit_is_not() -> None:
    """``limited`` (SafetyDecision): 0.32 m/s asked from 0.3 m/s is within the 0.05 m/s step: unchanged
    and not limited; 0.36 m/s is cut to 0.35 m/s, by 0.01 m/s: limited. Turning: 0.1 rad/s from rest
    is within the 0.15 rad/s step (not limited, no stop and no detail); 0.2 rad/s is cut to 0.15 rad/s,
    by 0.05 rad/s: limited."""
    s = cruising(0.3)
    d = s.filter(0.32, 0.0, SafetyInputs(), DT)
    assert (d.v, d.limited) == (0.32, False)
    s = cruising(0.3)
    d = s.filter(0.36, 0.0, SafetyInputs(), DT)
    assert d.v == pytest.approx(0.35, abs=1e-12) and d.limited
    d = SafetyLayer(LIM).filter(0.0, 0.1, SafetyInputs(), DT)
    assert (d.v, d.w, d.limited) == (0.0, 0.1, False)
    assert (d.stop, d.detail) == (None, "")  # SafetyDecision: no stop, no detail text
    d = SafetyLayer(LIM).filter(0.0, 0.2, SafetyInputs(), DT)  # 0.2 rad/s from rest: cut to 0.15
    assert d.w == pytest.approx(0.15, abs=1e-12) and d.limited


def test_the_wheel_ramp_shrinks_the_step_keeping_its_direction() -> None:
    """Spec defaults (max_wheel_accel 0.4 m/s^2, b = 0.58 m) at 10 Hz, from rest, asked for
    (0.6 m/s, 2.0 rad/s): the body limits give the step (0.05, 0.15); its faster wheel changes by
    0.05 + 0.15 x 0.29 = 0.0935 m/s, over 0.4 x 0.1 = 0.04, so the step is scaled by 0.04 / 0.0935:
    (0.021390, 0.064171)."""
    s = SafetyLayer(SafetyLimits(max_speed=0.6, max_yaw_rate=2.0), wheel_separation=0.58)
    d = s.filter(0.6, 2.0, SafetyInputs(), DT)
    k = 0.04 / 0.0935
    assert (d.v, d.w) == pytest.approx((0.05 * k, 0.15 * k), abs=1e-12)
    assert d.limited


def test_a_ramp_that_leaves_the_wheel_diamond_is_scaled_back_into_it() -> None:
    """From (0.6 m/s, 0) with a 3 rad/s^2 yaw ramp (and a wheel ramp that does not act), asked for
    (0.6, 2.0): the wheel diamond first gives (0.3, 1.0); the ramps move v to 0.6 - 0.05 = 0.55 and w
    to 0 + 0.3 = 0.3, a load of 0.55 / 0.6 + 0.3 / 2.0 = 1.06667 > 1, so both are divided by it:
    (0.515625, 0.28125)."""
    lim = SafetyLimits(max_speed=0.6, max_yaw_rate=2.0, max_accel=0.5, max_yaw_accel=3.0, max_wheel_accel=5.0)
    s = SafetyLayer(lim, wheel_separation=0.58)
    s._v = 0.6
    d = s.filter(0.6, 2.0, SafetyInputs(), DT)
    assert (d.v, d.w) == pytest.approx((0.515625, 0.28125), abs=1e-12)


def test_the_limits_name_the_platform_maximum_in_the_unit_of_each_cap() -> None:
    """Spec: max speed 1000 / 29 x 2 pi / 60 x 0.172 = 0.62110 m/s, max yaw rate 2 x 0.62110 / 0.58 =
    2.14172 rad/s; a faster cap is refused naming the key, the maximum to 3 decimals and the unit; a
    plain ``[safety]`` mapping is addressed as ``safety``."""
    spec = load_spec()
    with pytest.raises(ConfigError) as fast:
        SafetyLimits.from_spec(spec, {"max_speed": 0.7})
    assert str(fast.value) == (
        "safety.max_speed = 0.7: expected a finite number <= the platform maximum 0.621 m/s"
    )
    with pytest.raises(ConfigError) as spin:
        SafetyLimits.from_spec(spec, max_yaw_rate=3.0)
    assert str(spin.value) == (
        "safety.max_yaw_rate = 3.0: expected a finite number <= the platform maximum 2.142 rad/s"
    )
    assert SafetyLimits.from_spec(spec, {"max_speed": 0.5}).max_speed == 0.5


def test_an_obstacle_exactly_at_the_stopping_distance_does_not_stop_the_chair() -> None:
    """Module docstring: a stop needs an obstacle *closer* than the stopping distance. With margin
    0.25 m, reaction 0.5 s and braking 0.5 m/s^2, at 0.5 m/s it is 0.25 + 0.25 + 0.25 / 1.0 = 0.75 m
    (exact in binary): an obstacle at 0.75 m does not stop the chair, one at 0.74 m does."""
    lim = SafetyLimits(margin_m=0.25, reaction_time_s=0.5, brake_decel=0.5, max_accel=0.5)
    assert lim.stopping_distance(0.5) == 0.75
    s = SafetyLayer(lim)
    s._v = 0.5
    assert s.filter(0.5, 0.0, SafetyInputs(sonar_distance_m=0.75), DT).stop is None
    assert s.filter(0.5, 0.0, SafetyInputs(map_distance_m=0.74), DT).stop is StopReason.OBSTACLE_MAP
