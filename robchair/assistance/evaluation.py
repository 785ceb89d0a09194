"""Episodes of shared control on a planar chair: the simulated user, the assistance and the safety layer.

One episode: a floor's walls (:class:`sim.planar.PlanarWorld`), a start pose and a route; the
simulated user (:class:`sim.user.SimulatedUser`) pushes the joystick toward the route's goal from
the chair's true pose; :class:`robchair.sources.JoystickSource` scales the stick to the safety
layer's caps; the assistance stage (:class:`robchair.assistance.AssistedSource`) and the real
:class:`robchair.platform.safety.SafetyLayer` decide; the chair (:class:`PlanarChair`) is a unicycle
that follows the command within the safety layer's accelerations and its braking deceleration, its
laser (the ``laser_link`` mount; Hokuyo URG-04LX: 240 degrees, 683 beams, 5.6 m) scanning the walls
every 50 ms cycle. It is a kinematic model (no PyBullet): cheap enough for hundreds of episodes.
The safety layer gets what it gets on the chair: the corridor distance ahead from the scan, and for its
swept-footprint check the obstacle points all around the chair (:class:`LocalMemory`: the scans' returns
kept on a 2.5 cm grid in ``odom`` within :data:`MEMORY_RADIUS_M`, the planar analogue of the zoom map's
fine cells that :meth:`robchair.perception.Perception.obstacle_points_base` gives the runtime).

Metrics per episode (:func:`run_episode`): success, time, collisions, safety stops, minimum
clearance; agreement (mean cosine of the person's and the applied (v, w), each scaled to the limits)
and the share of cycles the assistance changed the command, with the agreement lost split by what
the stage did (``agreement_loss``); effort (the stick's path length and
reversals of its turn axis); comfort: peak and RMS longitudinal (dv/dt) and lateral (v w)
acceleration and peak longitudinal jerk. ISO 2631-1:1997 (Annex C) rates frequency-weighted RMS
acceleration: < 0.315 m/s^2 not uncomfortable, 0.315-0.63 a little, 0.5-1.0 fairly uncomfortable
(SPEC section 7); the values here are unweighted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robchair.assistance.stage import AssistedSource, cosine
from robchair.perception_queries import Corridor
from robchair.platform.kinematics import Pose2D
from robchair.platform.safety import Footprint, SafetyInputs, SafetyLayer, SafetyLimits
from robchair.platform.spec import RobChairSpec
from robchair.sources import CommandSource, JoystickSource, Observation

LASER_ANGLES = np.deg2rad(np.linspace(-120.0, 120.0, 683))


#: how far around the chair :class:`LocalMemory` keeps the returns it saw (m): the zoom map's reach
MEMORY_RADIUS_M = 3.0
#: the memory's cell (m): the zoom map's fine cells (5 cm grid, zoom factor 2)
MEMORY_CELL_M = 0.025


class LocalMemory:
    """The laser returns seen so far around the chair, for the safety layer's swept-footprint check.

    Returns are kept once per :data:`MEMORY_CELL_M` cell in ``odom`` and dropped beyond
    :data:`MEMORY_RADIUS_M` of the chair; :meth:`update` gives them in ``base_link``, so walls beside
    and behind the chair, outside the laser's 240 degrees, still count when the chair turns in place.
    """

    def __init__(self) -> None:
        self._cells: np.ndarray = np.zeros((0, 2), dtype=np.int64)

    def update(self, scan_base: np.ndarray, x: float, y: float, theta: float) -> np.ndarray:
        """Add a scan ``scan_base`` (N, 2, ``base_link``, m) taken at the pose ``(x, y, theta)`` (m, rad);
        the kept returns (M, 2) in ``base_link`` at that pose, m (cell centres)."""
        c, s = math.cos(theta), math.sin(theta)
        q = np.asarray(scan_base, dtype=float)
        odom = np.stack([x + c * q[:, 0] - s * q[:, 1], y + s * q[:, 0] + c * q[:, 1]], axis=1)
        cells = np.floor(odom[np.isfinite(odom).all(axis=1)] / MEMORY_CELL_M).astype(np.int64)
        cells = np.unique(np.concatenate([self._cells, cells]), axis=0)
        w = (cells + 0.5) * MEMORY_CELL_M
        near = np.hypot(w[:, 0] - x, w[:, 1] - y) <= MEMORY_RADIUS_M
        self._cells, w = cells[near], w[near]
        d = w - (x, y)
        return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)


@dataclass
class PlanarChair:
    """A unicycle in a planar world, with the spec's footprint and laser mount.

    Attributes:
        world: a :class:`sim.planar.PlanarWorld`.
        spec: the platform.
        limits: the safety layer's limits (braking deceleration, accelerations).
        x, y, theta: the true pose, m and rad.
        v, w: the true twist, m/s and rad/s.
    """

    world: Any
    spec: RobChairSpec
    limits: SafetyLimits
    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    v: float = 0.0
    w: float = 0.0
    laser_x: float = field(init=False)

    def __post_init__(self) -> None:
        self.laser_x = float(self.spec.mounts["laser_link"].transform()[0, 3])

    def scan(self) -> np.ndarray:
        """The laser's returns (N, 2) in ``base_link``, m."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        odom = self.world.scan(self.x + self.laser_x * c, self.y + self.laser_x * s, self.theta, LASER_ANGLES)
        d = odom - (self.x, self.y)
        return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)

    def move(self, v_cmd: float, w_cmd: float, dt: float) -> None:
        """Follow the command for ``dt`` s: speed changes at most ``max(max_accel, brake_decel) * dt``."""
        lim = self.limits
        dv = max(lim.max_accel, lim.brake_decel) * dt
        dw = lim.max_yaw_accel * dt * 2.0
        self.v = min(max(v_cmd, self.v - dv), self.v + dv)
        self.w = min(max(w_cmd, self.w - dw), self.w + dw)
        if abs(self.w) > 1e-9:
            r = self.v / self.w
            self.x += r * (math.sin(self.theta + self.w * dt) - math.sin(self.theta))
            self.y -= r * (math.cos(self.theta + self.w * dt) - math.cos(self.theta))
        else:
            self.x += self.v * dt * math.cos(self.theta)
            self.y += self.v * dt * math.sin(self.theta)
        self.theta += self.w * dt

    def clearance(self) -> float:
        b = self.spec.body
        return float(
            self.world.clearance(self.x, self.y, self.theta, b.centre_x, 0.5 * b.depth, 0.5 * b.width)
        )


