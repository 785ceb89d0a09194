"""Declarative scenes and scenarios (TOML in ``assets/scenes/``), strictly validated, built into PyBullet.

A **scene** file has a ``[scene]`` table and a list of ``[[object]]`` tables::

    [scene]
    name = "office"
    description = "..."

    [[object]]
    name = "north_wall"
    shape = "box"              # box | cylinder | sphere | capsule | mesh
    size = [10.0, 0.1, 2.5]    # box: full extents (m)
    xyz = [0.0, 3.0, 1.25]     # centre of the shape (mesh: its origin), metres
    yaw = 0.0                  # or rpy = [r, p, y], radians (not both)
    color = [0.8, 0.8, 0.8]    # RGB or RGBA in [0, 1]

    [[object]]
    name = "walker"
    shape = "mesh"
    mesh = "person_standing_2.obj"     # in assets/meshes/ (or relative to the scene file)
    xyz = [3.0, 1.0, 0.0]
    [object.motion]                     # scripted motion of a person: walks the waypoints at speed
    waypoints = [[3.0, 1.0], [8.0, 1.0]]
    speed = 1.2
    loop = true                         # back and forth; false = stop at the last waypoint
    avoid_chair = true                  # steps round the chair (sim.crowd); false: walks into it

``cylinder`` and ``capsule`` take ``radius`` and ``length`` (along the object's z), ``sphere`` takes
``radius``, ``mesh`` takes ``mesh`` and an optional ``scale``.

A **scenario** file has a ``[scenario]`` table (scene, duration, sensor, seed, start pose) and a
``[route]`` table (waypoints the chair follows with pure pursuit, cruise speed, look-ahead)::

    [scenario]
    name = "office_corridor"
    scene = "office"          # a scene name in the same folder, or a path relative to this file
    duration = 12.0           # seconds of simulated time
    sensor = "kinect2"        # kinect2 | kinect2-hd | kinect2-qhd | kinect1
    sonars = true
    seed = 0
    start = [0.0, 0.0, 0.0]   # x, y, yaw of base_link
    [route]
    waypoints = [[2.0, 0.0], [4.0, 1.0]]
    speed = 0.5
    lookahead = 0.6

Every key is checked (:mod:`robchair.platform.config`): an unknown key, a wrong type, a missing mesh or an
impossible pose (non-finite, under the floor, overlapping the chair at its start) raises
:class:`sim.errors.ScenarioError` naming the file, the line of the key, the field, the value and what
was expected.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from robchair.platform.config import ConfigSource, ConfigTable, load_toml
from robchair.platform.frames import quat_from_rpy, rotation_rpy
from robchair.platform.paths import ASSETS, SCENES
from sim.errors import ScenarioError
from sim.meshgen import Mesh, box, capsule, cylinder, read_obj, sphere

MESHES_DIR = ASSETS / "meshes"
SHAPES = ("box", "cylinder", "sphere", "capsule", "mesh")
SENSORS = ("kinect2", "kinect2-hd", "kinect2-qhd", "kinect1")

_SCENE_KEYS = {"name", "description"}
_OBJECT_KEYS = {
    "name",
    "shape",
    "size",
    "radius",
    "length",
    "mesh",
    "scale",
    "xyz",
    "yaw",
    "rpy",
    "color",
    "motion",
}
_MOTION_KEYS = {"waypoints", "speed", "loop", "avoid_chair"}
_SCENARIO_KEYS = {"name", "description", "scene", "duration", "sensor", "sonars", "seed", "start"}
_ROUTE_KEYS = {"waypoints", "speed", "lookahead"}
_FLOOR_TOLERANCE = 1e-3  # m: a shape may touch the floor, not go through it


@dataclass(frozen=True)
class Motion:
    """Scripted walk: along ``waypoints`` (x, y) at ``speed`` m/s, back and forth if ``loop``; a person
    who ``avoid_chair`` steps round the chair (:mod:`sim.crowd`), one who does not walks into it."""

    waypoints: tuple[tuple[float, float], ...]
    speed: float
    loop: bool = True
    avoid_chair: bool = True

    def pose_at(self, t: float) -> tuple[float, float, float]:
        """Position (x, y) and heading (yaw, along the walking direction) at time ``t`` seconds."""
        pts = np.asarray(self.waypoints, dtype=float)
        seg = np.diff(pts, axis=0)
        lengths = np.hypot(seg[:, 0], seg[:, 1])
        total = float(lengths.sum())
        s = self.speed * max(t, 0.0)
        backwards = False
        if self.loop and total > 0:
            s = s % (2 * total)
            if s > total:
                s, backwards = 2 * total - s, True
        s = min(s, total)
        k = int(np.searchsorted(np.cumsum(lengths), s, side="left"))
        k = min(k, len(lengths) - 1)
        s0 = float(np.cumsum(lengths)[k] - lengths[k])
        frac = 0.0 if lengths[k] == 0 else (s - s0) / lengths[k]
        x, y = pts[k] + frac * seg[k]
        yaw = math.atan2(seg[k][1], seg[k][0]) + (math.pi if backwards else 0.0)
        return float(x), float(y), yaw


@dataclass(frozen=True)
class SceneObject:
    """One body of a scene. ``size`` is the box extents; ``radius``/``length`` for round shapes."""

    name: str
    shape: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    size: tuple[float, float, float] | None = None
    radius: float | None = None
    length: float | None = None
    mesh_path: Path | None = None
    scale: float = 1.0
    motion: Motion | None = None

    @property
    def is_dynamic(self) -> bool:
        return self.motion is not None

    def local_mesh(self) -> Mesh:
        """The shape as a triangle mesh in its own frame (used for bounds and ground-truth maps)."""
        if self.shape == "box":
            assert self.size is not None
            return box(self.size)
        if self.shape == "cylinder":
            assert self.radius is not None and self.length is not None
            return cylinder(self.radius, self.length, 24)
        if self.shape == "sphere":
            assert self.radius is not None
            return sphere(self.radius, 12, 16)
        if self.shape == "capsule":
            assert self.radius is not None and self.length is not None
            return capsule(self.radius, self.length)
        assert self.mesh_path is not None
        m = _read_mesh_cached(self.mesh_path)
        return Mesh(m.vertices * self.scale, m.faces)

    def world_mesh(self, xyz: tuple[float, float, float] | None = None, yaw: float | None = None) -> Mesh:
        """The mesh placed at its pose (or at ``xyz``/``yaw`` for a moving object)."""
        rpy = self.rpy if yaw is None else (self.rpy[0], self.rpy[1], yaw)
        return self.local_mesh().transformed(rotation_rpy(*rpy), self.xyz if xyz is None else xyz)


@dataclass(frozen=True)
class Scene:
    """A named set of objects loaded from ``path``."""

    name: str
    path: Path
    objects: tuple[SceneObject, ...]
    description: str = ""

    def bounds_xy(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) over every object, including the whole walk of moving ones."""
        lo = np.array([np.inf, np.inf])
        hi = -lo
        for obj in self.objects:
            m = obj.world_mesh()
            lo = np.minimum(lo, m.vertices[:, :2].min(axis=0))
            hi = np.maximum(hi, m.vertices[:, :2].max(axis=0))
            if obj.motion is not None:
                w = np.asarray(obj.motion.waypoints)
                lo, hi = np.minimum(lo, w.min(axis=0) - 1), np.maximum(hi, w.max(axis=0) + 1)
        if not np.isfinite(lo).all():
            return (-1.0, -1.0, 1.0, 1.0)
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


