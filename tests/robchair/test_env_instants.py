"""The environment's chair read once per instant of the physics: the motor state and the true pose
are the readings they replace, and a new instant (a step, an emergency stop, a restart) reads anew."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")
gymnasium = pytest.importorskip("gymnasium")

import sim.envs  # noqa: E402, F401  (registers the ids)


@pytest.fixture
def env():  # type: ignore[no-untyped-def]
    e = gymnasium.make("RobChair/Navigation-v1")
    e.reset(seed=2)
    yield e.unwrapped
    e.close()


def test_the_motor_state_is_the_controllers_reading_through_the_tyres(env):
    motors = env._backend.motors
    rng = np.random.default_rng(0)
    for _ in range(12):
        env.step(np.array([rng.uniform(0.2, 1.0), rng.uniform(-1, 1)], np.float32))
        a, b = motors.read_state(), motors.read_state_reference()
        assert a == b and a.encoder_counts != (0, 0)
        assert motors.read_state() is a  # the same instant: the same reading
    motors.emergency_stop()
    stopped = motors.read_state()
    assert stopped.faults.emergency_stop and stopped == motors.read_state_reference()
    motors.release_stop()
    env.chair.step(1)  # the next physics step is another instant
    assert motors.read_state() is not stopped and motors.read_state() == motors.read_state_reference()


def test_the_true_pose_is_read_once_per_instant_and_anew_after_a_restart(env):
    truth = env._truth
    for _ in range(5):
        env.step(np.array([0.8, 0.3], np.float32))
        assert truth.now() == env.chair.ground_truth_pose()
    before = truth.now()
    steps = env.chair.world.steps
    env.chair.restart(env.start_pose)
    env.chair.step(steps)  # the same step count in another episode of the physics
    assert env.chair.world.steps == steps
    assert truth.now() == env.chair.ground_truth_pose() != before


def test_the_sensor_pose_and_the_heading_are_the_frames_modules_bit_for_bit():
    from robchair.envs.chair import se3_from_quat, yaw_from_quat
    from robchair.platform import frames

    rng = np.random.default_rng(3)
    for _ in range(2000):
        q = rng.normal(size=4) * rng.choice([1e-6, 1.0, 1e3])  # not normalised: both normalise
        pos = tuple(rng.uniform(-10, 10, 3))
        a, b = se3_from_quat(pos, tuple(q)), frames.se3_from_quat(pos, tuple(q))
        assert a.dtype == b.dtype and a.shape == b.shape == (4, 4)
        np.testing.assert_array_equal(a.view(np.uint64), b.view(np.uint64))
        ya, yb = yaw_from_quat(tuple(q)), frames.yaw_from_quat(tuple(q))
        assert np.float64(ya).view(np.uint64) == np.float64(yb).view(np.uint64)
    with pytest.raises(ValueError, match="non-zero"):
        se3_from_quat((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="non-zero"):
        yaw_from_quat((0.0, 0.0, 0.0, 0.0))
