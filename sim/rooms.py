"""Random floors for navigation research: rooms off a corridor, doorways, tables, clutter, walkers.

:func:`generate_floor` turns a seed into a :class:`sim.scene.Scene` (the project's scene type, built
into PyBullet like any scene file). The layout:

* a rectangular floor ``width`` x ``depth`` with outer walls 2.5 m high;
* a corridor 1.6-2.4 m wide along the south wall, the rooms north of it, split by interior walls;
* one doorway 0.8-1.2 m wide (the clear width of wheelchair-accessible doors, e.g. ADA 404.2.3
  asks for at least 0.815 m) from the corridor into each room, and a door between neighbouring rooms
  with probability ``connect_rooms``;
* per room up to ``max_tables`` tables (0.72-0.76 m high tops on four legs: the 1.63 m chair cannot
  drive under them; their tops lie in its height band), and clutter (boxes, bins, plant pots);
* optionally ``walkers`` people walking back and forth along the corridor or through a room.

Every floor is checked on the ground-truth grid before it is returned: the cells where the chair
fits through (clearance of half its width plus 2 cm to every surface in its height band, on a 5 cm
grid whose clearances are lower bounds) must join
every room with the corridor in one connected region. A floor that fails (a table or a box in a
doorway) is drawn again from the next sub-seed of the same seed, so a seed always gives the same floor.

Training and evaluation use seed ranges that never overlap: :data:`TRAIN_SEEDS` and
:data:`EVAL_SEEDS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from robchair.platform.paths import ASSETS
from sim.errors import SimError
from sim.scene import Motion, Scene, SceneObject

#: Seeds for training floors.
TRAIN_SEEDS = range(0, 1_000_000)
#: Seeds for evaluation floors (disjoint from :data:`TRAIN_SEEDS`).
EVAL_SEEDS = range(1_000_000_000, 1_000_010_000)

WALL_HEIGHT = 2.5  # m
WALL_THICKNESS = 0.1  # m
DOOR_WIDTH = (0.8, 1.2)  # m, clear width of a doorway
TABLE_HEIGHT = (0.72, 0.76)  # m, top surface
PERSON_MESH = ASSETS / "meshes" / "person_standing_1.obj"
MAX_TRIES = 50

_WALL = (0.85, 0.85, 0.82, 1.0)
_WOOD = (0.55, 0.38, 0.22, 1.0)
_CLUTTER = (0.3, 0.35, 0.45, 1.0)


class RoomsError(SimError, ValueError):
    """A random-floor argument is invalid, or no feasible floor was found for a seed."""


@dataclass(frozen=True)
class FloorConfig:
    """Ranges of the random floor.

    Attributes:
        width: Range of the floor's east-west size, m.
        depth: Range of the floor's north-south size, m.
        corridor: Range of the corridor's width, m.
        rooms: Range (inclusive) of the number of rooms.
        connect_rooms: Probability of a door between neighbouring rooms.
        max_tables: Most tables per room.
        max_clutter: Most clutter objects per room (and in the corridor).
        walkers: Number of walking people.
        walker_speed: Range of their walking speed, m/s.
        chair_width: Width of the chair the floor must let through, m.
        chair_height: Height of the chair (its obstacle band is 0.10 m .. this), m.
        pass_margin: Clearance beyond half the chair's width a passage needs, m.
        door_width: Range of the doorways' clear width, m.
    """

    width: tuple[float, float] = (8.0, 13.0)
    depth: tuple[float, float] = (6.5, 10.0)
    corridor: tuple[float, float] = (1.6, 2.4)
    rooms: tuple[int, int] = (2, 4)
    connect_rooms: float = 0.5
    max_tables: int = 2
    max_clutter: int = 3
    walkers: int = 0
    walker_speed: tuple[float, float] = (0.6, 1.2)
    chair_width: float = 0.64
    chair_height: float = 1.632
    pass_margin: float = 0.02
    door_width: tuple[float, float] = DOOR_WIDTH

    def __post_init__(self) -> None:
        for name in ("width", "depth", "corridor", "walker_speed", "door_width"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
                raise RoomsError(f"{name}={getattr(self, name)!r}: expected 0 < low <= high")
        if not 1 <= self.rooms[0] <= self.rooms[1]:
            raise RoomsError(f"rooms={self.rooms!r}: expected 1 <= low <= high")
        if self.width[0] < 2.5:
            raise RoomsError(f"width={self.width!r}: a room needs at least 2.5 m (fewer rooms fit otherwise)")
        if self.depth[0] - self.corridor[1] < 3.0:
            raise RoomsError(
                f"depth={self.depth!r} leaves rooms under 3 m deep beside corridor={self.corridor!r}"
            )
        for name in ("max_tables", "max_clutter", "walkers"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise RoomsError(f"{name}={v!r}: expected a non-negative integer")
        if not 0.0 <= self.connect_rooms <= 1.0:
            raise RoomsError(f"connect_rooms={self.connect_rooms!r}: expected a probability")

    @property
    def max_extent(self) -> float:
        """Longest straight line on any floor of this config (its diagonal), m."""
        return math.hypot(self.width[1], self.depth[1])


def _box(
    name: str, cx: float, cy: float, sx: float, sy: float, h: float, color: tuple[float, ...]
) -> SceneObject:
    return SceneObject(name=name, shape="box", xyz=(cx, cy, h / 2), size=(sx, sy, h), color=color)  # type: ignore[arg-type]


def _wall_x(name: str, x0: float, x1: float, y: float, doors: list[tuple[float, float]]) -> list[SceneObject]:
    """An east-west wall from x0 to x1 at y, with door gaps (centre, width)."""
    out = []
    edges = [x0]
    for c, w in sorted(doors):
        edges += [c - w / 2, c + w / 2]
    edges.append(x1)
    for k in range(0, len(edges), 2):
        a, b = edges[k], edges[k + 1]
        if b - a > 1e-3:
            out.append(_box(f"{name}_{k // 2}", (a + b) / 2, y, b - a, WALL_THICKNESS, WALL_HEIGHT, _WALL))
    return out


def _wall_y(name: str, y0: float, y1: float, x: float, doors: list[tuple[float, float]]) -> list[SceneObject]:
    """A north-south wall from y0 to y1 at x, with door gaps (centre, width)."""
    out = []
    edges = [y0]
    for c, w in sorted(doors):
        edges += [c - w / 2, c + w / 2]
    edges.append(y1)
    for k in range(0, len(edges), 2):
        a, b = edges[k], edges[k + 1]
        if b - a > 1e-3:
            out.append(_box(f"{name}_{k // 2}", x, (a + b) / 2, WALL_THICKNESS, b - a, WALL_HEIGHT, _WALL))
    return out


def _table(name: str, cx: float, cy: float, sx: float, sy: float, h: float, yaw: float) -> list[SceneObject]:
    """A table top on four legs (the top is 4 cm thick, legs 5 cm square)."""
    c, s = math.cos(yaw), math.sin(yaw)
    top = SceneObject(
        name=f"{name}_top",
        shape="box",
        xyz=(cx, cy, h - 0.02),
        size=(sx, sy, 0.04),
        rpy=(0.0, 0.0, yaw),
        color=_WOOD,
    )
    legs = []
    for k, (lx, ly) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        ox, oy = lx * (sx / 2 - 0.05), ly * (sy / 2 - 0.05)
        legs.append(
            SceneObject(
                name=f"{name}_leg{k}",
                shape="box",
                xyz=(cx + c * ox - s * oy, cy + s * ox + c * oy, (h - 0.04) / 2),
                size=(0.05, 0.05, h - 0.04),
                rpy=(0.0, 0.0, yaw),
                color=_WOOD,
            )
        )
    return [top, *legs]


def _clutter(name: str, rng: np.random.Generator, x: float, y: float) -> SceneObject:
    kind = int(rng.integers(3))
    if kind == 0:  # a box (carton, cabinet)
        sx, sy, h = rng.uniform(0.25, 0.6), rng.uniform(0.25, 0.6), rng.uniform(0.3, 1.0)
        yaw = float(rng.uniform(-math.pi, math.pi))
        return SceneObject(
            name=name, shape="box", xyz=(x, y, h / 2), size=(sx, sy, h), rpy=(0.0, 0.0, yaw), color=_CLUTTER
        )
    r, h = rng.uniform(0.12, 0.25), rng.uniform(0.3, 0.9)  # a bin or a plant pot
    return SceneObject(name=name, shape="cylinder", xyz=(x, y, h / 2), radius=r, length=h, color=_CLUTTER)


@dataclass(frozen=True)
class Floor:
    """A generated floor: the scene plus its layout (for tests and pictures).

    Attributes:
        scene: The scene.
        seed: The seed it came from.
        rooms: ``(x0, y0, x1, y1)`` of each room's inside.
        corridor: ``(x0, y0, x1, y1)`` of the corridor's inside.
        doors: ``(x, y, width)`` of each doorway's centre.
        attempt: Which sub-seed gave the first feasible floor (0 = the first draw).
    """

    scene: Scene
    seed: int
    rooms: tuple[tuple[float, float, float, float], ...]
    corridor: tuple[float, float, float, float]
    doors: tuple[tuple[float, float, float], ...]
    attempt: int


def _draw(seed: int, attempt: int, cfg: FloorConfig) -> Floor:
    rng = np.random.default_rng([seed, attempt])
    W = float(rng.uniform(*cfg.width))
    D = float(rng.uniform(*cfg.depth))
    C = float(rng.uniform(*cfg.corridor))
    n = int(rng.integers(cfg.rooms[0], cfg.rooms[1] + 1))
    n = max(1, min(n, int(W // 2.5)))
    t = WALL_THICKNESS
    objs: list[SceneObject] = []
    # outer walls (their inner faces at 0, W, 0, D)
    objs += [
        _box("wall_south", W / 2, -t / 2, W + 2 * t, t, WALL_HEIGHT, _WALL),
        _box("wall_north", W / 2, D + t / 2, W + 2 * t, t, WALL_HEIGHT, _WALL),
        _box("wall_west", -t / 2, D / 2, t, D, WALL_HEIGHT, _WALL),
        _box("wall_east", W + t / 2, D / 2, t, D, WALL_HEIGHT, _WALL),
    ]
    # room boundaries: cut points along x with every room at least 2.5 m wide
    widths = rng.dirichlet(np.full(n, 4.0)) * (W - 2.5 * n) + 2.5
    xs = np.concatenate([[0.0], np.cumsum(widths)])
    xs[-1] = W
    yc = C + t / 2  # corridor wall centre line
    rooms, doors, corridor_doors = [], [], []
    for k in range(n):
        a, b = float(xs[k]) + (t / 2 if k else 0.0), float(xs[k + 1]) - (t / 2 if k < n - 1 else 0.0)
        rooms.append((a, C + t, b, D))
        w = float(rng.uniform(*cfg.door_width))
        cx = float(rng.uniform(a + w / 2 + 0.3, b - w / 2 - 0.3))
        corridor_doors.append((cx, w))
        doors.append((cx, yc, w))
    objs += _wall_x("wall_corridor", 0.0, W, yc, corridor_doors)
    for k in range(1, n):
        x = float(xs[k])
        gaps = []
        if rng.random() < cfg.connect_rooms:
            w = float(rng.uniform(*cfg.door_width))
            cy = float(rng.uniform(C + t + w / 2 + 0.3, D - w / 2 - 0.3))
            gaps.append((cy, w))
            doors.append((x, cy, w))
        objs += _wall_y(f"wall_room{k}", C + t, D, x, gaps)

    # furniture: keep 1.0 m clear in front of every doorway so the floor stays feasible more often
    def near_door(x: float, y: float, r: float) -> bool:
        return any(math.hypot(x - dx, y - dy) < r + dw / 2 + 1.0 for dx, dy, dw in doors)

    for k, (a, b0, c, d) in enumerate(rooms):
        for m in range(int(rng.integers(0, cfg.max_tables + 1))):
            sx, sy = float(rng.uniform(0.8, 1.6)), float(rng.uniform(0.6, 0.9))
            yaw = float(rng.choice([0.0, math.pi / 2]))
            hx, hy = (sx / 2, sy / 2) if yaw == 0.0 else (sy / 2, sx / 2)
            if c - a < 2 * hx + 0.2 or d - b0 < 2 * hy + 0.2:
                continue
            x, y = (
                float(rng.uniform(a + hx + 0.1, c - hx - 0.1)),
                float(rng.uniform(b0 + hy + 0.1, d - hy - 0.1)),
            )
            if near_door(x, y, max(hx, hy)):
                continue
            objs += _table(f"room{k}_table{m}", x, y, sx, sy, float(rng.uniform(*TABLE_HEIGHT)), yaw)
        for m in range(int(rng.integers(0, cfg.max_clutter + 1))):
            x, y = float(rng.uniform(a + 0.4, c - 0.4)), float(rng.uniform(b0 + 0.4, d - 0.4))
            if not near_door(x, y, 0.3):
                objs.append(_clutter(f"room{k}_clutter{m}", rng, x, y))
    for m in range(int(rng.integers(0, cfg.max_clutter + 1))):
        # corridor clutter hugs a wall, leaving the corridor passable most of the time
        x = float(rng.uniform(0.4, W - 0.4))
        y = float(rng.choice([0.3, C - 0.3]))
        if not near_door(x, y, 0.3):
            objs.append(_clutter(f"corridor_clutter{m}", rng, x, y))
    for m in range(cfg.walkers):
        speed = float(rng.uniform(*cfg.walker_speed))
        if m % 2 == 0 or not rooms:  # along the corridor
            y = float(rng.uniform(0.5, C - 0.5))
            pts = ((0.5, y), (W - 0.5, y))
        else:  # from the corridor through a doorway into a room and back
            dx, dy, _ = doors[int(rng.integers(len(corridor_doors)))]
            pts = ((dx, C / 2), (dx, min(D - 0.6, dy + 2.0)))
        start = float(rng.uniform(0, 1))
        p0 = (pts[0][0] + start * (pts[1][0] - pts[0][0]), pts[0][1] + start * (pts[1][1] - pts[0][1]))
        objs.append(
            SceneObject(
                name=f"walker{m}",
                shape="mesh",
                xyz=(p0[0], p0[1], 0.0),
                mesh_path=PERSON_MESH,
                color=(0.75, 0.4, 0.35, 1.0),
                motion=Motion(waypoints=(p0, pts[1], pts[0]), speed=speed, loop=True),
            )
        )
    scene = Scene(
        name=f"rooms_{seed}",
        path=Path(f"rooms_{seed}.toml"),
        objects=tuple(objs),
        description=f"random floor {W:.1f} m x {D:.1f} m, {n} rooms, seed {seed}",
    )
    return Floor(scene, seed, tuple(rooms), (0.0, 0.0, W, C), tuple(doors), attempt)


def floor_is_feasible(floor: Floor, cfg: FloorConfig, cell: float = 0.05) -> bool:
    """Whether one connected region where the chair fits joins the corridor and every room.

    Checked on the ground-truth raster of the static objects in the chair's height band (walkers
    left out), with the clearance of half the chair's width plus ``cfg.pass_margin``.
    """
    from mapping.grid import GridSpec
    from sim.envs.errors import NavigationEnvError
    from sim.envs.geometry import FreeSpace

    x0, y0, x1, y1 = floor.scene.bounds_xy()
    nx, ny = math.ceil((x1 - x0 + 2) / cell), math.ceil((y1 - y0 + 2) / cell)
    grid = GridSpec(cell_size=cell, size_x=nx * cell, size_y=ny * cell, centre=((x0 + x1) / 2, (y0 + y1) / 2))
    try:
        fs = FreeSpace.from_scene(
            floor.scene, grid, (0.10, cfg.chair_height), cfg.chair_width / 2 + cfg.pass_margin
        )
    except NavigationEnvError:
        return False
    wanted = set()
    for a, b, c, d in (floor.corridor, *floor.rooms):
        i0, j0 = grid.world_to_index(a, b)
        i1, j1 = grid.world_to_index(c, d)
        ids = set(np.unique(fs.labels[int(i0) : int(i1) + 1, int(j0) : int(j1) + 1]).tolist()) - {0}
        if not ids:
            return False
        # the area's biggest passable part must be the one everybody shares
        win = fs.labels[int(i0) : int(i1) + 1, int(j0) : int(j1) + 1]
        counts = {k: int((win == k).sum()) for k in ids}
        wanted.add(max(counts, key=lambda k: counts[k]))
    return len(wanted) == 1


def generate_floor(seed: int, config: FloorConfig | None = None) -> Floor:
    """The random floor of ``seed`` (the first feasible draw of its sub-seeds).

    Args:
        seed: Non-negative integer; see :data:`TRAIN_SEEDS` and :data:`EVAL_SEEDS`.
        config: Ranges (default :class:`FloorConfig`).

    Raises:
        RoomsError: bad seed, or no feasible floor in :data:`MAX_TRIES` draws.
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise RoomsError(f"seed={seed!r}: expected a non-negative integer")
    cfg = config if config is not None else FloorConfig()
    for attempt in range(MAX_TRIES):
        floor = _draw(int(seed), attempt, cfg)
        if floor_is_feasible(floor, cfg):
            return floor
    raise RoomsError(f"seed={seed}: no feasible floor in {MAX_TRIES} draws with {cfg}")