@dataclass(frozen=True)
class Route:
    waypoints: tuple[tuple[float, float], ...]
    speed: float = 0.5
    lookahead: float = 0.6


@dataclass(frozen=True)
class Scenario:
    """What ``robchair sim`` runs: a scene, the chair's start and route, the sensor, duration and seed."""

    name: str
    path: Path
    scene: Scene
    route: Route
    duration: float = 10.0
    sensor: str = "kinect2"
    sonars: bool = True
    seed: int = 0
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    description: str = ""


# --- validation helpers ---------------------------------------------------------------------------

_mesh_cache: dict[Path, Mesh] = {}


def _read_mesh_cached(path: Path) -> Mesh:
    if path not in _mesh_cache:
        _mesh_cache[path] = read_obj(path)
    return _mesh_cache[path]


def _resolve(name: str, base: Path) -> Path:
    """A scene/scenario reference: an existing path, or a name in ``base`` or :data:`SCENES`."""
    p = Path(name)
    for cand in (p, base / p, base / f"{name}.toml", SCENES / f"{name}.toml"):
        if cand.is_file():
            return cand
    return base / f"{name}.toml"


# --- loading --------------------------------------------------------------------------------------


def _parse_object(t: ConfigTable) -> SceneObject:
    t.keys(_OBJECT_KEYS)
    name = t.string("name", t.where.replace("[", "").replace("]", ""))
    shape = t.string("shape", choices=SHAPES)
    need = {
        "box": {"size"},
        "cylinder": {"radius", "length"},
        "capsule": {"radius", "length"},
        "sphere": {"radius"},
        "mesh": {"mesh"},
    }[shape]
    extra = {"size", "radius", "length", "mesh", "scale"} - need - ({"scale"} if shape == "mesh" else set())
    for k in sorted(extra):
        if k in t:
            raise t.problem(k, f"not a parameter of a {shape} (a {shape} takes {', '.join(sorted(need))})")
    xyz = t.vector("xyz", 3)
    if "yaw" in t and "rpy" in t:
        raise t.problem("rpy", "give either yaw or rpy, not both")
    rpy = (0.0, 0.0, t.number("yaw")) if "yaw" in t else t.vector("rpy", 3, (0.0, 0.0, 0.0))
    c = t.vector("color", (3, 4), (0.7, 0.7, 0.7, 1.0), ge=0, le=1)
    color = (c[0], c[1], c[2], c[3] if len(c) == 4 else 1.0)
    kw: dict[str, Any] = {}
    if shape == "box":
        kw["size"] = t.vector("size", 3, gt=0)
    if shape in ("cylinder", "capsule", "sphere"):
        kw["radius"] = t.number("radius", gt=0)
    if shape in ("cylinder", "capsule"):
        kw["length"] = t.number("length", gt=0)
    if shape == "mesh":
        m = t.string("mesh")
        cands = [Path(t.source.name).parent / m, MESHES_DIR / m]
        found = next((c for c in cands if c.is_file()), None)
        if found is None:
            raise t.invalid(
                "mesh", f"a mesh file in {Path(t.source.name).parent} or {MESHES_DIR} (not found)"
            )
        kw["mesh_path"] = found.resolve()
        kw["scale"] = t.number("scale", 1.0, gt=0)
    motion = None
    if "motion" in t:
        mt = t.table("motion")
        mt.keys(_MOTION_KEYS)
        motion = Motion(mt.points("waypoints"), mt.number("speed", gt=0), mt.boolean("loop", True),
                            mt.boolean("avoid_chair", True))  # fmt: skip
    obj = SceneObject(
        name=name,
        shape=shape,
        xyz=(xyz[0], xyz[1], xyz[2]),
        rpy=(rpy[0], rpy[1], rpy[2]),
        color=color,
        motion=motion,
        **kw,
    )
    zmin = float(obj.world_mesh().vertices[:, 2].min())
    if zmin < -_FLOOR_TOLERANCE:
        raise t.problem("xyz", f"impossible pose: the object reaches {zmin:.3f} m, below the floor (z = 0)")
    return obj


