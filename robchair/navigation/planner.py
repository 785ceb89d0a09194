"""A grid planner on the chair's own occupancy map, and the classical baseline built on it.

Planning: the occupancy grid is inflated by half the chair's width plus a margin (cells closer than
that to an occupied cell are forbidden for ``base_link``), every free cell gets a cost that grows
near obstacles (so routes keep to the middle of passages), and Dijkstra's algorithm
(:func:`scipy.sparse.csgraph.dijkstra`, 8-connected grid, edge weight = length x mean cell cost)
runs from the goal, which gives the route from every cell at once. Cells the map has never seen
count as free (the map only knows what the chair has sensed). The route is the chain of
predecessors from the chair's cell, shortened to the cells where it turns.

Following: pure pursuit (Coulter 1992) with a look-ahead point on the route; a look-ahead point
more than 60 deg off the heading turns the chair on the spot; the speed falls near the goal. Where
the route ahead passes close to an obstacle (a doorway) the chair first turns on the spot until it
points along the route, then drives through slowly, so its footprint sweeps the passage straight.

:class:`BaselinePolicy` replans every ``replan_every`` steps, or at once when the route runs into a
cell the map has since marked occupied, from what the chair senses itself (the environment's
:meth:`own_occupancy` and its laser scans), never from the ground truth: the laser's returns are the
hard obstacles and the rest of the own map (the wide sonar cones) soft ones; where the safety layer
keeps stopping the chair it marks the cells ahead, backs up and replans.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from mapping.grid import GridSpec
from robchair.platform.errors import RobChairError


class PlanningError(RobChairError, ValueError):
    """A planner argument is invalid."""


@dataclass(frozen=True)
class PlannerConfig:
    """Grid-planner settings.

    Attributes:
        inflation: Forbidden distance from ``base_link`` to an occupied cell, m (half the chair's
            width plus a margin).
        comfort: Distance, m, beyond the inflation over which the cost falls to 1.
        comfort_weight: Extra cost factor at the inflation's edge.
        soft_weight: Extra cost of a cell within the inflation of a *soft* obstacle (one only a
            less precise sensor reports, see :func:`cost_map`).
    """

    inflation: float = 0.37
    comfort: float = 0.6
    comfort_weight: float = 4.0
    soft_weight: float = 3.0


def cost_map(
    occupied: npt.NDArray[np.bool_],
    cell: float,
    cfg: PlannerConfig,
    soft: npt.NDArray[np.bool_] | None = None,
) -> npt.NDArray[np.float64]:
    """Per-cell traversal cost (``inf`` = forbidden) of an occupancy grid.

    Args:
        occupied: ``(nx, ny)`` bool grid.
        cell: Cell size, m.
        cfg: Inflation and comfort settings.
        soft: ``(nx, ny)`` bool grid of soft obstacles (e.g. the wide cones of sonar echoes):
            passable at ``cfg.soft_weight`` extra cost within ``cfg.inflation`` of them.

    Returns:
        ``(nx, ny)`` float64: ``inf`` within ``cfg.inflation`` of an occupied cell, else
        ``1 + comfort_weight * max(0, 1 - (d - inflation) / comfort)`` (+ ``soft_weight`` near a
        soft obstacle).
    """
    from scipy import ndimage

    cost = np.ones(occupied.shape)
    if soft is not None and soft.any():
        cost += cfg.soft_weight * (ndimage.distance_transform_edt(~soft) * cell < cfg.inflation)
    if not occupied.any():
        return cost
    d = ndimage.distance_transform_edt(~occupied) * cell
    cost += cfg.comfort_weight * np.clip(1.0 - (d - cfg.inflation) / cfg.comfort, 0.0, 1.0)
    cost[d < cfg.inflation] = np.inf
    return cost


def _grid_graph(cost: npt.NDArray[np.float64]) -> Any:
    """Sparse 8-connected graph of the finite cells (edge = step length x mean of the two costs)."""
    from scipy.sparse import coo_matrix

    nx, ny = cost.shape
    idx = np.arange(nx * ny).reshape(nx, ny)
    rows, cols, w = [], [], []
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        a = idx[max(0, -di) : nx - max(0, di), max(0, -dj) : ny - max(0, dj)]
        b = idx[max(0, di) : nx + min(0, di) or None, max(0, dj) : ny + min(0, dj) or None]
        ca, cb = cost.ravel()[a.ravel()], cost.ravel()[b.ravel()]
        ok = np.isfinite(ca) & np.isfinite(cb)
        length = math.hypot(di, dj)
        rows.append(a.ravel()[ok])
        cols.append(b.ravel()[ok])
        w.append(length * (ca[ok] + cb[ok]) / 2)
    r, c, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
    n = nx * ny
    return coo_matrix(
        (np.concatenate([ww, ww]), (np.concatenate([r, c]), np.concatenate([c, r]))), shape=(n, n)
    ).tocsr()


def _nearest_finite(cost: npt.NDArray[np.float64], i: int, j: int) -> tuple[int, int] | None:
    fi, fj = np.nonzero(np.isfinite(cost))
    if len(fi) == 0:
        return None
    k = int(np.argmin((fi - i) ** 2 + (fj - j) ** 2))
    return int(fi[k]), int(fj[k])


def plan_path(
    occupied: npt.NDArray[np.bool_],
    grid: GridSpec,
    start: tuple[float, float],
    goal: tuple[float, float],
    cfg: PlannerConfig = PlannerConfig(),
    soft: npt.NDArray[np.bool_] | None = None,
) -> list[tuple[float, float]] | None:
    """Cheapest route (world x, y points, start first) from ``start`` to ``goal``, or None.

    A start or goal inside the inflated obstacles is moved to the nearest allowed cell (the chair
    may stand closer to a wall than the inflation; it leaves that way first).

    Args:
        occupied: ``(nx, ny)`` bool occupancy of ``grid`` (axis z).
        grid: The grid.
        start: Chair position (m).
        goal: Goal position (m).
        cfg: Planner settings.
        soft: Soft obstacles (see :func:`cost_map`).

    Raises:
        PlanningError: a point outside the grid.
    """
    from scipy.sparse.csgraph import dijkstra

    for name, p in (("start", start), ("goal", goal)):
        i, j = grid.world_to_index(p[0], p[1])
        if not bool(grid.contains_index(i, j)):
            raise PlanningError(f"{name} {tuple(p)} lies outside the planning grid {grid.extent}")
    cost = cost_map(occupied, grid.cell_size, cfg, soft)
    si, sj = (int(v) for v in grid.world_to_index(start[0], start[1]))
    gi, gj = (int(v) for v in grid.world_to_index(goal[0], goal[1]))
    s = (si, sj) if np.isfinite(cost[si, sj]) else _nearest_finite(cost, si, sj)
    g = (gi, gj) if np.isfinite(cost[gi, gj]) else _nearest_finite(cost, gi, gj)
    if s is None or g is None:
        return None
    ny = cost.shape[1]
    graph = _grid_graph(cost)
    dist, pred = dijkstra(graph, indices=g[0] * ny + g[1], return_predecessors=True)
    node = s[0] * ny + s[1]
    if not np.isfinite(dist[node]):
        return None
    cells = [node]
    while cells[-1] != g[0] * ny + g[1]:
        cells.append(int(pred[cells[-1]]))
    ii, jj = np.divmod(np.asarray(cells), ny)
    u, v = grid.index_to_world(ii, jj)
    pts = np.stack([u, v], axis=1)
    return [
        (float(start[0]), float(start[1])),
        *map(tuple, _corners(pts)[1:-1]),
        (float(goal[0]), float(goal[1])),
    ]  # type: ignore[list-item]


def _corners(pts: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Keep the first, the last and every point where the route changes direction."""
    if len(pts) <= 2:
        return pts
    d = np.diff(pts, axis=0)
    turn = np.any(np.abs(np.diff(np.sign(d), axis=0)) > 0, axis=1)
    keep = np.concatenate([[True], turn, [True]])
    return pts[keep]


