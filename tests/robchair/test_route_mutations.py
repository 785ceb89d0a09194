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


def test_a_chair_beside_the_end_slows_for_its_distance_to_the_last_waypoint() -> None:
    """Route (0, 0) -> (1, 0), chair at (0.98, 0.12) facing the last waypoint: progress 0.98 m leaves
    0.02 m of path but the waypoint is hypot(0.02, 0.12) = 0.12166 m away (over the 0.1 m tolerance,
    not done). The goal point is straight ahead (k = 0), so v = sqrt(2 x 0.4 x 0.12166) = 0.31198 m/s
    (the larger of the two distances decides, not the 0.02 m of path)."""
    theta = math.atan2(-0.12, 0.02)
    cmd, _ = _command(Route(((0.0, 0.0), (1.0, 0.0)), speed=0.4), 0.98, 0.12, theta)
    assert not cmd.done
    assert (cmd.v, cmd.w) == pytest.approx((math.sqrt(0.8 * math.hypot(0.02, 0.12)), 0.0), abs=1e-9)


def test_the_goal_point_follows_the_path_round_a_corner() -> None:
    """Route (0, 0) -> (1, 0) -> (1, 2), chair at (0.7, 0) heading +x: progress 0.7 m, the goal point
    0.6 m further is 0.3 m up the second segment, (1, 0.3): x_r = 0.3, y_r = 0.3, l^2 = 0.18,
    k = 0.6 / 0.18 = 3.33333, v = 0.4 / (1 + 0.6 k) = 0.13333 m/s, w = v k = 0.44444 rad/s (the stopping
    bound sqrt(2 x 0.4 x 2.3) = 1.36 m/s does not act)."""
    cmd, pp = _command(Route(((0.0, 0.0), (1.0, 0.0), (1.0, 2.0)), speed=0.4), 0.7, 0.0, 0.0)
    assert (cmd.v, cmd.w) == pytest.approx((0.4 / 3.0, 0.4 / 3.0 * 10.0 / 3.0), abs=1e-9)
    assert pp.length == pytest.approx(3.0, abs=1e-12)


def test_the_cross_track_error_is_the_distance_to_the_path() -> None:
    """Route (0, 0) -> (10, 0), no progress yet (the search window is the first 2 x 0.6 = 1.2 m): a
    chair at (0.5, 0.3) is 0.3 m from the path, one at (2, 0.3) is hypot(0.8, 0.3) = 0.85440 m from the
    window's end (1.2, 0). On a corner route (0, 0) -> (1, 0) -> (1, 2) with progress 0.9 m a chair at
    (1.4, 1.0) is 0.4 m from the second segment."""
    pp = PurePursuit(Route(((0.0, 0.0), (10.0, 0.0))), DiffDrive(load_spec()))
    assert pp.cross_track_error(Pose2D(0.5, 0.3, 0.0)) == pytest.approx(0.3, abs=1e-12)
    assert pp.cross_track_error(Pose2D(2.0, 0.3, 0.0)) == pytest.approx(math.hypot(0.8, 0.3), abs=1e-12)
    corner = PurePursuit(Route(((0.0, 0.0), (1.0, 0.0), (1.0, 2.0))), DiffDrive(load_spec()))
    corner._s = 0.9  # progress near the corner: the second segment is within the search window
    assert corner.cross_track_error(Pose2D(1.4, 1.0, 0.0)) == pytest.approx(0.4, abs=1e-12)


def test_a_repeated_waypoint_is_a_zero_length_segment_the_follower_steps_over() -> None:
    """Route (0, 0) -> (1, 0) -> (1, 0) -> (3, 0) (the second corner repeated): length 3 m; a chair on
    the path at (1.2, 0) heading +x drives straight at the route speed (0.4, 0): the zero-length
    segment neither divides by zero nor pulls the goal point back."""
    cmd, pp = _command(Route(((0.0, 0.0), (1.0, 0.0), (1.0, 0.0), (3.0, 0.0)), speed=0.4), 1.2, 0.0, 0.0)
    assert pp.length == pytest.approx(3.0, abs=1e-12)
    assert (cmd.v, cmd.w) == pytest.approx((0.4, 0.0), abs=1e-12)
    assert pp._s == pytest.approx(1.2, abs=1e-12)


