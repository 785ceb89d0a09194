"""The navigation environment's arguments: defaults, checks, normalised values (one place for all of them).

:class:`NavigationSettings` holds every keyword argument of
:class:`robchair.envs.navigation.RobChairNavigationEnv` except ``render_mode``; building one checks them
all before anything is simulated, and a bad value raises :class:`NavigationEnvError` naming the argument,
its value and what was expected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from robchair.platform.spec import RobChairSpec
from sim.envs.errors import NavigationEnvError
from sim.envs.geometry import PATCH_BEHIND, PATCH_CELL, PATCH_SHAPE
from sim.envs.randomization import DomainRandomization
from sim.envs.rewards import RewardWeights
from sim.scene import Scene, load_scene

AGENT_HZ = 10
SENSORS = ("kinect2", "kinect1")
POSE_SOURCES = ("ground_truth", "odometry")
MAP_MEMORIES = ("episode", "frame")
MAP_KINDS = ("thesis", "probabilistic")  # the episode map: accumulate only, or evidence (three-valued)
ACTION_TYPES = ("continuous", "discrete")
ROOM_SPLITS = ("train", "eval")
CAMERA_BACKENDS = ("raycast", "pybullet")


def load_scene_arg(scene: Scene | str | Path) -> Scene:
    """A scene given as a :class:`Scene`, a TOML path or the name of a scene in ``assets/scenes``.

    Raises:
        NavigationEnvError: no such file and no scene of that name.
    """
    if isinstance(scene, Scene):
        return scene
    from robchair.platform.paths import SCENES

    path = Path(scene)
    if not path.is_file():
        path = SCENES / f"{scene}.toml"
    if not path.is_file():
        raise NavigationEnvError(f"scene={scene!r}: no such file and no scene of that name in {SCENES}")
    return load_scene(path)


def pose_arg(value: Any, n: int, name: str) -> tuple[float, ...]:
    """``value`` as ``n`` finite floats.

    Raises:
        NavigationEnvError: naming ``name`` and the value when it is not ``n`` finite numbers.
    """
    try:
        t = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise NavigationEnvError(f"{name}={value!r}: expected {n} numbers") from None
    if len(t) != n or not all(math.isfinite(v) for v in t):
        raise NavigationEnvError(f"{name}={value!r}: expected {n} finite numbers")
    return t


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


@dataclass(frozen=True)
class NavigationSettings:
    """The environment's keyword arguments (see the environment's docstring for their meaning).

    Construction checks every value; afterwards ``goal_distance`` and ``patch_shape`` are tuples of
    numbers, ``randomization`` a :class:`DomainRandomization`, ``start``/``goal`` tuples or None.

    Raises:
        NavigationEnvError: the first argument with a bad value, named with the value and what was expected.
    """

    scene: Scene | str | Path = "office"
    sensor: str | None = "kinect2"
    kinect_decimation: int = 4
    sonars: bool = False
    laser: bool = False
    noise: bool = True
    agent_hz: int = AGENT_HZ
    start: tuple[float, float, float] | None = None
    goal: tuple[float, float] | None = None
    goal_distance: tuple[float, float] = (1.0, 5.0)
    goal_tolerance: float = 0.3
    pose_source: str = "ground_truth"
    map_memory: str = "episode"
    map_kind: str = "thesis"
    patch_shape: tuple[int, int] = PATCH_SHAPE
    patch_cell: float = PATCH_CELL
    patch_behind: float = PATCH_BEHIND
    max_speed: float | None = None
    max_yaw_rate: float | None = None
    reward_weights: RewardWeights | None = None
    spec: RobChairSpec | str | Path | None = None
    camera_backend: str = "raycast"
    randomization: DomainRandomization | bool = True
    action_type: str = "continuous"
    rooms: Any = None
    room_seeds: str = "train"
    walkers: int = 0
    depth_image: bool = False
    elevation_map: bool = False
    safety: bool = True

    def __post_init__(self) -> None:
        from sim.world import PHYSICS_HZ

        def fail(msg: str) -> None:
            raise NavigationEnvError(msg)

        if self.sensor is not None and self.sensor not in SENSORS:
            fail(f"sensor={self.sensor!r}: expected one of {SENSORS} or None")
        if self.sensor is None and not self.sonars and not self.laser:
            fail("sensor=None, sonars=False and laser=False: the chair would see nothing")
        if not _is_int(self.kinect_decimation) or self.kinect_decimation < 1:
            fail(f"kinect_decimation={self.kinect_decimation!r}: expected an integer >= 1")
        hz = self.agent_hz
        if not _is_int(hz) or hz <= 0 or PHYSICS_HZ % hz:
            fail(f"agent_hz={hz!r}: expected a positive divisor of {PHYSICS_HZ}")
        if self.pose_source not in POSE_SOURCES:
            fail(f"pose_source={self.pose_source!r}: expected one of {POSE_SOURCES}")
        if self.map_memory not in MAP_MEMORIES:
            fail(f"map_memory={self.map_memory!r}: expected one of {MAP_MEMORIES}")
        if self.map_kind not in MAP_KINDS:
            fail(f"map_kind={self.map_kind!r}: expected one of {MAP_KINDS}")
        lo, hi = pose_arg(self.goal_distance, 2, "goal_distance")
        if not 0 <= lo <= hi:
            fail(f"goal_distance={self.goal_distance!r}: expected 0 <= min <= max")
        for name, val, least in (
            ("goal_tolerance", self.goal_tolerance, 0.0),
            ("patch_cell", self.patch_cell, 0.0),
            ("patch_behind", self.patch_behind, None),
        ):
            ok = isinstance(val, int | float) and not isinstance(val, bool) and math.isfinite(val)
            if not ok or (least is not None and val <= least) or val < 0:
                fail(f"{name}={val!r}: expected a finite number > 0 (patch_behind: >= 0)")
        ps = pose_arg(self.patch_shape, 2, "patch_shape")
        if not all(v >= 1 and v == int(v) for v in ps):
            fail(f"patch_shape={self.patch_shape!r}: expected two positive integers")
        if self.camera_backend not in CAMERA_BACKENDS:
            fail(f"camera_backend={self.camera_backend!r}: expected 'raycast' or 'pybullet'")
        if lo <= self.goal_tolerance:
            fail(
                f"goal_distance={self.goal_distance!r}: the minimum must exceed "
                f"goal_tolerance={self.goal_tolerance!r} (an episode would succeed before its first step)"
            )
        rnd = self.randomization
        if rnd is True:
            rnd = DomainRandomization()
        elif rnd is False:
            rnd = DomainRandomization.off()
        elif not isinstance(rnd, DomainRandomization):
            fail(f"randomization={rnd!r}: expected True, False or a DomainRandomization")
        assert isinstance(rnd, DomainRandomization)
        if rnd.command_latency_s[1] >= 1.0 / hz:
            fail(
                f"randomization.command_latency_s={rnd.command_latency_s!r}: the latency must stay below "
                f"one agent period ({1.0 / hz} s)"
            )
        if self.action_type not in ACTION_TYPES:
            fail(f"action_type={self.action_type!r}: expected one of {ACTION_TYPES}")
        if self.room_seeds not in ROOM_SPLITS:
            fail(f"room_seeds={self.room_seeds!r}: expected one of {ROOM_SPLITS}")
        if self.depth_image and self.sensor is None:
            fail("depth_image=True needs a Kinect (sensor='kinect2' or 'kinect1')")
        if not _is_int(self.walkers) or self.walkers < 0:
            fail(f"walkers={self.walkers!r}: expected a non-negative integer")
        if self.rooms is not None:
            from sim.rooms import FloorConfig

            if not isinstance(self.rooms, FloorConfig):
                fail(f"rooms={self.rooms!r}: expected a sim.rooms.FloorConfig or None")
        for name, limit in (("max_speed", self.max_speed), ("max_yaw_rate", self.max_yaw_rate)):
            if limit is not None and not (
                isinstance(limit, int | float)
                and not isinstance(limit, bool)
                and math.isfinite(limit)
                and limit > 0
            ):
                fail(f"{name}={limit!r}: expected a finite number > 0")
        norm = {
            "goal_distance": (lo, hi),
            "patch_shape": (int(ps[0]), int(ps[1])),
            "randomization": rnd,
            "start": pose_arg(self.start, 3, "start") if self.start is not None else None,
            "goal": pose_arg(self.goal, 2, "goal") if self.goal is not None else None,
            "goal_tolerance": float(self.goal_tolerance),
            "patch_cell": float(self.patch_cell),
            "patch_behind": float(self.patch_behind),
        }
        for k, v in norm.items():
            object.__setattr__(self, k, v)

    @property
    def random_floors(self) -> bool:
        """Every episode on a new generated floor (``scene="rooms"`` or a ``rooms`` configuration)."""
        return self.rooms is not None or (isinstance(self.scene, str) and self.scene == "rooms")

    def floor_config(self) -> Any:
        """The :class:`sim.rooms.FloorConfig` of the generated floors (None: a fixed scene)."""
        if not self.random_floors:
            return None
        from sim.rooms import FloorConfig

        return self.rooms if self.rooms is not None else FloorConfig(walkers=self.walkers)
