"""Reward terms of the navigation task: pure functions of the step's outcome."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the navigation reward.

    Attributes:
        progress: Reward per metre the goal distance shrank during the step.
        collision: Penalty when the chair touched a scene body during the step.
        time: Cost of every step.
        success: Bonus when the goal is reached.
    """

    progress: float = 1.0
    collision: float = 10.0
    time: float = 0.01
    success: float = 10.0


def reward_terms(
    prev_distance: float,
    distance: float,
    collided: bool,
    reached: bool,
    weights: RewardWeights = RewardWeights(),
) -> dict[str, float]:
    """The reward's parts: ``progress``, ``collision``, ``time``, ``success`` (their sum is the reward)."""
    return {
        "progress": weights.progress * (prev_distance - distance),
        "collision": -weights.collision if collided else 0.0,
        "time": -weights.time,
        "success": weights.success if reached else 0.0,
    }


def navigation_reward(
    prev_distance: float,
    distance: float,
    collided: bool,
    reached: bool,
    weights: RewardWeights = RewardWeights(),
) -> float:
    """Reward of one step: progress toward the goal, minus collision and time costs, plus success.

    ``progress * (prev_distance - distance) - time - collision * collided + success * reached``.

    Args:
        prev_distance: Goal distance before the step, m.
        distance: Goal distance after the step, m.
        collided: The chair touched a scene body during the step.
        reached: The goal is reached after the step.
        weights: The weights.
    """
    return float(sum(reward_terms(prev_distance, distance, collided, reached, weights).values()))
