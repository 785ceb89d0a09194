"""The safety layer: every stop reason, the limits, the stopping distance, the stop log."""

from __future__ import annotations

import logging
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from robchair.platform.errors import ConfigError
from robchair.platform.kinematics import DiffDrive
from robchair.platform.safety import SafetyInputs, SafetyLayer, SafetyLimits, StopReason
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
