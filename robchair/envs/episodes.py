"""Where episodes of the navigation environment may start and end: sampling and checking start and goal.

:class:`EpisodeSampler` works on the scene's ground truth (:class:`sim.envs.geometry.FreeSpace`, built from
:func:`sim.truth.scene_occupancy`): a start is a cell where the chair can turn on the spot, a goal a free
cell at a straight-line distance in ``goal_distance`` from the start and in the same connected region.
A given start or goal is checked the same way, and a bad one is refused naming the point and the obstacle.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from mapping.grid import GridSpec
from robchair.envs.arguments import pose_arg
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import RobChairSpec
from sim.envs.errors import NavigationEnvError
from sim.envs.geometry import FreeSpace
from sim.scene import Scene

MAP_MARGIN = 1.0  # m around the scene's bounds
START_MARGIN = 0.10  # m of extra clearance around the chair's turning circle at start and goal
PASS_MARGIN = 0.05  # m each side of the chair's width for two free regions to count as connected


def scene_grid(scene: Scene, cell: float) -> GridSpec:
    """A grid of ``cell`` m covering the scene's bounds plus :data:`MAP_MARGIN` on every side."""
    x0, y0, x1, y1 = scene.bounds_xy()
    nx = math.ceil((x1 - x0 + 2 * MAP_MARGIN) / cell)
    ny = math.ceil((y1 - y0 + 2 * MAP_MARGIN) / cell)
    return GridSpec(cell_size=cell, size_x=nx * cell, size_y=ny * cell, centre=((x0 + x1) / 2, (y0 + y1) / 2))