def test_a_route_file_loads_with_its_values(tmp_path) -> None:
    """A route file in the documented format (the one of examples/routes/short_turn.toml): waypoints
    (0, 0), (1.5, 0), (2.2, 0.5), speed 0.3 m/s, look-ahead 0.5 m, goal tolerance 0.1 m; path length
    1.5 + hypot(0.7, 0.5) = 2.36023 m."""
    path = tmp_path / "short_turn.toml"
    path.write_text(
        "waypoints = [[0.0, 0.0], [1.5, 0.0], [2.2, 0.5]]\n"
        "speed = 0.3\nlookahead_m = 0.5\ngoal_tolerance_m = 0.1\n"
    )
    route = Route.load(path)
    assert route == Route(
        ((0.0, 0.0), (1.5, 0.0), (2.2, 0.5)), speed=0.3, lookahead_m=0.5, goal_tolerance_m=0.1
    )
    pp = PurePursuit(route, DiffDrive(load_spec()))
    assert pp.length == pytest.approx(1.5 + math.hypot(0.7, 0.5), abs=1e-12)
    assert pp.search_window_m == pytest.approx(1.0, abs=1e-12)  # two look-aheads (class docstring)


def test_a_route_table_gets_the_documented_defaults_and_its_own_values() -> None:
    """The route file format (Route docstring): speed 0.3 m/s, look-ahead 0.6 m and goal tolerance
    0.1 m when not given; given values are kept."""
    assert Route.from_dict({"waypoints": [[0, 0], [1, 0]]}, where="route") == Route(
        ((0.0, 0.0), (1.0, 0.0)), speed=0.3, lookahead_m=0.6, goal_tolerance_m=0.1
    )
    r = Route.from_dict(
        {"waypoints": [[0, 0], [1, 0]], "speed": 0.5, "lookahead_m": 0.7, "goal_tolerance_m": 0.2},
        where="route",
    )
    assert (r.speed, r.lookahead_m, r.goal_tolerance_m) == (0.5, 0.7, 0.2)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"waypoints": [[0, 0]]}, "route.waypoints = [[0, 0]]: expected a list of at least 2"),
        ({"waypoints": [[0, 0], [1, 0]], "speedy": 1}, "route.speedy: unknown key"),
        ({"waypoints": [[0, 0], [1, 0]], "speed": 0.0}, "route.speed = 0.0: expected a finite number > 0"),
        ({"waypoints": [[0, 0], [1, 0]], "lookahead_m": 0.0}, "route.lookahead_m = 0.0: expected"),
        ({"waypoints": [[0, 0], [1, 0]], "goal_tolerance_m": 0.0}, "route.goal_tolerance_m = 0.0: expected"),
    ],
)
def test_a_bad_route_table_is_refused_naming_the_key(table: dict, message: str) -> None:
    """The route file rules (Route docstring): at least two waypoints, positive numbers, known keys;
    the error names ``route.<key>`` in the config dialect."""
    from robchair.platform.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        Route.from_dict(table, where="route")
    assert message in str(err.value)


@pytest.mark.parametrize("kwargs", [{"speed": 0.0}, {"lookahead_m": -1.0}, {"goal_tolerance_m": 0.0}])
def test_a_route_built_in_code_is_checked_like_a_file(kwargs: dict) -> None:
    """A Route made directly is held to the same rules: one waypoint or a non-positive number is refused;
    small positive numbers (0.05) are accepted."""
    from robchair.platform.errors import ConfigError

    with pytest.raises(ConfigError):
        Route(((0.0, 0.0), (1.0, 0.0)), **kwargs)
    with pytest.raises(ConfigError):
        Route(((0.0, 0.0),))
    Route(((0.0, 0.0), (1.0, 0.0)), speed=0.05, lookahead_m=0.05, goal_tolerance_m=0.05)


