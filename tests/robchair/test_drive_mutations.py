"""Drive limits and route completion against hand values from the spec (assets/robchair.toml)."""

from __future__ import annotations

import math

import pytest

from robchair.platform.kinematics import DiffDrive, Pose2D
from robchair.platform.safety import SafetyInputs, SafetyLayer, SafetyLimits
from robchair.platform.spec import load_spec
from robchair.route import PurePursuit, Route
from robchair.sources import Observation

# spec: wheel radius 0.172 m, gear 29:1, max_motor_rpm 1000, wheel separation 0.58 m
R, GEAR, MAX_RPM, B = 0.172, 29.0, 1000.0, 0.58
RPM_PER_M_S = GEAR * 60.0 / (2.0 * math.pi * R)  # motor RPM per m/s of a wheel: 1610.07
V_MAX = MAX_RPM / RPM_PER_M_S  # 0.62109 m/s


@pytest.fixture(scope="module")
def drive() -> DiffDrive:
    return DiffDrive(load_spec())


@pytest.mark.parametrize(
    ("v", "w", "peak_left"),
    [
        (1.0, 0.0, True),  # 1610 RPM both wheels
        (0.7, 0.3, False),  # right wheel 0.787 m/s = 1267 RPM is the peak
        (-2.0, 1.0, True),
        (0.0, 5.0, False),  # turning on the spot: 1.45 m/s = 2335 RPM per wheel
    ],
)
def test_limit_scales_a_too_fast_twist_to_exactly_the_motor_cap(drive, v, w, peak_left) -> None:
    """Hand values: the wheel speeds are v -+ w b / 2 (b = 0.58 m), in motor RPM x 1610.07 (spec: 29 x 60 /
    (2 pi 0.172 m)); the limited twist puts the faster wheel at the spec's 1000 RPM, not below it, and
    keeps w / v (the same curve)."""
    lv, lw = drive.limit(v, w)
    left = (lv - lw * B / 2) * RPM_PER_M_S
    right = (lv + lw * B / 2) * RPM_PER_M_S
    peak = abs(left) if peak_left else abs(right)
    assert peak == pytest.approx(MAX_RPM, abs=1e-6)
    assert max(abs(left), abs(right)) == pytest.approx(MAX_RPM, abs=1e-6)
    if v:
        assert lw / lv == pytest.approx(w / v)
    else:
        assert lv == 0.0


def test_limit_never_returns_a_twist_above_the_motor_cap(drive) -> None:
    """Spec: ``max_motor_rpm = 1000``; the limited twist, converted back, must not exceed it at all (the
    Roboteq driver refuses anything above ``max_rpm``)."""
    worst = 0.0
    for i in range(200):
        v, w = 0.3 + 0.01 * i, 0.05 * (i % 40) - 1.0
        left, right = drive.motor_rpm(*drive.limit(v, w))
        worst = max(worst, abs(left), abs(right))
    assert worst <= MAX_RPM


def test_a_twist_within_the_cap_is_left_alone(drive) -> None:
    """0.6 m/s straight is 0.6 x 1610.07 = 966 RPM, under 1000: unchanged."""
    assert drive.limit(0.6, 0.0) == (0.6, 0.0)
    assert drive.max_speed == pytest.approx(V_MAX, rel=1e-9)


def test_the_safety_layer_lets_the_platform_maximum_through_once_ramped_up() -> None:
    """A 1 m/s command is capped at the platform's maximum (spec: 1000 RPM / 29 x 2 pi x 0.172 m / 60 =
    0.62110 m/s, the limit ``SafetyLimits.from_spec`` takes) and reached, not held below it, once the
    0.5 m/s^2 ramp had time (2 s at 10 Hz)."""
    spec = load_spec()
    layer = SafetyLayer(SafetyLimits.from_spec(spec))
    v = 0.0
    for k in range(30):
        d = layer.filter(1.0, 0.0, SafetyInputs(stamp_ns=k * 100_000_000), 0.1)
        assert d.v <= V_MAX + 1e-12
        v = d.v
    assert v == pytest.approx(V_MAX, abs=1e-9)


def _drive_route(route: Route, drive: DiffDrive, dt: float = 0.1, max_s: float = 120.0):
    """Follow ``route`` with a unicycle integrated by hand; returns (done time s, distance m, pose)."""
    pp = PurePursuit(route, drive)
    x = y = th = 0.0
    travelled = 0.0
    for k in range(round(max_s / dt)):
        cmd = pp.command(Observation(round(k * dt * 1e9), Pose2D(x, y, th), None, (), None))
        if cmd.done:
            return k * dt, travelled, (x, y)
        x += cmd.v * dt * math.cos(th + cmd.w * dt / 2)
        y += cmd.v * dt * math.sin(th + cmd.w * dt / 2)
        th += cmd.w * dt
        travelled += abs(cmd.v) * dt
    raise AssertionError(f"route not completed in {max_s} s; at ({x:.2f}, {y:.2f}) after {travelled:.2f} m")