class EpisodeSampler:
    """Start and goal of an episode in one scene.

    Args:
        scene: the scene.
        grid: the raster's grid (the episode map's).
        band: the chair's height band (z_min, z_max), m.
        spec: the platform spec (the chair's width).
        robot_radius: radius of the chair's turning circle about ``base_link``, m.
        goal_distance: (min, max) straight-line distance from start to goal, m.
        anchor: a point the free region must contain (e.g. a fixed start); None: the largest region.

    Raises:
        NavigationEnvError: no free region, or no cell where the chair can turn on the spot.
    """

    def __init__(
        self,
        scene: Scene,
        grid: GridSpec,
        band: tuple[float, float],
        spec: RobChairSpec,
        robot_radius: float,
        goal_distance: tuple[float, float],
        anchor: tuple[float, float] | None = None,
    ) -> None:
        self.scene, self.grid, self.spec = scene, grid, spec
        self.robot_radius = float(robot_radius)
        self.goal_distance = goal_distance
        self.free_space = FreeSpace.from_scene(
            scene, grid, band, spec.body.width / 2 + PASS_MARGIN, anchor=anchor
        )
        self.start_cells = self.free_space.candidates(self.robot_radius + START_MARGIN)
        if len(self.start_cells) == 0:
            raise NavigationEnvError(
                f"scene {scene.name!r}: no free cell where the chair can turn on the spot"
            )

    def sample(
        self, rng: np.random.Generator, start: Any = None, goal: Any = None, goal_tolerance: float = 0.0
    ) -> tuple[Pose2D, tuple[float, float]]:
        """Start pose and goal of an episode: the given ones (checked) or drawn from ``rng``.

        Args:
            rng: the episode's random stream.
            start, goal: a given (x, y, theta) start and (x, y) goal, m and rad, or None to draw one.
            goal_tolerance: the episode's success radius, m: a goal this close to the start is refused.

        Raises:
            NavigationEnvError: a given point outside the map (said before anything is drawn), a goal
                within ``goal_tolerance`` of the start, a goal where the chair cannot stand or that no
                passage wide enough joins to the start, or no start/goal at ``goal_distance``.
        """
        if start is not None:
            start = Pose2D(*pose_arg(start, 3, "start"))
            self._check_on_map("start", (start.x, start.y))
        if goal is not None:
            goal = pose_arg(goal, 2, "goal")
            self._check_on_map("goal", goal)
            if start is None:
                start = self._sample_start(rng, np.array(goal))
        elif start is not None:
            goal = self._sample_goal(rng, start)
        else:
            for _ in range(100):
                cand = self._sample_start(rng, None)
                try:
                    goal = self._sample_goal(rng, cand)
                except NavigationEnvError:
                    continue
                start = cand
                break
            else:
                raise NavigationEnvError(
                    f"scene {self.scene.name!r}: found no start with a goal at {self.goal_distance} m "
                    "in 100 tries"
                )
        gap = math.hypot(goal[0] - start.x, goal[1] - start.y)
        if gap <= goal_tolerance:
            raise NavigationEnvError(
                f"goal {tuple(goal)} is {gap:.2f} m from the start {(start.x, start.y)}, within the goal "
                f"tolerance {goal_tolerance} m: the episode would be over before it began"
            )
        self.check_goal(start, goal)
        return start, goal

    def _check_on_map(self, name: str, xy: Any) -> None:
        i, j = self.grid.world_to_index(xy[0], xy[1])
        if not bool(self.grid.contains_index(i, j)):
            raise NavigationEnvError(f"{name} {tuple(xy)} lies outside the scene's map {self.grid.extent}")

    def check_goal(self, start: Pose2D, goal: tuple[float, float]) -> None:
        """The goal must leave room for the chair and be reachable from the start.

        Raises:
            NavigationEnvError: naming the goal and the nearest obstacle, or the start it is cut off from.
        """
        fs = self.free_space
        width = self.spec.body.width
        i, j = self.grid.world_to_index(goal[0], goal[1])
        if fs.clearance[i, j] < width / 2:
            name, dist = fs.nearest_obstacle(goal)
            raise NavigationEnvError(
                f"goal {tuple(goal)}: {max(dist, 0.0):.2f} m from {name!r}, the chair "
                f"({width} m wide) cannot stand there"
            )
        a = fs.label_near((start.x, start.y), self.robot_radius)
        b = fs.label_near(goal, self.robot_radius)
        if a == 0 or a != b:
            name, _ = fs.nearest_obstacle(goal)
            raise NavigationEnvError(
                f"goal {tuple(goal)} is not reachable from the start {(start.x, start.y)}: no passage "
                f"{width + 2 * PASS_MARGIN:.2f} m wide joins them (near the goal: {name!r})"
            )

    def _in_range(self, cells: npt.NDArray[np.float64], xy: Any) -> npt.NDArray[np.float64]:
        d = np.hypot(cells[:, 0] - xy[0], cells[:, 1] - xy[1])
        return cells[(d >= self.goal_distance[0]) & (d <= self.goal_distance[1])]

    def _sample_start(self, rng: np.random.Generator, goal: npt.NDArray[np.float64] | None) -> Pose2D:
        cells = self.start_cells
        if goal is not None:
            cells = self._in_range(cells, goal)
            if len(cells) == 0:
                raise NavigationEnvError(
                    f"no free start at {self.goal_distance} m from the goal {tuple(goal)}"
                )
        x, y = cells[int(rng.integers(len(cells)))]
        return Pose2D(float(x), float(y), float(rng.uniform(-math.pi, math.pi)))

    def _sample_goal(self, rng: np.random.Generator, start: Pose2D) -> tuple[float, float]:
        cells = self._in_range(self.start_cells, (start.x, start.y))
        if len(cells) == 0:
            raise NavigationEnvError(f"no free goal at {self.goal_distance} m from the start {start}")
        x, y = cells[int(rng.integers(len(cells)))]
        return float(x), float(y)


def check_reset_options(options: Mapping[str, Any] | None, random_floors: bool) -> dict[str, Any]:
    """The ``reset`` options as a dict, refusing unknown keys.

    Raises:
        NavigationEnvError: an unknown option, naming it and the allowed ones.
    """
    opts = dict(options or {})
    allowed = {"start", "goal"} | ({"room_seed"} if random_floors else set())
    unknown = set(opts) - allowed
    if unknown:
        raise NavigationEnvError(f"reset options {sorted(unknown)}: unknown (allowed: {sorted(allowed)})")
    return opts