def test_a_route_built_in_code_names_its_bad_key_and_value_under_route() -> None:
    """The config dialect (robchair.platform.config, Route docstring): ``route.<key> = <value>: expected
    <what>``, the value shown as TOML lists: one waypoint (0, 0) is ``[[0.0, 0.0]]``, and a zero speed
    is ``route.speed = 0.0``."""
    from robchair.platform.errors import ConfigError

    with pytest.raises(ConfigError) as one:
        Route(((0.0, 0.0),))
    assert str(one.value).startswith("route.waypoints = [[0.0, 0.0]]: expected a list of at least 2")
    with pytest.raises(ConfigError) as slow:
        Route(((0.0, 0.0), (1.0, 0.0)), speed=0.0)
    assert str(slow.value).startswith("route.speed = 0.0: expected a finite number > 0")


def test_a_bad_value_in_a_route_file_is_refused_naming_the_file_and_line(tmp_path) -> None:
    """Route.load's documented message ``<file>:<line>: <key> = <value>: expected <what>``: a file whose
    second line is ``speed = -1.0`` is refused as ``<file>:2: speed = -1.0: expected ...``; a file that
    is not there as ``<file>: route file does not exist``."""
    from robchair.platform.errors import ConfigError

    path = tmp_path / "bad.toml"
    path.write_text("waypoints = [[0.0, 0.0], [1.0, 0.0]]\nspeed = -1.0\n")
    with pytest.raises(ConfigError) as err:
        Route.load(path)
    assert str(err.value).startswith(f"{path}:2: speed = -1.0: expected a finite number > 0")
    missing = tmp_path / "none.toml"
    with pytest.raises(ConfigError) as gone:
        Route.load(missing)
    assert str(gone.value) == f"{missing}: route file does not exist"


def test_a_new_follower_is_not_done_and_starts_at_the_beginning_of_the_path() -> None:
    """PurePursuit's documented state: ``done`` is False until the last waypoint is reached, and the
    progress along the path starts at 0 m."""
    pp = PurePursuit(Route(((0.0, 0.0), (3.0, 0.0))), DiffDrive(load_spec()))
    assert pp.done is False
    assert pp._s == 0.0


CORNER = ((0.0, 0.0), (1.0, 0.0), (1.0, 2.0))


def _cross_track(waypoints, x: float, y: float, progress: float = 0.0) -> float:
    pp = PurePursuit(Route(waypoints), DiffDrive(load_spec()))
    pp._s = progress
    return pp.cross_track_error(Pose2D(x, y, 0.0))


@pytest.mark.parametrize(
    ("waypoints", "x", "y", "progress", "expected"),
    [
        # behind the start of (0, 0) -> (10, 0): the nearest path point is the start itself
        (((0.0, 0.0), (10.0, 0.0)), -0.5, 0.3, 0.0, math.hypot(0.5, 0.3)),
        # a route that ends on a repeated waypoint: past its end, the nearest point is the end (1, 0)
        (((0.0, 0.0), (1.0, 0.0), (1.0, 0.0)), 1.2, 0.3, 0.0, math.hypot(0.2, 0.3)),
        # beside the first leg of the corner route, 0.5 m right of (0.9, 0); the corner (1, 0) is farther
        (CORNER, 0.9, -0.5, 0.0, 0.5),
        # past the end of the first leg, at (1.5, 0.1): the second leg's (1, 0.1) is 0.5 m away, nearer than
        # the corner (hypot(0.5, 0.1) = 0.50990 m); the first leg does not extend beyond its end
        (CORNER, 1.5, 0.1, 0.0, 0.5),
        # progress 1.2 m (0.2 m up the second leg): at (1.5, 0.3) the nearest point is (1, 0.3), not a point
        # on the first leg's extension beyond the corner
        (CORNER, 1.5, 0.3, 1.2, 0.5),
        # progress 0.5 m on (0, 0) -> (10, 0) and the chair back at (0.2, 0): progress does not go back,
        # the distance is to (0.5, 0)
        (((0.0, 0.0), (10.0, 0.0)), 0.2, 0.0, 0.5, 0.3),
    ],
    ids=["behind-start", "repeated-end", "beside-first-leg", "past-first-leg", "past-corner", "no-return"],
)
def test_the_cross_track_error_is_measured_to_the_nearest_point_of_the_path_ahead(
    waypoints, x: float, y: float, progress: float, expected: float
) -> None:
    """PurePursuit's documented projection (class docstring): the closest path point within the window
    [progress, progress + 2 look-aheads] (1.2 m here), the path being the polyline itself (segments end
    at their waypoints); each expected distance is a hand computation given beside its case."""
    assert _cross_track(waypoints, x, y, progress) == pytest.approx(expected, abs=1e-9)


