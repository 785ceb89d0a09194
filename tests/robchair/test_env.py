"""The Gymnasium navigation environment: contract, determinism, rewards, collisions, observations.

Its pure functions (reward, goal bearing, egocentric patch, depth noise) are tested in test_env_functions.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from robchair.envs.navigation import FreeSpace, NavigationEnvError

pytest.importorskip("pybullet")
gymnasium = pytest.importorskip("gymnasium")

import sim.envs  # noqa: E402  (registers the ids)

ENV_ID = "RobChair/Navigation-v0"


@pytest.fixture(scope="module")
def env():
    from robchair.envs.navigation import RobChairNavigationEnv

    e = RobChairNavigationEnv(render_mode="rgb_array", randomization=False)  # as RobChair/Navigation-v0
    yield e
    e.close()


@pytest.fixture(scope="module")
def unsafe_env():
    """As ``env`` with the safety layer off: the agent's command reaches the motors unchanged."""
    from robchair.envs.navigation import RobChairNavigationEnv

    e = RobChairNavigationEnv(randomization=False, safety=False)
    yield e
    e.close()


def _run(env, seed, actions, options=None):
    obs, _ = env.reset(seed=seed, options=options)
    out = [obs]
    rewards = []
    for a in actions:
        obs, r, term, trunc, _ = env.step(a)
        out.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return out, rewards


# ---- the environment --------------------------------------------------------------------------


def test_free_space_of_the_office_joins_corridor_and_room_through_the_doorway(env):
    fs: FreeSpace = env.free_space
    i0, j0 = fs.grid.world_to_index(0.0, 0.0)
    ir, jr = fs.grid.world_to_index(9.0, -1.0)  # in the room, behind the 1.4 m doorway
    it, jt = fs.grid.world_to_index(9.2, 1.3)  # under the table
    assert fs.region[i0, j0] and fs.region[ir, jr] and not fs.region[it, jt]
    # the corridor is 2.4 m wide with 0.1 m walls: 1.15 m from its centre line to the walls
    assert 1.0 <= fs.clearance[i0, j0] <= 1.2
    io, jo = fs.grid.world_to_index(3.0, 2.0)  # outside the building
    assert not fs.region[io, jo]


def test_env_checker_accepts_the_environment():
    from gymnasium.utils.env_checker import check_env

    e = gymnasium.make(ENV_ID)
    try:
        check_env(e.unwrapped)
    finally:
        e.close()


def test_registered_ids_use_lazy_entry_points_and_a_time_limit():
    """Every id names its class as a "module:Class" string (nothing imported at registration), a
    navigation env or a subclass of it, and ends episodes after 300 agent steps."""
    import importlib

    from robchair.envs.navigation import RobChairNavigationEnv

    for env_id in sim.envs.ENV_IDS:
        spec = gymnasium.spec(env_id)
        assert isinstance(spec.entry_point, str), env_id
        module, name = spec.entry_point.split(":")
        assert module.startswith("robchair.envs."), env_id
        assert issubclass(getattr(importlib.import_module(module), name), RobChairNavigationEnv), env_id
        assert spec.max_episode_steps == 300
    light = gymnasium.spec("RobChair/Navigation-v1")
    assert light.entry_point == "robchair.envs.navigation:RobChairNavigationEnv"


def test_same_seed_gives_the_same_episode_bit_for_bit(env):
    actions = [np.array([0.8, 0.3], np.float32), np.array([1.0, -0.5], np.float32)] * 4
    obs_a, rew_a = _run(env, 11, actions)
    _run(env, 5, actions[:3])  # another episode in between must leave no trace
    obs_b, rew_b = _run(env, 11, actions)
    assert rew_a == rew_b
    assert len(obs_a) == len(obs_b)
    for oa, ob in zip(obs_a, obs_b):
        for k in oa:
            np.testing.assert_array_equal(oa[k], ob[k])
    assert any(o["occupancy"].any() for o in obs_a)  # the comparison covered a real map
    fresh = gymnasium.make("sim.envs:" + ENV_ID)  # the module:id form imports sim.envs by itself
    try:
        obs_c, rew_c = _run(fresh, 11, actions)
    finally:
        fresh.close()
    assert rew_c == rew_a
    for oa, oc in zip(obs_a, obs_c, strict=True):
        for k in oa:
            np.testing.assert_array_equal(oa[k], oc[k])


def test_different_seeds_give_different_starts_and_goals(env):
    _, info_a = env.reset(seed=1)
    _, info_b = env.reset(seed=2)
    assert (info_a["pose"], info_a["goal"]) != (info_b["pose"], info_b["goal"])


