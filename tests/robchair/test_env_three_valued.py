"""The v2 ids: the episode map is the probabilistic one and the occupancy patch tells free from unknown."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pybullet")
gymnasium = pytest.importorskip("gymnasium")

import sim.envs  # noqa: E402
from robchair.envs.observation import PATCH_FREE, PATCH_OCCUPIED, PATCH_UNKNOWN  # noqa: E402
from sim.envs.errors import NavigationEnvError  # noqa: E402

FACING_WALL = {"start": (0.0, 0.0, math.pi / 2), "goal": (4.0, 0.0)}  # the corridor wall's face at y = 1.2


def _row(x_ahead: float, cell: float = 0.1, behind: float = 1.6) -> int:
    return int((x_ahead + behind) // cell)


def test_every_v1_id_has_a_v2_twin_with_the_probabilistic_map():
    for env_id in sim.envs.ENV_IDS:
        if env_id.endswith("-v1"):
            kw = gymnasium.spec(env_id.replace("-v1", "-v2")).kwargs
            assert kw == {**gymnasium.spec(env_id).kwargs, "map_kind": "probabilistic"}


def test_the_v2_patch_is_free_before_the_wall_occupied_on_it_and_unknown_behind_the_chair():
    env = gymnasium.make("RobChair/NavigationKinect-v2", randomization=False)
    try:
        assert env.observation_space["occupancy"].high.max() == PATCH_UNKNOWN
        obs, _ = env.reset(seed=0, options=FACING_WALL)
        patch = obs["occupancy"]
        assert env.observation_space.contains(obs)
        centre = slice(28, 36)  # +-0.4 m about the chair's axis
        assert (patch[_row(1.15) : _row(1.35), centre] == PATCH_OCCUPIED).any()  # the wall's face
        assert (patch[_row(0.6) : _row(1.0), centre] == PATCH_FREE).mean() > 0.5  # seen through
        assert (patch[: _row(-0.8), :] == PATCH_UNKNOWN).all()  # behind: never seen
        assert (patch[_row(1.4) :, centre] != PATCH_FREE).all()  # beyond the wall: not free
    finally:
        env.close()


def test_the_v1_patch_stays_binary_and_cannot_tell_unseen_from_free():
    env = gymnasium.make("RobChair/NavigationKinect-v1", randomization=False)
    try:
        assert env.observation_space["occupancy"].high.max() == 1
        obs, _ = env.reset(seed=0, options=FACING_WALL)
        assert set(np.unique(obs["occupancy"])) <= {0, 1}
    finally:
        env.close()


def test_an_unknown_map_kind_is_refused_by_name():
    with pytest.raises(NavigationEnvError, match="map_kind='octomap'"):
        gymnasium.make("RobChair/Navigation-v1", map_kind="octomap")
