"""The navigation environment's contract: footprint collisions, reset validation, the end of an
episode, contacts seen in sub-steps, per-episode domain randomisation, pickling and copying."""

from __future__ import annotations

import copy
import math
import pickle
from pathlib import Path

import numpy as np
import pytest

from robchair.envs.navigation import NavigationEnvError

pytest.importorskip("pybullet")
gymnasium = pytest.importorskip("gymnasium")

import sim.envs  # noqa: E402,F401  (registers the ids)


@pytest.fixture(scope="module")
def env():
    from robchair.envs.navigation import RobChairNavigationEnv

    e = RobChairNavigationEnv(sensor=None, sonars=True)
    yield e
    e.close()


def test_a_tyre_14_cm_from_the_corridor_wall_is_not_a_collision():
    from robchair.envs.navigation import RobChairNavigationEnv

    # the collision geometry alone: the safety layer off, the command reaches the motors unchanged
    env = RobChairNavigationEnv(sensor=None, sonars=True, safety=False)
    try:
        # the corridor's left wall has its face at y = 1.2; the chair's left tyre reaches y = 0.76 + 0.32
        env.reset(seed=0, options={"start": (1.0, 0.76, 0.0), "goal": (4.5, 0.76)})
        for _ in range(10):
            _, _, terminated, _, info = env.step(np.array([0.6, 0.0], np.float32))
            assert not info["collision"], info.get("contacts")
            assert not terminated
        assert info["pose"][0] > 1.15  # it drove along the wall
    finally:
        env.close()


def test_a_start_inside_a_wall_is_refused_naming_the_point_and_the_wall(env):
    with pytest.raises(NavigationEnvError, match=r"start \(2\.25, 1\.25.*corridor_wall_left"):
        env.reset(seed=0, options={"start": (2.25, 1.25, 0.0), "goal": (4.5, 0.0)})
    with pytest.raises(NavigationEnvError, match=r"step.*before reset"):
        env.step(np.zeros(2, np.float32))  # the refused episode never started


def test_a_goal_inside_a_wall_is_refused_naming_the_point_and_the_wall(env):
    with pytest.raises(NavigationEnvError, match=r"goal \(2\.25, 1\.25\).*corridor_wall_left"):
        env.reset(seed=0, options={"goal": (2.25, 1.25)})


def test_a_goal_cut_off_from_the_start_is_refused(env):
    # (3.0, 2.0) lies outside the building, 0.75 m beyond the corridor's left wall
    with pytest.raises(NavigationEnvError, match=r"goal \(3\.0, 2\.0\) is not reachable"):
        env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (3.0, 2.0)})


def test_goal_distance_must_start_above_the_goal_tolerance():
    from robchair.envs.navigation import RobChairNavigationEnv

    with pytest.raises(NavigationEnvError, match=r"goal_distance.*goal_tolerance"):
        RobChairNavigationEnv(sensor=None, sonars=True, goal_distance=(0.0, 0.2))


def test_a_step_after_the_episode_terminated_raises_and_pays_nothing(env):
    env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (0.6, 0.0)})
    for _ in range(30):
        _, _, terminated, _, info = env.step(np.array([0.5, 0.0], np.float32))
        if terminated:
            break
    assert terminated and info["is_success"]
    with pytest.raises(NavigationEnvError, match="after the episode terminated"):
        env.step(np.array([0.5, 0.0], np.float32))


def test_a_contact_within_a_sub_step_is_reported_by_name():
    from robchair.envs.navigation import RobChairNavigationEnv
    from sim.scene import Motion, Scene, SceneObject

    # a runner crosses the standing chair's footprint at 4 m/s within the first 1 s agent step (after
    # reset's one cycle standing still): overlapping at t = 1.5 s, clear of it at the step's end (2 s)
    runner = SceneObject(
        name="runner",
        shape="cylinder",
        xyz=(0.2, -6.5, 0.85),
        radius=0.25,
        length=1.7,
        motion=Motion(waypoints=((0.2, -6.5), (0.2, 9.5)), speed=4.0, loop=False),
    )
    walls = tuple(
        SceneObject(name=f"wall_{k}", shape="box", xyz=xyz, size=size)
        for k, (xyz, size) in enumerate(
            (
                ((0.0, 10.0, 1.0), (20.0, 0.1, 2.0)),
                ((0.0, -10.0, 1.0), (20.0, 0.1, 2.0)),
                ((10.0, 0.0, 1.0), (0.1, 20.0, 2.0)),
                ((-10.0, 0.0, 1.0), (0.1, 20.0, 2.0)),
            )
        )
    )
    scene = Scene("crossing", Path("crossing.toml"), (*walls, runner))
    e = RobChairNavigationEnv(scene=scene, sensor=None, sonars=True, agent_hz=1)
    try:
        e.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (-5.0, 0.0)})
        _, _, terminated, _, info = e.step(np.zeros(2, np.float32))
        assert info["collision"] and terminated
        assert info["contacts"] == ["runner"]
        assert e.contacts() == []  # at the end of the step the runner is past the chair
    finally:
        e.close()


