"""Tests of differential-drive kinematics and encoder odometry."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from robchair.platform.kinematics import (
    DiffDrive,
    KinematicsError,
    Odometry,
    Pose2D,
    int32_delta,
    integrate_arc,
    wrap_angle,
    wrap_int32,
)
from robchair.platform.spec import load_spec

SPEC = load_spec()
DD = DiffDrive(SPEC)
R, B = 0.172, 0.58
COUNTS_PER_M = 116000 / (2 * math.pi * R)  # encoder on the motor: 1000 PPR x 4 x 29 per wheel turn


def test_max_speed_follows_from_1000_rpm_through_the_1_to_29_gearbox():
    expected = 1000 / 29 * 2 * math.pi / 60 * R  # 0.6211 m/s
    assert DD.max_speed == pytest.approx(expected, rel=1e-12)
    assert DD.max_speed == pytest.approx(0.6211, abs=1e-4)
    assert DD.max_yaw_rate == pytest.approx(2 * expected / B, rel=1e-12)


def test_motor_rpm_hand_computed():
    # 0.5 m/s straight: wheel 0.5 / 0.172 rad/s, x 29 through the gearbox, to RPM
    rpm = 0.5 / R * 29 * 60 / (2 * math.pi)
    left, right = DD.motor_rpm(0.5, 0.0)
    assert left == pytest.approx(rpm, rel=1e-12) and right == pytest.approx(rpm, rel=1e-12)
    # spin in place at 1 rad/s: wheels at -+ 0.29 m/s
    left, right = DD.motor_rpm(0.0, 1.0)
    assert left == pytest.approx(-0.29 / R * 29 * 60 / (2 * math.pi), rel=1e-12)
    assert right == pytest.approx(-left, rel=1e-12)
    assert DD.rpm_to_wheel(1000.0) == pytest.approx(1000 / 29 * 2 * math.pi / 60, rel=1e-12)


speeds = st.floats(-2.0, 2.0, allow_nan=False)


@given(v=speeds, w=speeds)
def test_twist_to_wheels_to_rpm_and_back_is_identity(v, w):
    v2, w2 = DD.twist_from_rpm(*DD.motor_rpm(v, w))
    assert v2 == pytest.approx(v, abs=1e-12) and w2 == pytest.approx(w, abs=1e-12)


@given(v=speeds, w=speeds)
def test_limit_keeps_the_curve_and_respects_max_rpm(v, w):
    lv, lw = DD.limit(v, w)
    left, right = DD.motor_rpm(lv, lw)
    assert max(abs(left), abs(right)) <= 1000.0
    assert lv * w == pytest.approx(lw * v, abs=1e-12)  # same ratio w / v
    if max(abs(x) for x in DD.motor_rpm(v, w)) <= 1000.0:
        assert (lv, lw) == (v, w)


@pytest.mark.parametrize("v", [0.62, 0.75, 2.0])
def test_limit_at_full_speed_never_exceeds_1000_rpm_at_any_of_4001_turn_rates(v):
    """The cap is Table 9.1's 1000 RPM exactly: the Roboteq driver refuses anything above it."""
    for w in [-2.14 + 4.28 * i / 4000 for i in range(4001)]:
        left, right = DD.motor_rpm(*DD.limit(v, w))
        assert max(abs(left), abs(right)) <= 1000.0, (v, w, left, right)


def test_non_finite_twist_is_refused():
    with pytest.raises(KinematicsError, match="v = nan"):
        DD.wheel_speeds(float("nan"), 0.0)


@given(st.integers(-(2**40), 2**40), st.integers(-(2**31) + 1, 2**31 - 1))
def test_int32_delta_recovers_any_change_below_2_31_across_wraps(start, change):
    a = wrap_int32(start)
    b = wrap_int32(start + change)
    assert -(2**31) <= a < 2**31 and -(2**31) <= b < 2**31
    assert int32_delta(b, a) == change


def _drive(odo: Odometry, v: float, w: float, duration: float, steps: int, start=(0, 0)) -> Pose2D:
    """Feed the odometry the rounded cumulative counts of a constant twist, as a controller would."""
    cl = cr = 0.0
    odo.update(wrap_int32(start[0]), wrap_int32(start[1]))
    pose = odo.pose
    for _ in range(steps):
        dl, dr = DD.counts_for_motion(v, w, duration / steps)
        cl += dl
        cr += dr
        pose = odo.update(wrap_int32(start[0] + round(cl)), wrap_int32(start[1] + round(cr)))
    return pose


def _exact_pose(v: float, w: float, t: float) -> Pose2D:
    if w == 0:
        return Pose2D(v * t, 0.0, 0.0)
    return Pose2D(v / w * math.sin(w * t), v / w * (1 - math.cos(w * t)), wrap_angle(w * t))


