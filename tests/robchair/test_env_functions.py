"""The navigation environment's pure functions: reward, goal bearing, egocentric patch, depth noise
(the environment itself: test_env.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robchair.envs.navigation import (
    RewardWeights,
    decimated_depth_noise,
    egocentric_patch,
    goal_in_robot_frame,
    navigation_reward,
    reward_terms,
)
from robchair.platform.kinematics import Pose2D

pytest.importorskip("pybullet")
pytest.importorskip("gymnasium")


# ---- pure functions ---------------------------------------------------------------------------


def test_reward_function_matches_hand_computed_values():
    # 20 cm of progress, 0.01 time cost
    assert navigation_reward(5.0, 4.8, False, False) == pytest.approx(0.19)
    # moving away by 10 cm and hitting something
    assert navigation_reward(2.0, 2.1, True, False) == pytest.approx(-0.1 - 10.0 - 0.01)
    # the last 25 cm onto the goal
    assert navigation_reward(0.5, 0.25, False, True) == pytest.approx(0.25 - 0.01 + 10.0)
    w = RewardWeights(progress=2.0, collision=1.0, time=0.5, success=3.0)
    assert navigation_reward(1.0, 0.0, True, True, w) == pytest.approx(2.0 - 1.0 - 0.5 + 3.0)
    assert reward_terms(1.0, 0.0, True, True, w) == {
        "progress": 2.0,
        "collision": -1.0,
        "time": -0.5,
        "success": 3.0,
    }


def test_goal_bearing_is_measured_counter_clockwise_from_the_robot_heading():
    north = Pose2D(1.0, 1.0, math.pi / 2)
    assert goal_in_robot_frame(north, (1.0, 3.0)) == pytest.approx((2.0, 0.0))
    assert goal_in_robot_frame(north, (0.0, 1.0)) == pytest.approx((1.0, math.pi / 2))  # west is to the left
    assert goal_in_robot_frame(north, (3.0, 1.0)) == pytest.approx((2.0, -math.pi / 2))
    assert goal_in_robot_frame(Pose2D(0.0, 0.0, 0.0), (-1.0, 0.0))[1] == pytest.approx(math.pi)


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(-50, 50),
    y=st.floats(-50, 50),
    theta=st.floats(-math.pi, math.pi),
    gx=st.floats(-50, 50),
    gy=st.floats(-50, 50),
)
def test_goal_distance_and_bearing_lead_back_to_the_goal(x, y, theta, gx, gy):
    dist, bearing = goal_in_robot_frame(Pose2D(x, y, theta), (gx, gy))
    assert -math.pi < bearing <= math.pi
    assert x + dist * math.cos(theta + bearing) == pytest.approx(gx, abs=1e-9)
    assert y + dist * math.sin(theta + bearing) == pytest.approx(gy, abs=1e-9)


@settings(max_examples=100, deadline=None)
@given(
    x=st.floats(-3, 3),
    y=st.floats(-3, 3),
    theta=st.floats(-math.pi, math.pi),
    i=st.integers(0, 31),
    j=st.integers(0, 31),
)
def test_egocentric_patch_sees_a_cell_where_its_pose_puts_it(x, y, theta, i, j):
    from mapping.grid import GridSpec

    grid = GridSpec(cell_size=0.1, size_x=20.0, size_y=20.0, centre=(0.0, 0.0))
    occ = np.zeros(grid.shape, dtype=bool)
    # the patch cell (i, j) is at robot-frame (-1.0 + (i + 0.5) 0.1, (j + 0.5 - 16) 0.1)
    rx, ry = -1.0 + (i + 0.5) * 0.1, (j + 0.5 - 16) * 0.1
    wx = x + math.cos(theta) * rx - math.sin(theta) * ry
    wy = y + math.sin(theta) * rx + math.cos(theta) * ry
    occ[grid.world_to_index(wx, wy)] = True
    patch = egocentric_patch(occ, grid, Pose2D(x, y, theta), (32, 32), 0.1, 1.0)
    assert patch[i, j] == 1
    # a nearest-cell lookup of a rotated lattice can hit one world cell from at most 4 patch cells
    assert 1 <= patch.sum() <= 4


def _one_obstacle_grid(x, y):
    from mapping.grid import GridSpec

    grid = GridSpec(cell_size=0.1, size_x=10.0, size_y=10.0, centre=(0.0, 0.0))
    occ = np.zeros(grid.shape, dtype=bool)
    i, j = grid.world_to_index(x, y)
    occ[i, j] = True
    return grid, occ


def test_egocentric_patch_places_an_obstacle_ahead_and_left_in_the_right_cell():
    # robot at (1, 1) facing +x; obstacle 1.05 m ahead and 0.05 m to the left
    grid, occ = _one_obstacle_grid(2.05, 1.05)
    patch = egocentric_patch(occ, grid, Pose2D(1.0, 1.0, 0.0), (64, 64), 0.1, 1.6)
    # row = (1.05 + 1.6) / 0.1 - 0.5 = 26, column = 0.05 / 0.1 - 0.5 + 32 = 32
    assert patch.sum() == 1 and patch[26, 32] == 1


def test_egocentric_patch_rotates_with_the_robot():
    # robot at (1, 1) facing +y (north): 1.05 m ahead, 0.05 m left is world (0.95, 2.05)
    grid, occ = _one_obstacle_grid(0.95, 2.05)
    patch = egocentric_patch(occ, grid, Pose2D(1.0, 1.0, math.pi / 2), (64, 64), 0.1, 1.6)
    assert patch.sum() == 1 and patch[26, 32] == 1
    # behind the robot (facing south, the same obstacle is 1.05 m behind and 0.05 m to its right)
    patch = egocentric_patch(occ, grid, Pose2D(1.0, 1.0, -math.pi / 2), (64, 64), 0.1, 1.6)
    # row = (-1.05 + 1.6) / 0.1 - 0.5 = 5, column = -0.05 / 0.1 - 0.5 + 32 = 31
    assert patch.sum() == 1 and patch[5, 31] == 1


def test_egocentric_patch_is_zero_outside_the_map():
    grid, occ = _one_obstacle_grid(0.05, 0.05)
    occ[:] = True
    patch = egocentric_patch(occ, grid, Pose2D(4.9, 0.0, 0.0), (10, 10), 0.1, 0.0)
    # row 0 (centre x = 4.95) is the map's last cell; row 1 (x = 5.05) lies outside the 10 m map
    assert patch[0].all() and not patch[1:].any()


def test_decimated_depth_noise_has_the_kinect2_axial_sigma_and_keeps_points_on_their_rays():
    from dataclasses import replace

    from sim.kinect import MODELS

    model = replace(MODELS["kinect2"], width=128, height=106)
    rays = model.intrinsics.rays()
    clean = 2.0 * rays  # a wall facing the camera 2 m away
    clean[0, 0] = np.nan  # no return stays no return
    noisy = decimated_depth_noise(clean, model, np.random.default_rng(0))
    assert np.isnan(noisy[0, 0]).all()
    z = noisy[..., 0][1:-1, 1:-1]  # interior: normals defined, theta ~ 0 for the lateral rays nearby
    # Fankhauser 2015 at z = 2 m, theta = 0: 1.5 - 0.5 * 2 + 0.3 * 4 = 1.7 mm; 1 mm rounding adds 1/12 mm^2
    assert np.std(z - 2.0) == pytest.approx(math.sqrt(1.7e-3**2 + 1e-6 / 12), rel=0.06)
    assert np.allclose(np.round(noisy[..., 0][1:] * 1000), noisy[..., 0][1:] * 1000)  # whole millimetres
    np.testing.assert_allclose(noisy[1:] / noisy[1:, :, :1], rays[1:], rtol=1e-9)  # same ray, new depth
