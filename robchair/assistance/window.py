"""The dynamic-window search of the assistance: constant-twist arcs scored over a short horizon.

A candidate is a body twist (v, w) held for the horizon; its arc is sampled at a few times and the
chair's footprint (a rectangle, :class:`robchair.platform.spec.Body`) is placed at each sample. Its
clearance is the smallest distance from an obstacle point to that rectangle along the arc. The score
trades agreement with the person's command, clearance and progress, as the dynamic-window approach
does (Fox, Burgard and Thrun, "The dynamic window approach to collision avoidance", IEEE Robotics &
Automation Magazine 4(1), 1997: heading + clearance + velocity). Everything is one numpy pass over
candidates x samples x points, so one decision fits the 2 ms budget of the 20 Hz loop on the chair's
Raspberry Pi (SPEC section 7; ``robchair bench assist`` measures it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robchair.platform.spec import Body


def first_per_cell(points: np.ndarray, cell_m: float) -> np.ndarray:
    """Index of the first point (N, 2) in each ``cell_m`` grid cell, in (ix, iy) lexicographic order.

    The same indices as ``np.unique(floor(points / cell_m), axis=0, return_index=True)``: the two cell
    indices are packed into one int64 key whose order is their lexicographic order, so numpy sorts a
    flat array instead of rows (about 10x faster for a few thousand points).
    """
    cells = np.floor(points / cell_m).astype(np.int64)
    if len(cells) == 0:
        return np.zeros(0, dtype=np.intp)
    lo = cells.min(axis=0)
    span = int(cells[:, 1].max() - lo[1]) + 1
    key = (cells[:, 0] - lo[0]) * span + (cells[:, 1] - lo[1])
    return np.unique(key, return_index=True)[1]


@dataclass(frozen=True)
class Footprint:
    """The chair's rectangle in ``base_link``: x in [centre_x - half_depth, centre_x + half_depth]."""

    centre_x: float
    half_depth: float
    half_width: float

    @classmethod
    def from_body(cls, body: Body) -> Footprint:
        return cls(float(body.centre_x), 0.5 * float(body.depth), 0.5 * float(body.width))

    @property
    def front_x(self) -> float:
        return self.centre_x + self.half_depth

    @property
    def rear_x(self) -> float:
        return self.centre_x - self.half_depth

    def distance(self, q: np.ndarray) -> np.ndarray:
        """Distance (m) from points ``q`` (..., 2) in the footprint's frame to the rectangle (0 inside)."""
        dx = np.maximum(np.abs(q[..., 0] - self.centre_x) - self.half_depth, 0.0)
        dy = np.maximum(np.abs(q[..., 1]) - self.half_width, 0.0)
        return np.sqrt(dx * dx + dy * dy)


