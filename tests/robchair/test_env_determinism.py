"""Determinism of the navigation environment across episodes: what ran before never shows in an episode.

Two environments live through different first episodes (other seeds, other starts, other ramped
commands, randomisation on); their second episodes, with the same seed and the same ramped commands,
must agree bit for bit in every observation, reward and pose. The first environment's first episode drives
forward and back to where it started (wheels turned back about to where they were): the physics
engine's contact cache then still holds the wheels' old contact points, which a state snapshot
restored with ``restoreState`` keeps, and the next episode from that start would feel them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pybullet")
gymnasium = pytest.importorskip("gymnasium")

import sim.envs  # noqa: E402,F401  (registers the ids)

STEPS = 32


def _ramp(k: int, phase: float) -> np.ndarray:
    """A command that changes every step: speed ramps up and down, the yaw rate swings."""
    v = 0.15 + 0.5 * abs(math.sin(0.19 * k + phase))
    w = 0.6 * math.sin(0.31 * k + 2.0 * phase)
    return np.array([v, w], np.float32)


def _back_and_forth(k: int, phase: float) -> np.ndarray:
    """Forward, then back by about as much: the chair ends near its start."""
    return np.array([0.3 * math.sin(2.0 * math.pi * k / STEPS), 0.0], np.float32)


def _episode(env, seed, phase, options=None, command=_ramp):
    obs, info = env.reset(seed=seed, options=options)
    out = [(obs, 0.0, info["pose"])]
    for k in range(STEPS):
        obs, reward, terminated, truncated, info = env.step(command(k, phase))
        out.append((obs, reward, info["pose"]))
        if terminated or truncated:
            break
    return out


def _assert_identical(a, b):
    assert len(a) == len(b)
    for (oa, ra, pa), (ob, rb, pb) in zip(a, b, strict=True):
        assert oa.keys() == ob.keys()
        for key in oa:
            assert np.array_equal(oa[key], ob[key]), key
        assert ra == rb
        assert pa == pb


@pytest.mark.parametrize("env_id", ["RobChair/Navigation-v1", "RobChair/NavigationSonar-v0"])
def test_a_second_episode_does_not_depend_on_what_the_first_one_did(env_id):
    first = gymnasium.make(env_id)
    second = gymnasium.make(env_id)
    try:
        # different first episodes: other seeds, starts, goals and commands
        start = (0.2, 0.0, 0.1)
        ep_a = _episode(first, 11, 0.0, {"start": start, "goal": (4.0, 0.0)}, _back_and_forth)
        ep_b = _episode(second, 12, 1.3, {"start": (0.5, -0.3, 0.4), "goal": (4.5, 0.0)})
        assert len(ep_a) == len(ep_b) == STEPS + 1
        assert math.dist(ep_a[-1][2][:2], start[:2]) < 0.05  # back near the start
        opts = {"start": start, "goal": (8.0, 0.0)}
        again_a = _episode(first, 5, 0.7, opts)
        again_b = _episode(second, 5, 0.7, opts)
        assert len(again_a) == STEPS + 1  # the whole episode ran: no collision, no goal
        _assert_identical(again_a, again_b)
    finally:
        first.close()
        second.close()