def drive(chair: PlanarChair, stage: AssistedSource, cycles: int, rate_hz: float = 20.0,
          until: Any = None, stall_s: float | None = None) -> dict[str, Any]:  # fmt: skip
    """Run the stage and the safety layer on the chair for up to ``cycles`` cycles (or ``until()``).

    ``stall_s``: end early when the chair has moved less than 5 cm and turned less than 0.1 rad over
    the last ``stall_s`` seconds (stuck: the person pushes at a post that the safety layer holds
    it before; the rest of the time limit would change nothing but the run time).

    Returns:
        ``poses`` (K, 3), ``applied`` (K, 2) the safety layer's output, ``twist`` (K, 2) the chair's,
        ``reports`` the stage's :attr:`AssistedSource.last` per cycle, ``stops`` the stop reasons,
        ``contact`` whether the footprint touched a wall, ``clearance_m`` its smallest clearance.
    """
    safety = SafetyLayer(chair.limits, wheel_separation=chair.spec.wheel_separation,
                         footprint=Footprint.from_spec(chair.spec))
    memory = LocalMemory()
    corridor = Corridor.from_spec(chair.spec)
    dt = 1.0 / rate_hz
    holder: dict[str, np.ndarray] = {}
    stage.obstacles = lambda obs: holder["p"]
    poses, applied, twist, reports = [], [], [], []
    contact, min_clear = False, math.inf
    for k in range(cycles):
        pts = chair.scan()
        holder["p"] = pts
        stamp = round(k * dt * 1e9)
        cmd = stage.command(Observation(stamp, Pose2D(chair.x, chair.y, chair.theta), None, (), None))
        around = memory.update(pts, chair.x, chair.y, chair.theta)
        inputs = SafetyInputs(stamp, map_distance_m=corridor.distance_ahead(pts), deadman=cmd.deadman,
                              obstacles_xy=around)
        dec = safety.filter(cmd.v, cmd.w, inputs, dt)
        chair.move(dec.v, dec.w, dt)
        clear = chair.clearance()
        min_clear = min(min_clear, clear)
        poses.append((chair.x, chair.y, chair.theta))
        applied.append((dec.v, dec.w))
        twist.append((chair.v, chair.w))
        reports.append(dict(stage.last))
        if clear <= 0.0:
            contact = True
            break  # the chair touched a wall: the episode ends there
        if until is not None and until():
            break
        lag = round(stall_s * rate_hz) if stall_s else 0
        if lag and k >= lag:
            x0, y0, t0 = poses[-1 - lag]
            if math.hypot(chair.x - x0, chair.y - y0) < 0.05 and abs(chair.theta - t0) < 0.1:
                break
    return {"poses": np.array(poses), "applied": np.array(applied), "twist": np.array(twist),
            "reports": reports, "stops": [s.reason.value for s in safety.stops], "contact": contact,
            "clearance_m": min_clear}  # fmt: skip


