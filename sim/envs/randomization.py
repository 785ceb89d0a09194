"""Domain randomisation of the simulated chair: the ranges, and one episode's draw from them.

Every range is a closed interval ``(low, high)`` sampled uniformly (``low == high`` fixes the value).
The environment draws one :class:`EpisodeDynamics` per episode from its ``np_random`` after the start
and the goal, always in the same order, so the same seed gives the same chair bit for bit.

Sources of the default ranges:

* tyre radius: pneumatic tyres change their rolling radius with pressure and load by a few tenths of a
  percent; the odometry keeps the spec's radius, which is what makes it drift;
* floor friction: rubber on dry vinyl, linoleum and sealed concrete, Coulomb coefficients 0.6-1.0;
* payload: the person in the seat, 50-120 kg (adult users of powered wheelchairs);
* motor plant: the identified ``omega_n`` and ``xi`` (SPEC 5, thesis Appendix B) within +-5 %, the spread
  of the three step tests behind each mean;
* sensor noise: the models' noise standard deviations scaled by 0.8-1.2;
* command latency: 0-50 ms between the agent's command and the motor controller (serial link and
  controller cycle of the real chair).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from sim.errors import SimError

Range = tuple[float, float]


@dataclass(frozen=True)
class EpisodeDynamics:
    """One episode's chair, drawn from :class:`DomainRandomization`.

    Attributes:
        tyre_radius_scale: True (left, right) tyre radius relative to the spec's.
        floor_friction: Coulomb friction coefficient of the floor.
        payload_kg: Mass of the person in the seat, kg.
        motor_omega_n_scale: Natural frequency of each motor plant relative to the identified one.
        motor_xi_scale: Damping ratio of each motor plant relative to the identified one.
        sensor_noise_scale: Factor on every sensor's noise standard deviation.
        command_latency_s: Delay from the agent's command to the motor controller, s.
    """

    tyre_radius_scale: tuple[float, float] = (1.0, 1.0)
    floor_friction: float = 1.0
    payload_kg: float = 0.0
    motor_omega_n_scale: tuple[float, float] = (1.0, 1.0)
    motor_xi_scale: tuple[float, float] = (1.0, 1.0)
    sensor_noise_scale: float = 1.0
    command_latency_s: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (for ``info`` and JSON)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class DomainRandomization:
    """Ranges of the per-episode randomisation (uniform; ``(a, a)`` fixes a value).

    Attributes:
        tyre_radius_scale: Range of each tyre's true radius relative to the spec's (drawn per wheel).
        floor_friction: Range of the floor's friction coefficient.
        payload_kg: Range of the seated person's mass, kg.
        motor_omega_n_scale: Range of each motor plant's natural frequency relative to the identified.
        motor_xi_scale: Range of each motor plant's damping ratio relative to the identified.
        sensor_noise_scale: Range of the factor on the sensors' noise standard deviations.
        command_latency_s: Range of the command latency, s.
    """

    tyre_radius_scale: Range = (0.995, 1.005)
    floor_friction: Range = (0.6, 1.0)
    payload_kg: Range = (50.0, 120.0)
    motor_omega_n_scale: Range = (0.95, 1.05)
    motor_xi_scale: Range = (0.95, 1.05)
    sensor_noise_scale: Range = (0.8, 1.2)
    command_latency_s: Range = (0.0, 0.05)

    _LIMITS = {  # noqa: RUF012 - class constant, not a field
        "tyre_radius_scale": (0.9, 1.1),
        "floor_friction": (0.05, 2.0),
        "payload_kg": (0.0, 250.0),
        "motor_omega_n_scale": (0.5, 2.0),
        "motor_xi_scale": (0.5, 2.0),
        "sensor_noise_scale": (0.0, 5.0),
        "command_latency_s": (0.0, 0.5),
    }

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            lo_ok, hi_ok = self._LIMITS[f.name]
            try:
                lo, hi = (float(v) for v in value)
            except (TypeError, ValueError):
                raise SimError(f"{f.name}={value!r}: expected a range (low, high)") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and lo_ok <= lo <= hi <= hi_ok):
                raise SimError(f"{f.name}={value!r}: expected {lo_ok} <= low <= high <= {hi_ok}")
            object.__setattr__(self, f.name, (lo, hi))

    @classmethod
    def off(cls) -> DomainRandomization:
        """No randomisation: the nominal chair (spec tyres, friction 1, no payload, no latency)."""
        return cls(
            tyre_radius_scale=(1.0, 1.0),
            floor_friction=(1.0, 1.0),
            payload_kg=(0.0, 0.0),
            motor_omega_n_scale=(1.0, 1.0),
            motor_xi_scale=(1.0, 1.0),
            sensor_noise_scale=(1.0, 1.0),
            command_latency_s=(0.0, 0.0),
        )

    def sample(self, rng: np.random.Generator) -> EpisodeDynamics:
        """One episode's chair; always draws the same count of numbers in the same order."""

        def u(r: Range, n: int = 1) -> Any:
            x = rng.uniform(r[0], r[1], size=n)
            return float(x[0]) if n == 1 else (float(x[0]), float(x[1]))

        return EpisodeDynamics(
            tyre_radius_scale=u(self.tyre_radius_scale, 2),
            floor_friction=u(self.floor_friction),
            payload_kg=u(self.payload_kg),
            motor_omega_n_scale=u(self.motor_omega_n_scale, 2),
            motor_xi_scale=u(self.motor_xi_scale, 2),
            sensor_noise_scale=u(self.sensor_noise_scale),
            command_latency_s=u(self.command_latency_s),
        )
