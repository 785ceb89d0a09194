"""Shared control as a Gymnasium environment (``RobChair/SharedControl-v0``): learn to assist a person.

A seeded simulated user (:class:`sim.user.SimulatedUser`, a preset of :data:`sim.user.PRESETS`) wants
to reach the episode's goal by the shortest route on the scene's ground truth and pushes the joystick
toward it, with their reaction delay, hand dynamics, tremor and dead zone. The agent sees what the
person pushes beside the light observation and chooses the command the chair applies; the reward
pays progress and safety and charges disagreement with the person.

Usage::

    import gymnasium
    import sim.envs  # registers the ids

    env = gymnasium.make("RobChair/SharedControl-v0", user="tremor")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(obs["joystick"])  # apply the person's command
"""

from __future__ import annotations

import math
from typing import Any, SupportsFloat

import gymnasium
import numpy as np
from gymnasium.utils import EzPickle

from robchair.assistance.stage import cosine
from robchair.envs.navigation import RobChairNavigationEnv
from sim.envs.errors import NavigationEnvError

AGREEMENT_WEIGHT = 0.05  # per step: 300 steps of full disagreement cost 15, beyond the success bonus (10)
SAFETY_WEIGHT = 0.05  # per step the safety layer had to change the applied command


class RobChairSharedControlEnv(RobChairNavigationEnv):
    """Apply a command for a person who steers the chair toward a goal with a joystick.

    The task, scene, chair, physics, sensors, runtime and episode end are those of
    :class:`robchair.envs.navigation.RobChairNavigationEnv` (its docstring; the id registers the
    light observation on the office scene). What differs:

    ## The person

    On every reset a :class:`sim.user.SimulatedUser` of preset ``user`` (``"typical"``, ``"tremor"``,
    ``"switch"``, or a :class:`sim.user.UserParams`) is seeded from ``np_random`` (after start, goal
    and the chair's draw). Their route is the shortest path from the start to the goal on the scene's
    ground truth inflated by half the chair's width (:func:`robchair.navigation.planner.plan_path`,
    string-pulled), or the straight line when there is none. They look at the chair's true pose and
    sample the stick at their own rate on the physics clock.

    ## Observation Space

    The light observation's ``Dict`` plus ``joystick``: ``Box(-1, 1, (2,), float32)``, the person's
    stick (forward, turn; +turn is counter-clockwise) at the end of the step, i.e. what they ask for
    during the next one.

    ## Action Space

    The applied command, as in the navigation env: ``[v, w]`` normalised to ``max_speed`` and
    ``max_yaw_rate`` (then the safety layer and the motors' limits). Applying ``obs["joystick"]``
    unchanged is the ``off`` mode of the assistance stage.

    ## Rewards

    The navigation terms (``progress``, ``collision``, ``time``, ``success``, weights ``reward_weights``)
    plus

    * ``agreement``: ``agreement_weight * (cos - 1)`` where ``cos`` is the cosine between the person's
      stick during the step and the normalised action (the evaluation's agreement metric,
      :func:`robchair.assistance.stage.cosine`); when the person lets go (stick zero), ``-agreement_weight
      * min(1, |action|)``: moving a person who asked to stand still is the worst disagreement. Zero
      when the command is the person's.
    * ``safety``: ``-safety_weight`` on every step the safety layer had to change the applied command
      (a command that needs the stop is unsafe even when the stop saves the chair).

    ``info["reward_terms"]`` holds every part; their sum is the reward. ``info["joystick"]`` is the
    stick the step's reward compared the action with.

    Args:
        render_mode: ``None`` or ``"rgb_array"``.
        user: the simulated user's preset name or parameters.
        agreement_weight: weight of ``agreement`` per step (>= 0).
        safety_weight: weight of ``safety`` per step (>= 0).
        **kwargs: the navigation env's arguments.

    Raises:
        NavigationEnvError: an unknown preset, a negative or non-finite weight, or a bad navigation
            argument.
    """

    def __init__(self, render_mode: str | None = None, user: Any = "tremor",
                 agreement_weight: float = AGREEMENT_WEIGHT, safety_weight: float = SAFETY_WEIGHT,
                 **kwargs: Any) -> None:  # fmt: skip
        from sim.user import PRESETS, UserParams

        if isinstance(user, str):
            if user not in PRESETS:
                raise NavigationEnvError(f"user={user!r}: expected one of {', '.join(PRESETS)} or UserParams")
            params = PRESETS[user]
        elif isinstance(user, UserParams):
            params = user
        else:
            raise NavigationEnvError(f"user={user!r}: expected one of {', '.join(PRESETS)} or UserParams")
        for name, w in (("agreement_weight", agreement_weight), ("safety_weight", safety_weight)):
            if isinstance(w, bool) or not isinstance(w, int | float) or not math.isfinite(w) or w < 0:
                raise NavigationEnvError(f"{name}={w!r}: expected a finite number >= 0")
        super().__init__(render_mode, **kwargs)
        EzPickle.__init__(self, render_mode, user=user, agreement_weight=agreement_weight,
                          safety_weight=safety_weight, **kwargs)  # fmt: skip
        self.user_params = params
        self.agreement_weight, self.safety_weight = float(agreement_weight), float(safety_weight)
        spaces = dict(self.observation_space.spaces)  # type: ignore[attr-defined]
        spaces["joystick"] = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.observation_space = gymnasium.spaces.Dict(spaces)  # type: ignore[assignment]
        self.person: Any = None
        self._stick = np.zeros(2, np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """The navigation env's reset, then a new simulated user for the episode (see the class)."""
        obs, info = super().reset(seed=seed, options=options)
        from sim.user import SimulatedUser

        start = (self.start_pose.x, self.start_pose.y)
        world = self.chair.world

        def pose() -> tuple[float, float, float]:
            p = self.chair.ground_truth_pose()
            return p.x, p.y, p.theta

        seed_ = int(self.np_random.integers(0, 2**31 - 1))
        route = self.user_route(start, self.goal)
        self.person = SimulatedUser(route, pose, lambda: round(world.time * 1e9), self.user_params, seed_)
        return self._with_stick(obs), info

    def user_route(self, start: tuple[float, float], goal: tuple[float, float]) -> list[tuple[float, float]]:
        """The person's waypoints from ``start`` to ``goal`` (goal last), m: see the class."""
        from robchair.navigation.planner import PlannerConfig, cost_map, plan_path, shortcut

        cfg = PlannerConfig(inflation=self.spec_robot.body.width / 2, comfort=1.0, comfort_weight=0.0)
        occupied = self.free_space.occupied
        route = plan_path(occupied, self.grid, start, goal, cfg)
        if route is None:
            return [goal]
        cost = cost_map(occupied, self.grid.cell_size, cfg)
        cost[tuple(int(v) for v in self.grid.world_to_index(*start))] = 1.0  # the start may hug a wall
        return [*shortcut(route, cost, self.grid)[1:-1], goal]

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        """The navigation env's step with the agreement and safety terms (see the class).

        Raises:
            NavigationEnvError: as the navigation env's step.
        """
        stick = (float(self._stick[0]), float(self._stick[1]))
        v, w = self.action_twist(action) if self.person is not None else (0.0, 0.0)
        obs, _, terminated, truncated, info = super().step(action)
        a = (v / self.max_speed, w / self.max_yaw_rate)
        if stick == (0.0, 0.0):
            agreement = -self.agreement_weight * min(1.0, math.hypot(*a))
        else:
            agreement = self.agreement_weight * (cosine(stick, a) - 1.0)
        terms = {**info["reward_terms"], "agreement": agreement,
                 "safety": -self.safety_weight if info["safety"]["intervened"] else 0.0}  # fmt: skip
        info["reward_terms"], info["joystick"] = terms, stick
        return self._with_stick(obs), float(sum(terms.values())), terminated, truncated, info

    def _with_stick(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        r = self.person.read()
        self._stick = np.clip(np.array([r.forward, r.turn], np.float32), -1.0, 1.0)
        return {**obs, "joystick": self._stick.copy()}


__all__ = ["AGREEMENT_WEIGHT", "SAFETY_WEIGHT", "RobChairSharedControlEnv"]