def load_scene(path: Path | str) -> Scene:
    """Load and validate a scene file (see the module docstring).

    Raises:
        ScenarioError: The file is missing or not TOML, or a key is unknown, missing or invalid (the
            message names the file, the line, the field, the value and what was expected).
    """
    path = Path(path)
    data, source = load_toml(path, ScenarioError, "scene file")
    top = ConfigTable(data, source)
    top.keys({"scene", "object"})
    head = top.table("scene", {})
    head.keys(_SCENE_KEYS)
    objects = tuple(_parse_object(t) for t in top.tables("object", []))
    names = [o.name for o in objects]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise top.tables("object")[names.index(dup[0], names.index(dup[0]) + 1)].problem(
            "name", f"duplicate object name {dup[0]!r}"
        )
    return Scene(
        name=head.string("name", path.stem),
        path=path,
        objects=objects,
        description=str(head.raw("description", "")),
    )


def load_scenario(path: Path | str, robot_radius: float = 0.55) -> Scenario:
    """Load and validate a scenario file and the scene it names.

    Args:
        path: the scenario TOML, or a scenario name in :data:`robchair.platform.paths.SCENES`.
        robot_radius: radius (m) of the circle around the start pose the chair occupies; a static
            object lower than the chair whose footprint enters it is an impossible start.

    Raises:
        ScenarioError: The scenario or its scene is invalid (see :func:`load_scene`).
    """
    name = str(path)
    path = Path(path)
    if not path.is_file():
        path = _resolve(name, SCENES)
        if not path.is_file() and path.parent == SCENES:  # a name, not a path: say which exist
            known = ", ".join(p.stem for p in list_scenarios())
            raise ConfigSource(error=ScenarioError).invalid("scenario", name, f"one of {known}, or a file")
    data, source = load_toml(path, ScenarioError, "scenario file")
    top = ConfigTable(data, source)
    top.keys({"scenario", "route"})
    if "scenario" not in top:
        raise source.missing("scenario", "a [scenario] table (is this a scene file?)")
    head = top.table("scenario")
    head.keys(_SCENARIO_KEYS)
    route_t = top.table("route")
    route_t.keys(_ROUTE_KEYS)
    scene_name = head.string("scene")
    scene_path = _resolve(scene_name, path.parent)
    if not scene_path.is_file():
        raise head.invalid("scene", f"the name of a scene file (not found: {scene_path})")
    scene = load_scene(scene_path)
    start = head.vector("start", 3, (0.0, 0.0, 0.0))
    route = Route(
        waypoints=route_t.points("waypoints"),
        speed=route_t.number("speed", Route.speed, gt=0),
        lookahead=route_t.number("lookahead", Route.lookahead, gt=0),
    )
    scenario = Scenario(
        name=str(head.raw("name", path.stem)),
        path=path,
        scene=scene,
        route=route,
        duration=head.number("duration", Scenario.duration, gt=0),
        sensor=head.string("sensor", Scenario.sensor, choices=SENSORS),
        sonars=head.boolean("sonars", Scenario.sonars),
        seed=head.integer("seed", Scenario.seed, ge=0),
        start=(start[0], start[1], start[2]),
        description=str(head.raw("description", "")),
    )
    _check_start_clear(head, scene, scenario.start, robot_radius)
    _check_waypoints_clear(route_t, scene, scenario.route.waypoints)
    return scenario


