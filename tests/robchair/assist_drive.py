"""Drive the assistance stage and the real safety layer on the planar chair (for tests).

The chair (:class:`robchair.assistance.evaluation.PlanarChair`) is a unicycle following the safety
layer's output; its laser (``laser_link``, URG-04LX field of view 240 degrees, 683 beams, 5.6 m:
Hokuyo URG-04LX specification) scans :class:`sim.planar.PlanarWorld` every cycle at 20 Hz.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from robchair.assistance import AssistConfig, AssistedSource
from robchair.assistance.evaluation import PlanarChair
from robchair.assistance.evaluation import drive as planar_drive
from robchair.platform.safety import SafetyLimits
from robchair.platform.spec import load_spec
from robchair.sources import Command, Observation
from sim.planar import PlanarWorld

RATE_HZ = 20.0


class Scripted:
    """A person whose command is ``fn(k)`` at cycle ``k``."""

    def __init__(self, fn):  # type: ignore[no-untyped-def]
        self.fn, self.k = fn, 0

    def command(self, obs: Observation) -> Command:
        c = self.fn(self.k)
        self.k += 1
        return c


@dataclass
class Drive:
    poses: list[tuple[float, float, float]] = field(default_factory=list)
    applied: list[tuple[float, float]] = field(default_factory=list)
    reports: list[dict] = field(default_factory=list)  # type: ignore[type-arg]
    contact: bool = False
    stops: list[str] = field(default_factory=list)


def drive(
    world: PlanarWorld,
    mode: str,
    person,
    start: tuple[float, float, float],
    cycles: int,  # type: ignore[no-untyped-def]
    config: AssistConfig | None = None,
) -> Drive:
    spec = load_spec()
    limits = SafetyLimits.from_spec(spec)
    chair = PlanarChair(world, spec, limits, *start)
    stage = AssistedSource(person, spec, limits.max_speed, limits.max_yaw_rate, mode, config, rate_hz=RATE_HZ)
    d = planar_drive(chair, stage, cycles, RATE_HZ)
    poses = [start, *[tuple(p) for p in d["poses"]]]
    applied = [(float(a), float(b)) for a, b in d["applied"]]
    return Drive(poses, applied, d["reports"], d["contact"], d["stops"])  # type: ignore[arg-type]