# one count is 9.3e-6 m at the wheel; rounding to counts at every step bounds the error well below 1e-4
@pytest.mark.parametrize(
    ("v", "w", "duration"),
    [(0.5, 0.0, 4.0), (0.4, 0.3, 5.0), (0.0, 0.8, 3.0), (-0.3, -0.5, 4.0), (0.6, 2.0, 2.0)],
    ids=["straight", "left-arc", "spin-in-place", "reverse-right-arc", "tight-arc"],
)
def test_twist_to_counts_to_odometry_round_trip(v, w, duration):
    pose = _drive(Odometry(SPEC), v, w, duration, steps=50)
    exact = _exact_pose(v, w, duration)
    assert pose.x == pytest.approx(exact.x, abs=1e-4)
    assert pose.y == pytest.approx(exact.y, abs=1e-4)
    assert pose.theta == pytest.approx(exact.theta, abs=1e-4)


def test_arc_integration_is_exact_for_one_big_step():
    # a quarter circle of radius 1 m in a single update: exact arc integration needs no small steps
    odo = Odometry(SPEC)
    odo.update(0, 0)
    dl = (1 - B / 2) * math.pi / 2 * COUNTS_PER_M
    dr = (1 + B / 2) * math.pi / 2 * COUNTS_PER_M
    pose = odo.update(round(dl), round(dr))
    assert pose.x == pytest.approx(1.0, abs=2e-5)
    assert pose.y == pytest.approx(1.0, abs=2e-5)
    assert pose.theta == pytest.approx(math.pi / 2, abs=1e-4)


@pytest.mark.parametrize("start", [(2**31 - 1000, 2**31 - 50), (-(2**31) + 10, -(2**31) + 300)])
def test_counter_wrap_around_gives_the_same_pose_as_unwrapped_counters(start):
    # driving forwards from near +2^31 wraps to negative counts; reversing near -2^31 wraps to positive
    sign = 1 if start[0] > 0 else -1
    wrapped = _drive(Odometry(SPEC), sign * 0.5, 0.2, 3.0, steps=30, start=start)
    plain = _drive(Odometry(SPEC), sign * 0.5, 0.2, 3.0, steps=30)
    assert (wrapped.x, wrapped.y, wrapped.theta) == pytest.approx((plain.x, plain.y, plain.theta), abs=1e-12)
    assert abs(wrapped.x) > 1.0


def test_first_update_only_latches_and_reset_returns_to_the_given_pose():
    odo = Odometry(SPEC, pose=Pose2D(1.0, 2.0, 0.5))
    assert odo.update(123456, -98765) == Pose2D(1.0, 2.0, 0.5)
    odo.update(123456 + 1000, -98765 + 1000)
    assert odo.pose.x > 1.0
    odo.reset()
    assert odo.update(5, 5) == Pose2D()


def test_non_integer_counts_are_refused():
    with pytest.raises(KinematicsError, match=r"counts_left = 1\.5"):
        Odometry(SPEC).update(1.5, 2)  # type: ignore[arg-type]


def test_encoder_on_wheel_changes_the_count_scale():
    import copy
    import tomllib

    from robchair.platform.spec import DEFAULT_SPEC_PATH, spec_from_dict

    with DEFAULT_SPEC_PATH.open("rb") as fh:
        d = tomllib.load(fh)
    d = copy.deepcopy(d)
    d["drive"]["encoder_on"] = "wheel"
    dd = DiffDrive(spec_from_dict(d))
    assert dd.wheel_angle_to_counts(2 * math.pi) == pytest.approx(4000)
    assert DD.wheel_angle_to_counts(2 * math.pi) == pytest.approx(116000)


def test_a_boolean_is_not_an_encoder_count():
    """Odometry.update refuses a count that is not an integer (its docstring); True and False are not
    counter readings, though Python's bool is an int subclass."""
    with pytest.raises(KinematicsError, match=r"counts_left = True: expected an integer encoder count"):
        Odometry(SPEC).update(True, 0)
    with pytest.raises(KinematicsError, match=r"counts_right = False"):
        Odometry(SPEC).update(0, False)


def test_an_arc_of_exactly_two_radians_lands_on_its_circle():
    """Hand geometry: with b = 0.5 m, the right wheel driving 1 m and the left 0 m, base_link moves
    d = 0.5 m while turning dtheta = 2 rad, on a circle of radius d / dtheta = 0.25 m about (0, 0.25):
    it ends at (0.25 sin 2, 0.25 (1 - cos 2)) = (0.22732, 0.35404) heading 2 rad (the chord formula's
    half angle is exactly 1 rad here)."""
    pose = integrate_arc(Pose2D(), 0.0, 1.0, 0.5)
    assert pose.x == pytest.approx(0.25 * math.sin(2.0), abs=1e-12)
    assert pose.y == pytest.approx(0.25 * (1.0 - math.cos(2.0)), abs=1e-12)
    assert pose.theta == pytest.approx(2.0, abs=1e-12)
