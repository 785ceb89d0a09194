"""A stand-in env for `robchair bench env`: Gymnasium's ``AsyncVectorEnv`` on this machine without RobChair.

The stand-in has the light env's observation and action spaces and does a fixed amount of pure
computation per step, calibrated to the light env's CPU per step measured earlier in the same run.
Two Async workers of it against one of it in-process is what Gymnasium's lockstep vector env (pipes,
shared-memory observations, the info merge) and the machine's scheduler allow for that much work per
step, with nothing of the twin in it: the ceiling of the "2 Async workers" rows. The ``info`` variant
returns the light env's own ``info`` of one step at every step, so the parent merges what it merges for
the real env.
"""

from __future__ import annotations

import time
from typing import Any

import gymnasium
import numpy as np

#: Iterations of :func:`_work` per calibration run.
_CALIBRATE_N = 200_000


def _work(n: int) -> float:
    """``n`` iterations of scalar arithmetic (the stand-in's step)."""
    x = 0.0
    for k in range(n):
        x += (k & 7) * 0.5
    return x


def iterations_for(cpu_ms: float) -> int:
    """Iterations of :func:`_work` that take ``cpu_ms`` of CPU here, back to back (median of 5)."""
    times = []
    for _ in range(5):
        c = time.thread_time()
        _work(_CALIBRATE_N)
        times.append(time.thread_time() - c)
    per = float(np.median(times)) / _CALIBRATE_N
    return max(1, round(cpu_ms * 1e-3 / per)) if per > 0 else _CALIBRATE_N


class StandInEnv(gymnasium.Env):  # type: ignore[misc]
    """``iterations`` of :func:`_work` per step; zero observations of ``observation_space``; ``info``
    returned as given (a dict) at every step."""

    def __init__(
        self, observation_space: Any, action_space: Any, iterations: int, info: dict[str, Any]
    ) -> None:
        self.observation_space = observation_space
        self.action_space = action_space
        self.iterations = int(iterations)
        self.info = info
        self._obs = _zeros(observation_space)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        return self._obs, {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        _work(self.iterations)
        return self._obs, 0.0, False, False, self.info


def _zeros(space: Any) -> Any:
    """A zero (or first) element of a Box, Discrete or Dict space."""
    if isinstance(space, gymnasium.spaces.Dict):
        return {k: _zeros(s) for k, s in space.spaces.items()}
    if isinstance(space, gymnasium.spaces.Box):
        return np.zeros(space.shape, space.dtype)
    return space.sample()


def light_template(env_id: str, seed: int) -> tuple[Any, Any, dict[str, Any]]:
    """The env's observation and action spaces and its ``info`` after one step from a seeded reset."""
    env = gymnasium.make(env_id)
    try:
        env.reset(seed=seed)
        env.action_space.seed(seed)
        info = env.step(env.action_space.sample())[4]
        return env.observation_space, env.action_space, dict(info)
    finally:
        env.close()


def measure_standin(env_id: str, cpu_ms: float, steps: int, repeats: int, seed: int) -> dict[str, Any]:
    """Steps per second of one stand-in in-process and of two in Async workers, with and without the
    env's info: medians, and the two speedups over one."""
    import statistics

    obs_space, act_space, info = light_template(env_id, seed)
    n = iterations_for(cpu_ms)

    def rate(env: Any, workers: int) -> float:
        env.reset(seed=seed)
        env.action_space.seed(seed)
        action = env.action_space.sample()  # a vector env's space is the batched one
        for _ in range(5):
            env.step(action)
        t0 = time.perf_counter()
        for _ in range(steps):
            env.step(action)
        return workers * steps / (time.perf_counter() - t0)

    out: dict[str, Any] = {"iterations": n, "cpu_ms_asked": cpu_ms}
    one = StandInEnv(obs_space, act_space, n, {})
    out["one_steps_per_s"] = statistics.median(rate(one, 1) for _ in range(repeats))
    for key, inf in (("async2_steps_per_s", {}), ("async2_with_info_steps_per_s", info)):
        fns = [lambda inf=inf: StandInEnv(obs_space, act_space, n, inf) for _ in range(2)]
        envs = gymnasium.vector.AsyncVectorEnv(fns, context="fork")
        try:
            out[key] = statistics.median(rate(envs, 2) for _ in range(repeats))
        finally:
            envs.close()
    out["speedup"] = out["async2_steps_per_s"] / out["one_steps_per_s"]
    out["speedup_with_info"] = out["async2_with_info_steps_per_s"] / out["one_steps_per_s"]
    return out