def run_episode(world: Any, spec: RobChairSpec, start: tuple[float, float, float],
                route: list[tuple[float, float]], mode: str, user: Any, seed: int, max_time_s: float = 60.0,
                rate_hz: float = 20.0, stall_s: float | None = 15.0) -> dict[str, Any]:  # fmt: skip
    """One episode with a simulated user of :class:`sim.user.UserParams` ``user``; returns its metrics.

    The episode ends at the goal, at a contact, after ``max_time_s`` or when stuck for ``stall_s``
    (:func:`drive`); only the goal with no contact is a success.
    """
    from sim.user import SimulatedUser

    limits = SafetyLimits.from_spec(spec)
    chair = PlanarChair(world, spec, limits, *start)
    clock = {"ns": 0}
    person = SimulatedUser(route, lambda: (chair.x, chair.y, chair.theta), lambda: clock["ns"], user, seed)
    joystick: CommandSource = JoystickSource(person, limits.max_speed, limits.max_yaw_rate)

    class Ticking:
        def command(self, obs: Observation) -> Any:
            clock["ns"] = obs.stamp_ns
            return joystick.command(obs)

    stage = AssistedSource(Ticking(), spec, limits.max_speed, limits.max_yaw_rate, mode, rate_hz=rate_hz)
    d = drive(chair, stage, round(max_time_s * rate_hz), rate_hz, until=lambda: person.done, stall_s=stall_s)
    return episode_metrics(d, person, limits, rate_hz)


def loss_key(report: dict[str, Any]) -> str:
    """What the stage did in one cycle, for attributing lost agreement: its ``action``, and the
    doorway passage's phase when it drove one (``window/back-off``, ``door/pass``, ...)."""
    phase = report.get("door_phase")
    return f"{report['action']}/{phase}" if phase else str(report["action"])


def episode_metrics(d: dict[str, Any], person: Any, limits: SafetyLimits, rate_hz: float) -> dict[str, Any]:
    """The metrics of one :func:`drive` (see the module).

    ``agreement_loss`` splits ``1 - agreement`` by what the stage did (:func:`loss_key`): the sum of
    ``1 - cosine`` over that kind of cycle divided by every counted cycle, so the values add up to
    ``1 - agreement`` (the cycles where the person's command is zero do not count, as for the
    agreement).
    """
    dt = 1.0 / rate_hz
    scale = (limits.max_speed, limits.max_yaw_rate)
    cos, changed = [], 0
    loss: dict[str, float] = {}
    for r in d["reports"]:
        p, a = r["person"], r["applied"]
        if p != (0.0, 0.0):
            cos.append(cosine((p[0] / scale[0], p[1] / scale[1]), (a[0] / scale[0], a[1] / scale[1])))
            key = loss_key(r)
            loss[key] = loss.get(key, 0.0) + 1.0 - cos[-1]
        changed += bool(r["overridden"])
    v, w = d["twist"][:, 0], d["twist"][:, 1]
    a_lon = np.diff(np.concatenate([[0.0], v])) / dt
    a_lat = v * w
    jerk = np.diff(a_lon) / dt if len(a_lon) > 1 else np.zeros(1)
    h = np.array(person.history) if person.history else np.zeros((1, 3))
    stick = h[:, 1:]
    turn = stick[:, 1][np.abs(stick[:, 1]) > 1e-9]
    return {
        "success": bool(person.done and not d["contact"]),
        "time_s": len(d["reports"]) * dt,
        "collisions": int(d["contact"]),
        "safety_stops": len(d["stops"]),
        "min_clearance_m": float(d["clearance_m"]),
        "agreement": float(np.mean(cos)) if cos else 1.0,
        "agreement_loss": {k: v / len(cos) for k, v in sorted(loss.items())},
        "overridden_share": changed / max(1, len(d["reports"])),
        "joystick_path": float(np.sum(np.hypot(*np.diff(stick, axis=0).T))) if len(stick) > 1 else 0.0,
        "reversals": int(np.sum(np.diff(np.sign(turn)) != 0)) if len(turn) > 1 else 0,
        "peak_lon_accel": float(np.max(np.abs(a_lon))),
        "rms_lon_accel": float(np.sqrt(np.mean(a_lon**2))),
        "peak_lat_accel": float(np.max(np.abs(a_lat))),
        "rms_lat_accel": float(np.sqrt(np.mean(a_lat**2))),
        "peak_jerk": float(np.max(np.abs(jerk))),
        "path": d["poses"][:, :2].tolist(),
    }