def test_sampled_start_and_goal_lie_in_free_space_at_the_asked_distance(env):
    for seed in range(5):
        _, info = env.reset(seed=seed)
        x, y, _ = info["pose"]
        gx, gy = info["goal"]
        assert 1.0 <= math.hypot(gx - x, gy - y) <= 5.0
        for px, py in ((x, y), (gx, gy)):
            i, j = env.grid.world_to_index(px, py)
            assert env.free_space.region[i, j]
            assert env.free_space.clearance[i, j] >= env.robot_radius


def test_driving_straight_at_a_wall_terminates_with_the_collision_penalty(unsafe_env):
    # facing the corridor's left wall at y = 1.2; the footrest is 0.58 m ahead of base_link
    env = unsafe_env
    env.reset(seed=0, options={"start": (0.0, 0.0, math.pi / 2), "goal": (9.0, 0.0)})
    for _ in range(40):
        _, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0], np.float32))
        if terminated:
            break
    assert terminated and not truncated
    assert info["collision"] and not info["is_success"]
    assert info["contacts"] == ["corridor_wall_left"]
    assert info["reward_terms"]["collision"] == -10.0
    assert reward < -9.0
    # the chair stopped at the wall: base_link at about 1.2 - 0.58 from the corridor's centre line
    assert 0.5 < info["pose"][1] < 0.7


def test_the_safety_layer_stops_the_agent_in_front_of_a_wall_and_says_why(env):
    # facing the corridor's left wall at y = 1.2 at full speed: the shield stops the chair before it
    env.reset(seed=0, options={"start": (0.0, 0.0, math.pi / 2), "goal": (9.0, 0.0)})
    stops = []
    for _ in range(40):
        _, _, terminated, _, info = env.step(np.array([1.0, 0.0], np.float32))
        assert not terminated and not info["collision"]
        assert set(info["safety"]) == {"intervened", "reason"}
        if info["command_applied"][0] == 0.0 and info["command"][0] > 0.0:
            stops.append(info["safety"])
    assert stops, "the safety layer never stopped the forward command"
    assert all(s["intervened"] for s in stops)
    assert all(s["reason"].startswith(("obstacle_map", "obstacle_sonar")) for s in stops)
    # stopped short of the wall: the footrest (0.58 m ahead of base_link) stays off y = 1.2
    assert info["pose"][1] + 0.58 < 1.2
    assert env.contacts() == []


def test_without_the_safety_layer_the_same_action_reaches_the_motors_unchanged(unsafe_env):
    unsafe_env.reset(seed=0, options={"start": (0.0, 0.0, math.pi / 2), "goal": (9.0, 0.0)})
    for _ in range(40):
        _, _, terminated, _, info = unsafe_env.step(np.array([1.0, 0.0], np.float32))
        assert info["safety"] == {"intervened": False, "reason": None}
        assert info["command_applied"] == info["command"]
        if terminated:
            break
    assert info["collision"]


def test_a_person_walking_into_the_standing_chair_ends_the_episode_as_a_collision():
    from robchair.envs.navigation import RobChairNavigationEnv

    # outdoor scene: walker_towards leaves (11, 1.5) at 0.8 m/s toward -x, straight at the chair
    e = RobChairNavigationEnv(scene="outdoor", sensor=None, sonars=True)
    try:
        e.reset(seed=0, options={"start": (9.0, 1.5, 0.0), "goal": (9.0, -1.0)})
        n_steps = 0
        for _ in range(40):
            _, reward, terminated, _, info = e.step(np.zeros(2, np.float32))
            n_steps += 1
            if terminated:
                break
        assert terminated and info["collision"] and "walker_towards" in info["contacts"]
        assert reward < -9.0
        # front of the chair at 9.58 m, the person ~0.25 m wide: about (11 - 0.25 - 9.58) / 0.8 = 1.5 s
        assert 10 <= n_steps <= 20
        # the person passed through; the chair was not flung away
        assert math.hypot(info["pose"][0] - 9.0, info["pose"][1] - 1.5) < 0.05
    finally:
        e.close()


def test_the_wall_ahead_shows_in_the_forward_rows_of_the_occupancy_patch(env):
    obs, _ = env.reset(seed=0, options={"start": (0.0, 0.0, math.pi / 2), "goal": (9.0, 0.0)})
    occ = obs["occupancy"]
    # the wall is 1.2 m ahead: rows (1.2 + 1.6) / 0.1 = 28 (its near face, minus noise) and beyond
    rows = np.nonzero(occ.any(axis=1))[0]
    assert rows.size and 26 <= rows.min() <= 30
    assert not occ[:26].any()  # nothing between the chair and the wall