def shortcut(
    route: list[tuple[float, float]], cost: npt.NDArray[np.float64], grid: GridSpec
) -> list[tuple[float, float]]:
    """String pulling: drop every point the route can skip on a straight line of finite-cost cells."""
    if len(route) <= 2:
        return route

    def clear(a: tuple[float, float], b: tuple[float, float]) -> bool:
        n = max(2, int(math.hypot(b[0] - a[0], b[1] - a[1]) / (grid.cell_size / 3)))
        t = np.linspace(0.0, 1.0, n)
        i, j = grid.world_to_index(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))
        ok = grid.contains_index(i, j)
        return bool(ok.all() and np.isfinite(cost[i, j]).all())

    out = [route[0]]
    k = 0
    while k < len(route) - 1:
        far = k + 1
        for m in range(len(route) - 1, k + 1, -1):
            if clear(route[k], route[m]):
                far = m
                break
        out.append(route[far])
        k = far
    return out


def path_length(points: Any) -> float:
    """Length of a polyline, m."""
    p = np.asarray(points, dtype=float)
    return float(np.hypot(*np.diff(p, axis=0).T).sum()) if len(p) > 1 else 0.0


def route_blocked(
    route: list[tuple[float, float]], occupied: npt.NDArray[np.bool_], grid: GridSpec, cfg: PlannerConfig
) -> bool:
    """Whether the route ahead passes within the inflation of a cell the map now holds occupied."""
    from scipy import ndimage

    if not occupied.any() or len(route) < 2:
        return False
    near = ndimage.binary_dilation(occupied, iterations=max(1, int(cfg.inflation / grid.cell_size) - 1))
    pts = np.asarray(route)
    for a, b in itertools.pairwise(pts):
        n = max(2, int(np.hypot(*(b - a)) / (grid.cell_size / 2)))
        t = np.linspace(0.0, 1.0, n)[:, None]
        q = a + t * (b - a)
        # the chair may stand closer to a wall than the inflation: judge the route ahead of it only
        q = q[np.hypot(q[:, 0] - pts[0, 0], q[:, 1] - pts[0, 1]) > cfg.inflation + 0.2]
        i, j = grid.world_to_index(q[:, 0], q[:, 1])
        ok = grid.contains_index(i, j)
        if near[i[ok], j[ok]].any():
            return True
    return False