def test_a_chair_exactly_at_the_goal_tolerance_is_done() -> None:
    """Done *within* ``goal_tolerance_m`` (class docstring), the bound included: route (0, 0) -> (2, 0)
    with a 0.125 m tolerance (exact in binary), chair at (1.875, 0): 0.125 m from the goal and progress
    1.875 m = 2 - 0.125 m (the follower's progress already at 1 m, so the search window reaches it)."""
    route = Route(((0.0, 0.0), (2.0, 0.0)), speed=0.4, goal_tolerance_m=0.125)
    pp = PurePursuit(route, DiffDrive(load_spec()))
    pp._s = 1.0
    cmd, _ = _command(route, 1.875, 0.0, 0.0, pp)
    assert cmd.done and (cmd.v, cmd.w) == (0.0, 0.0) and pp.done is True


def test_a_multi_leg_route_is_done_at_its_last_waypoint_not_its_second() -> None:
    """Corner route (0, 0) -> (1, 0) -> (1, 2) (length 3 m): a chair at its second waypoint (1, 0) with
    progress 1 m is 2 m from the last one, so it is not done and drives on; one at (1, 1.95) with progress
    2.95 m is within the 0.1 m tolerance: done."""
    cmd, pp = _command(Route(CORNER, speed=0.4), 1.0, 0.0, math.pi / 2)
    assert not cmd.done and cmd.v > 0.0
    pp._s = 2.5
    done, _ = _command(Route(CORNER, speed=0.4), 1.0, 1.95, math.pi / 2, pp)
    assert done.done


def test_a_goal_point_abeam_turns_the_chair_in_place_toward_it() -> None:
    """Route (0, 0) -> (0, 5), chair at the origin heading +x: the goal point (0, 0.6) is abeam to the
    left (x_r = 0, y_r = 0.6), not ahead, so the chair turns in place counter-clockwise at half the
    maximum yaw rate (class docstring; REP-103 positive yaw is to the left): (0, 1.07086)."""
    cmd, _ = _command(Route(((0.0, 0.0), (0.0, 5.0)), speed=0.4), 0.0, 0.0, 0.0)
    assert (cmd.v, cmd.w) == pytest.approx((0.0, 0.5 * MAX_YAW_RATE), abs=1e-9)


def test_a_route_table_of_a_run_file_is_read_and_its_errors_name_the_file_and_line(tmp_path) -> None:
    """Route.from_dict takes a checked table (``ConfigTable``, as ``robchair run`` passes its ``[route]``):
    a good table gives its values, and a bad value on line 3 is named ``<file>:3: route.speed``."""
    from robchair.platform.config import ConfigTable, load_toml
    from robchair.platform.errors import ConfigError

    good = tmp_path / "good.toml"
    good.write_text("[route]\nwaypoints = [[0.0, 0.0], [2.0, 0.0]]\nspeed = 0.5\n")
    data, source = load_toml(good)
    route = Route.from_dict(ConfigTable(data["route"], source, "route"))
    assert route == Route(((0.0, 0.0), (2.0, 0.0)), speed=0.5)
    bad = tmp_path / "bad.toml"
    bad.write_text("[route]\nwaypoints = [[0.0, 0.0], [2.0, 0.0]]\nspeed = 0.0\n")
    data, source = load_toml(bad)
    with pytest.raises(ConfigError) as err:
        Route.from_dict(ConfigTable(data["route"], source, "route"))
    assert str(err.value).startswith(f"{bad}:3: route.speed = 0.0: expected a finite number > 0")
