"""Pure pursuit's commands against hand computations (Coulter 1992, as robchair.route documents it).

Hand values use the spec (wheel radius 0.172 m, separation 0.58 m, 1000 RPM through 29:1: a maximum
wheel speed of 0.62110 m/s, so a maximum yaw rate of 2 x 0.62110 / 0.58 = 2.14172 rad/s), the route's
speed 0.4 m/s, look-ahead 0.6 m, goal tolerance 0.1 m and the follower's 0.4 m/s^2 stopping deceleration.
"""

from __future__ import annotations

import math

import pytest

from robchair.platform.kinematics import DiffDrive, Pose2D
from robchair.platform.spec import load_spec
from robchair.route import PurePursuit, Route
from robchair.sources import Observation

MAX_YAW_RATE = 2 * 1000.0 / (29.0 * 60.0 / (2 * math.pi * 0.172)) / 0.58  # 2.14172 rad/s


def _command(route: Route, x: float, y: float, theta: float, pp: PurePursuit | None = None):
    pp = pp if pp is not None else PurePursuit(route, DiffDrive(load_spec()))
    return pp.command(Observation(0, Pose2D(x, y, theta), None, (), None)), pp


def test_a_goal_point_behind_and_to_the_right_turns_the_chair_in_place_clockwise() -> None:
    """Route (0, 0) -> (-2, 0), chair at the origin heading -1 rad: the goal point (-0.6, 0) is at
    x_r = -0.6 cos(-1) = -0.324 (behind), y_r = 0.6 sin(-1) = -0.505 (right), so the chair turns in
    place at half the maximum yaw rate, clockwise: (0, -1.07086)."""
    cmd, _ = _command(Route(((0.0, 0.0), (-2.0, 0.0)), speed=0.4), 0.0, 0.0, -1.0)
    assert (cmd.v, cmd.w) == pytest.approx((0.0, -0.5 * MAX_YAW_RATE), abs=1e-9)
    assert not cmd.done


def test_a_goal_point_straight_behind_turns_counter_clockwise() -> None:
    """Route (0, 0) -> (-2, 0), heading +x: the goal point is straight behind (y_r = 0); the turn is then
    counter-clockwise (positive, REP-103) at half the maximum yaw rate."""
    cmd, _ = _command(Route(((0.0, 0.0), (-2.0, 0.0)), speed=0.4), 0.0, 0.0, 0.0)
    assert (cmd.v, cmd.w) == pytest.approx((0.0, 0.5 * MAX_YAW_RATE), abs=1e-9)


def test_off_the_path_the_curvature_slows_and_turns_the_chair_toward_it() -> None:
    """Route (0, 0) -> (10, 0), chair at (0, -0.3) heading +x: the goal point (0.6, 0) is at x_r = 0.6,
    y_r = 0.3, l^2 = 0.45, so k = 2 y_r / l^2 = 1.33333; v = 0.4 / (1 + 0.6 k) = 0.22222 m/s (the stopping
    bound sqrt(2 x 0.4 x 10.0045) = 2.83 m/s does not act) and w = v k = 0.29630 rad/s."""
    cmd, _ = _command(Route(((0.0, 0.0), (10.0, 0.0)), speed=0.4), 0.0, -0.3, 0.0)
    assert (cmd.v, cmd.w) == pytest.approx((0.4 / 1.8, 0.4 / 1.8 * 4.0 / 3.0), abs=1e-9)


def test_on_the_path_the_chair_drives_at_the_route_speed() -> None:
    """Route (0, 0) -> (10, 0), chair at the origin heading +x: k = 0, so (0.4, 0)."""
    cmd, _ = _command(Route(((0.0, 0.0), (10.0, 0.0)), speed=0.4), 0.0, 0.0, 0.0)
    assert (cmd.v, cmd.w) == pytest.approx((0.4, 0.0), abs=1e-12)


def test_near_the_last_waypoint_the_speed_is_the_stopping_bound() -> None:
    """Route (0, 0) -> (1, 0), chair at (0.85, 0): 0.15 m to go (more than the 0.1 m tolerance), so
    v = sqrt(2 x 0.4 x 0.15) = 0.34641 m/s, under the route's 0.4 m/s."""
    cmd, _ = _command(Route(((0.0, 0.0), (1.0, 0.0)), speed=0.4), 0.85, 0.0, 0.0)
    assert (cmd.v, cmd.w) == pytest.approx((math.sqrt(0.12), 0.0), abs=1e-9)
    assert not cmd.done


def test_within_the_tolerance_of_the_end_the_route_is_done_and_stays_done() -> None:
    """Route (0, 0) -> (1, 0), chair at (0.95, 0): 0.05 m from the goal, progress 0.95 m past
    1 - 0.6 m: done, (0, 0). Asked again from anywhere (the origin), it stays done with zero speed."""
    route = Route(((0.0, 0.0), (1.0, 0.0)), speed=0.4)
    cmd, pp = _command(route, 0.95, 0.0, 0.0)
    assert cmd.done and (cmd.v, cmd.w) == (0.0, 0.0) and pp.done is True
    again, _ = _command(route, 0.0, 0.0, 0.0, pp)
    assert again.done and (again.v, again.w) == (0.0, 0.0)