@dataclass
class PurePursuit:
    """Pure-pursuit follower of a polyline route for a differential drive.

    Attributes:
        lookahead: Look-ahead distance, m.
        cruise: Cruise speed, m/s.
        max_yaw_rate: Largest yaw rate commanded, rad/s.
        turn_in_place: Heading error (rad) beyond which the chair turns on the spot.
        decel: Deceleration used to slow down for the goal, m/s^2.
        tight: Clearance (m, from the route near the chair to the nearest mapped obstacle) under
            which a passage counts as tight (a doorway): the chair aligns first and drives slowly.
        tight_speed: Speed in a tight passage, m/s.
        tight_align: Heading error (rad) beyond which the chair turns on the spot in a tight passage.
    """

    lookahead: float = 0.6
    cruise: float = 0.55
    max_yaw_rate: float = 1.2
    turn_in_place: float = math.radians(60.0)
    decel: float = 0.4
    tight: float = 0.6
    tight_speed: float = 0.25
    tight_align: float = math.radians(15.0)

    def command(
        self,
        pose: tuple[float, float, float],
        route: list[tuple[float, float]],
        clearance: float = math.inf,
    ) -> tuple[float, float]:
        """Twist (v m/s, w rad/s) toward the look-ahead point of ``route`` from ``pose`` (x, y, yaw).

        ``clearance`` (m) is the least distance from the route ahead to a mapped obstacle; under
        ``tight`` the chair turns on the spot until it points along the route within ``tight_align``
        (its footprint then sweeps the passage straight) and drives at ``tight_speed``.
        """
        tight = clearance < self.tight
        x, y, th = pose
        pts = np.asarray(route, dtype=float)
        p = np.array([x, y])
        # closest point of the route, then walk the look-ahead along it
        best, best_d, best_s = 0, math.inf, 0.0
        cum = (
            np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
            if len(pts) > 1
            else np.zeros(1)
        )
        for k in range(len(pts) - 1):
            a, b = pts[k], pts[k + 1]
            ln2 = float(np.dot(b - a, b - a))
            t = 0.0 if ln2 == 0 else float(np.clip(np.dot(p - a, b - a) / ln2, 0.0, 1.0))
            d = float(np.hypot(*(a + t * (b - a) - p)))
            if d < best_d:
                best, best_d, best_s = k, d, float(cum[k] + t * math.sqrt(ln2))
        del best
        s = best_s + self.lookahead
        if len(pts) == 1 or s >= cum[-1]:
            target = pts[-1]
        else:
            k = int(np.searchsorted(cum, s, side="right") - 1)
            seg = cum[k + 1] - cum[k]
            target = pts[k] + (s - cum[k]) / seg * (pts[k + 1] - pts[k]) if seg > 0 else pts[k]
        dx, dy = target - p
        c, sn = math.cos(th), math.sin(th)
        xr, yr = c * dx + sn * dy, -sn * dx + c * dy
        err = math.atan2(yr, xr)
        remaining = float(cum[-1] - best_s) + best_d
        if abs(err) > (self.tight_align if tight else self.turn_in_place):
            w_turn = self.max_yaw_rate if abs(err) > 2 * self.tight_align else self.max_yaw_rate / 2
            return 0.0, math.copysign(w_turn, err)
        cruise = min(self.cruise, self.tight_speed) if tight else self.cruise
        v = min(cruise, math.sqrt(2 * self.decel * max(remaining, 0.0)))
        l2 = max(xr * xr + yr * yr, 1e-9)
        w = float(np.clip(v * 2.0 * yr / l2, -self.max_yaw_rate, self.max_yaw_rate))
        return v, w