def test_the_open_corridor_floor_ahead_stays_free_in_the_occupancy_patch(env):
    # the decimated Kinect sees 4 m of corridor floor; floor noise must not turn into obstacles
    env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (4.0, 0.0)})
    occ = None
    for _ in range(5):
        obs, *_ = env.step(np.array([0.2, 0.0], np.float32))
        occ = obs["occupancy"]
    # robot frame x in [1, 4] m -> rows 26..55; |y| < 0.4 m -> columns 28..35 (the plant is at y = -0.85)
    assert not occ[26:56, 28:36].any()
    assert occ.any()  # while the corridor walls do show


@pytest.mark.parametrize("memory", ["episode", "frame"])
def test_map_memory_decides_whether_a_wall_left_behind_stays_in_the_patch(env, memory):
    # face the corridor's left wall, then turn on the spot to face the right one
    env.map_memory = memory
    try:
        env.reset(seed=0, options={"start": (0.0, 0.0, math.pi / 2), "goal": (9.0, 0.0)})
        for _ in range(40):
            obs, _, terminated, _, info = env.step(np.array([0.0, -1.0], np.float32))
            assert not terminated
            if abs(info["pose"][2] + math.pi / 2) < 0.2:
                break
        for _ in range(4):
            obs, *_ = env.step(np.array([0.0, 0.0], np.float32))
    finally:
        env.map_memory = "episode"
    occ = obs["occupancy"]
    # the right wall 1.2 m ahead (row 28) is seen either way; the left wall is now 1.2 m behind (row 4)
    assert occ[26:31].any()
    assert occ[:10].any() == (memory == "episode")


def test_driving_toward_the_goal_earns_progress_reward(unsafe_env):
    # the drive's own response to full speed (the safety layer's acceleration limit is tested apart)
    env = unsafe_env
    env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (4.0, 0.0)})
    progress, rewards, distances = [], [], []
    for _ in range(10):
        obs, reward, terminated, _, info = env.step(np.array([1.0, 0.0], np.float32))
        progress.append(info["reward_terms"]["progress"])
        rewards.append(reward)
        distances.append(info["distance"])
        assert not terminated
    assert all(p > 0 for p in progress)
    assert sum(rewards) > 0.3  # about 0.5 m covered in 1 s (motor rise time included)
    assert distances == sorted(distances, reverse=True)
    assert abs(obs["goal"][1]) < 0.1  # still heading at the goal


def test_reaching_the_goal_terminates_with_the_success_bonus(env):
    env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (1.0, 0.0)})
    for _ in range(40):
        _, reward, terminated, _, info = env.step(np.array([0.5, 0.0], np.float32))
        if terminated:
            break
    assert terminated and info["is_success"] and not info["collision"]
    assert info["distance"] <= 0.3
    assert info["reward_terms"]["success"] == 10.0 and reward > 9.0


def test_observations_lie_inside_the_observation_space(env):
    obs, _ = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs, *_ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        assert env.observation_space.contains(obs)


def test_out_of_range_actions_are_clipped_like_the_unit_box(env):
    actions_big = [np.array([5.0, 0.0])] * 3
    actions_one = [np.array([1.0, 0.0])] * 3
    _, ra = _run(env, 4, actions_big)
    _, rb = _run(env, 4, actions_one)
    assert ra == rb


def test_bad_actions_and_options_are_refused_with_a_clear_error(env):
    env.reset(seed=0)
    with pytest.raises(NavigationEnvError, match="action"):
        env.step(np.array([np.nan, 0.0]))
    with pytest.raises(NavigationEnvError, match="action"):
        env.step(np.array([1.0, 0.0, 0.0]))
    with pytest.raises(NavigationEnvError, match="unknown"):
        env.reset(options={"stat": (0, 0, 0)})
    with pytest.raises(NavigationEnvError, match="outside"):
        env.reset(options={"start": (0.0, 0.0, 0.0), "goal": (500.0, 0.0)})


@pytest.mark.parametrize(
    ("action", "says"),
    [
        (np.array([[0.5, 0.0]]), r"shape \(1, 2\)"),
        (np.array([[0.5], [0.0]]), r"shape \(2, 1\)"),
        (np.array([True, False]), "dtype bool"),
        (np.array([0.5 + 1j, 0.0]), "dtype complex128"),
        ("go", "dtype <U2"),
        ([0.5, "left"], "dtype <U"),
        ([[0.5, 0.0], [0.1]], "two finite real numbers"),
    ],
    ids=["shape-1x2", "shape-2x1", "bool", "complex", "string", "mixed", "ragged"],
)
def test_an_action_that_is_not_two_real_numbers_is_refused_with_a_clear_error(env, action, says):
    """The action space is Box(-1, 1, (2,)): only a shape-(2,) array of real numbers belongs to it."""
    env.reset(seed=0)
    with pytest.raises(NavigationEnvError, match=f"^action=[^\n]*{says}"):
        env.step(action)


