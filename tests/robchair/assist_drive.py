"""A kinematic drive of the assistance stage and the real safety layer in a planar world (for tests).

The chair is a unicycle that follows the safety layer's output exactly; its laser (the spec's
``laser_link`` mount, URG-04LX field of view 240 degrees at 0.352 degree steps, range 5.6 m: Hokuyo
URG-04LX specification) scans :class:`sim.planar.PlanarWorld` every cycle at 20 Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from robchair.assistance import AssistedSource
from robchair.perception_queries import Corridor
from robchair.platform.kinematics import Pose2D
from robchair.platform.safety import SafetyInputs, SafetyLayer, SafetyLimits
from robchair.platform.spec import load_spec
from robchair.sources import Command, Observation
from sim.planar import PlanarWorld

RATE_HZ = 20.0
ANGLES = np.deg2rad(np.arange(-120.0, 120.0, 0.352))


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


def drive(world: PlanarWorld, mode: str, person, start: tuple[float, float, float], cycles: int) -> Drive:  # type: ignore[no-untyped-def]
    spec = load_spec()
    limits = SafetyLimits.from_spec(spec)
    safety = SafetyLayer(limits)
    corridor = Corridor.from_spec(spec)
    laser_x = float(spec.mounts["laser_link"].transform()[0, 3])
    b = spec.body
    x, y, th = start
    out = Drive()

    def base_points(px: float, py: float, pth: float) -> np.ndarray:
        lx, ly = px + laser_x * math.cos(pth), py + laser_x * math.sin(pth)
        odom = world.scan(lx, ly, pth, ANGLES)
        d = odom - (px, py)
        c, s = math.cos(pth), math.sin(pth)
        return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)

    state = {"pts": np.zeros((0, 2))}
    stage = AssistedSource(person, spec, limits.max_speed, limits.max_yaw_rate, mode,
                           obstacles=lambda obs: state["pts"], rate_hz=RATE_HZ)  # fmt: skip
    dt = 1.0 / RATE_HZ
    for k in range(cycles):
        pts = base_points(x, y, th)
        state["pts"] = pts
        stamp = round(k * dt * 1e9)
        cmd = stage.command(Observation(stamp, Pose2D(x, y, th), None, (), None))
        dec = safety.filter(cmd.v, cmd.w, SafetyInputs(stamp, map_distance_m=corridor.distance_ahead(pts),
                                                     deadman=cmd.deadman), dt)  # fmt: skip
        out.reports.append(dict(stage.last))
        out.applied.append((dec.v, dec.w))
        if dec.w != 0.0:
            r = dec.v / dec.w
            x += r * (math.sin(th + dec.w * dt) - math.sin(th))
            y -= r * (math.cos(th + dec.w * dt) - math.cos(th))
        else:
            x += dec.v * dt * math.cos(th)
            y += dec.v * dt * math.sin(th)
        th += dec.w * dt
        out.poses.append((x, y, th))
        out.contact |= world.contact(x, y, th, b.centre_x, 0.5 * b.depth, 0.5 * b.width)
    out.stops = [s.reason.value for s in safety.stops]
    return out