def arc_poses(v: np.ndarray, w: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Poses (C, T, 3) x, y, theta of constant twists ``v`` (C,) m/s, ``w`` (C,) rad/s at ``times`` (T,) s.

    Unicycle arcs from the origin: ``x = v sin(w t) / w``, ``y = v (1 - cos(w t)) / w`` (the limit
    ``x = v t`` for ``w -> 0``).
    """
    th = w[:, None] * times[None, :]
    small = np.abs(w) < 1e-6
    ws = np.where(small, 1.0, w)[:, None]
    x = np.where(small[:, None], v[:, None] * times[None, :], v[:, None] * np.sin(th) / ws)
    y = np.where(small[:, None], 0.0, v[:, None] * (1.0 - np.cos(th)) / ws)
    return np.stack([x, y, th], axis=-1)


def arc_clearance(
    footprint: Footprint, v: np.ndarray, w: np.ndarray, times: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """Smallest footprint-to-point distance (C,) m along each arc; +inf without points.

    Args:
        footprint: the chair's rectangle.
        v, w: candidate twists (C,), m/s and rad/s.
        times: sample times along the horizon (T,), s (include 0 to check the current pose).
        points: obstacle points (N, 2) in ``base_link`` at the current pose, m.
    """
    if len(points) == 0:
        return np.full(len(v), np.inf)
    pose = arc_poses(v, w, times).astype(points.dtype)  # (C, T, 3)
    c, s = np.cos(pose[..., 2])[..., None], np.sin(pose[..., 2])[..., None]
    dx = points[None, None, :, 0] - pose[..., 0, None]
    dy = points[None, None, :, 1] - pose[..., 1, None]
    q = np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)  # points in each sampled pose's frame
    return np.asarray(footprint.distance(q).min(axis=(1, 2)))


@dataclass(frozen=True)
class WindowParams:
    """Weights and samples of the search (dimensionless weights, SI otherwise).

    Attributes:
        n_v: speed samples from 0 to the person's speed request.
        n_w: yaw-rate samples over [-max_yaw_rate, max_yaw_rate].
        horizon_s: how long each candidate twist is held, s.
        n_t: samples along the horizon (the first at t = 0).
        min_clearance_m: a candidate passing closer than this to a point is not admissible, m.
        clearance_sat_m: clearance beyond this scores as much as this, m.
        w_agree, w_clear, w_progress: weights of agreement, clearance and progress.
        w_guide: weight of the agreement with a guide twist (the doorway's centre line).
    """

    n_v: int = 7
    n_w: int = 15
    horizon_s: float = 1.2
    n_t: int = 6
    min_clearance_m: float = 0.04
    clearance_sat_m: float = 0.35
    w_agree: float = 1.0
    w_clear: float = 0.35
    w_progress: float = 0.25
    w_guide: float = 2.0


def search(
    footprint: Footprint,
    params: WindowParams,
    v_person: float,
    w_person: float,
    max_speed: float,
    max_yaw_rate: float,
    points: np.ndarray,
    guide: tuple[float, float] | None = None,
) -> tuple[float, float, float, float]:
    """Best admissible twist for a forward request.

    The person's own command is candidate 0: when its clearance reaches ``clearance_sat_m`` it is
    returned unchanged (the assistance does not touch a safe command).

    Args:
        footprint: the chair's rectangle.
        params: the search's samples and weights.
        v_person, w_person: the person's request, m/s (> 0) and rad/s.
        max_speed, max_yaw_rate: the limits that scale the agreement, m/s and rad/s.
        points: obstacle points (N, 2) in ``base_link``, m.
        guide: a twist toward progress (m/s, rad/s): the doorway passage's along the door's centre
            line (:class:`robchair.assistance.passage.Passage`); it joins the candidates and each
            candidate scores ``w_guide (1 - |candidate - guide| / 2)`` more (scaled to the limits).
            With a guide the person's twist is searched around even when clear.

    Returns:
        ``(v, w, clearance_m, person_clearance_m)``: the chosen twist (0, 0 when nothing is admissible),
        its clearance and that of the person's command.
    """
    times = np.linspace(0.0, params.horizon_s, params.n_t)
    # only points the footprint can come near within the horizon count
    reach = abs(v_person) * params.horizon_s + math.hypot(footprint.front_x, footprint.half_width)
    reach += params.clearance_sat_m
    points = points[np.einsum("ij,ij->i", points, points) <= reach * reach].astype(np.float32)
    clear_p = float(arc_clearance(footprint, np.array([v_person]), np.array([w_person]), times, points)[0])
    if clear_p >= params.clearance_sat_m and guide is None:
        return v_person, w_person, clear_p, clear_p
    vs = np.linspace(0.0, v_person, params.n_v)
    ws = np.linspace(-max_yaw_rate, max_yaw_rate, params.n_w)
    vg, wg = np.meshgrid(vs, ws, indexing="ij")
    extra_v, extra_w = ([guide[0]], [guide[1]]) if guide is not None else ([], [])
    v = np.concatenate([[v_person], vg.ravel(), extra_v])
    w = np.concatenate([[w_person], wg.ravel(), extra_w])
    clear = np.concatenate([[clear_p], arc_clearance(footprint, v[1:], w[1:], times, points)])
    up = np.array([v_person / max_speed, w_person / max_yaw_rate])
    dist = np.hypot(v / max_speed - up[0], w / max_yaw_rate - up[1])
    score = (
        params.w_agree * (1.0 - 0.5 * dist)
        + params.w_clear * np.minimum(clear, params.clearance_sat_m) / params.clearance_sat_m
        + params.w_progress * v / max_speed
    )
    if guide is not None:
        gd = np.hypot((v - guide[0]) / max_speed, (w - guide[1]) / max_yaw_rate)
        score += params.w_guide * (1.0 - 0.5 * gd)
    ok = clear >= params.min_clearance_m
    if not ok.any():
        return 0.0, 0.0, float(clear.max()), float(clear[0])
    score[~ok] = -np.inf
    i = int(np.argmax(score))
    return float(v[i]), float(w[i]), float(clear[i]), float(clear[0])
