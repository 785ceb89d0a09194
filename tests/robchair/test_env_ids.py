"""Every registered id: Gymnasium's checker, determinism by seed with randomisation on, vector envs."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pybullet")
gymnasium = pytest.importorskip("gymnasium")

import sim.envs  # noqa: E402

_LIGHT_IDS = [i for i in sim.envs.ENV_IDS if "Kinect" not in i and i != "RobChair/Navigation-v0"]
# the -v2 ids are their -v1 twins with the probabilistic map: one of them runs by default, all with -m slow
FAST_IDS = [
    i if not i.endswith("-v2") or i == "RobChair/Navigation-v2" else pytest.param(i, marks=pytest.mark.slow)
    for i in _LIGHT_IDS
]


def _episode(env, seed, n=6):
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    out = [obs]
    for _ in range(n):
        obs, r, term, trunc, info = env.step(env.action_space.sample())
        out.append((obs, r))
        if term or trunc:
            break
    return out, info


def _same(a, b):
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _same(a[k], b[k])
    elif isinstance(a, tuple):
        for x, y in zip(a, b, strict=True):
            _same(x, y)
    else:
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("env_id", sim.envs.ENV_IDS)
def test_the_env_checker_accepts_every_registered_id(env_id):
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make(env_id)
    try:
        check_env(env.unwrapped, skip_render_check=True)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", FAST_IDS)
def test_the_same_seed_gives_the_same_episode_with_randomisation_on(env_id):
    env = gymnasium.make(env_id)
    try:
        a, info_a = _episode(env, 21)
        _episode(env, 22, 2)
        b, info_b = _episode(env, 21)
    finally:
        env.close()
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        _same(x, y)
    assert info_a["dynamics"] == info_b["dynamics"]


def test_random_floors_change_with_the_seed_and_evaluation_floors_come_from_their_own_range():
    from sim.rooms import EVAL_SEEDS, TRAIN_SEEDS

    env = gymnasium.make("RobChair/NavigationRooms-v1").unwrapped
    try:
        env.reset(seed=1)
        first = env.room_seed
        env.reset(seed=2)
        assert env.room_seed != first and env.room_seed in TRAIN_SEEDS
        env.reset(seed=0, options={"room_seed": EVAL_SEEDS[3]})
        assert env.scene.name == f"rooms_{EVAL_SEEDS[3]}"
    finally:
        env.close()
    ev = gymnasium.make("RobChair/NavigationRooms-v1", room_seeds="eval").unwrapped
    try:
        ev.reset(seed=5)
        assert ev.room_seed in EVAL_SEEDS
    finally:
        ev.close()


def test_the_discrete_variant_maps_its_five_actions_to_documented_twists():
    from robchair.envs.navigation import DISCRETE_ACTIONS, NavigationEnvError

    env = gymnasium.make("RobChair/NavigationDiscrete-v1").unwrapped
    try:
        assert env.action_space.n == 5 and DISCRETE_ACTIONS[0] == (0.0, 0.0)
        assert env.action_twist(2) == pytest.approx((0.7 * env.max_speed, 0.0))
        assert env.action_twist(3)[1] > 0 > env.action_twist(4)[1]  # left is counter-clockwise (REP-103)
        with pytest.raises(NavigationEnvError, match="action"):
            env.action_twist(5)
    finally:
        env.close()


def test_depth_image_and_elevation_map_options_add_their_observations():
    env = gymnasium.make("RobChair/NavigationKinect-v1", depth_image=True, elevation_map=True)
    try:
        obs, _ = env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (4.0, 0.0)})
        assert obs["depth"].shape == (106, 128) and obs["depth"].max() > 1.0
        assert obs["elevation"].shape == (64, 64) and obs["elevation"].max() > 0.5  # the corridor's walls
        assert env.observation_space.contains(obs)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", FAST_IDS)
def test_a_sync_vector_env_runs_every_fast_id(env_id):
    """Two copies of each id in one vector env: every batched observation lies in the batched space,
    rewards are finite, one per copy, and the two copies (seeds 3 and 4) start apart."""
    envs = gymnasium.make_vec(env_id, num_envs=2, vectorization_mode="sync")
    try:
        obs, _ = envs.reset(seed=3)
        assert envs.observation_space.contains(obs)
        flat = [np.asarray(v) for v in (obs.values() if isinstance(obs, dict) else [obs])]
        assert all(v.shape[0] == 2 for v in flat)
        assert any(not np.array_equal(v[0], v[1]) for v in flat)  # seeds 3 and 4 differ
        envs.action_space.seed(3)
        for _ in range(3):
            obs, reward, term, trunc, _ = envs.step(envs.action_space.sample())
            assert envs.observation_space.contains(obs)
            assert reward.shape == (2,) and np.isfinite(reward).all()
            assert term.shape == trunc.shape == (2,) and term.dtype == trunc.dtype == np.bool_
    finally:
        envs.close()


@pytest.mark.slow
@pytest.mark.parametrize("env_id", sim.envs.ENV_IDS)
@pytest.mark.parametrize("mode", ["sync", "async"])
def test_vector_envs_run_every_id(env_id, mode):
    envs = gymnasium.make_vec(env_id, num_envs=2, vectorization_mode=mode)
    try:
        envs.reset(seed=3)
        for _ in range(3):
            envs.step(envs.action_space.sample())
    finally:
        envs.close()


def test_the_light_observation_carries_the_hokuyo_scan_of_the_wall_ahead():
    env = gymnasium.make("RobChair/Navigation-v1", randomization=False)
    try:
        # facing the corridor's left wall (face at y = 1.2); laser_link is 0.60 m ahead of base_link
        obs, _ = env.reset(seed=0, options={"start": (0.0, 0.0, math.pi / 2), "goal": (4.0, 0.0)})
        laser = obs["laser"]
        assert laser.shape == (682,)  # URG-04LX steps 44..725
        assert laser[340] == pytest.approx(0.6, abs=0.03)  # beam 340 (step 384) looks straight ahead
        assert env.observation_space.contains(obs)
        rows = np.nonzero(obs["occupancy"].any(axis=1))[0]
        assert rows.size and rows.min() <= 29  # the scan's hits are in the chair's own map
    finally:
        env.close()