def _check_waypoints_clear(
    table: ConfigTable, scene: Scene, waypoints: Sequence[tuple[float, float]]
) -> None:
    """Refuse a route waypoint inside the footprint (convex hull from above) of a static object."""
    from scipy.spatial import ConvexHull, QhullError

    for obj in scene.objects:
        if obj.is_dynamic:
            continue
        xy = obj.world_mesh().vertices[:, :2]
        try:
            hull = ConvexHull(xy)
        except QhullError:  # a flat object seen edge-on from above has no area
            continue
        # facets: a . p + b <= 0 inside; 1 mm of slack keeps a waypoint on the surface outside
        for i, wp in enumerate(waypoints):
            if bool(np.all(hull.equations[:, :2] @ np.asarray(wp) + hull.equations[:, 2] < -1e-3)):
                raise table.problem(
                    "waypoints",
                    f"waypoint {i} {tuple(wp)} lies inside object {obj.name!r} of scene {scene.path.name}",
                )


def _check_start_clear(
    head: ConfigTable, scene: Scene, start: tuple[float, float, float], radius: float
) -> None:
    """Refuse a start pose whose footprint circle overlaps a static object (or a person's start)."""
    c = np.array(start[:2])
    for obj in scene.objects:
        pos = obj.xyz
        if obj.motion is not None:
            x, y, _ = obj.motion.pose_at(0.0)
            pos = (x, y, obj.xyz[2])
        v = obj.world_mesh(xyz=pos).vertices
        lo, hi = v[:, :2].min(axis=0), v[:, :2].max(axis=0)
        nearest = np.clip(c, lo, hi)
        if float(np.hypot(*(nearest - c))) < radius:
            raise head.problem(
                "start",
                f"impossible pose: the chair at {tuple(start)} (radius {radius:.2f} m) overlaps "
                f"object {obj.name!r} of scene {scene.path.name}",
            )


def list_scenarios(folder: Path = SCENES) -> list[Path]:
    """Scenario files (those with a [scenario] table) in ``folder``, sorted by name."""
    out = []
    for p in sorted(folder.glob("*.toml")):
        try:
            if "scenario" in tomllib.loads(p.read_text()):
                out.append(p)
        except (OSError, tomllib.TOMLDecodeError):
            continue
    return out


def ground_truth_points(
    scene: Scene, spacing: float, rng: np.random.Generator, include_dynamic: bool = False
) -> npt.NDArray[np.float64]:
    """Points sampled on every static object's surface (area-weighted, ~one per ``spacing``^2 m^2).

    Used to rasterise the scene's ground-truth occupancy; moving people are left out unless asked.
    """
    chunks = []
    for obj in scene.objects:
        if obj.is_dynamic and not include_dynamic:
            continue
        m = obj.world_mesh()
        areas = m.triangle_areas()
        n = np.maximum(1, np.ceil(areas / spacing**2)).astype(np.int64)
        tri = np.repeat(np.arange(len(m.faces)), n)
        u, v = rng.random(len(tri)), rng.random(len(tri))
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        a, b, c = (m.vertices[m.faces[tri, k]] for k in range(3))
        chunks.append(a + u[:, None] * (b - a) + v[:, None] * (c - a))
    return np.concatenate(chunks) if chunks else np.zeros((0, 3))


