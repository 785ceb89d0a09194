"""Run navigation episodes for evaluation: one pure function per episode, so episodes can be
distributed over processes or machines (``evaluate_episode(env_id, seed, policy_spec) -> dict``).

Policies are named by a spec string:

* ``baseline`` - :class:`robchair.navigation.planner.BaselinePolicy` (planner on the chair's own map);
* ``random`` - uniformly random actions (seeded by the episode's seed);
* ``MODULE:CALLABLE`` - ``CALLABLE(env)`` (imported from ``MODULE``, the current folder first on the
  import path) returns the policy: a callable
  ``policy(obs, info) -> action``, optionally with ``reset()`` called at the start of the episode.
"""

from __future__ import annotations

import importlib
import math
import os
import sys
from typing import Any

import numpy as np

from robchair.navigation.metrics import barn_score, spl_term
from robchair.navigation.planner import (
    BaselinePolicy,
    PlannerConfig,
    RandomPolicy,
    cost_map,
    path_length,
    plan_path,
    shortcut,
)
from robchair.platform.errors import RobChairError

_ENVS: dict[tuple[str, str], Any] = {}


class EvaluationError(RobChairError, ValueError):
    """An evaluation argument (environment id, policy spec) is invalid."""


def policy_factory(spec: str) -> Any:
    """The factory ``CALLABLE`` of a ``MODULE:CALLABLE`` spec (None for ``baseline`` / ``random``).

    Raises:
        EvaluationError: an unknown name, a module or attribute that does not exist.
    """
    if spec in ("baseline", "random"):
        return None
    if ":" not in spec:
        raise EvaluationError(f"policy {spec!r}: expected 'baseline', 'random' or MODULE:CALLABLE")
    mod_name, _, attr = spec.partition(":")
    if os.getcwd() not in sys.path:  # MODULE may live in the current folder (e.g. examples.sb3_light)
        sys.path.insert(0, os.getcwd())
    try:
        factory = getattr(importlib.import_module(mod_name), attr)
    except ModuleNotFoundError as exc:
        raise EvaluationError(f"policy {spec!r}: no module {exc.name!r}") from None
    except AttributeError:
        raise EvaluationError(f"policy {spec!r}: module {mod_name!r} has no {attr!r}") from None
    if not callable(factory):
        raise EvaluationError(f"policy {spec!r}: {attr!r} is not callable")
    return factory


def make_policy(spec: str, env: Any, seed: int) -> Any:
    """The policy named by ``spec`` for ``env`` (see the module docstring).

    Raises:
        EvaluationError: an unknown name, a module or attribute that does not exist.
    """
    if spec == "baseline":
        return BaselinePolicy(env)
    if spec == "random":
        return RandomPolicy(env, seed)
    factory = policy_factory(spec)
    return factory(env)


def _env(env_id: str, env_kwargs: dict[str, Any]) -> Any:
    """One environment per (id, arguments) and process, reused across episodes (reset is by seed)."""
    import gymnasium

    import sim.envs  # registers the ids

    key = (env_id, repr(sorted(env_kwargs.items())))
    if key not in _ENVS:
        if env_id not in gymnasium.registry:
            raise EvaluationError(f"--env {env_id!r}: not a registered id (RobChair ids: {sim.envs.ENV_IDS})")
        _ENVS[key] = gymnasium.make(env_id, **env_kwargs)
    return _ENVS[key]


def close_envs() -> None:
    """Close the environments this process keeps for evaluation."""
    for env in _ENVS.values():
        env.close()
    _ENVS.clear()


def shortest_path_length(env: Any, start: tuple[float, float], goal: tuple[float, float]) -> float:
    """Length (m) of the shortest route for the chair on the scene's ground truth (SPL's ``l``).

    Planned on the ground-truth raster inflated by half the chair's width, without comfort cost,
    string-pulled, never shorter than the straight line, less the goal tolerance (an episode succeeds
    on the tolerance circle, so that is where the shortest successful path ends).
    """
    u = env.unwrapped
    cfg = PlannerConfig(inflation=u.spec_robot.body.width / 2, comfort=1.0, comfort_weight=0.0)
    route = plan_path(u.free_space.occupied, u.grid, start, goal, cfg)
    straight = math.hypot(goal[0] - start[0], goal[1] - start[1])
    if route is None:
        return max(straight - u.goal_tolerance, 0.0)
    cost = cost_map(u.free_space.occupied, u.grid.cell_size, cfg)
    cost[tuple(int(v) for v in u.grid.world_to_index(*start))] = 1.0  # the start may hug a wall
    length = max(path_length(shortcut(route, cost, u.grid)), straight)
    return max(length - u.goal_tolerance, 0.0)


