"""Command sources: what gives the runtime a body twist (v, w) each cycle.

A source sees an :class:`Observation` (pose estimate, motor state, sonar readings, the nearest obstacle
ahead) and returns a :class:`Command`. Sources here: a joystick with a dead-man button and any policy
callable; the route follower is :class:`robchair.route.PurePursuit`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from hw.interfaces import MotorState, SonarArrayReading
from robchair.platform.kinematics import Pose2D


@dataclass(frozen=True)
class Observation:
    """What a command source sees each cycle.

    Attributes:
        stamp_ns: time of the cycle on the backend's clock.
        pose: odometry pose in ``odom`` (m, rad).
        motor: the motor controller's state (None when it could not be read).
        sonars: the sonar array readings of this cycle (empty on cycles without sonar reads).
        obstacle_distance_m: nearest obstacle ahead in the chair's corridor from its front edge, m.
    """

    stamp_ns: int
    pose: Pose2D
    motor: MotorState | None
    sonars: tuple[SonarArrayReading | None, ...]
    obstacle_distance_m: float | None


@dataclass(frozen=True)
class Command:
    """A body twist: ``v`` m/s forward, ``w`` rad/s counter-clockwise."""

    v: float
    w: float
    deadman: bool | None = None  # joystick button; None when the source has none
    done: bool = False  # the source has finished (route completed)


class CommandSource(Protocol):
    def command(self, obs: Observation) -> Command: ...


class JoystickSource:
    """Twist from a :class:`hw.interfaces.Joystick`: forward and turn axes scaled to the speed caps."""

    def __init__(self, joystick: Any, max_speed: float, max_yaw_rate: float) -> None:
        self.joystick = joystick
        self.max_speed = max_speed
        self.max_yaw_rate = max_yaw_rate

    def command(self, obs: Observation) -> Command:
        r = self.joystick.read()
        return Command(r.forward * self.max_speed, r.turn * self.max_yaw_rate, deadman=bool(r.deadman))


class PolicySource:
    """Any callable ``policy(observation) -> (v, w)`` (a learned policy, a test script)."""

    def __init__(self, policy: Callable[[Observation], tuple[float, float]]) -> None:
        self.policy = policy

    def command(self, obs: Observation) -> Command:
        v, w = self.policy(obs)
        return Command(float(v), float(w))