@dataclass
class SceneBodies:
    """PyBullet body ids of a built scene, the moving ones with their scripts, and where they are.

    Attributes:
        ids: body id of each object by name.
        moving: (body id, object) of every scripted person.
        poses: where each scripted person stands now, (x, y, yaw) in ``map`` by name.
    """

    ids: dict[str, int] = field(default_factory=dict)
    moving: list[tuple[int, SceneObject]] = field(default_factory=list)
    poses: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    _forces: dict[str, Any] = field(default_factory=dict)
    _t: float | None = None

    def reset(self) -> None:
        """Every scripted person back onto its script (before a restart at time 0)."""
        for f in self._forces.values():
            f.reset()
        self._t = None

    def update(self, client: int, t: float, chair: Any = None) -> None:
        """Place every scripted person at its position for time ``t`` (kinematic: mass 0, teleported).

        Args:
            client: the PyBullet client.
            t: scene time, s (the walks' timetable); called once per physics step.
            chair: ``(footprint, (x, y, yaw))``, a :class:`sim.crowd.Footprint` and the chair's pose
                in ``map``: the people keep clear of it (:class:`sim.crowd.SocialForce`); None: they
                walk their scripts exactly.
        """
        import pybullet as p

        from sim.crowd import SocialForce

        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        for body, obj in self.moving:
            assert obj.motion is not None
            x, y, yaw = obj.motion.pose_at(t)
            force = self._forces.get(obj.name)
            if force is None:
                force = self._forces[obj.name] = SocialForce(obj.motion.speed)
            near = chair if obj.motion.avoid_chair else None
            if dt > 0.0 and (near is not None or force.offset.any() or force.rate.any()):
                xn, yn, _ = obj.motion.pose_at(t + dt)
                u = np.array([xn - x, yn - y]) / dt  # the script's velocity over the coming step
                px, py = force.step(np.array([x, y]), u, dt, near)
                vx, vy = u + force.rate
                if force.offset.any() and math.hypot(vx, vy) > 1e-3:
                    yaw = math.atan2(vy, vx)  # facing where it walks while off its script
                x, y = float(px), float(py)
            self.poses[obj.name] = (x, y, yaw)
            q = quat_from_rpy(obj.rpy[0], obj.rpy[1], yaw + obj.rpy[2])
            p.resetBasePositionAndOrientation(body, (x, y, obj.xyz[2]), q, physicsClientId=client)


def build_scene(scene: Scene, client: int) -> SceneBodies:
    """Create one static (mass 0) PyBullet body per object; meshes as concave triangle meshes."""
    import pybullet as p

    out = SceneBodies()
    for obj in scene.objects:
        kw: dict[str, Any] = {}
        if obj.shape == "box":
            assert obj.size is not None
            geom, kw = p.GEOM_BOX, {"halfExtents": [s / 2 for s in obj.size]}
            vkw = kw
        elif obj.shape == "sphere":
            geom, kw = p.GEOM_SPHERE, {"radius": obj.radius}
            vkw = kw
        elif obj.shape == "cylinder":
            geom = p.GEOM_CYLINDER
            kw = {"radius": obj.radius, "height": obj.length}
            vkw = {"radius": obj.radius, "length": obj.length}
        elif obj.shape == "capsule":
            geom = p.GEOM_CAPSULE
            kw = {"radius": obj.radius, "height": obj.length}
            vkw = {"radius": obj.radius, "length": obj.length}
        else:
            geom = p.GEOM_MESH
            kw = {
                "fileName": str(obj.mesh_path),
                "meshScale": [obj.scale] * 3,
                "flags": p.GEOM_FORCE_CONCAVE_TRIMESH,
            }
            vkw = {"fileName": str(obj.mesh_path), "meshScale": [obj.scale] * 3}
        col = p.createCollisionShape(geom, physicsClientId=client, **kw)
        vis = p.createVisualShape(geom, rgbaColor=list(obj.color), physicsClientId=client, **vkw)
        pos = obj.xyz
        yaw = obj.rpy[2]
        if obj.motion is not None:
            x, y, walk_yaw = obj.motion.pose_at(0.0)
            pos, yaw = (x, y, obj.xyz[2]), walk_yaw + obj.rpy[2]
        q = quat_from_rpy(obj.rpy[0], obj.rpy[1], yaw)
        body = p.createMultiBody(0.0, col, vis, basePosition=pos, baseOrientation=q, physicsClientId=client)
        out.ids[obj.name] = body
        if obj.motion is not None:
            out.moving.append((body, obj))
            out.poses[obj.name] = obj.motion.pose_at(0.0)
    return out
