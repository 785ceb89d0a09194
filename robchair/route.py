"""A scripted route and the one route follower (pure pursuit) every loop uses.

A :class:`Route` is a polyline of waypoints in the frame the odometry runs in (``odom``, which a
scenario places at its start pose in ``map``) with a cruise speed and a look-ahead distance; it loads
from TOML. :class:`PurePursuit` turns the pose estimate into a body twist (v, w) each cycle and says
when the route is done.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from robchair.platform.config import (
    ConfigSource,
    ConfigTable,
    bounds,
    check_dataclass,
    load_dataclass,
    load_toml,
)
from robchair.platform.frames import invert, se2, transform_points
from robchair.platform.kinematics import DiffDrive, Pose2D
from robchair.sources import Command, Observation

ROUTE_KEYS = ("waypoints", "speed", "lookahead_m", "goal_tolerance_m")


@dataclass(frozen=True)
class Route:
    """A scripted route: waypoints (m) and how to follow them.

    TOML file::

        waypoints = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.5]]
        speed = 0.3            # cruise speed, m/s
        lookahead_m = 0.6      # pure-pursuit look-ahead distance, m
        goal_tolerance_m = 0.1 # done when this close to the last waypoint, m

    Raises:
        ConfigError: fewer than two waypoints, a non-finite waypoint, a non-positive number or an
            unknown key, in the :mod:`robchair.platform.config` dialect
            (``route.speed = -1.0: expected ...``).
    """

    waypoints: tuple[tuple[float, float], ...]
    speed: float = field(default=0.3, metadata=bounds(gt=0))
    lookahead_m: float = field(default=0.6, metadata=bounds(gt=0))
    goal_tolerance_m: float = field(default=0.1, metadata=bounds(gt=0))

    def __post_init__(self) -> None:
        _check_waypoints(ConfigTable({"waypoints": _as_lists(self.waypoints)}, where="route"))
        check_dataclass(self, "route")

    @classmethod
    def load(cls, path: Path | str) -> Route:
        """Read a route file (see the class docstring).

        Raises:
            ConfigError: the file is missing, unreadable, not TOML, or a key is unknown or invalid
                (``<file>:<line>: <key> = <value>: expected <what>``).
        """
        data, source = load_toml(path, what="route file")
        return cls.from_dict(data, source)

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any] | ConfigTable, source: ConfigSource | None = None, where: str = ""
    ) -> Route:
        """From a TOML table (``where`` is its path in the file, e.g. ``"route"``), checked key by key."""
        table = data if isinstance(data, ConfigTable) else ConfigTable(data, source, where)
        table.keys(ROUTE_KEYS)
        _check_waypoints(table)
        return load_dataclass(cls, table)


def _check_waypoints(table: ConfigTable) -> None:
    table.points("waypoints", min_count=2)


def _as_lists(v: Any) -> Any:
    return [_as_lists(a) for a in v] if isinstance(v, tuple | list) else v


class PurePursuit:
    """Follow a :class:`Route` with pure pursuit (Coulter 1992) on the differential drive.

    The goal point is ``lookahead_m`` along the path beyond the progress: the arc length of the closest
    path point within a search window of two look-aheads ahead of the previous progress (progress never
    goes backwards, and never jumps to a later stretch of the path that passes nearby). Curvature to
    reach it: ``k = 2 y_r / l^2`` with ``y_r`` its lateral offset in the chair's frame and ``l`` its
    distance; ``w = v k``. The speed is the cruise speed, lowered
    in tight turns (``v / (1 + 0.6 |k|)``) and so the chair can stop at the last waypoint
    (``v <= sqrt(2 a d)``, ``d`` the path left, at least the distance to the last waypoint); the twist
    is scaled to the platform's wheel limits keeping the curvature. A goal point behind the chair turns
    it in place. Done within ``goal_tolerance_m`` of the last waypoint once the progress along the path
    is within ``goal_tolerance_m`` of its end.
    """

    def __init__(self, route: Route, drive: DiffDrive, decel: float = 0.4) -> None:
        self.route = route
        self.drive = drive
        self.decel = decel
        self._pts = np.asarray(route.waypoints, dtype=float)
        seg = np.diff(self._pts, axis=0)
        self._seg_len = np.hypot(seg[:, 0], seg[:, 1])
        self._cum = np.concatenate([[0.0], np.cumsum(self._seg_len)])
        self.length = float(self._cum[-1])
        self._s = 0.0  # progress along the path, m
        #: how far ahead of the progress the closest path point is searched, m
        self.search_window_m = 2.0 * route.lookahead_m
        self.done = False

    def _point_at(self, s: float) -> np.ndarray:
        s = min(max(s, 0.0), self.length)
        i = int(np.searchsorted(self._cum, s, side="right") - 1)
        i = min(i, len(self._seg_len) - 1)
        t = (s - self._cum[i]) / self._seg_len[i] if self._seg_len[i] > 0 else 0.0
        return self._pts[i] + t * (self._pts[i + 1] - self._pts[i])  # type: ignore[no-any-return]

    def _project(self, p: np.ndarray) -> float:
        """Arc length of the closest path point to ``p`` within the search window ahead of the progress.

        Only the stretch ``[s, s + window]`` of the path (``window`` = :attr:`search_window_m`) is
        searched, so progress moves along the path: where the path passes near a later stretch of
        itself (a loop whose end lies on the way in), the later stretch is out of reach until the
        progress gets there.
        """
        a, ln, c0 = self._pts[:-1], self._seg_len, self._cum[:-1]
        lo, hi = self._s, self._s + self.search_window_m
        ok = (ln > 0) & (self._cum[1:] >= lo) & (c0 <= hi)
        if not ok.any():
            return self._s
        safe = np.where(ln > 0, ln, 1.0)
        ab = self._pts[1:] - a
        t = np.einsum("ij,ij->i", p - a, ab) / safe**2
        s = np.clip(c0 + np.clip(t, 0.0, 1.0) * ln, lo, hi)  # arc length of the nearest point in the window
        on = a + ((s - c0) / safe)[:, None] * ab  # the point at arc length s on segment i
        d = np.where(ok, np.hypot(*(p - on).T), np.inf)
        return float(s[int(np.argmin(d))])

    def cross_track_error(self, pose: Pose2D) -> float:
        """Distance (m) from ``pose`` to the path at the current progress."""
        p = np.array([pose.x, pose.y])
        return float(np.hypot(*(p - self._point_at(self._project(p)))))

    def command(self, obs: Observation) -> Command:
        pose = obs.pose
        p = np.array([pose.x, pose.y])
        goal = self._pts[-1]
        to_goal = float(np.hypot(*(goal - p)))
        self._s = self._project(p)
        tol = self.route.goal_tolerance_m
        if self.done or (to_goal <= tol and self._s >= self.length - tol):
            self.done = True
            return Command(0.0, 0.0, done=True)
        target = self._point_at(self._s + self.route.lookahead_m)
        if self._s + self.route.lookahead_m >= self.length:
            target = goal
        # the goal point in base_link: T_base_odom = inverse(T_odom_base)
        x_r, y_r = transform_points(invert(se2(pose.x, pose.y, pose.theta)), target)
        l2 = x_r * x_r + y_r * y_r
        if x_r <= 0.0:  # goal point behind: turn in place toward it
            w = math.copysign(0.5 * self.drive.max_yaw_rate, y_r if y_r != 0 else 1.0)
            return Command(0.0, w)
        k = 2.0 * y_r / l2 if l2 > 0 else 0.0
        # slow down for the end of the path, not for the goal point: a loop passes its goal on the way in
        to_end = max(self.length - self._s, to_goal)
        v = min(self.route.speed / (1.0 + 0.6 * abs(k)), math.sqrt(2.0 * self.decel * to_end))
        v, w = self.drive.limit(v, v * k)
        return Command(v, w)