def evaluate_episode(
    env_id: str,
    seed: int,
    policy_spec: str,
    env_kwargs: dict[str, Any] | None = None,
    keep_trajectory: bool = False,
) -> dict[str, Any]:
    """Run one episode of ``policy_spec`` on ``env_id`` from ``reset(seed=seed)`` and measure it.

    Args:
        env_id: A registered Gymnasium id.
        seed: The episode's seed (start, goal, floor, chair, noise, and the random policy).
        policy_spec: ``baseline``, ``random`` or ``MODULE:CALLABLE``.
        env_kwargs: Extra arguments for :func:`gymnasium.make`.
        keep_trajectory: Add ``trajectory`` (driven x, y), ``routes`` (the baseline's plans), the
            ground-truth and own occupancy (for pictures) to the result.

    Returns:
        ``seed``, ``success``, ``collision``, ``contacts``, ``truncated``, ``steps``, ``time_s``,
        ``path_length_m``, ``shortest_path_m``, ``spl``, ``barn_score``, ``safety_interventions``
        (steps on which the safety layer changed the command: stopped or limited it) and
        ``safety_stops`` (steps it stopped the chair) - both None when the environment reports no
        safety layer - ``start``, ``goal``, ``scene``.
    """
    env = _env(env_id, dict(env_kwargs or {}))
    obs, info = env.reset(seed=int(seed))
    policy = make_policy(policy_spec, env, int(seed))
    if hasattr(policy, "reset"):
        policy.reset()
    u = env.unwrapped
    start = tuple(info["pose"][:2])
    goal = tuple(info["goal"])
    traj = [start]
    interventions: int | None = None
    stops: int | None = None
    terminated = truncated = False
    steps = 0
    while not (terminated or truncated):
        obs, _, terminated, truncated, info = env.step(policy(obs, info))
        steps += 1
        traj.append(tuple(info["pose"][:2]))
        shield = info.get("safety")
        if isinstance(shield, dict) and "intervened" in shield:
            interventions = (interventions or 0) + int(bool(shield["intervened"]))
            limited = str(shield.get("reason") or "").startswith("limited")  # else a stop reason
            stops = (stops or 0) + int(bool(shield["intervened"]) and not limited)
    shortest = shortest_path_length(env, start, goal)  # type: ignore[arg-type]
    driven = path_length(traj)
    success = bool(info["is_success"])
    time_s = steps / u.agent_hz
    out: dict[str, Any] = {
        "seed": int(seed),
        "scene": u.scene.name,
        "start": list(info_start(start)),
        "goal": list(goal),
        "success": success,
        "collision": bool(info["collision"]),
        "contacts": list(info.get("contacts", [])),
        "truncated": bool(truncated and not terminated),
        "steps": steps,
        "time_s": time_s,
        "path_length_m": driven,
        "shortest_path_m": shortest,
        "spl": spl_term(success, shortest, driven),
        "barn_score": barn_score(success, shortest, u.drive.max_speed, time_s),
        "safety_interventions": interventions,
        "safety_stops": stops,
    }
    if keep_trajectory:
        grid, own = u.own_occupancy()
        out["trajectory"] = np.asarray(traj).tolist()
        out["routes"] = [list(map(list, r)) for r in getattr(policy, "routes", [])]
        out["_grid"] = grid
        out["_own"] = own
        out["_truth"] = u.free_space.occupied.copy()
    return out


def info_start(start: tuple[float, ...]) -> tuple[float, float]:
    """(x, y) of a start as JSON-friendly floats."""
    return float(start[0]), float(start[1])