def test_a_route_that_passes_its_goal_early_is_completed_only_at_its_end(drive) -> None:
    """The route (0, 0) -> (2, 0) -> (2, 1) -> (1, 1) -> (1, 0.08) is 2 + 1 + 1 + 0.92 = 4.92 m long (hand
    value); its first leg passes 0.08 m from the goal, inside goal_tolerance_m = 0.1 m. Only the progress
    guard (done within one look-ahead, 0.6 m, of the end) keeps it from reporting completion there,
    after 1 m: it must drive at least 4.92 - 0.6 - 0.1 m first and stop within 0.1 m of (1, 0.08)."""
    route = Route(((0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (1.0, 1.0), (1.0, 0.08)), speed=0.4)
    _, travelled, (x, y) = _drive_route(route, drive)
    assert travelled >= 4.92 - 0.6 - 0.1
    assert math.hypot(x - 1.0, y - 0.08) <= 0.1 + 1e-9


def test_a_closed_route_is_completed_only_after_driving_round_it(drive) -> None:
    """A 2 m square that ends where it starts is 8 m long (hand value); the chair starts on its goal and
    must drive round it (at least 8 - 0.6 - 0.1 m: look-ahead and goal tolerance) before it is done."""
    square = Route(((0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.0, 0.0)), speed=0.4)
    first = PurePursuit(square, drive).command(Observation(0, Pose2D(0.0, 0.0, 0.0), None, (), None))
    assert not first.done and first.v > 0.0
    _, travelled, (x, y) = _drive_route(square, drive)
    assert travelled >= 8.0 - 0.6 - 0.1
    assert math.hypot(x, y) <= 0.1 + 1e-9


def test_an_open_route_is_completed_within_the_goal_tolerance(drive) -> None:
    """A 3 m straight route: done within goal_tolerance_m = 0.1 m of (3, 0), after about 3 m."""
    _, travelled, (x, y) = _drive_route(Route(((0.0, 0.0), (3.0, 0.0)), speed=0.4), drive)
    assert math.hypot(x - 3.0, y) <= 0.1 + 1e-9
    assert 2.9 - 1e-9 <= travelled <= 3.1


@pytest.mark.parametrize(
    ("theta", "wrapped"),
    [
        (-math.pi, math.pi),
        (3.0 * math.pi, math.pi),
        (4.0, 4.0 - 2.0 * math.pi),
        (-2.5 * math.pi, -0.5 * math.pi),
    ],
)
def test_angles_wrap_to_minus_pi_exclusive_to_pi_inclusive(theta, wrapped) -> None:
    """REP-103 yaw in (-pi, pi]: -pi is pi, 3 pi is pi, 4 rad is 4 - 2 pi, -2.5 pi is -0.5 pi."""
    from robchair.platform.kinematics import wrap_angle

    assert wrap_angle(theta) == pytest.approx(wrapped, abs=1e-12)


@pytest.mark.parametrize("wheels", [(math.nan, 0.0), (0.0, math.inf)])
def test_a_non_finite_wheel_speed_is_refused_by_twist(drive, wheels) -> None:
    """Either wheel speed not finite: a KinematicsError naming it, not a NaN twist."""
    from robchair.platform.kinematics import KinematicsError

    name = "wl" if math.isnan(wheels[0]) else "wr"
    with pytest.raises(KinematicsError, match=name):
        drive.twist(*wheels)


def test_odometry_reset_puts_the_pose_zeroes_the_distance_and_relatches_the_counters() -> None:
    """Spec: 1000 PPR x 4 (quadrature) x 29 (gear) = 116 000 counts per wheel revolution on the motor
    shaft; both wheels one revolution forward is 2 pi x 0.172 m = 1.0807 m. After a reset to (1, 2, 0.5)
    the distance is 0 and the next reading only latches the counters (the pose stays)."""
    from robchair.platform.kinematics import Odometry

    odo = Odometry(load_spec())
    odo.update(0, 0)
    odo.update(116_000, 116_000)
    assert odo.distance == pytest.approx(2 * math.pi * R, rel=1e-9)
    assert (odo.pose.x, odo.pose.y) == pytest.approx((2 * math.pi * R, 0.0), abs=1e-9)
    odo.reset(Pose2D(1.0, 2.0, 0.5))
    assert odo.distance == 0.0
    assert odo.update(500_000, -7) == Pose2D(1.0, 2.0, 0.5)
    odo.reset()
    assert odo.pose == Pose2D() and odo.distance == 0.0


def test_odometry_adds_up_the_distance_of_every_reading_and_uses_its_own_spec() -> None:
    """Two readings of one wheel revolution each (116 000 counts, see above) are 2 x 2 pi x 0.172 m =
    2.1614 m from a distance of 0; with a spec whose wheel radius is 0.2 m, one revolution is 2 pi x 0.2 m
    = 1.2566 m (the odometry's own spec, not the default one)."""
    import dataclasses

    from robchair.platform.kinematics import Odometry

    spec = load_spec()
    odo = Odometry(spec)
    assert odo.distance == 0.0
    for counts in (0, 116_000, 232_000):
        odo.update(counts, counts)
    assert odo.distance == pytest.approx(2 * 2 * math.pi * R, rel=1e-9)
    big = Odometry(dataclasses.replace(spec, drive=dataclasses.replace(spec.drive, wheel_radius=0.2)))
    big.update(0, 0)
    big.update(116_000, 116_000)
    assert big.distance == pytest.approx(2 * math.pi * 0.2, rel=1e-9)


def test_odometry_and_wheel_speeds_name_the_bad_input() -> None:
    """A count that is not an integer names its side; a non-finite w is refused by wheel_speeds."""
    from robchair.platform.kinematics import KinematicsError, Odometry

    with pytest.raises(KinematicsError, match="counts_right"):
        Odometry(load_spec()).update(0, 1.5)  # type: ignore[arg-type]
    with pytest.raises(KinematicsError, match="w = nan"):
        DiffDrive(load_spec()).wheel_speeds(0.0, math.nan)


def test_a_drive_without_a_spec_uses_the_platform_spec() -> None:
    """DiffDrive() loads assets/robchair.toml: the same 0.62110 m/s maximum as computed above."""
    assert DiffDrive().max_speed == pytest.approx(V_MAX, rel=1e-9)