class BaselinePolicy:
    """The classical baseline: plan on the chair's own map, replan, follow with pure pursuit.

    Works on any :class:`robchair.envs.navigation.RobChairNavigationEnv` (continuous actions); it reads
    the chair's own occupancy (:meth:`own_occupancy`), its pose estimate and the goal from ``info``,
    the laser scan from the observation and the safety layer's report from ``info["safety"]``.

    * Planning map: the chair's own occupancy plus the cells where the safety layer stopped it. When
      no route exists on it (the sonar cones' wide arcs can close a doorway on the map), the planner
      falls back to the obstacles the laser has located (its returns accumulated over the episode,
      placed with the pose estimate) plus those stop cells, then to the same with the inflation cut
      to half the chair's width; with no route at all the chair turns on the spot to look around.
    * Tight passages: the follower aligns and slows down where the route ahead runs closer than
      ``follower.tight`` to a mapped obstacle (see :class:`PurePursuit`).
    * Recovery: after ``stuck_steps`` agent steps in a row on which the safety layer stopped a
      forward command for an obstacle, the cells ahead of the chair's front at the reported
      distance are marked occupied, the chair backs up ``backup_steps`` steps (when the laser shows
      nothing behind it) and replans.

    Args:
        env: The environment (wrappers are unwrapped).
        planner: Planner settings.
        follower: Follower settings.
        replan_every: Agent steps between replans.
        stuck_steps: Consecutive obstacle stops that trigger the recovery.
        backup_steps: Agent steps of reversing in a recovery.
        backup_speed: Reversing speed, m/s.
        map_range: Laser returns beyond this range (m) are not accumulated (a heading error
            displaces far returns most).
        map_max_yaw_rate: No laser returns are accumulated while the chair turns faster than
            this (rad/s, the measured yaw rate).
    """

    def __init__(
        self,
        env: Any,
        planner: PlannerConfig | None = None,
        follower: PurePursuit | None = None,
        replan_every: int = 10,
        stuck_steps: int = 3,
        backup_steps: int = 6,
        backup_speed: float = 0.15,
        map_range: float = 3.0,
        map_max_yaw_rate: float = 0.3,
    ) -> None:
        self.env = getattr(env, "unwrapped", env)
        if getattr(self.env, "action_type", "continuous") != "continuous":
            raise PlanningError("the baseline drives continuous (v, w) actions; use a continuous id")
        body = self.env.spec_robot.body
        self.cfg = planner if planner is not None else PlannerConfig(inflation=body.width / 2 + 0.05)
        self.follower = follower if follower is not None else PurePursuit()
        self.replan_every = int(replan_every)
        self.stuck_steps = int(stuck_steps)
        self.backup_steps = int(backup_steps)
        self.backup_speed = float(backup_speed)
        self.map_range = float(map_range)
        self.map_max_yaw_rate = float(map_max_yaw_rate)
        self._front = float(body.centre_x + body.depth / 2)
        self._rear = float(body.centre_x - body.depth / 2)
        self._half_width = float(body.width / 2)
        # the laser's beam model, as the environment's observation builder describes the scan
        laser = getattr(getattr(self.env, "obs_builder", None), "laser_model", None)
        self._beams: npt.NDArray[np.float64] | None = None
        if laser is not None:
            m = self.env.spec_robot.laser_mount
            self._beams = np.asarray(laser.angles(), dtype=float)
            self._laser_xy = (float(m.xyz[0]), float(m.xyz[1]))
            self._laser_max = float(laser.range_max)
        self.reset()

    def reset(self) -> None:
        """Forget the route and the episode's maps (call at every episode start)."""
        self.route: list[tuple[float, float]] | None = None
        self.routes: list[list[tuple[float, float]]] = []
        self._since = 0
        self._stuck = 0
        self._backup = 0
        self._laser_hits: npt.NDArray[np.bool_] | None = None
        self._marks: npt.NDArray[np.bool_] | None = None
        self._dist: npt.NDArray[np.float64] | None = None

    def _add_scan(self, grid: GridSpec, obs: Any, pose: tuple[float, float, float]) -> None:
        """Accumulate this step's laser returns (placed with the pose estimate) in the laser grid."""
        if self._laser_hits is None:
            self._laser_hits = np.zeros(grid.shape, dtype=bool)
        if self._beams is None or not isinstance(obs, dict) or "laser" not in obs:
            return
        vel = obs.get("velocity")
        if vel is not None and abs(float(vel[1])) > self.map_max_yaw_rate:
            return  # the scan's time within the step is not the pose's: a turning chair smears walls
        r = np.asarray(obs["laser"], dtype=float)
        ok = (r > 0.05) & (r < min(self.map_range, 0.98 * self._laser_max))
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        lx, ly = (
            x + c * self._laser_xy[0] - s * self._laser_xy[1],
            y + s * self._laser_xy[0] + c * self._laser_xy[1],
        )
        a = th + self._beams[ok]
        i, j = grid.world_to_index(lx + r[ok] * np.cos(a), ly + r[ok] * np.sin(a))
        inside = grid.contains_index(i, j)
        self._laser_hits[i[inside], j[inside]] = True

    def _mark_ahead(self, grid: GridSpec, pose: tuple[float, float, float], distance: float) -> None:
        """Mark the strip across the chair's path ``distance`` m ahead of its front as occupied."""
        if self._marks is None:
            self._marks = np.zeros(grid.shape, dtype=bool)
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        ahead = self._front + distance + grid.cell_size / 2
        lat = np.linspace(-self._half_width, self._half_width, 9)
        i, j = grid.world_to_index(x + c * ahead - s * lat, y + s * ahead + c * lat)
        inside = grid.contains_index(i, j)
        self._marks[i[inside], j[inside]] = True

    def _clear_behind(self, grid: GridSpec, pose: tuple[float, float, float]) -> bool:
        """Whether the laser has located nothing in the strip the chair sweeps backing up 0.3 m."""
        if self._laser_hits is None or not self._laser_hits.any():
            return True
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        back = np.linspace(self._rear - 0.3, self._rear, 5)
        lat = np.linspace(-self._half_width - 0.05, self._half_width + 0.05, 9)
        bb, ll = np.meshgrid(back, lat)
        i, j = grid.world_to_index(x + c * bb - s * ll, y + s * bb + c * ll)
        inside = grid.contains_index(i, j)
        return not bool(self._laser_hits[i[inside], j[inside]].any())

    def _turn_clear(self, grid: GridSpec, pose: tuple[float, float, float]) -> bool:
        """Whether the laser has located nothing in the circle the footprint sweeps turning on the spot."""
        if self._laser_hits is None or not self._laser_hits.any():
            return True
        reach = math.hypot(max(self._front, -self._rear), self._half_width) + 0.05
        x, y = pose[0], pose[1]
        n = math.ceil(reach / grid.cell_size)
        ci, cj = grid.world_to_index(x, y)
        i0, i1 = max(int(ci) - n, 0), min(int(ci) + n + 1, grid.shape[0])
        j0, j1 = max(int(cj) - n, 0), min(int(cj) + n + 1, grid.shape[1])
        ii, jj = np.nonzero(self._laser_hits[i0:i1, j0:j1])
        if len(ii) == 0:
            return True
        u, v = grid.index_to_world(ii + i0, jj + j0)
        return bool((np.hypot(u - x, v - y) > reach).all())

    def _plan(
        self,
        grid: GridSpec,
        occ: npt.NDArray[np.bool_],
        start: tuple[float, float],
        goal: tuple[float, float],
    ) -> list[tuple[float, float]] | None:
        """Plan on the hard obstacles with the rest of the own map soft.

        Two inflations: the planner's, and half the chair's width plus 1 cm (a narrow doorway the
        follower passes aligned and slowly); the second route is taken when the first does not exist
        or is much longer (a detour through unseen space around a doorway that is only narrow). With
        no route at all the stop cells are forgotten (the chair may have boxed itself in with them).
        """
        from scipy import ndimage

        tight = replace(self.cfg, inflation=self._half_width + 0.01)
        for attempt in range(2):
            blocked = self._hard(grid, occ)
            soft = occ & ~blocked
            route = plan_path(blocked, grid, start, goal, self.cfg, soft)
            narrow = plan_path(blocked, grid, start, goal, tight, soft)
            if narrow is not None and (route is None or path_length(narrow) < 0.7 * path_length(route)):
                route = narrow
            if route is not None:
                self._dist = (
                    ndimage.distance_transform_edt(~blocked) * grid.cell_size if blocked.any() else None
                )
                return route
            if attempt == 0 and self._marks is not None and self._marks.any():
                self._marks[:] = False
            else:
                break
        return None

    def _hard(self, grid: GridSpec, occ: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
        """Hard obstacles: the laser's returns (the own map before any) and the stop cells."""
        laser = self._laser_hits
        hard = laser.copy() if laser is not None and laser.any() else occ.copy()
        if self._marks is not None:
            hard |= self._marks
        return hard

    def _clearance(self, grid: GridSpec, pose: tuple[float, float, float], reach: float = 1.2) -> float:
        """Least distance (m) to a planning obstacle along the route from the chair to ``reach`` m ahead."""
        if self._dist is None or self.route is None:
            return math.inf
        pts = np.asarray(self.route, dtype=float)
        p = np.asarray(pose[:2])
        samples = [p]
        for a, b in itertools.pairwise(pts):
            n = max(2, int(np.hypot(*(b - a)) / (grid.cell_size / 2)))
            samples.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
        q = np.vstack(samples)
        d_from = np.hypot(q[:, 0] - p[0], q[:, 1] - p[1])
        # the part of the route near the chair (the chair stands on it or close to it)
        k0 = int(np.argmin(d_from[1:])) + 1 if len(q) > 1 else 0
        ahead = q[k0:]
        run = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ahead, axis=0).T))])
        q = np.vstack([p[None, :], ahead[run <= reach]])
        i, j = grid.world_to_index(q[:, 0], q[:, 1])
        inside = grid.contains_index(i, j)
        if not inside.any():
            return math.inf
        return float(self._dist[i[inside], j[inside]].min())

    def __call__(self, obs: Any, info: dict[str, Any]) -> npt.NDArray[np.float32]:
        """The normalised action for this step."""
        grid, occ = self.env.own_occupancy()
        pose = tuple(float(v) for v in info["pose_estimate"])
        x, y = pose[0], pose[1]
        goal = tuple(info["goal"])
        self._add_scan(grid, obs, pose)  # type: ignore[arg-type]
        shield = info.get("safety") or {}
        reason = str(shield.get("reason") or "")
        cmd = info.get("command", (0.0, 0.0))
        if reason.startswith("obstacle") and float(cmd[0]) > 0.0:
            self._stuck += 1
        else:
            self._stuck = 0
        if self._stuck >= self.stuck_steps:
            self._stuck = 0
            try:
                dist = float(reason.split(" at ")[1].split(" m")[0])
            except (IndexError, ValueError):
                dist = 0.0
            self._mark_ahead(grid, pose, dist)  # type: ignore[arg-type]
            self._backup = self.backup_steps if self._clear_behind(grid, pose) else 0  # type: ignore[arg-type]
            self.route = None
        if self._backup > 0:
            self._backup -= 1
            return np.array([-self.backup_speed / self.env.max_speed, 0.0], dtype=np.float32)
        blocked = self._hard(grid, occ)
        if (
            self.route is None
            or self._since >= self.replan_every
            or route_blocked(self.route, blocked, grid, self.cfg)
        ):
            route = self._plan(grid, occ, (x, y), goal)  # type: ignore[arg-type]
            self._since = 0
            if route is None:  # nowhere to go on any map: turn on the spot and look around
                self.route = None
                return np.array(
                    [0.0, 0.5 * self.follower.max_yaw_rate / self.env.max_yaw_rate], dtype=np.float32
                )
            self.route = route
            self.routes.append(route)
        self._since += 1
        v, w = self.follower.command(pose, self.route, self._clearance(grid, pose))  # type: ignore[arg-type]
        if v == 0.0 and w != 0.0 and not self._turn_clear(grid, pose) and self._clear_behind(grid, pose):  # type: ignore[arg-type]
            # turning on the spot sweeps the footprint's front corners, which no sensor guards
            return np.array([-self.backup_speed / self.env.max_speed, 0.0], dtype=np.float32)
        return np.array([v / self.env.max_speed, w / self.env.max_yaw_rate], dtype=np.float32).clip(-1, 1)


class RandomPolicy:
    """Uniformly random actions from the environment's action space (seeded per episode)."""

    def __init__(self, env: Any, seed: int = 0) -> None:
        self.space = env.action_space
        self.space.seed(seed)

    def reset(self) -> None:
        """Nothing to forget."""

    def __call__(self, obs: Any, info: dict[str, Any]) -> Any:
        return self.space.sample()