def test_a_bool_is_not_a_discrete_action():
    from robchair.envs.observation import action_space, action_to_twist
    from robchair.platform.kinematics import DiffDrive

    space, drive = action_space("discrete"), DiffDrive()
    assert action_to_twist(1, space, drive, 0.6, 2.0) == pytest.approx((0.18, 0.0))  # 0.3 x 0.6 m/s
    with pytest.raises(NavigationEnvError, match="expected an integer"):
        action_to_twist(True, space, drive, 0.6, 2.0)


def test_a_goal_far_off_the_floor_is_refused_as_outside_the_map_even_without_a_start(env):
    with pytest.raises(NavigationEnvError, match=r"^goal \(500\.0, 0\.0\) lies outside the scene's map"):
        env.reset(options={"goal": (500.0, 0.0)})


def test_a_goal_at_the_start_is_refused_at_reset(env):
    # the default goal tolerance is 0.3 m: a goal 0.2 m from the start is reached before any step
    _, info = env.reset(seed=0)
    x, y, theta = info["pose"]
    for goal in ((x, y), (x + 0.2, y)):
        with pytest.raises(NavigationEnvError, match=r"within the goal tolerance 0\.3 m"):
            env.reset(options={"start": (x, y, theta), "goal": goal})


def test_bad_constructor_arguments_are_refused_before_anything_is_built():
    from robchair.envs.navigation import RobChairNavigationEnv

    with pytest.raises(NavigationEnvError, match="render_mode"):
        RobChairNavigationEnv(render_mode="human")
    with pytest.raises(NavigationEnvError, match="sensor"):
        RobChairNavigationEnv(sensor="kinect2-hd")
    with pytest.raises(NavigationEnvError, match="see nothing"):
        RobChairNavigationEnv(sensor=None, sonars=False)
    with pytest.raises(NavigationEnvError, match="agent_hz"):
        RobChairNavigationEnv(agent_hz=7)
    with pytest.raises(NavigationEnvError, match="scene"):
        RobChairNavigationEnv(scene="no_such_scene")


def test_render_draws_the_chair_and_the_goal_where_they_are(env):
    env.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (4.0, 0.0)})
    img = env.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    red = np.argwhere((img == (220, 30, 30)).all(axis=2))
    green = np.argwhere((img == (0, 170, 0)).all(axis=2))
    assert len(red) and len(green)
    # same row band (both at y ~ 0), goal 4 m = 40 cells = 120 px east of the chair's footprint centre
    px_per_m = 3 / env.grid.cell_size
    dx = green[:, 1].mean() - red[:, 1].mean()
    assert dx == pytest.approx((4.0 - env.spec_robot.body.centre_x) * px_per_m, abs=4)
    assert green[:, 0].mean() == pytest.approx(red[:, 0].mean(), abs=4)


def test_a_random_policy_runs_until_the_time_limit_truncates(env):
    e = gymnasium.wrappers.TimeLimit(env, max_episode_steps=5)
    obs, _ = e.reset(seed=9)
    e.action_space.seed(9)
    done = False
    n = 0
    while not done:
        assert e.observation_space.contains(obs)
        obs, _, terminated, truncated, _ = e.step(e.action_space.sample())
        n += 1
        done = terminated or truncated
    assert n <= 5 and (truncated or terminated)


def test_close_releases_the_pybullet_client_and_is_idempotent():
    import pybullet as p

    from robchair.envs.navigation import RobChairNavigationEnv

    e = RobChairNavigationEnv(sensor=None, sonars=True)
    e.reset(seed=0)
    client = e.chair.world.client
    assert p.getConnectionInfo(physicsClientId=client)["isConnected"] == 1
    e.close()
    assert p.getConnectionInfo(physicsClientId=client)["isConnected"] == 0
    e.close()
    with pytest.raises(NavigationEnvError, match="closed"):
        e.step(np.zeros(2))


def test_sonar_only_variant_observes_six_ranges_and_is_deterministic():
    e = gymnasium.make("RobChair/NavigationSonar-v0")
    try:
        actions = [np.array([0.6, 0.2], np.float32)] * 6
        obs_a, rew_a = _run(e, 2, actions)
        obs_b, rew_b = _run(e, 2, actions)
        assert rew_a == rew_b
        for oa, ob in zip(obs_a, obs_b):
            assert e.observation_space.contains(oa)
            assert oa["sonar"].shape == (6,)
            for k in oa:
                np.testing.assert_array_equal(oa[k], ob[k])
    finally:
        e.close()


