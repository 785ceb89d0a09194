"""``RobChair/SharedControl-v0``: the person's joystick in the observation and the documented reward terms."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")
gymnasium = pytest.importorskip("gymnasium")

import sim.envs  # noqa: E402,F401  (registers the ids)
from robchair.envs.navigation import NavigationEnvError  # noqa: E402


@pytest.fixture(scope="module")
def env():
    e = gymnasium.make("RobChair/SharedControl-v0", randomization=False)
    yield e
    e.close()


def _push_until_the_person_moves_the_stick(env, action=None):
    """Steps with the person's own command (or ``action(stick)``) until the stick is off zero."""
    obs, _ = env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (4.0, 0.0)})
    for _ in range(20):
        stick = obs["joystick"]
        obs, reward, _, _, info = env.step(stick if action is None else action(stick))
        if np.any(stick != 0.0):
            return stick, reward, info
    raise AssertionError("the person never moved the stick")


def test_the_observation_carries_the_persons_stick_in_its_space(env):
    obs, _ = env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (4.0, 0.0)})
    assert obs["joystick"].shape == (2,) and obs["joystick"].dtype == np.float32
    assert env.observation_space.contains(obs)
    assert "laser" in obs and "goal" in obs  # the light observation is kept
    for _ in range(12):  # the person's reaction delay is 0.35 s; after 1.2 s they push toward the goal ahead
        obs, *_ = env.step(obs["joystick"])
    assert obs["joystick"][0] > 0.3


def test_applying_the_persons_command_costs_no_agreement_and_the_terms_sum_to_the_reward(env):
    stick, reward, info = _push_until_the_person_moves_the_stick(env)
    assert info["joystick"] == pytest.approx(tuple(stick))
    assert info["reward_terms"]["agreement"] == pytest.approx(0.0, abs=1e-6)  # cos = 1
    assert reward == pytest.approx(sum(info["reward_terms"].values()))


def test_the_opposite_command_costs_twice_the_agreement_weight(env):
    """Hand value: cos(-u, u) = -1, so ``agreement = weight * (-1 - 1) = -2 * weight`` (0.05 default)."""
    _, _, info = _push_until_the_person_moves_the_stick(env, action=lambda s: -s)
    assert info["reward_terms"]["agreement"] == pytest.approx(-0.1, abs=1e-6)


def test_moving_while_the_person_lets_go_costs_the_full_agreement_weight(env):
    """Hand value: the stick is zero for the first step (reaction delay 0.35 s of the tremor preset),
    and full speed straight ahead (norm 1) costs ``weight * min(1, 1) = 0.05``."""
    env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (4.0, 0.0)})
    _, _, _, _, info = env.step(np.array([1.0, 0.0], np.float32))  # full speed ahead: no motor over its RPM
    assert info["joystick"] == (0.0, 0.0)
    assert info["reward_terms"]["agreement"] == pytest.approx(-0.05)


def test_the_person_walks_round_the_office_walls_to_a_goal_behind_one():
    """The office (assets/scenes/office.toml): the corridor's left wall has its face at y = 1.2, the
    room's west wall at x = 6.0 with its doorway at |y| < 0.7. The straight line from (0, 0) to
    (7, 2) in the room crosses the corridor wall at x = 4.2, so the person's route turns at the
    doorway: its first waypoint lies in the corridor before the doorway, its last is the goal."""
    e = gymnasium.make("RobChair/SharedControl-v0").unwrapped
    try:
        route = e.user_route((0.0, 0.0), (7.0, 2.0))
    finally:
        e.close()
    assert route[-1] == (7.0, 2.0) and len(route) >= 2
    x, y = route[0]
    assert 4.5 < x < 6.5 and abs(y) < 0.7


def test_an_unknown_user_preset_or_a_negative_weight_is_refused_by_name():
    from robchair.envs.shared_control import RobChairSharedControlEnv

    with pytest.raises(NavigationEnvError, match=r"user='nobody'.*typical, tremor, switch"):
        RobChairSharedControlEnv(user="nobody")
    with pytest.raises(NavigationEnvError, match=r"agreement_weight=-1.*>= 0"):
        RobChairSharedControlEnv(agreement_weight=-1.0)
