"""The assistance stage: a command source that wraps the person's and helps them drive.

It sits in the one drive loop (:class:`robchair.runtime.Runtime`) between the person's command (a
:class:`robchair.sources.JoystickSource`, real or simulated) and the safety layer
(:class:`robchair.platform.safety.SafetyLayer`), which still checks everything it outputs. Modes
(:data:`MODES`, switchable at runtime through :attr:`AssistedSource.mode`):

- ``off``: the person's command, unchanged (the safety layer alone);
- ``shield``: the person's command, its forward speed capped by a ramp from ``shield_slow_m`` down
  to ``shield_stop_m`` of free corridor ahead (the slow-down zone of Nav2's Collision Monitor,
  https://docs.nav2.org/configuration/packages/configuring-collision-monitor.html, made continuous);
- ``assist``: the admissible twist nearest the person's over a short horizon
  (:func:`robchair.assistance.window.search`, a dynamic-window search); near a doorway the person
  points at, the doorway passage's twist (:class:`robchair.assistance.passage.Passage`, back-off
  included) when it keeps clear for ``GUIDE_HORIZON_S``, else the window guided by it. The person's
  own twist passes unchanged when, held, it takes the chair through the doorway with the safety
  layer's margin (:meth:`AssistedSource._person_clears`), and a chair already near the centre line
  and along it follows the line at once (``JOIN_*``) instead of braking onto the approach pose and
  turning there: a clean push is not slowed by the passage;
- ``door``: ``assist``, and when a doorway (:func:`robchair.assistance.doorway.find_doorways`) lies
  where the person's command points, the chair follows the doorway's centre line at the person's
  speed (at most ``door_speed``) and hands control back once its rear edge is through, or once the
  person has steered away for ``override_s`` (doorway assistance of partially automated wheelchairs:
  Argall lab, Northwestern, SPEC section 7). A doorway is taken only while the chair faces through it
  (within ``MAX_ENGAGE_PHI_RAD`` of its normal), and a different one only ``NEW_DOOR_M`` from where
  the last was let go.

The person always wins:

- a released dead-man, or a zero command, gives zero (``v = w = 0``) in every mode (the dead-man
  also ends a doorway passage; a zero command pauses it);
- a reverse command beyond ``reverse_release`` of the speed cap held for ``override_s`` passes
  unchanged and lets the doorway go (the chair's sensors look forward; the safety layer bounds it); a
  slighter or shorter one, the tremor of a stick about its centre, counts as no forward speed;
- a command opposite to the assistance (cosine < 0 between the two twists scaled to the limits)
  held for ``override_s`` passes unchanged from then on: the person's command is applied at most
  ``ceil(override_s * rate_hz)`` cycles after it began (6 cycles, 0.3 s, at 20 Hz), and the doorway
  is let go.

Every cycle :attr:`AssistedSource.last` says what the stage did and why (``action``, ``reason``, the
person's and the applied twist, the clearance, the doorway) and :attr:`AssistedSource.counts` counts
the actions, the way the safety layer reports its stops.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robchair.assistance.doorway import Doorway, DoorwayParams, find_doorways
from robchair.assistance.passage import Passage, PassageParams, PointMemory, door_coordinates, refine
from robchair.assistance.window import Footprint, WindowParams, arc_clearance, first_per_cell, search
from robchair.platform.config import bounds, check_dataclass
from robchair.platform.errors import ConfigError
from robchair.platform.kinematics import Pose2D
from robchair.platform.safety import SafetyLimits
from robchair.platform.spec import RobChairSpec
from robchair.sources import Command, CommandSource, Observation

MODES = ("off", "shield", "assist", "door")
SAME_DOOR_M = 0.5  # m: a doorway found again within this of the last one keeps its passage
# m: once a doorway is let go (through, or the person steered away), another one is taken only after the
# chair has moved this far from there: the person's swing of the stick past a doorway they are
# aligning with, or in the room just entered, points at any gap in view (random floors, seeds
# 1000000009, 1000000075, 1000000097: a gap 2 m aside taken over the doorway being passed, or in the
# room, and the chair turned away from the goal); the same doorway is taken again at once
NEW_DOOR_M = 1.0
# rad: a doorway is taken only while the chair's heading is within this of its normal (through it). The
# corridor's side doors are seen at 85-100 degrees; the office floor's seed 1000000028 took a gap at
# 156 degrees, half behind the chair, turned toward it and never reached the doorway ahead
MAX_ENGAGE_PHI_RAD = math.radians(120.0)
GUIDE_HORIZON_S = 0.5  # s: how far ahead ``assist`` checks the doorway passage's twist before taking it
# s: ``assist`` lets the person's own twist through a doorway when, held, it brings the rear edge
# ``door_through_m`` past the doorway's plane within this, the safety layer's corridor around and ahead
# of the footprint clear of every point (:meth:`AssistedSource._person_clears`). The approach pose is
# 1.0 m before the plane and the approach brakes onto it from 0.48 m before it at 0.49 m/s (the typical
# user's push): 1.48 + 0.26 + 0.2 m to go at 0.49 m/s is 4.0 s
CLEAR_HORIZON_S = 5.0
# ``assist`` follows the doorway's centre line at once (the passage's ``pass`` law, no approach pose and
# no turn in place) from a chair JOIN_BEFORE_M to JOIN_FROM_M before the doorway's plane, within
# JOIN_OFFSET_M of the line and JOIN_PHI_RAD of its normal: the line law (``lookahead_m`` 0.25 m) joins
# the line within about 0.5 m. Aiming at the approach pose instead brings the chair there askew (office
# episode 7, typical user: 7 degrees), where the person's straight push does not clear the jambs and
# the passage brakes and turns in place. Not from farther: there the line law, blended with a tremor
# user's swings by the window, snaked along the corridor and reached the doorway 30 degrees askew
# (office episode 1, tremor user: 6.4 s slower)
JOIN_BEFORE_M = 0.9
JOIN_FROM_M = 1.6
JOIN_OFFSET_M = 0.12
JOIN_PHI_RAD = math.radians(15.0)


def check_mode(mode: str) -> str:
    """``mode`` if it is one of :data:`MODES`, else ConfigError naming the allowed values."""
    if mode not in MODES:
        raise ConfigError(f"assistance mode {mode!r}: expected one of {', '.join(MODES)}")
    return mode


@dataclass(frozen=True)
class AssistConfig:
    """Parameters of the stage (SI units).

    Attributes:
        override_s: how long an opposite command must last before it wins, s.
        shield_slow_m: free corridor ahead below which ``shield`` starts slowing, m.
        shield_stop_m: free corridor ahead at which ``shield`` has slowed to zero, m.
        door_speed: forward speed cap while passing a doorway, m/s.
        door_engage_rad: the person's intended direction (current heading + w * 1 s) must be within
            this of the doorway's bearing for ``door`` to take it, rad.
        door_release_rad: the person's intended direction this far from the doorway, held for
            ``override_s``, lets it go, rad.
        door_lookahead_m: look-ahead of the pursuit of the doorway's centre line, m.
        door_through_m: the rear edge this far past the doorway's plane ends the passage, m.
        steer_share: a turn command below this share of the yaw-rate cap never lets a doorway go.
        reverse_release: a reverse command faster than this share of the speed cap, held for
            ``override_s``, passes unchanged and lets the doorway go; a slighter or shorter one
            (tremor about the stick's centre) counts as zero forward speed.
        crop_m: obstacle points farther than this from ``base_link`` are ignored, m.
        cell_m: obstacle points are thinned to one per cell of this size, m.
    """

    override_s: float = field(default=0.3, metadata=bounds(gt=0, le=2.0))
    shield_slow_m: float = field(default=1.0, metadata=bounds(gt=0))
    shield_stop_m: float = field(default=0.2, metadata=bounds(ge=0))
    door_speed: float = field(default=0.45, metadata=bounds(gt=0))
    door_engage_rad: float = field(default=0.45, metadata=bounds(gt=0, le=math.pi))
    door_release_rad: float = field(default=0.9, metadata=bounds(gt=0, le=math.pi))
    door_lookahead_m: float = field(default=0.25, metadata=bounds(gt=0))
    door_through_m: float = field(default=0.2, metadata=bounds(ge=0))
    steer_share: float = field(default=0.3, metadata=bounds(ge=0, le=1.0))
    reverse_release: float = field(default=0.5, metadata=bounds(ge=0, le=1.0))
    crop_m: float = field(default=2.5, metadata=bounds(gt=0))
    cell_m: float = field(default=0.04, metadata=bounds(gt=0))

    def __post_init__(self) -> None:
        check_dataclass(self, "assistance")
        if self.shield_stop_m >= self.shield_slow_m:
            raise ConfigError(
                f"assistance.shield_stop_m = {self.shield_stop_m}: "
                f"expected < shield_slow_m = {self.shield_slow_m}"
            )


def thin_points(points: np.ndarray, crop_m: float, cell_m: float) -> np.ndarray:
    """Points (N, 2) within ``crop_m`` of the origin, one per ``cell_m`` grid cell (the first of each)."""
    p = points[np.einsum("ij,ij->i", points, points) <= crop_m * crop_m]
    if len(p) == 0:
        return p
    return p[np.sort(first_per_cell(p, cell_m))]


def perception_obstacles(perception: Any, corridor_front_x: float) -> Callable[[Observation], np.ndarray]:
    """Obstacle points (N, 2) in ``base_link`` from a :class:`robchair.perception.Perception`.

    The last laser scan's returns in the chair's height band, and the nearest obstacle ahead the
    sonars and the depth camera report (``Observation.obstacle_distance_m``) as a point on the
    centre line.
    """

    def points(obs: Observation) -> np.ndarray:
        odom = perception.scan_points_odom()
        pose = obs.pose
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        if odom is None or len(odom) == 0:
            base = np.zeros((0, 2))
        else:
            d = odom - (pose.x, pose.y)
            base = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)
        if obs.obstacle_distance_m is not None and math.isfinite(obs.obstacle_distance_m):
            base = np.vstack([base, [[corridor_front_x + obs.obstacle_distance_m, 0.0]]])
        return base

    return points


def _unit(v: float, w: float, max_speed: float, max_yaw_rate: float) -> tuple[float, float]:
    return v / max_speed, w / max_yaw_rate


def cosine(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Cosine between two scaled twists (1 when both are zero, 0 when one is)."""
    na, nb = math.hypot(*a), math.hypot(*b)
    if na < 1e-9 and nb < 1e-9:
        return 1.0
    if na < 1e-9 or nb < 1e-9:
        return 0.0
    return (a[0] * b[0] + a[1] * b[1]) / (na * nb)


class AssistedSource:
    """The assistance stage around the person's command source.

    Args:
        person: the person's command source (a joystick source).
        spec: the platform (footprint).
        max_speed, max_yaw_rate: the limits the twists are scaled by (the safety layer's caps), m/s, rad/s.
        mode: one of :data:`MODES`.
        config: the stage's parameters.
        window: the window search's samples and weights.
        doorway: what counts as a doorway.
        obstacles: ``obs -> points (N, 2)`` in ``base_link``; None: from the runtime's perception once
            :meth:`bind` is called (the runtime calls it when it starts).
        rate_hz: the loop rate (turns ``override_s`` into cycles).

    Raises:
        ConfigError: an unknown mode.
    """

    def __init__(self, person: CommandSource, spec: RobChairSpec, max_speed: float, max_yaw_rate: float,
                 mode: str = "off", config: AssistConfig | None = None, window: WindowParams | None = None,
                 doorway: DoorwayParams | None = None,
                 obstacles: Callable[[Observation], np.ndarray] | None = None,
                 rate_hz: float = 20.0) -> None:  # fmt: skip
        self.person = person
        self.footprint = Footprint.from_body(spec.body)
        self.max_speed, self.max_yaw_rate = float(max_speed), float(max_yaw_rate)
        self.config = config or AssistConfig()
        self.window = window or WindowParams()
        self.doorway = doorway or DoorwayParams()
        self.obstacles = obstacles
        self.override_cycles = max(1, math.ceil(self.config.override_s * rate_hz - 1e-9))
        self._mode = check_mode(mode)
        self._conflict = 0
        self._reverse = 0  # cycles the person has pulled back beyond reverse_release
        self._away = 0  # cycles the person has steered away from the doorway being passed
        self._door: Doorway | None = None  # the doorway being passed, in odom
        self._last_door: Doorway | None = None  # the last doorway engaged, in odom
        self._held = False  # a doorway was being passed at the last cycle that looked for one
        self._handback: tuple[float, float] | None = None  # odom (x, y) where the last one was let go
        self.dt = 1.0 / rate_hz
        self.passage_params = PassageParams(door_speed=self.config.door_speed,
                                            lookahead_m=self.config.door_lookahead_m)  # fmt: skip
        self._passage = Passage(self.passage_params, self.footprint, self.max_yaw_rate)
        self._memory = PointMemory(round(self.passage_params.memory_s * rate_hz))
        self._stopping = SafetyLimits().stopping_distance  # the safety layer's (default margin, brake)
        self.last: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    @property
    def mode(self) -> str:
        return self._mode

    @mode.setter
    def mode(self, mode: str) -> None:
        self._mode = check_mode(mode)
        self._conflict, self._reverse, self._away, self._door = 0, 0, 0, None
        self._held, self._handback = False, None

    def bind(self, runtime: Any) -> None:
        """Take the obstacle points from the runtime's perception (unless given at construction)."""
        if self.obstacles is None:
            self.obstacles = perception_obstacles(runtime.perception, self.footprint.front_x)

    def _report(self, person: Command, out: Command, action: str, reason: str, **extra: Any) -> Command:
        self.counts[action] = self.counts.get(action, 0) + 1
        self.last = {"mode": self._mode, "action": action, "reason": reason,
                     "person": (person.v, person.w), "applied": (out.v, out.w),
                     "overridden": action not in ("pass", "zero"), **extra}  # fmt: skip
        return out

    def command(self, obs: Observation) -> Command:
        """The twist to hand the safety layer this cycle (see the module's rules)."""
        p = self.person.command(obs)
        if (
            p.deadman is False
            or (p.v == 0.0 and p.w == 0.0)
            or not (math.isfinite(p.v) and math.isfinite(p.w))
        ):
            self._conflict, self._reverse = 0, 0
            if p.deadman is False:
                self._door = None  # a released dead-man ends the passage; a zero command only pauses it
            zero = Command(0.0, 0.0, deadman=p.deadman, done=p.done)
            if not (math.isfinite(p.v) and math.isfinite(p.w)):
                return self._report(p, p, "pass", "non-finite command: the safety layer stops")
            return self._report(
                p, zero, "zero", "dead-man released" if p.deadman is False else "zero command"
            )
        if self._mode == "off":
            return self._report(p, p, "pass", "assistance off")
        pulled = p.v < -self.config.reverse_release * self.max_speed
        self._reverse = self._reverse + 1 if pulled else 0
        if self._reverse >= self.override_cycles:
            self._conflict, self._door = 0, None  # a deliberate pull back lets the doorway go
            return self._report(p, p, "pass", "reverse: the person's command")
        if p.v < 0.0:  # a slighter or shorter pull back (tremor about the centre): no forward speed
            p = Command(0.0, p.w, deadman=p.deadman, done=p.done)
        assert self.obstacles is not None, "AssistedSource needs obstacles= or bind(runtime)"
        cfg = self.config
        far = max(cfg.crop_m, self.doorway.max_range_m + self.doorway.max_width_m)
        raw = np.asarray(self.obstacles(obs), dtype=float).reshape(-1, 2)
        seen = thin_points(raw, far, cfg.cell_m)
        near = seen[np.einsum("ij,ij->i", seen, seen) <= cfg.crop_m * cfg.crop_m]
        # the passage's forward gap on every point near the front, as the safety layer measures it
        front = raw[np.einsum("ij,ij->i", raw, raw) <= cfg.crop_m * cfg.crop_m]
        self._memory.add(near, obs.pose.x, obs.pose.y, obs.pose.theta)
        v, w, action, reason, extra = self._assist(p, obs.pose, near, seen, front)
        up = _unit(p.v, p.w, self.max_speed, self.max_yaw_rate)
        if "_door" in extra:
            # the passage's aim is the doorway (it may turn, wait or back off on the way): the person
            # opposes it by pointing more than 90 degrees from both the doorway and its approach pose
            opposed = self._steers_away(extra.pop("_door"), p, math.pi / 2)
        else:
            opposed = cosine(up, _unit(v, w, self.max_speed, self.max_yaw_rate)) < 0.0
        self._conflict = self._conflict + 1 if opposed else 0
        if self._conflict >= self.override_cycles:
            self._door = None
            return self._report(p, p, "override", "the person's opposite command won", **extra)
        out = Command(v, w, deadman=p.deadman, done=p.done)
        if action != "pass" and math.isclose(v, p.v, abs_tol=1e-9) and math.isclose(w, p.w, abs_tol=1e-9):
            action = "pass"
        return self._report(p, out, action, reason, **extra)

    def _assist(self, p: Command, pose: Pose2D, pts: np.ndarray, seen: np.ndarray, front: np.ndarray
                ) -> tuple[float, float, str, str, dict[str, Any]]:  # fmt: skip
        cfg = self.config
        if self._mode == "shield":
            d = _corridor_free(pts, self.footprint)
            ramp = min(max((d - cfg.shield_stop_m) / (cfg.shield_slow_m - cfg.shield_stop_m), 0.0), 1.0)
            v = min(p.v, ramp * self.max_speed)
            return (
                v,
                p.w,
                "shield",
                f"{d:.2f} m free ahead: speed cap {ramp * self.max_speed:.2f} m/s",
                {"free_m": d},
            )
        door = self._doorway(p, pose, seen)
        guide = None
        if door is not None:
            behind = self._memory.in_base(pose.x, pose.y, pose.theta)
            if self._mode == "door":
                # the person's deflection toward the doorway sets the passage's pace
                speed = self.max_speed * min(1.0, math.hypot(*_unit(p.v, p.w, self.max_speed,
                                                                     self.max_yaw_rate)))  # fmt: skip
                v, w, phase = self._passage.twist(door, speed, self.dt, front, behind)
                extra = {"door_width_m": door.width, "door_distance_m": math.hypot(door.cx, door.cy),
                         "door_phase": phase, "_door": door}  # fmt: skip
                return v, w, "door", f"{phase}: a {door.width:.2f} m doorway", extra
            ds, de, dphi = door_coordinates(door)
            if (
                self._passage.phase == "approach"
                and -JOIN_FROM_M <= ds <= -JOIN_BEFORE_M
                and abs(de) <= JOIN_OFFSET_M
                and abs(dphi) <= JOIN_PHI_RAD
            ):
                self._passage.phase = "pass"
            if self._passage.phase in ("approach", "align", "pass") and self._person_clears(door, p, front):
                # the person already drives cleanly through: no approach pose, no turn in place; should
                # their arc stop clearing, the passage follows the centre line from here (from within
                # JOIN_FROM_M; from farther it approaches again: see JOIN_FROM_M)
                if ds >= -JOIN_FROM_M:
                    self._passage.phase = "pass"
                extra = {"door_width_m": door.width, "door_phase": "clear", "_door": door}
                return p.v, p.w, "pass", f"the person's arc clears a {door.width:.2f} m doorway", extra
            vg, wg, phase = self._passage.twist(door, p.v, self.dt, front, behind)
            if vg <= 0.0 or self._guide_clear(vg, wg, pts):
                # backing off (checked against the points seen behind), turning in place, or clear for
                # the next half second: the passage's own twist reaches the approach pose and the line
                extra = {
                    "door_width_m": door.width,
                    "door_phase": phase,
                    "door_guide": (vg, wg),
                    "_door": door,
                }
                return vg, wg, "window", f"{phase}: guided through a {door.width:.2f} m doorway", extra
            guide = (vg, wg)
        v, w, clear, clear_p = search(
            self.footprint, self.window, p.v, p.w, self.max_speed, self.max_yaw_rate, pts, guide
        )
        extra = {"clearance_m": clear, "person_clearance_m": clear_p}
        if guide is not None:
            extra["door_guide"] = guide
        if v == 0.0 and w == 0.0:
            return v, w, "stop", "no admissible twist within the horizon", extra
        return v, w, "window", f"person's twist clears {clear_p:.2f} m: nearest admissible twist", extra

    def _person_clears(self, d: Doorway, p: Command, pts: np.ndarray) -> bool:
        """Whether the person's twist, held, takes the chair through the doorway ``d`` (``base_link``).

        Held until the rear edge is ``door_through_m`` past the doorway's plane (at most
        ``CLEAR_HORIZON_S``; a longer way is not judged), the footprint widened by the safety layer's
        corridor margin (``PassageParams.corridor_margin_m`` a side) and stretched ahead by its
        stopping distance at the person's speed keeps clear of every point ``pts`` (N, 2): the body
        passes both jambs with the margin and the safety layer never stops it on the way. Sampled
        every 4 cm of travel.
        """
        if p.v <= 0.0:
            return False
        s, _, phi = door_coordinates(d)
        if abs(phi) >= math.pi / 3:
            return False
        fp = self.footprint
        arc = (self.config.door_through_m - fp.rear_x - s) / math.cos(phi)
        if arc <= 0.0 or arc > p.v * CLEAR_HORIZON_S:
            return False
        ahead = self._stopping(p.v)
        margin = self.passage_params.corridor_margin_m
        box = Footprint(fp.centre_x + 0.5 * ahead, fp.half_depth + 0.5 * ahead, fp.half_width + margin)
        reach = arc + box.front_x + box.half_width
        near = pts[np.einsum("ij,ij->i", pts, pts) <= reach * reach].astype(np.float32)
        times = np.linspace(0.0, arc / p.v, max(2, math.ceil(arc / 0.04) + 1))
        return float(arc_clearance(box, np.array([p.v]), np.array([p.w]), times, near)[0]) > 0.0

    def _guide_clear(self, v: float, w: float, pts: np.ndarray) -> bool:
        """Whether holding ``(v, w)`` for ``GUIDE_HORIZON_S`` keeps the window's minimum clearance."""
        times = np.linspace(0.0, GUIDE_HORIZON_S, 4)
        clear = arc_clearance(self.footprint, np.array([v]), np.array([w]), times, pts.astype(np.float32))
        return float(clear[0]) >= self.window.min_clearance_m

    def _doorway(self, p: Command, pose: Pose2D, pts: np.ndarray) -> Doorway | None:
        cfg = self.config
        heading = _intent(p)
        if self._door is None and self._held:  # let go since (override, reverse, dead-man)
            self._held, self._handback = False, (pose.x, pose.y)
        if self._door is not None:
            d = refine(self._door.inverse_transformed(pose.x, pose.y, pose.theta), pts)
            self._door = d.transformed(pose.x, pose.y, pose.theta)
            along = -(d.cx * d.nx + d.cy * d.ny)  # base_link's distance past the doorway's plane
            if along - (self.footprint.half_depth - self.footprint.centre_x) > cfg.door_through_m:
                self._door = None  # through: hand back
                self._held, self._handback = False, (pose.x, pose.y)
                return None
            # the person steers away, held for override_s: a tremor's swing of the stick past
            # steer_share (half a period, 0.1 s at 5 Hz) does not drop the doorway mid-approach
            self._away = self._away + 1 if along < 0 and self._steers_away(d, p) else 0
            if self._away >= self.override_cycles:
                self._door, self._away = None, 0
                self._held, self._handback = False, (pose.x, pose.y)
                return None
            return d
        for d in find_doorways(pts, self.doorway):
            # the chair faces the doorway's through direction within MAX_ENGAGE_PHI_RAD (a side door of a
            # corridor is seen at about 90 degrees; one behind its plane's normal is not the way ahead)
            facing = abs(math.atan2(d.ny, d.nx)) <= MAX_ENGAGE_PHI_RAD
            if facing and abs(_wrap(math.atan2(d.cy, d.cx) - heading)) <= cfg.door_engage_rad:
                d = refine(d, pts)
                odom = d.transformed(pose.x, pose.y, pose.theta)
                last = self._last_door
                new = last is None or math.hypot(odom.cx - last.cx, odom.cy - last.cy) > SAME_DOOR_M
                hb = self._handback
                if new and hb is not None and math.hypot(pose.x - hb[0], pose.y - hb[1]) < NEW_DOOR_M:
                    continue  # another doorway right after one was let go
                self._door, self._held = odom, True
                if new:
                    # a new doorway (the same one again keeps its passage: how far it backed off)
                    self._passage = Passage(self.passage_params, self.footprint, self.max_yaw_rate)
                self._last_door = odom
                return d
        return None

    def _steers_away(self, d: Doorway, p: Command, limit: float | None = None) -> bool:
        """Whether the person turns (at least ``steer_share`` of the yaw-rate cap) toward a direction
        (:func:`_intent`) farther than ``limit`` (default ``door_release_rad``) from both the
        doorway's bearing and that of its approach pose. A straight push lets the passage carry on,
        however the passage has turned the chair."""
        if abs(p.w) < self.config.steer_share * self.max_yaw_rate:
            return False
        heading = _intent(p)
        off = abs(_wrap(math.atan2(d.cy, d.cx) - heading))
        a = self.passage_params.approach_m
        ax, ay = d.cx - a * d.nx, d.cy - a * d.ny
        if math.hypot(ax, ay) > 0.3:
            off = min(off, abs(_wrap(math.atan2(ay, ax) - heading)))
        return off > (self.config.door_release_rad if limit is None else limit)


def _corridor_free(pts: np.ndarray, fp: Footprint) -> float:
    """Free length (m) ahead of the footprint's front edge in its own width (+inf when clear)."""
    if len(pts) == 0:
        return math.inf
    inside = (np.abs(pts[:, 1]) <= fp.half_width) & (pts[:, 0] > fp.centre_x)
    if not inside.any():
        return math.inf
    return max(0.0, float(pts[inside, 0].min()) - fp.front_x)


def _intent(p: Command) -> float:
    """Where the person points, rad in ``base_link``: the heading their turn rate reaches in 1 s."""
    return max(-math.pi / 2, min(math.pi / 2, p.w * 1.0))


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi
