"""The grid planner, the pure-pursuit follower and the route check of the classical baseline."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapping.grid import GridSpec
from robchair.navigation.planner import (
    PlannerConfig,
    PlanningError,
    PurePursuit,
    cost_map,
    path_length,
    plan_path,
    route_blocked,
)


def _room_with_wall(gap_centre=None, gap=1.2):
    """A 10 m x 6 m grid, a wall across x = 5 with an optional gap."""
    grid = GridSpec(cell_size=0.1, size_x=10.0, size_y=6.0, centre=(5.0, 3.0))
    occ = np.zeros(grid.shape, dtype=bool)
    i, _ = grid.world_to_index(5.0, 0.0)
    occ[i, :] = True
    if gap_centre is not None:
        _, j0 = grid.world_to_index(5.0, gap_centre - gap / 2)
        _, j1 = grid.world_to_index(5.0, gap_centre + gap / 2)
        occ[i, j0 + 1 : j1] = False
    return grid, occ


def test_cost_is_infinite_within_the_inflation_and_falls_to_one_far_away():
    grid, occ = _room_with_wall()
    cost = cost_map(occ, 0.1, PlannerConfig(inflation=0.37, comfort=0.6, comfort_weight=4.0))
    i, j = grid.world_to_index(np.array([5.2, 5.5, 8.0]), np.array([3.0, 3.0, 3.0]))
    assert math.isinf(cost[i[0], j[0]])
    assert 1.0 < cost[i[1], j[1]] < 5.0
    assert cost[i[2], j[2]] == 1.0


def test_the_route_goes_through_the_doorway_and_is_not_much_longer_than_needed():
    grid, occ = _room_with_wall(gap_centre=4.5, gap=1.2)
    route = plan_path(occ, grid, (2.0, 1.0), (8.0, 1.0))
    assert route is not None and route[0] == (2.0, 1.0) and route[-1] == (8.0, 1.0)
    pts = np.asarray(route)
    crossing = pts[np.argmin(np.abs(pts[:, 0] - 5.0))]
    assert abs(crossing[1] - 4.5) < 0.3  # through the gap's middle
    straight = math.hypot(2.5, 3.5) + math.hypot(3.0, 3.5)
    assert path_length(route) < 1.25 * straight  # it keeps off the door posts, at a small detour


def test_no_route_when_the_wall_is_closed_or_the_door_too_narrow_for_the_chair():
    grid, occ = _room_with_wall()
    assert plan_path(occ, grid, (2.0, 1.0), (8.0, 1.0)) is None
    grid, occ = _room_with_wall(gap_centre=3.0, gap=0.6)  # 0.6 m: narrower than the 0.64 m chair
    assert plan_path(occ, grid, (2.0, 1.0), (8.0, 1.0)) is None


def test_points_outside_the_grid_are_refused():
    grid, occ = _room_with_wall(gap_centre=3.0)
    with pytest.raises(PlanningError, match="goal"):
        plan_path(occ, grid, (2.0, 1.0), (80.0, 1.0))


def test_a_route_through_a_newly_seen_obstacle_is_blocked():
    grid, occ = _room_with_wall(gap_centre=4.5, gap=1.2)
    route = [(2.0, 4.5), (8.0, 4.5)]
    cfg = PlannerConfig()
    assert not route_blocked(route, occ, grid, cfg)
    i, j = grid.world_to_index(6.5, 4.5)
    occ[i, j] = True
    assert route_blocked(route, occ, grid, cfg)


def test_pure_pursuit_turns_toward_the_route_and_slows_for_the_goal():
    pp = PurePursuit(lookahead=0.6, cruise=0.5, max_yaw_rate=0.8)
    v, w = pp.command((0.0, 0.0, 0.0), [(0.0, 0.0), (5.0, 0.0)])
    assert v == pytest.approx(0.5) and w == pytest.approx(0.0)
    v, w = pp.command((0.0, -0.3, 0.0), [(0.0, 0.0), (5.0, 0.0)])
    assert v > 0 and w > 0  # the route is to the left: turn counter-clockwise
    v, w = pp.command((0.0, 0.0, math.pi), [(0.0, 0.0), (5.0, 0.0)])
    assert v == 0.0 and abs(w) == pytest.approx(0.8)  # behind: turn on the spot
    v, _ = pp.command((4.95, 0.0, 0.0), [(0.0, 0.0), (5.0, 0.0)])
    assert v < 0.25  # v <= sqrt(2 a d) near the goal


def test_the_follower_aligns_on_the_spot_before_a_tight_passage_and_drives_slowly_in_it():
    pp = PurePursuit()
    pose, route = (0.0, 0.0, math.radians(30)), [(0.0, 0.0), (5.0, 0.0)]
    v, w = pp.command(pose, route)
    assert v > 0.3  # in the open a 30 deg heading error is taken while driving
    v, w = pp.command(pose, route, clearance=0.45)  # a doorway ahead: align first
    assert v == 0.0 and w < 0.0
    v, w = pp.command((0.0, 0.0, math.radians(5)), route, clearance=0.45)
    assert 0.0 < v <= pp.tight_speed


class _ChairOnAGrid:
    """The parts of the navigation environment the baseline reads: the spec, limits, own map."""

    action_type = "continuous"
    max_speed = 0.62
    max_yaw_rate = 2.14

    def __init__(self, grid, occ):
        from robchair.platform.spec import load_spec

        self.spec_robot = load_spec()
        self.grid, self.occ = grid, occ

    def own_occupancy(self):
        return self.grid, self.occ.copy()


def _info(pose, goal, reason=None, command=(0.5, 0.0)):
    return {
        "pose_estimate": pose,
        "goal": goal,
        "command": command,
        "safety": {"intervened": reason is not None, "reason": reason},
    }


def test_the_baseline_backs_up_and_plans_around_where_the_safety_layer_keeps_stopping_it():
    from robchair.navigation.planner import BaselinePolicy

    grid = GridSpec(cell_size=0.1, size_x=10.0, size_y=6.0, centre=(5.0, 3.0))
    env = _ChairOnAGrid(grid, np.zeros(grid.shape, dtype=bool))  # the map shows nothing ahead
    policy = BaselinePolicy(env, stuck_steps=3)
    pose, goal = (2.0, 3.0, 0.0), (8.0, 3.0)
    a = policy(None, _info(pose, goal))
    assert a[0] > 0  # straight on toward the goal
    stop = "obstacle_sonar: obstacle at 0.20 m ahead < stopping distance 0.46 m"
    for _ in range(2):
        policy(None, _info(pose, goal, stop))
    a = policy(None, _info(pose, goal, stop))  # the third stop in a row: recover
    assert a[0] < 0 and a[1] == 0.0  # back up, straight
    for _ in range(policy.backup_steps - 1):
        assert policy(None, _info(pose, goal, None, command=(-0.15, 0.0)))[0] < 0
    policy(None, _info(pose, goal, None, command=(-0.15, 0.0)))
    # the new route leaves the straight line where the chair was stopped (0.58 + 0.2 m ahead)
    assert max(abs(p[1] - 3.0) for p in policy.route) > 0.5


def test_the_baseline_plans_on_the_laser_obstacles_when_sonar_cones_close_a_doorway_on_its_map():
    from robchair.navigation.planner import BaselinePolicy

    grid, laser = _room_with_wall(gap_centre=3.0, gap=1.0)
    occ = laser.copy()
    i, _ = grid.world_to_index(5.0, 0.0)
    _, j0 = grid.world_to_index(5.0, 2.4)
    _, j1 = grid.world_to_index(5.0, 3.6)
    occ[i - 2 : i + 3, j0:j1] = True  # a wide sonar arc fills the doorway
    env = _ChairOnAGrid(grid, occ)
    policy = BaselinePolicy(env)
    assert plan_path(occ, grid, (2.0, 3.0), (8.0, 3.0), policy.cfg) is None
    policy._laser_hits = laser  # what the laser located: the wall and its doorway
    route = policy._plan(grid, occ, (2.0, 3.0), (8.0, 3.0))
    assert route is not None and route[-1] == (8.0, 3.0)


def test_the_baseline_backs_up_before_turning_on_the_spot_next_to_an_obstacle():
    from robchair.navigation.planner import BaselinePolicy

    grid = GridSpec(cell_size=0.1, size_x=10.0, size_y=6.0, centre=(5.0, 3.0))
    env = _ChairOnAGrid(grid, np.zeros(grid.shape, dtype=bool))
    policy = BaselinePolicy(env)
    pose, goal = (5.0, 3.0, 0.0), (5.0, 0.5)  # the goal is behind the right shoulder: turn on the spot
    policy._laser_hits = np.zeros(grid.shape, dtype=bool)
    a = policy(None, _info(pose, goal, command=(0.0, 0.0)))
    assert a[0] == 0.0 and a[1] < 0.0  # nothing near: turn
    policy.reset()
    policy._laser_hits = np.zeros(grid.shape, dtype=bool)
    i, j = grid.world_to_index(5.55, 3.3)  # a box beside the front corner the turn would sweep
    policy._laser_hits[i, j] = True
    a = policy(None, _info(pose, goal, command=(0.0, 0.0)))
    assert a[0] < 0.0 and a[1] == 0.0  # back out first
