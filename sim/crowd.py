"""Scripted people who keep clear of the chair: the social force model on their walks.

A scripted person (:class:`sim.scene.Motion`) walks its waypoints on a timetable. Walking the script
blindly takes a person straight through a chair that stands in the way (the chair's safety layer has
stopped it there), which no pedestrian does. Here each person follows the *social force model* of
Helbing & Molnár (1995), "Social force model for pedestrian dynamics", Phys. Rev. E 51, 4282:

    dv/dt = (w - v) / tau + F_chair,      |v| <= v_max = 1.3 v0

* the driving term relaxes the velocity ``v`` towards the desired velocity ``w`` in ``tau`` = 0.5 s;
  the person's goal is its own place on the timetable, so ``w`` is the script's velocity plus a pull
  back onto the script (the offset from it closed in :attr:`SocialForce.return_s`), at most ``v_max``;
* the chair repels like a border of the paper (its footprint rectangle, at the pose the physics gives):
  ``U(r) = U0 exp(-r / R)`` with ``r`` the distance from the person's centre to the nearest point of the
  footprint, ``U0`` = 10 m^2/s^2, ``R`` = 0.2 m; a force from outside the field of view (2 phi = 200 deg
  around the walking direction) counts ``c`` = 0.5 of it. Beyond :data:`CHAIR_FORCE_RANGE_M` (where it
  has fallen below 0.003 m/s^2) the force is taken as zero.

The state is the offset ``d`` of the person from its scripted place and the offset's rate. With the
chair far away the force vanishes and the offset stays exactly zero, so the person walks its script to
the cell, as before; only near the chair does it step aside, and it gets back onto its timetable
afterwards (catching up at up to ``v_max``). Integrated with semi-implicit Euler at the physics' step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Helbing & Molnár (1995), Sec. II: relaxation time, border potential U0 and range R, half of the
#: field of view, weight of what is behind, and the largest speed as a multiple of the desired one.
HM_RELAXATION_S = 0.5
HM_BORDER_U0 = 10.0  # m^2/s^2
HM_BORDER_R = 0.2  # m
HM_VIEW_HALF_ANGLE = math.radians(100.0)
HM_BEHIND_WEIGHT = 0.5
HM_MAX_SPEED_FACTOR = 1.3
#: beyond this distance from the footprint the chair's force (50 exp(-r / 0.2) m/s^2) is zero, m
CHAIR_FORCE_RANGE_M = 2.0


@dataclass(frozen=True)
class Footprint:
    """The chair's footprint as a rectangle in ``base_link`` (m): x in ``[x_min, x_max]``,
    ``|y| <= half_width``."""

    x_min: float
    x_max: float
    half_width: float

    def nearest(self, pose: tuple[float, float, float], p: np.ndarray) -> tuple[float, np.ndarray]:
        """Distance (m) from the world point ``p`` (2,) to the footprint of the chair at ``pose``
        (x, y, yaw in ``map``), and the unit vector (2,) from the footprint towards ``p`` (from the
        footprint's centre when ``p`` is inside it)."""
        x, y, yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = p[0] - x, p[1] - y
        lx, ly = c * dx + s * dy, -s * dx + c * dy  # p in base_link
        qx = min(max(lx, self.x_min), self.x_max)
        qy = min(max(ly, -self.half_width), self.half_width)
        ex, ey = lx - qx, ly - qy
        r = math.hypot(ex, ey)
        if r < 1e-9:  # inside: away from the centre
            ex, ey = lx - 0.5 * (self.x_min + self.x_max), ly
            n = math.hypot(ex, ey)
            ex, ey = (ex / n, ey / n) if n > 1e-9 else (1.0, 0.0)
            r = 0.0
        else:
            ex, ey = ex / r, ey / r
        return r, np.array([c * ex - s * ey, s * ex + c * ey])


@dataclass
class SocialForce:
    """One scripted person under the social force of the chair (see the module docstring).

    Args:
        speed: the script's walking speed ``v0``, m/s.
        return_s: time constant of the pull back onto the script, s (the desired velocity gains
            ``-d / return_s``: 1 s, about two steps of a walk).
    """

    speed: float
    return_s: float = 1.0
    relaxation_s: float = HM_RELAXATION_S
    u0: float = HM_BORDER_U0
    r0: float = HM_BORDER_R

    def __post_init__(self) -> None:
        self.offset = np.zeros(2)  # d: where the person is, less where the script has it, m
        self.rate = np.zeros(2)  # d', m/s

    def reset(self) -> None:
        """Back onto the script, at rest relative to it."""
        self.offset[:] = 0.0
        self.rate[:] = 0.0

    def step(self, scripted: np.ndarray, script_velocity: np.ndarray, dt: float,
             chair: tuple[Footprint, tuple[float, float, float]] | None) -> np.ndarray:  # fmt: skip
        """Advance ``dt`` s and return the person's position (2,) in ``map``.

        Args:
            scripted: the script's position (2,) now, m.
            script_velocity: the script's velocity (2,) now, m/s.
            dt: time step, s.
            chair: the chair's footprint and pose (x, y, yaw), or None (no chair).
        """
        p = scripted + self.offset
        v = script_velocity + self.rate
        v_max = HM_MAX_SPEED_FACTOR * self.speed
        w = script_velocity - self.offset / self.return_s
        wn = float(np.hypot(*w))
        if wn > v_max:
            w *= v_max / wn
        force = (w - v) / self.relaxation_s
        if chair is not None:
            r, n = chair[0].nearest(chair[1], p)
            if r < CHAIR_FORCE_RANGE_M:
                f = (self.u0 / self.r0) * math.exp(-r / self.r0) * n
                heading = w if wn > 1e-9 else v
                hn = float(np.hypot(*heading))
                # the chair lies along -n; outside the field of view around the heading it weighs c
                if hn > 1e-9 and float(np.dot(heading, -n)) < hn * math.cos(HM_VIEW_HALF_ANGLE):
                    f = HM_BEHIND_WEIGHT * f
                force = force + f
        v = v + force * dt
        vn = float(np.hypot(*v))
        if vn > v_max:
            v *= v_max / vn
        self.rate = v - script_velocity
        self.offset = self.offset + self.rate * dt
        if not (np.all(np.isfinite(self.offset)) and np.all(np.isfinite(self.rate))):
            self.reset()
        return scripted + self.offset  # type: ignore[no-any-return]
