"""Fast paths of an environment step, each against the exact path it replaces (bit for bit)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapping.grid import GridSpec
from robchair.platform.kinematics import Pose2D
from sim.envs.geometry import egocentric_patch, egocentric_values

pytest.importorskip("pybullet")
gymnasium = pytest.importorskip("gymnasium")

import sim.envs  # noqa: E402, F401  (registers the ids)


def _counted(fn, calls: list[int]):  # type: ignore[no-untyped-def]
    """``fn`` that appends to ``calls`` at every call."""

    def wrapper(*a, **k):  # type: ignore[no-untyped-def]
        calls.append(1)
        return fn(*a, **k)

    return wrapper


def _grids() -> list[GridSpec]:
    return [GridSpec(cell_size=0.1, size_x=15.8, size_y=8.2, centre=(4.0, -1.0)),
            GridSpec(cell_size=0.05, size_x=6.0, size_y=4.0)]  # fmt: skip


def test_the_compiled_egocentric_crop_is_numpys_bit_for_bit():
    """sim.envs._patch_kernels.crop against the numpy crop: random poses in and far outside the grid,
    on cell edges (yaw 0 and pi/2 put centres on cell boundaries), bool, uint8 and float32 values."""
    rng = np.random.default_rng(3)
    for grid in _grids():
        nx, ny = grid.shape
        occ = rng.random((nx, ny)) < 0.3
        codes = rng.integers(0, 3, (nx, ny)).astype(np.uint8)
        top = rng.uniform(0.0, 2.5, (nx, ny)).astype(np.float32)
        x0, x1, y0, y1 = grid.extent
        poses = [Pose2D(float(rng.uniform(x0 - 3, x1 + 3)), float(rng.uniform(y0 - 3, y1 + 3)),
                        float(rng.uniform(-math.pi, math.pi))) for _ in range(200)]  # fmt: skip
        poses += [Pose2D(x0 + 1.0, y0 + 1.0, 0.0), Pose2D(x0 + 2.0, y0 + 0.5, math.pi / 2),
                  Pose2D(1e300, -1e300, 1.0), Pose2D(x1 + 100.0, y1, -math.pi)]  # fmt: skip
        inside = 0
        for pose in poses:
            for shape, cell, behind in (((64, 64), 0.1, 1.6), ((10, 7), 0.05, 0.0)):
                a = egocentric_patch(occ, grid, pose, shape, cell, behind)
                b = egocentric_patch(occ, grid, pose, shape, cell, behind, compiled=False)
                assert a.dtype == b.dtype == np.uint8 and a.shape == shape
                np.testing.assert_array_equal(a, b)
                inside += int(b.sum())
                for vals, fill in ((codes, 2), (top, 0.0), (top, 7.5)):
                    a = egocentric_values(vals, grid, pose, shape, cell, behind, fill)
                    b = egocentric_values(vals, grid, pose, shape, cell, behind, fill, compiled=False)
                    assert a.dtype == b.dtype == vals.dtype
                    np.testing.assert_array_equal(a.view(np.uint8), b.view(np.uint8))
        assert inside > 1000  # the poses saw the grid, not only the fill


def test_a_thesis_maps_occupied_cells_come_without_its_codes(monkeypatch):
    """Perception.occupied_2d of the thesis map is the band's boolean grid itself, equal to where its
    nav_msgs codes are 100 (the earlier path), without computing those codes."""
    import mapping.derived as derived
    from robchair.perception import Perception
    from robchair.platform.spec import load_spec

    spec = load_spec()
    p = Perception(spec, grid=GridSpec(cell_size=0.1, size_x=6.0, size_y=6.0), map_kind="thesis")
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-3, 3, 4000), rng.uniform(-3, 3, 4000), rng.uniform(0.0, 2.0, 4000)])
    p.map.insert(pts, sensor_origin=(0.0, 0.0, 0.5))
    ref = p.occupancy_2d() == 100
    assert 0 < ref.sum() < ref.size
    monkeypatch.setattr(derived, "occupancy_codes", lambda *a, **k: pytest.fail("codes computed"))
    np.testing.assert_array_equal(p.occupied_2d(), ref)


def test_a_probabilistic_env_step_reads_the_maps_codes_once(monkeypatch):
    """A -v2 (probabilistic map) step computes the band's codes once; occupied is where they are 100."""
    from robchair.perception import Perception

    env = gymnasium.make("RobChair/Navigation-v2", max_episode_steps=10).unwrapped
    try:
        env.reset(seed=0)
        calls: list[int] = []
        monkeypatch.setattr(Perception, "occupancy_2d", _counted(Perception.occupancy_2d, calls))
        env.step(np.array([0.3, 0.1], np.float32))
        assert len(calls) == 1
        np.testing.assert_array_equal(env._occ, env.runtime.perception.occupancy_2d() == 100)
    finally:
        env.close()


def _drive(env, steps: int = 6) -> list[tuple[float, float, float]]:
    return [env.step(np.array([0.8, 0.4 - 0.15 * k], np.float32))[4]["pose"] for k in range(steps)]


@pytest.mark.parametrize("randomization", [False, True])
def test_the_physics_steps_look_for_a_latent_set_point_only_while_one_waits(monkeypatch, randomization):
    """EpisodeClock hands the motors' apply_due to the physics steps only while a set point waits for
    its due step (a command latency > 0); with none pending the 24 steps of an agent period call
    nothing, and the episode is the one a check before every physics step gives."""
    from robchair.envs import chair as ec

    calls: list[int] = []
    monkeypatch.setattr(ec.EpisodeMotors, "apply_due", _counted(ec.EpisodeMotors.apply_due, calls))
    poses = []
    for always in (False, True):
        env = gymnasium.make("RobChair/Navigation-v1", randomization=randomization).unwrapped
        try:
            env.reset(seed=5)
            if always:  # the earlier path: apply_due before every physics step
                chair, due = env.chair, env._backend.motors.apply_due
                monkeypatch.setattr(
                    chair, "step_collecting_contacts", _with_before(chair.step_collecting_contacts, due)
                )
            latency = env._backend.motors.latency_steps
            assert (latency > 0) == randomization  # seed 5 draws a latency: both cases are seen
            calls.clear()
            poses.append(_drive(env))
            own = 6 if latency == 0 else 0  # set_speeds_rpm applies a set point without latency itself
            # with a latency the set point waits in every period: its steps look (both paths)
            stepping = 6 * env.substeps if always or latency else 0
            assert len(calls) == own + stepping, (always, latency)
        finally:
            env.close()
    assert poses[0] == poses[1]


def _with_before(step, before):  # type: ignore[no-untyped-def]
    return lambda n, _before=None: step(n, before)


def test_the_chairs_pose_is_refused_when_the_physics_diverged():
    """SimRobot.base_pose checks the 7 numbers as floats: a NaN or inf anywhere raises."""
    from sim.chair import SimChair
    from sim.errors import SimulationDivergedError

    chair = SimChair(sensor=None, sonars=False)
    try:
        chair.step(2)
        g = chair.ground_truth_pose()
        assert all(map(math.isfinite, (g.x, g.y, g.theta)))
        import pybullet as p

        for bad in ((math.nan, 0.0, 0.3), (0.0, math.inf, 0.3)):
            p.resetBasePositionAndOrientation(chair.robot.body, bad, (0, 0, 0, 1),
                                              physicsClientId=chair.world.client)  # fmt: skip
            with pytest.raises(SimulationDivergedError, match="non-finite"):
                chair.ground_truth_pose()
    finally:
        chair.close()