def test_odometry_pose_source_stays_close_to_ground_truth_over_a_short_drive():
    from robchair.envs.navigation import RobChairNavigationEnv

    e = RobChairNavigationEnv(pose_source="odometry")
    try:
        e.reset(seed=0, options={"start": (0.0, 0.0, 0.0), "goal": (4.0, 0.0)})
        for _ in range(15):
            _, _, _, _, info = e.step(np.array([0.8, 0.2], np.float32))
        (x, y, th), (ex, ey, eth) = info["pose"], info["pose_estimate"]
        assert math.hypot(x - ex, y - ey) < 0.1
        assert abs(th - eth) < 0.05
        assert (x, y) != (ex, ey)  # it is an estimate, not the ground truth
    finally:
        e.close()


@pytest.mark.slow
def test_bench_env_writes_one_row_per_configuration_against_the_physics_only_baseline(tmp_path, capsys):
    import argparse
    import json
    import os
    import re

    from robchair.commands import bench_env

    parser = argparse.ArgumentParser()
    bench_env.register(parser.add_subparsers())
    # --out is the results folder; the bench writes bench_env.json in it (robchair.commands.bench_output)
    args = parser.parse_args(["env", "--steps", "3", "--repeats", "1", "--out", str(tmp_path / "bench")])
    assert args.func(args) == 0
    result = json.loads((tmp_path / "bench" / "bench_env.json").read_text())
    names = [r["config"] for r in result["rows"]]
    assert names == [c["name"] for c in bench_env.CONFIGS]
    assert result["rows"][0]["ratio_to_physics_only"] == 1.0
    for r in result["rows"]:
        assert r["median_steps_per_s"] > 0 and len(r["steps_per_s"]) == 1
        assert r["real_time_factor"] == pytest.approx(r["median_steps_per_s"] / 10)
    out = capsys.readouterr().out
    assert "light, 2 Async workers" in out
    by_name = {r["config"]: r for r in result["rows"]}
    assert by_name["Kinect, 2 independent processes"]["speedup_vs_one_env"] > 0
    assert by_name["light, 1 ms idle per step"]["idle_cpu_vs_one_env"] > 0  # its CPU over back to back
    assert "light, 1 ms idle per step: " in out
    for r in result["rows"]:
        if r["config"].endswith("2 Async workers") and os.path.isdir("/proc/self/task"):
            # each worker's threads and its CPU per step over one env's: oversubscription shows here
            assert len(r["worker_threads"]) == 2 and min(r["worker_threads"]) >= 1
            assert r["worker_cpu_vs_one_env"] > 0
    # every target gets its line with the verdict, whatever the machine's speed (no target asserted here)
    targets = {**bench_env.TARGET_RATIO_PHYSICS, **bench_env.TARGET_SPEEDUP}
    for name, goal in targets.items():
        assert re.search(rf"^{re.escape(name)}: .*target >= {goal}x.*: (met|missed)\)$", out, re.M), name


def test_bench_env_measures_the_v1_ids_without_gymnasiums_upgrade_warning() -> None:
    """The ids the bench's targets name are v1; Gymnasium warns "is out of date" for each make of one
    (a v2 is registered), which flooded the bench's output. The bench silences that one warning."""
    import warnings

    from robchair.commands import bench_env

    light = next(c for c in bench_env.CONFIGS if c.get("id") == "RobChair/Navigation-v1")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = bench_env.measure(light, steps=1, repeats=1, seed=0)
    assert res["median_steps_per_s"] > 0
    assert not [w for w in caught if "out of date" in str(w.message)]


def test_bench_env_reads_a_process_cpu_time_from_proc() -> None:
    """The async rows' per-worker CPU comes from /proc/<pid>/stat: for this process it follows the
    CPU it burns (within the clock tick), and a missing pid gives None, not a number."""
    import os
    import sys
    import time

    from robchair.commands import bench_env

    if not sys.platform.startswith("linux"):
        pytest.skip("/proc is Linux's")
    (before,) = bench_env._cpu_of([os.getpid()]) or [None]
    c0 = time.process_time()
    while time.process_time() - c0 < 0.3:
        pass
    (after,) = bench_env._cpu_of([os.getpid()]) or [None]
    assert before is not None and after is not None
    assert after - before == pytest.approx(0.3, abs=0.05)
    assert bench_env._cpu_of([]) is None
    assert bench_env._cpu_of([2**22 + 12345]) is None
