"""Doorway passage: onto the door's centre line at an approach pose, backing off first when too close.

A doorway engaged by the ``door`` mode (:mod:`robchair.assistance.stage`) is passed in three phases,
the way assisted door passage on partially automated wheelchairs does (the Argall lab,
Northwestern: detect the doorway ahead, drive to a pose in front of it aligned with its normal, then
through; SPEC section 7), and the way a differential drive reaches a pose (turn toward it, drive,
turn to its heading):

1. ``approach``: drive to the approach pose, ``approach_m`` before the doorway's plane on its centre
   line, facing through it. The chair turns toward that pose and moves forward as it faces it
   (``v = v_person cos^2(bearing)``, none while the safety layer's corridor holds a point within
   ``stop_gap_m``), braking at ``APPROACH_DECEL`` onto it; within ``arrive_m`` of it, or once it lies
   beside or behind the chair within ``pass_by_m`` (chasing a point that close only turns the chair
   back and forth) or ahead within ``pass_by_m`` where the corridor holds the chair, it turns in place
   onto the door's normal (``align``), and from then on never approaches again, unless aligned it
   finds itself more than ``reapproach_m`` off the centre line (it overshot the pose, or took the
   doorway late, beside it): then it approaches again (at most ``max_reapproaches`` times), reaching
   the pose only within ``arrive_m`` (or, held by the corridor, within ``pass_by_m``).
2. ``back-off``: when the approach pose lies behind the chair and near (it came too close to the
   wall, off the line or askew: the jambs would stop it), or when turning toward it would sweep a
   corner into something, it reverses (toward that pose, or straight back) at ``reverse_speed``, at
   most ``reverse_m`` per passage, each step checked against the points seen in the last
   ``memory_s`` (the sensors look forward; the safety layer only checks forward motion).
3. ``pass``: once aligned (``align_tol_rad``), follow the centre line at the person's speed (at most
   ``door_speed``): head for the point ``lookahead_m`` ahead on the line, turning at ``heading_gain``
   per radian off it and slowing by ``cos^2`` of that, until the rear is through. The residual offset
   from the line decays over about ``lookahead_m`` of travel. A jamb in the safety layer's corridor
   within ``stop_gap_m`` slows the chair to a creep; where even that would stop it before the front is
   more than ``front_in_m`` past the doorway's plane (at the wall's face, askew), the chair backs off
   turning onto the normal (within ``reverse_m``) and follows the line again from farther out.

Everything here is in a doorway frame: ``s`` the signed distance of ``base_link`` along the normal
from the doorway's plane (negative before it), ``e`` its offset left of the centre line, ``phi`` its
heading from the normal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robchair.assistance.doorway import Doorway
from robchair.assistance.window import Footprint, arc_clearance, first_per_cell
from robchair.perception_queries import Corridor

# m/s^2: the approach brakes onto its pose at this. The safety layer ramps each wheel's rim speed at most
# max_wheel_accel = 0.4 m/s^2 (SafetyLimits), |dv| + |dw| b / 2 together: planned at 0.4 m/s^2, the
# braking lags whenever the chair also turns, and it overshot the pose by 0.13-0.25 m along the corridor
# (13 of 29 failed random-floor episodes, seeds 1000000000 and on); 0.25 m/s^2 leaves 0.15 m/s^2 to the turn.
APPROACH_DECEL = 0.25


@dataclass(frozen=True)
class PassageParams:
    """Parameters of the passage (SI units).

    Attributes:
        approach_m: ``base_link``'s distance before the doorway's plane at the approach pose, m. 1.0 m
            puts the front edge (0.58 m ahead of ``base_link``) 0.42 m before the wall, beyond
            ``stop_gap_m``, so a jamb a few cm inside the safety corridor does not stop the chair there;
            the front corners' turning circle (radius hypot(0.58, 0.32) = 0.66 m) stays clear of the
            wall, and the rear corners' (hypot(0.26, 0.32) = 0.41 m) of the far wall of a 1.6 m
            corridor (0.6 m behind).
        arrive_m: the approach pose is reached within this, m.
        pass_by_m: an approach pose beside or behind the chair (more than 60 degrees off its heading),
            or ahead of it while the safety layer's corridor holds a point within ``stop_gap_m`` (the
            chair could only turn toward a pose it may not drive to), within this counts as reached, m.
        line_tol_m: the chair is on the centre line within this, m.
        reapproach_m: aligned farther than this off the centre line, the chair approaches again, m.
            From 1.0 m before the plane the line law cannot take out more than about 0.05 m before the
            front reaches the jambs (the offset decays over ``lookahead_m`` of travel, 0.42 m are left,
            and the heading it takes meanwhile, atan(e / lookahead_m), puts a jamb in the safety
            corridor): 9 of 29 failed random-floor episodes stalled there from 0.12-0.25 m off.
        max_reapproaches: at most this many re-approaches per passage.
        align_tol_rad: and aligned with the normal within this, rad.
        turn_accel: deceleration planned when turning in place onto a heading, rad/s^2.
        turn_rate: fastest turn in place, rad/s.
        reverse_speed: backing-off speed, m/s.
        reverse_m: longest back-off of one passage, m.
        reverse_near_m: an approach pose behind the chair and nearer than this is reached in reverse, m.
        lookahead_m: look-ahead along the centre line while passing, m.
        heading_gain: yaw rate per radian of heading error while passing, 1/s.
        door_speed: fastest forward speed through the doorway, m/s.
        memory_s: how long seen points are kept to check a back-off, s.
        front_in_m: a creep that stalls before the front edge is this far past the doorway's plane
            backs off, m (at the wall's face, askew, the jamb stays in the safety corridor).
        stop_gap_m: a point this near ahead of the front edge in the safety layer's corridor (the
            chair's width plus ``corridor_margin_m`` a side) would stop the chair there (the stopping
            distance at ``door_speed``: 0.15 + 0.45 x 0.3 + 0.45^2 / 1.6 = 0.41 m): the approach does
            not creep forward into it, and the pass slows down within it, m.
        creep_gap_m: while passing, the forward speed is ``(gap - creep_gap_m) / 0.6`` within ``stop_gap_m``
            of a point in that corridor (the safety layer's stopping distance 0.15 + 0.3 v + v^2 / 1.6
            stays below the gap); the chair backs off when that falls under 0.02 m/s, m.
        corridor_margin_m: the safety layer's lateral margin, m
            (:meth:`robchair.perception_queries.Corridor.from_spec`).
    """

    approach_m: float = 1.0
    arrive_m: float = 0.05
    pass_by_m: float = 0.15
    line_tol_m: float = 0.03
    reapproach_m: float = 0.1
    max_reapproaches: int = 2
    align_tol_rad: float = math.radians(2.5)
    turn_accel: float = 1.0
    turn_rate: float = 1.0
    reverse_speed: float = 0.15
    reverse_m: float = 1.0
    reverse_near_m: float = 0.6
    lookahead_m: float = 0.25
    heading_gain: float = 2.5
    door_speed: float = 0.45
    memory_s: float = 3.0
    front_in_m: float = 0.05
    stop_gap_m: float = 0.45
    creep_gap_m: float = 0.17
    corridor_margin_m: float = 0.05


def door_coordinates(d: Doorway) -> tuple[float, float, float]:
    """``(s, e, phi)`` of ``base_link`` for a doorway ``d`` given in ``base_link``."""
    tx, ty = -d.ny, d.nx
    s = -(d.cx * d.nx + d.cy * d.ny)
    e = -(d.cx * tx + d.cy * ty)
    phi = -math.atan2(d.ny, d.nx)
    return s, e, phi


def refine(d: Doorway, points: np.ndarray, band_m: float = 0.25, reach_m: float = 1.2) -> Doorway:
    """The doorway ``d`` (``base_link``) re-measured on the wall around it in ``points`` (N, 2).

    The wall's near face is the line fitted (total least squares, twice: the second time to the points
    within 4 cm of the first line) to the points within ``band_m`` of the doorway's plane, from 5 cm
    beyond each jamb up to ``reach_m`` (a jamb's own face, perpendicular to the wall, is left out);
    the jambs are the points along that face nearest the gap's middle on either side. Seen at an
    angle, the first detection can pair a jamb's near corner with the other's far corner (a wall is
    0.1 m thick: a 7-degree tilt over 0.85 m); this one uses the whole face. Returns ``d`` unchanged
    when either side has fewer than 5 points or the result is not a doorway like ``d``.
    """
    c = np.array([d.cx, d.cy])
    n = np.array([d.nx, d.ny])
    half = 0.5 * d.width
    sel = None
    for band in (band_m, 0.04):
        t = np.array([-n[1], n[0]])
        q = points - c
        a, b = q @ t, q @ n
        sel = (np.abs(b) <= band) & (np.abs(a) >= half + 0.05) & (np.abs(a) <= half + reach_m)
        if (sel & (a > 0)).sum() < 5 or (sel & (a < 0)).sum() < 5:
            return d
        p = points[sel]
        mean = p.mean(axis=0)
        _, _, vt = np.linalg.svd(p - mean)
        t2 = vt[0] if vt[0] @ t > 0 else -vt[0]
        n2 = np.array([t2[1], -t2[0]])
        n = n2 if n2 @ n > 0 else -n2
        c = mean + ((c - mean) @ t2) * t2  # the old centre's foot on the face
    t = np.array([-n[1], n[0]])
    q = points - c
    a, b = q @ t, q @ n
    near = (b >= -0.03) & (b <= 0.15) & (np.abs(a) <= half + reach_m)
    lo, hi = a[near & (a < 0)], a[near & (a > 0)]
    if len(lo) == 0 or len(hi) == 0:
        return d
    a_lo, a_hi = float(lo.max()), float(hi.min())
    width = a_hi - a_lo
    if not abs(width - d.width) <= 0.15:
        return d
    c = c + 0.5 * (a_lo + a_hi) * t
    return Doorway(float(c[0]), float(c[1]), float(n[0]), float(n[1]), width)


class PointMemory:
    """Obstacle points seen in the last ``memory_s`` seconds, kept in ``odom`` (one per 4 cm cell)."""

    def __init__(self, keep_cycles: int, cell_m: float = 0.04) -> None:
        self.keep, self.cell = max(1, keep_cycles), cell_m
        self._frames: list[np.ndarray] = []

    def add(self, base_points: np.ndarray, x: float, y: float, theta: float) -> None:
        c, s = math.cos(theta), math.sin(theta)
        odom = base_points @ np.array([[c, s], [-s, c]]) + (x, y)
        self._frames = [*self._frames[-(self.keep - 1) :], odom] if self.keep > 1 else [odom]

    def in_base(self, x: float, y: float, theta: float) -> np.ndarray:
        """The remembered points (M, 2) in ``base_link`` at ``(x, y, theta)``, one per cell."""
        if not self._frames:
            return np.zeros((0, 2))
        p = np.vstack(self._frames)
        p = p[first_per_cell(p, self.cell)] - (x, y)
        c, s = math.cos(theta), math.sin(theta)
        return np.stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]], axis=1)

    def clear(self) -> None:
        self._frames = []


def _turn_to(err: float, params: PassageParams, max_yaw_rate: float) -> float:
    """Yaw rate that turns by ``err`` rad and stops on it (``sqrt(2 a |err|)``, capped), rad/s."""
    rate = min(params.turn_rate, max_yaw_rate, math.sqrt(2.0 * params.turn_accel * abs(err)))
    return math.copysign(rate, err)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class Passage:
    """The passage controller of one doorway (see the module).

    Args:
        params: the passage's parameters.
        footprint: the chair's rectangle (the back-off's check).
        max_yaw_rate: the yaw-rate cap, rad/s.

    The forward checks (``stop_gap_m``, ``creep_gap_m``) measure the gap ahead with the safety layer's
    own corridor model (:class:`robchair.perception_queries.Corridor`, the chair's width plus
    ``corridor_margin_m`` a side ahead of the front edge, the body itself beside it), so that a point
    the safety layer stops for is one the passage creeps and backs off for.
    """

    def __init__(self, params: PassageParams, footprint: Footprint, max_yaw_rate: float) -> None:
        self.params, self.footprint, self.max_yaw_rate = params, footprint, max_yaw_rate
        hw = footprint.half_width
        self.corridor = Corridor(footprint.front_x, hw + params.corridor_margin_m, hw)
        self.phase = "approach"
        self.reversed_m = 0.0
        self._backed = 0.0
        self.reapproaches = 0
        self._reapproach = False  # approaching again: the pose is reached within arrive_m only

    def twist(self, d: Doorway, v_person: float, dt: float, ahead: np.ndarray,
              behind: np.ndarray | None = None,
              allow_reverse: bool = True) -> tuple[float, float, str]:  # fmt: skip
        """``(v, w, phase)`` this cycle for the doorway ``d`` (in ``base_link``) and the person's speed.

        Args:
            d: the doorway in ``base_link``.
            v_person: the person's forward speed request, m/s (>= 0; it scales every forward phase).
            dt: the cycle, s (the back-off's distance).
            ahead: the obstacle points (N, 2) in ``base_link`` now (the passage's forward check: give
                them unthinned, as the safety layer gets them; one point per cell can drop the one
                on the corridor's edge that stops the chair).
            behind: points (M, 2) in ``base_link`` that a back-off must clear (None: no back-off).
            allow_reverse: False: no back-off (the approach turns in place toward the pose instead).
        """
        p = self.params
        s, e, phi = door_coordinates(d)
        aligned = abs(phi) <= p.align_tol_rad
        if (
            self.phase == "align"
            and aligned
            and abs(e) > p.reapproach_m
            and self.reapproaches < p.max_reapproaches
        ):
            self.reapproaches += 1
            self._reapproach = True
            self.phase = "approach"
        if self.phase in ("pass", "back-off-pass") or (
            aligned and (abs(e) <= p.line_tol_m or self.phase == "align")
        ):
            v, w = self._pass(d, v_person)
            front_before = s + self.footprint.front_x < p.front_in_m  # the front is not yet between the jambs
            if self.phase == "back-off-pass" and front_before:
                return self._back_off_pass(phi, dt, behind, allow_reverse)
            gap = self._gap(ahead)
            if v > 0.0 and gap < p.stop_gap_m:
                # a jamb in the safety corridor: creep, slow enough that the safety layer lets the line
                # law correct on the way (stopping distance 0.15 + 0.3 v + v^2 / 1.6 < gap)
                v = min(v, max(0.0, (gap - p.creep_gap_m) / 0.6))
                if v < 0.02 and front_before:
                    return self._back_off_pass(phi, dt, behind, allow_reverse)
            self.phase = "pass"
            return v, w, "pass"
        return self._approach(d, v_person, dt, ahead, behind, allow_reverse)

    def _back_off_pass(self, phi: float, dt: float, behind: np.ndarray | None,
                       allow_reverse: bool) -> tuple[float, float, str]:  # fmt: skip
        """Back by ``2 pass_by_m`` per attempt (within ``reverse_m``) turning onto the door's normal,
        then follow the line again from farther out; without room behind, turn in place onto it."""
        p = self.params
        w = _turn_to(_wrap(-phi), p, self.max_yaw_rate)
        if (allow_reverse and self.reversed_m < p.reverse_m and self._reverse_clear(behind)
                and (self.phase != "back-off-pass" or self._backed < p.pass_by_m * 2)):  # fmt: skip
            if self.phase != "back-off-pass":
                self._backed = 0.0
            self.phase = "back-off-pass"
            self.reversed_m += p.reverse_speed * dt
            self._backed += p.reverse_speed * dt
            return -p.reverse_speed, w, "back-off"
        self.phase = "pass"
        return 0.0, w, "pass"

    def _gap(self, pts: np.ndarray) -> float:
        """Free length (m) ahead of the front edge in the safety layer's corridor (+inf when clear)."""
        d = self.corridor.distance_ahead(np.asarray(pts, dtype=float).reshape(-1, 2))
        return math.inf if d is None else d

    def _blocked(self, pts: np.ndarray) -> bool:
        """Whether a point lies within ``stop_gap_m`` ahead of the front edge in the safety corridor."""
        return self._gap(pts) < self.params.stop_gap_m

    def _approach(self, d: Doorway, v_person: float, dt: float, ahead: np.ndarray,
                  behind: np.ndarray | None, allow_reverse: bool) -> tuple[float, float, str]:  # fmt: skip
        p = self.params
        _, _, phi = door_coordinates(d)
        # the approach pose in base_link: A = c - approach_m n
        ax, ay = d.cx - p.approach_m * d.nx, d.cy - p.approach_m * d.ny
        dist = math.hypot(ax, ay)
        bearing = math.atan2(ay, ax)
        ahead_of = abs(bearing) <= math.pi / 3
        # beside or behind and near: reached (a re-approach drives there); ahead and near, where the
        # safety corridor holds the chair: reached too (it could only turn toward it)
        near = (not ahead_of and not self._reapproach) or (ahead_of and self._blocked(ahead))
        if self.phase == "align" or dist <= p.arrive_m or (dist <= p.pass_by_m and near):
            turn, phase = _wrap(-phi), "align"
            self._reapproach = False
        else:
            turn, phase = math.atan2(ay, ax), "approach"
        back = _wrap(turn - math.pi)  # the same target seen from the chair's back
        if (phase == "approach" and abs(turn) > math.pi / 2 and dist <= p.reverse_near_m and allow_reverse
                and self.reversed_m < p.reverse_m and self._reverse_clear(behind)):  # fmt: skip
            # the approach pose is near and behind (too close to the wall, off the line): reverse onto it
            v = -min(p.reverse_speed, dist + 0.03) * math.cos(back) ** 2
            self.phase = "back-off"
            self.reversed_m += abs(v) * dt
            return v, _turn_to(back, p, self.max_yaw_rate), "back-off"
        if abs(turn) > math.radians(30.0) and not self._turn_clear(turn, behind):
            # turning here would sweep a corner into something: back straight off, then turn
            if allow_reverse and self.reversed_m < p.reverse_m and self._reverse_clear(behind):
                self.phase = "back-off"
                self.reversed_m += p.reverse_speed * dt
                return -p.reverse_speed, 0.0, "back-off"
            self.phase = phase
            return 0.0, 0.0, phase
        self.phase = phase
        w = _turn_to(turn, p, self.max_yaw_rate)
        if phase == "align":
            return 0.0, w, phase
        v = max(0.0, v_person) * max(0.0, math.cos(turn)) ** 2
        if self._blocked(ahead):  # the safety layer would stop a forward creep, and the turn with it
            v = 0.0
        # the person's pace, braking at APPROACH_DECEL onto the approach pose (the chair turns in place there)
        return min(v, math.sqrt(2.0 * APPROACH_DECEL * dist) + 0.02), w, phase

    def _turn_clear(self, turn: float, pts: np.ndarray | None) -> bool:
        """Whether turning in place by ``turn`` rad keeps the footprint 3 cm from ``pts``."""
        if pts is None or len(pts) == 0:
            return True
        rate = math.copysign(1.0, turn)
        times = np.linspace(0.0, abs(turn), 9)
        return float(arc_clearance(self.footprint, np.zeros(1), np.array([rate]), times, pts)[0]) >= 0.03

    def _reverse_clear(self, pts: np.ndarray | None) -> bool:
        """Whether 0.2 m straight back keeps the footprint 3 cm from ``pts`` (None: not checked)."""
        if pts is None or len(pts) == 0:
            return pts is not None
        times = np.linspace(0.0, 0.2 / self.params.reverse_speed, 5)
        v = np.array([-self.params.reverse_speed])
        return float(arc_clearance(self.footprint, v, np.zeros(1), times, pts)[0]) >= 0.03

    def _pass(self, d: Doorway, v_person: float) -> tuple[float, float]:
        p = self.params
        _, e, phi = door_coordinates(d)
        alpha = _wrap(-math.atan2(e, p.lookahead_m) - phi)  # heading error to the point ahead on the line
        v = min(max(0.0, v_person), p.door_speed) * max(0.0, math.cos(alpha)) ** 2
        w = p.heading_gain * alpha
        cap = min(p.turn_rate, self.max_yaw_rate)
        return v, max(-cap, min(cap, w))