def _drift(env, seed):
    env.reset(seed=seed, options={"start": (-0.5, 0.0, 0.0), "goal": (4.5, 0.0)})
    for _ in range(20):
        _, _, _, _, info = env.step(np.array([0.8, 0.0], np.float32))
    (x, y, t), (xe, ye, te) = info["pose"], info["pose_estimate"]
    return x - xe, y - ye, t - te, info["dynamics"]


def test_each_episode_draws_its_own_chair_from_np_random_and_a_seed_repeats_it():
    from robchair.envs.navigation import RobChairNavigationEnv

    e = RobChairNavigationEnv(sensor=None, sonars=True, pose_source="odometry")
    try:
        a1, a2, b = _drift(e, 1), _drift(e, 1), _drift(e, 2)
    finally:
        e.close()
    assert a1 == a2  # same seed, same chair, same drift
    assert a1[3] != b[3]  # other seed, other tyres, friction, payload, motors, noise and latency
    assert a1[:3] != b[:3]  # ... and so another odometry drift
    d = a1[3]
    assert 50.0 <= d["payload_kg"] <= 120.0
    assert all(0.995 <= k <= 1.005 for k in d["tyre_radius_scale"])
    assert 0.0 <= d["command_latency_s"] <= 0.05


def test_randomisation_ranges_are_arguments_and_bad_ranges_are_refused():
    from robchair.envs.navigation import RobChairNavigationEnv
    from sim.envs.randomization import DomainRandomization
    from sim.errors import SimError

    with pytest.raises(SimError, match="payload_kg"):
        DomainRandomization(payload_kg=(120.0, 50.0))
    with pytest.raises(NavigationEnvError, match="randomization"):
        RobChairNavigationEnv(sensor=None, sonars=True, randomization="yes")
    r = DomainRandomization(payload_kg=(80.0, 80.0), command_latency_s=(0.02, 0.02))
    e = RobChairNavigationEnv(sensor=None, sonars=True, randomization=r)
    try:
        _, info = e.reset(seed=3)
        assert info["dynamics"]["payload_kg"] == 80.0
        assert info["dynamics"]["command_latency_s"] == 0.02
    finally:
        e.close()


@pytest.mark.parametrize("env_id", ["RobChair/NavigationSonar-v0", "RobChair/SharedControl-v0"])
def test_the_environment_pickles_and_deep_copies_into_an_equal_environment(env_id):
    e = gymnasium.make(env_id)
    try:
        clone = pickle.loads(pickle.dumps(e))
        twin = copy.deepcopy(e)
        try:
            obs = [x.reset(seed=4)[0] for x in (e, clone, twin)]
            for o in obs[1:]:
                for k in o:
                    np.testing.assert_array_equal(o[k], obs[0][k])
        finally:
            clone.close()
            twin.close()
    finally:
        e.close()


def test_an_environment_built_with_an_explicit_spec_pickles_too():
    from robchair.envs.navigation import RobChairNavigationEnv
    from robchair.platform.spec import load_spec

    spec = load_spec()
    assert pickle.loads(pickle.dumps(spec)) == spec
    assert copy.deepcopy(spec).mounts["kinect_link"] == spec.mounts["kinect_link"]
    e = RobChairNavigationEnv(sensor=None, sonars=True, spec=spec)
    try:
        clone = pickle.loads(pickle.dumps(e))
        try:
            assert clone.spec_robot == spec  # the explicit spec, not the default one loaded again
            obs = [x.reset(seed=7)[0] for x in (e, clone)]
            assert obs[0].keys() == obs[1].keys()
            for k in obs[0]:
                np.testing.assert_array_equal(obs[1][k], obs[0][k])
            steps = [x.step(np.array([0.5, 0.2], dtype=np.float32)) for x in (e, clone)]
            assert steps[0][1] == steps[1][1]  # the same reward
            for k in steps[0][0]:
                np.testing.assert_array_equal(steps[1][0][k], steps[0][0][k])
        finally:
            clone.close()
    finally:
        e.close()


def test_metadata_declares_the_autoreset_mode():
    from gymnasium.vector import AutoresetMode

    from robchair.envs.navigation import RobChairNavigationEnv

    assert RobChairNavigationEnv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert math.isfinite(RobChairNavigationEnv.metadata["render_fps"])
