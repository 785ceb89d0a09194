"""Goal navigation for the simulated RobChair as a Gymnasium environment (``RobChair/Navigation-v0``).

The agent commands a normalised body twist; the command goes through the same kinematics, motor plant
and PID as every other simulated drive (:class:`sim.robot.SimRobot`); the agent sees an egocentric patch
of the 2D occupancy grid that the variable-height-voxel map (:mod:`mapping.vhv`) builds from the
simulated sensors, plus the goal in its own frame and its measured speed.

Usage::

    import gymnasium
    import sim.envs  # registers RobChair/Navigation-v0 and RobChair/NavigationSonar-v0

    env = gymnasium.make("RobChair/Navigation-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=0)
    for _ in range(100):
        action = env.action_space.sample()  # (v, w) in [-1, 1]^2
        obs, reward, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            obs, info = env.reset()
    picture = env.render()  # (H, W, 3) uint8 top-down map
    env.close()

Pure pieces (tested by hand) live in :mod:`sim.envs.rewards` (:func:`navigation_reward`) and
:mod:`sim.envs.geometry` (:func:`goal_in_robot_frame`, :func:`egocentric_patch`, :class:`FreeSpace`);
they are re-exported here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.utils import EzPickle
from gymnasium.vector import AutoresetMode

from mapping.grid import GridSpec
from robchair.envs.chair import EpisodeNoise, episode_backend
from robchair.kinematics import DiffDrive, Pose2D
from robchair.perception import Perception
from robchair.runtime import CycleResult, Runtime, RuntimeConfig
from robchair.sources import Command
from robchair.spec import RobChairSpec, load_spec
from sim.envs.errors import NavigationEnvError
from sim.envs.geometry import (
    PATCH_BEHIND,
    PATCH_CELL,
    PATCH_SHAPE,
    FreeSpace,
    decimated_depth_noise,
    egocentric_patch,
    egocentric_values,
    goal_in_robot_frame,
    patch_cell_centres,
    planar_transform,
)
from sim.envs.randomization import DomainRandomization, EpisodeDynamics
from sim.envs.rewards import RewardWeights, navigation_reward, reward_terms
from sim.scene import Scene, load_scene

AGENT_HZ = 10
OCC_Z_MIN = 0.10  # m: above the floor's depth noise, like the runner's occupancy band
MAP_MARGIN = 1.0  # m around the scene's bounds
SETTLE_STEPS = 12  # physics steps with zero command after placing the chair
ODOM_HZ = 60  # encoder read-out for odometry (as the runner's control loop)
START_MARGIN = 0.10  # m of extra clearance around the chair's turning circle at start and goal
PASS_MARGIN = 0.05  # m each side of the chair's width for two free regions to count as connected
SENSORS = ("kinect2", "kinect1")
POSE_SOURCES = ("ground_truth", "odometry")
MAP_MEMORIES = ("episode", "frame")
SPEED_OBS_FACTOR = 1.5  # the velocity box holds measured overshoot beyond the command limits
ACTION_TYPES = ("continuous", "discrete")
#: Discrete actions as normalised (v, w) (times ``max_speed`` m/s and ``max_yaw_rate`` rad/s):
#: 0 stop, 1 forward slow, 2 forward fast, 3 turn left on the spot, 4 turn right on the spot.
DISCRETE_ACTIONS = ((0.0, 0.0), (0.3, 0.0), (0.7, 0.0), (0.0, 0.5), (0.0, -0.5))
ROOM_SPLITS = ("train", "eval")
ELEVATION_MAX = 2.5  # m, top of the elevation observation's box
LASER_ACCURACY_SIGMAS = 3.0  # the datasheet's +- accuracy is this many standard deviations (sim.laser)


# --------------------------------------------------------------------------------------------
# the environment
# --------------------------------------------------------------------------------------------


def shield_report(cycle: CycleResult) -> dict[str, Any]:
    """``info["safety"]``: whether and why the safety layer changed the agent's command in a cycle.

    Returns ``{"intervened": bool, "reason": str | None}``; the reason is the stop reason and its
    detail (e.g. ``"obstacle_map: ..."``), or ``"limited: ..."`` when a speed or acceleration limit
    changed the twist.
    """
    d = cycle.decision
    if not cycle.intervened:
        return {"intervened": False, "reason": None}
    if d.stop is not None:
        reason = f"{d.stop.value}: {d.detail}" if d.detail else d.stop.value
    else:
        reason = f"limited: {d.detail}" if d.detail else "limited: speed or acceleration limit"
    return {"intervened": True, "reason": reason}


class GroundTruthLocalisation:
    """The physics' ground truth in place of wheel odometry (``pose_source="ground_truth"``).

    Duck-types :class:`robchair.kinematics.Odometry` for the runtime: ``update`` ignores the
    encoder counts and returns the simulated chair's true planar pose.
    """

    def __init__(self, chair: Any) -> None:
        self.chair = chair
        self.pose = chair.ground_truth_pose()
        self.distance = 0.0

    def update(self, *_counts: Any) -> Pose2D:
        pose = self.chair.ground_truth_pose()
        self.distance += math.hypot(pose.x - self.pose.x, pose.y - self.pose.y)
        self.pose = pose
        return pose


def _load_scene_arg(scene: Scene | str | Path) -> Scene:
    if isinstance(scene, Scene):
        return scene
    from robchair.paths import SCENES

    path = Path(scene)
    if not path.is_file():
        path = SCENES / f"{scene}.toml"
    if not path.is_file():
        raise NavigationEnvError(f"scene={scene!r}: no such file and no scene of that name in {SCENES}")
    return load_scene(path)


def _pose_arg(value: Any, n: int, name: str) -> tuple[float, ...]:
    try:
        t = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise NavigationEnvError(f"{name}={value!r}: expected {n} numbers") from None
    if len(t) != n or not all(math.isfinite(v) for v in t):
        raise NavigationEnvError(f"{name}={value!r}: expected {n} finite numbers")
    return t


class RobChairNavigationEnv(gymnasium.Env[dict[str, np.ndarray], np.ndarray], EzPickle):
    """Drive the simulated RobChair to a goal without touching anything, seeing only its own sensors.

    ## Description

    The PyBullet twin of the RobChair Storm wheelchair (SPEC section 4) stands in a scene from
    ``assets/scenes`` (default: the office with a corridor, a doorway and a table the chair must not
    drive under). Each episode samples a goal position (and, unless fixed, a start pose) in the scene's
    free space; the agent must bring ``base_link`` within ``goal_tolerance`` of the goal. Physics runs
    at 240 Hz; the agent acts at ``agent_hz`` (10 Hz by default). The agent's command goes through
    the differential-drive kinematics to motor RPM set points of the simulated Roboteq channels, i.e.
    through the identified motor plant and its PID (thesis Appendix B), so speed follows with the real
    chair's rise time and overshoot. After every agent step the simulated sensors (a Kinect at reduced
    resolution and/or the two three-sonar arrays) are inserted into a variable-height-voxel map of the
    episode, whose 2D occupancy in the chair's height band gives the observation.

    ## Action Space

    ``Box(-1, 1, (2,), float32)``: ``[v, w]`` normalised; ``v * max_speed`` m/s forward speed and
    ``w * max_yaw_rate`` rad/s yaw rate (counter-clockwise), both by default the kinematic limits of
    :class:`robchair.kinematics.DiffDrive` (0.62 m/s, 2.14 rad/s); the pair is then scaled down
    uniformly so no motor exceeds its maximum RPM. Actions outside the box are clipped; non-finite
    actions raise :class:`NavigationEnvError`. With ``action_type="discrete"``: ``Discrete(5)``, the
    normalised pairs of :data:`DISCRETE_ACTIONS` (0 stop, 1 forward at 0.3, 2 forward at 0.7, 3 turn
    left on the spot at 0.5, 4 turn right at 0.5; times ``max_speed`` and ``max_yaw_rate``).

    ## Observation Space

    ``Dict``:

    | key       | space                                 | meaning                                          |
    |-----------|---------------------------------------|--------------------------------------------------|
    | occupancy | Box(0, 1, patch_shape, uint8)         | egocentric occupancy patch, 1 = occupied         |
    | goal      | Box([0, -pi], [max_goal_obs, pi])     | goal distance (m), bearing (rad), robot frame    |
    | velocity  | Box(-1.5 x limits, 1.5 x limits)      | measured (v m/s, w rad/s) from the wheel speeds  |
    | sonar     | Box(0, max range, (6,)) (sonars only) | left then right array ranges, no echo = max      |
    | depth     | Box(0, max range, (H, W)) (option)    | the Kinect's depth (m) along its axis, 0 = none  |
    | elevation | Box(0, 2.5, patch_shape) (option)     | egocentric highest structure per cell (m)        |

    The occupancy patch (default 64x64 cells of 10 cm) has row ``i`` forward (row 0 is 1.6 m behind
    ``base_link``) and column ``j`` to the left (centred), see :func:`egocentric_patch`. A cell is
    occupied when the episode's map holds a structure overlapping [0.10 m, chair height]: a table top
    counts, the floor does not. Cells never observed are 0. The map keeps every frame of the episode
    (``map_memory="episode"``; people who walk leave trails) or only the latest one (``"frame"``). The
    map and the observed goal/bearing use ``pose_source``: the physics' ground truth (default) or the
    chair's wheel odometry.

    ## Rewards

    :func:`navigation_reward`: ``progress * (d_prev - d) - time - collision * [contact] + success *
    [reached]`` with the default :class:`RewardWeights` ``(1.0 per m, 10.0, 0.01, 10.0)``; ``d`` is the
    true distance from ``base_link`` to the goal. ``info["reward_terms"]`` holds the parts.

    ## Starting State

    The chair stands still at the start pose, motors and controllers reset. Unless ``start`` is given,
    the start is a free-space cell where the chair can turn on the spot, with a uniform heading; the
    goal is a free cell at a straight-line distance in ``goal_distance`` from the start, in the same
    connected region. Both come from ``self.np_random``, as does the seed of every sensor's noise.
    ``reset(options={"start": (x, y, yaw), "goal": (x, y)})`` fixes them for one episode; a start
    where the chair's collision footprint overlaps a scene object, a goal closer to an obstacle than
    half the chair's width, or a goal no passage wide enough for the chair joins to the start makes
    ``reset`` raise :class:`NavigationEnvError` naming the point and the obstacle.

    ## Domain randomisation

    Each episode draws its own chair from ``self.np_random`` (after start and goal), uniformly within
    the ranges of ``randomization`` (:class:`sim.envs.randomization.DomainRandomization`; defaults):
    tyre radii relative to the spec (0.995-1.005 per wheel; the odometry keeps the spec's radius),
    floor friction (0.6-1.0), payload (the person, 50-120 kg), each motor plant's ``omega_n`` and
    ``xi`` (x 0.95-1.05), the sensors' noise (x 0.8-1.2) and the command latency (0-50 ms).
    ``randomization=False`` gives the nominal chair. ``info["dynamics"]`` holds the episode's draw.

    ## Episode End

    1. Termination: the goal is reached (distance <= ``goal_tolerance``; ``info["is_success"]``).
    2. Termination: collision, any contact between the chair and a scene body during the step, or
       an overlap with a walking person (who passes through the chair in the physics, see
       :meth:`_touching_people`) (``info["collision"]``, names in ``info["contacts"]``).
    3. Truncation: ``max_episode_steps`` (300 for the registered ids).

    Contacts are collected over every physics sub-step of the agent step, so a contact that is over
    by the end of the step still ends the episode and is named. A ``step`` after termination raises
    :class:`NavigationEnvError` (and pays nothing): call ``reset``. ``metadata["autoreset_mode"]`` is
    ``NEXT_STEP``. The environment pickles and deep-copies (``gymnasium.utils.EzPickle``: the copy is
    a new environment built from the same arguments, before its first ``reset``).

    ## Arguments

    ``gymnasium.make("RobChair/Navigation-v0", render_mode="rgb_array", **kwargs)`` with keyword
    arguments ``scene`` (name or path or :class:`sim.scene.Scene`), ``sensor`` (``"kinect2"``,
    ``"kinect1"`` or None), ``kinect_decimation`` (4: 512x424 -> 128x106 rays, same field of view;
    a decimated camera gets the model's axial noise only, see :func:`decimated_depth_noise`),
    ``sonars`` (bool), ``noise`` (sensor noise), ``agent_hz``, ``start`` ((x, y, yaw) or None),
    ``goal`` ((x, y) or None), ``goal_distance`` ((min, max) m), ``goal_tolerance`` (m),
    ``pose_source``, ``map_memory``, ``patch_shape``, ``patch_cell``, ``patch_behind``, ``max_speed``,
    ``max_yaw_rate``, ``reward_weights`` (:class:`RewardWeights`), ``spec`` (platform spec or TOML
    path), ``camera_backend`` (``"raycast"`` or ``"pybullet"``), ``randomization`` (True, False or a
    :class:`sim.envs.randomization.DomainRandomization`), ``action_type`` (``"continuous"`` or
    ``"discrete"``), ``depth_image`` / ``elevation_map`` (add those observations), ``scene="rooms"``
    or ``rooms`` (a :class:`sim.rooms.FloorConfig`: a new random floor every episode, drawn from
    ``np_random`` among the ``room_seeds`` split, ``"train"`` or ``"eval"``; ``reset`` option
    ``room_seed`` picks one; ``walkers`` people walk on it). ``render()`` returns a top-down
    picture of the episode's map, the scene, the path, the chair and the goal.
    """

    metadata: dict[str, Any] = {  # noqa: RUF012
        "render_modes": ["rgb_array"],
        "render_fps": AGENT_HZ,
        # vector envs reset a finished sub-env on the step after it ended (a step after the end raises)
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        render_mode: str | None = None,
        *,
        scene: Scene | str | Path = "office",
        sensor: str | None = "kinect2",
        kinect_decimation: int = 4,
        sonars: bool = False,
        laser: bool = False,
        noise: bool = True,
        agent_hz: int = AGENT_HZ,
        start: tuple[float, float, float] | None = None,
        goal: tuple[float, float] | None = None,
        goal_distance: tuple[float, float] = (1.0, 5.0),
        goal_tolerance: float = 0.3,
        pose_source: str = "ground_truth",
        map_memory: str = "episode",
        patch_shape: tuple[int, int] = PATCH_SHAPE,
        patch_cell: float = PATCH_CELL,
        patch_behind: float = PATCH_BEHIND,
        max_speed: float | None = None,
        max_yaw_rate: float | None = None,
        reward_weights: RewardWeights | None = None,
        spec: RobChairSpec | str | Path | None = None,
        camera_backend: str = "raycast",
        randomization: DomainRandomization | bool = True,
        action_type: str = "continuous",
        rooms: Any = None,
        room_seeds: str = "train",
        walkers: int = 0,
        depth_image: bool = False,
        elevation_map: bool = False,
        safety: bool = True,
    ) -> None:
        from sim.world import PHYSICS_HZ

        EzPickle.__init__(
            self,
            render_mode,
            scene=scene,
            sensor=sensor,
            kinect_decimation=kinect_decimation,
            sonars=sonars,
            laser=laser,
            noise=noise,
            agent_hz=agent_hz,
            start=start,
            goal=goal,
            goal_distance=goal_distance,
            goal_tolerance=goal_tolerance,
            pose_source=pose_source,
            map_memory=map_memory,
            patch_shape=patch_shape,
            patch_cell=patch_cell,
            patch_behind=patch_behind,
            max_speed=max_speed,
            max_yaw_rate=max_yaw_rate,
            reward_weights=reward_weights,
            spec=spec,
            camera_backend=camera_backend,
            randomization=randomization,
            action_type=action_type,
            rooms=rooms,
            room_seeds=room_seeds,
            walkers=walkers,
            depth_image=depth_image,
            elevation_map=elevation_map,
            safety=safety,
        )

        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise NavigationEnvError(
                f"render_mode={render_mode!r}: expected None or one of {self.metadata['render_modes']}"
            )
        self.render_mode = render_mode
        if sensor is not None and sensor not in SENSORS:
            raise NavigationEnvError(f"sensor={sensor!r}: expected one of {SENSORS} or None")
        if sensor is None and not sonars and not laser:
            raise NavigationEnvError("sensor=None, sonars=False and laser=False: the chair would see nothing")
        if (
            isinstance(kinect_decimation, bool)
            or not isinstance(kinect_decimation, int)
            or kinect_decimation < 1
        ):
            raise NavigationEnvError(f"kinect_decimation={kinect_decimation!r}: expected an integer >= 1")
        if (
            isinstance(agent_hz, bool)
            or not isinstance(agent_hz, int)
            or agent_hz <= 0
            or PHYSICS_HZ % agent_hz
        ):
            raise NavigationEnvError(f"agent_hz={agent_hz!r}: expected a positive divisor of {PHYSICS_HZ}")
        if pose_source not in POSE_SOURCES:
            raise NavigationEnvError(f"pose_source={pose_source!r}: expected one of {POSE_SOURCES}")
        if map_memory not in MAP_MEMORIES:
            raise NavigationEnvError(f"map_memory={map_memory!r}: expected one of {MAP_MEMORIES}")
        lo, hi = _pose_arg(goal_distance, 2, "goal_distance")
        if not 0 <= lo <= hi:
            raise NavigationEnvError(f"goal_distance={goal_distance!r}: expected 0 <= min <= max")
        for name, val, least in (
            ("goal_tolerance", goal_tolerance, 0.0),
            ("patch_cell", patch_cell, 0.0),
            ("patch_behind", patch_behind, None),
        ):
            ok = isinstance(val, int | float) and not isinstance(val, bool) and math.isfinite(val)
            if not ok or (least is not None and val <= least) or val < 0:
                raise NavigationEnvError(f"{name}={val!r}: expected a finite number > 0 (patch_behind: >= 0)")
        ps = _pose_arg(patch_shape, 2, "patch_shape")
        if not all(v >= 1 and v == int(v) for v in ps):
            raise NavigationEnvError(f"patch_shape={patch_shape!r}: expected two positive integers")
        if camera_backend not in ("raycast", "pybullet"):
            raise NavigationEnvError(f"camera_backend={camera_backend!r}: expected 'raycast' or 'pybullet'")
        if lo <= goal_tolerance:
            raise NavigationEnvError(
                f"goal_distance={goal_distance!r}: the minimum must exceed goal_tolerance={goal_tolerance!r} "
                "(an episode would succeed before its first step)"
            )
        if randomization is True:
            randomization = DomainRandomization()
        elif randomization is False:
            randomization = DomainRandomization.off()
        elif not isinstance(randomization, DomainRandomization):
            raise NavigationEnvError(
                f"randomization={randomization!r}: expected True, False or a DomainRandomization"
            )
        if randomization.command_latency_s[1] >= 1.0 / agent_hz:
            raise NavigationEnvError(
                f"randomization.command_latency_s={randomization.command_latency_s!r}: the latency must "
                f"stay below one agent period ({1.0 / agent_hz} s)"
            )
        self.randomization = randomization
        if action_type not in ACTION_TYPES:
            raise NavigationEnvError(f"action_type={action_type!r}: expected one of {ACTION_TYPES}")
        if room_seeds not in ROOM_SPLITS:
            raise NavigationEnvError(f"room_seeds={room_seeds!r}: expected one of {ROOM_SPLITS}")
        if depth_image and sensor is None:
            raise NavigationEnvError("depth_image=True needs a Kinect (sensor='kinect2' or 'kinect1')")
        self.action_type = action_type
        self.safety_enabled = bool(safety)
        self.depth_image, self.elevation_map = bool(depth_image), bool(elevation_map)
        from sim import rooms as _rooms

        self.rooms_config: Any = None
        self.room_seed: int | None = None
        if rooms is not None or scene == "rooms":
            if isinstance(walkers, bool) or not isinstance(walkers, int) or walkers < 0:
                raise NavigationEnvError(f"walkers={walkers!r}: expected a non-negative integer")
            cfg = rooms if rooms is not None else _rooms.FloorConfig(walkers=walkers)
            if not isinstance(cfg, _rooms.FloorConfig):
                raise NavigationEnvError(f"rooms={rooms!r}: expected a sim.rooms.FloorConfig or None")
            self.rooms_config = cfg
            self._room_range = _rooms.TRAIN_SEEDS if room_seeds == "train" else _rooms.EVAL_SEEDS
            self.room_seed = self._room_range[0]
            scene = _rooms.generate_floor(self.room_seed, cfg).scene

        self.metadata = {**self.metadata, "render_fps": agent_hz}
        self.spec_robot = spec if isinstance(spec, RobChairSpec) else load_spec(spec)
        self.drive = DiffDrive(self.spec_robot)
        self.scene = _load_scene_arg(scene)
        self.sensor, self.sonars_on, self.noise = sensor, bool(sonars), bool(noise)
        self.laser_on = bool(laser)
        self.agent_hz = agent_hz
        self.substeps = PHYSICS_HZ // agent_hz
        self.goal_distance = (lo, hi)
        self.goal_tolerance = float(goal_tolerance)
        self.pose_source = pose_source
        self.map_memory = map_memory
        self.patch_shape = (int(ps[0]), int(ps[1]))
        self.patch_cell, self.patch_behind = float(patch_cell), float(patch_behind)
        self.max_speed = float(max_speed) if max_speed is not None else self.drive.max_speed
        self.max_yaw_rate = float(max_yaw_rate) if max_yaw_rate is not None else self.drive.max_yaw_rate
        for name, val in (("max_speed", self.max_speed), ("max_yaw_rate", self.max_yaw_rate)):
            if not (math.isfinite(val) and val > 0):
                raise NavigationEnvError(f"{name}={val!r}: expected a finite number > 0")
        self.weights = reward_weights if reward_weights is not None else RewardWeights()
        self.fixed_start = _pose_arg(start, 3, "start") if start is not None else None
        self.fixed_goal = _pose_arg(goal, 2, "goal") if goal is not None else None
        self.band = (OCC_Z_MIN, float(self.spec_robot.body.height))

        from sim.backend import robot_radius

        self.robot_radius = robot_radius(self.spec_robot)
        self._decimation, self._camera_backend = kinect_decimation, camera_backend
        self._setup_scene()
        self._define_spaces()
        self._map: Any = None
        self._occ: npt.NDArray[np.bool_] | None = None
        self._sensor_rng = np.random.default_rng(0)
        self._path: list[tuple[float, float]] = []
        self.start_pose = Pose2D()
        self.goal = (0.0, 0.0)
        self._prev_distance = 0.0
        self._sonar_ranges = np.zeros(6, dtype=np.float32)
        self.dynamics = EpisodeDynamics()
        self._ended = False

    # ---- construction ------------------------------------------------------------------------

    def _setup_scene(self) -> None:
        """Grid, free space and the simulated chair for ``self.scene``."""
        x0, y0, x1, y1 = self.scene.bounds_xy()
        cs = self.patch_cell
        nx = math.ceil((x1 - x0 + 2 * MAP_MARGIN) / cs)
        ny = math.ceil((y1 - y0 + 2 * MAP_MARGIN) / cs)
        self.grid = GridSpec(
            cell_size=cs, size_x=nx * cs, size_y=ny * cs, centre=((x0 + x1) / 2, (y0 + y1) / 2)
        )
        anchor = self.fixed_start[:2] if self.fixed_start is not None else None
        self.free_space = FreeSpace.from_scene(
            self.scene,
            self.grid,
            self.band,
            self.spec_robot.body.width / 2 + PASS_MARGIN,
            anchor=anchor,  # type: ignore[arg-type]
        )
        self._start_cells = self.free_space.candidates(self.robot_radius + START_MARGIN)
        if len(self._start_cells) == 0:
            raise NavigationEnvError(
                f"scene {self.scene.name!r}: no free cell where the chair can turn on the spot"
            )

        self._build_chair(self._decimation, self._camera_backend)

    def _build_chair(self, decimation: int, camera_backend: str) -> None:
        import pybullet as p

        from sim.backend import SimChair

        model: Any = None
        if self.sensor is not None:
            from sim.kinect import get_model

            base = get_model(self.sensor)
            # fewer rays over the same field of view: the same camera at a lower resolution
            model = replace(
                base,
                name=f"{base.name}/{decimation}",
                width=max(1, base.width // decimation),
                height=max(1, base.height // decimation),
            )
        self._chair: Any = SimChair(
            self.spec_robot,
            self.scene,
            (0.0, 0.0, 0.0),
            sensor=model,
            sonars=self.sonars_on,
            seed=0,
            camera_backend=camera_backend,
            noise=self.noise,
            tyre_radius_error=0.0,  # drawn per episode instead (domain randomisation)
        )
        self.client = self._chair.world.client
        self.robot = self._chair.robot
        # The Kinect models' lateral noise is in pixels of the full image (1.6 px for the v2); applied
        # to a decimated image it would be `decimation` times too wide and smear the floor into
        # obstacles. A decimated camera therefore renders clean geometry and gets the axial noise here
        # (see decimated_depth_noise); at full resolution the model's own noise applies unchanged.
        self._own_noise = self.noise and model is not None and decimation > 1
        if self._own_noise:
            self._chair.kinect.noise = False
        # every episode starts from this snapshot (contacts and solver caches included), so the same
        # seed gives the same episode bit for bit, however many episodes ran before
        self._state_id = p.saveState(physicsClientId=self.client)
        dyn = p.getDynamicsInfo(self.robot.body, -1, physicsClientId=self.client)
        self._inertial = (tuple(dyn[3]), tuple(dyn[4]))
        self._t_base_cam = self.spec_robot.mounts["kinect_link"].transform()
        if self._chair.kinect is not None:
            self._t_base_cam = self._t_base_cam @ self._chair.kinect.output_pose(np.eye(4))
        self._scene_bodies = frozenset(self._chair.bodies.ids.values())
        self._body_names = {v: k for k, v in self._chair.bodies.ids.items()}
        self._nominal_plants = (self.robot.left.plant.plant, self.robot.right.plant.plant)
        self._base_mass = float(dyn[0])
        self._base_inertia = tuple(float(v) for v in dyn[2])
        self._sonar_noise = {m: float(a.noise_std_m) for m, a in self._chair.sonars.items()}
        self._laser: Any = None
        if self.laser_on:
            from sim.laser import LaserSim

            self._laser = LaserSim(
                self.client,
                mirror=self._chair.mirror,
                exclude_bodies=(self.robot.body,),  # used when no other sensor made the mirror
                noise=self.noise,
                accuracy_sigmas=LASER_ACCURACY_SIGMAS,
            )
            self._laser_ranges = np.zeros(self._laser.model.n_beams, dtype=np.float32)
        self._people = tuple(body for body, _ in self._chair.bodies.moving)
        self._noise = EpisodeNoise()
        self._backend = episode_backend(
            self._chair, self._noise, laser=self._laser, own_depth_noise=self._own_noise,
            laser_accuracy_sigmas=LASER_ACCURACY_SIGMAS,
        )  # fmt: skip
        self._frames: dict[str, np.ndarray] = {}
        cam = self._backend.depth_camera
        if cam is not None and cam.frame_id not in self.spec_robot.mounts:
            self._frames[cam.frame_id] = self._t_base_cam
        self.runtime = Runtime(
            self._backend,
            spec=self.spec_robot,
            config=RuntimeConfig(rate_hz=float(self.agent_hz), camera_every=1, sonar_every=1),
            perception=self._new_perception(),
            safety_enabled=self.safety_enabled,
        )
        self._closed = False

    def _new_perception(self) -> Perception:
        """The runtime's perception stage for an episode: one map of the scene's grid for every sensor."""
        from mapping.vhv import VHVMap

        return Perception(
            self.spec_robot,
            map=VHVMap(self.grid, tolerance=self.patch_cell),
            grid=self.grid,
            sonar_map=None,
            band=self.band,
            frames=self._frames,
            tolerance=self.patch_cell,
        )

    def _define_spaces(self) -> None:
        if self.action_type == "discrete":
            self.action_space = spaces.Discrete(len(DISCRETE_ACTIONS))  # type: ignore[assignment]
        else:
            self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        x0, x1, y0, y1 = self.grid.extent
        self.max_goal_obs = float(math.hypot(x1 - x0, y1 - y0))
        if self.rooms_config is not None:  # one box for every floor the generator can draw
            self.max_goal_obs = float(self.rooms_config.max_extent)
        vmax = SPEED_OBS_FACTOR * self.drive.max_speed
        wmax = SPEED_OBS_FACTOR * self.drive.max_yaw_rate
        self._vel_high = np.array([vmax, wmax], np.float32)
        obs: dict[str, spaces.Space[Any]] = {
            "occupancy": spaces.Box(0, 1, shape=self.patch_shape, dtype=np.uint8),
            "goal": spaces.Box(
                np.array([0.0, -math.pi], np.float32),
                np.array([self.max_goal_obs, math.pi], np.float32),
                dtype=np.float32,
            ),
            "velocity": spaces.Box(-self._vel_high, self._vel_high, dtype=np.float32),
        }
        if self.sonars_on:
            self.sonar_max_range = float(max(a.model.max_range_m for a in self._chair.sonars.values()))
            obs["sonar"] = spaces.Box(0.0, self.sonar_max_range, shape=(6,), dtype=np.float32)
        if self._laser is not None:
            lm = self._laser.model
            obs["laser"] = spaces.Box(0.0, lm.range_max, shape=(lm.n_beams,), dtype=np.float32)
        if self.depth_image:
            m = self._chair.kinect.model
            self._depth_shape = (int(m.height), int(m.width))
            self._depth_max = float(m.max_range_m)
            self._depth = np.zeros(self._depth_shape, dtype=np.float32)
            obs["depth"] = spaces.Box(0.0, self._depth_max, shape=self._depth_shape, dtype=np.float32)
        if self.elevation_map:
            obs["elevation"] = spaces.Box(0.0, ELEVATION_MAX, shape=self.patch_shape, dtype=np.float32)
        self.observation_space = spaces.Dict(obs)  # type: ignore[assignment]

    # ---- episode -----------------------------------------------------------------------------

    def _sample_start_goal(self, options: Mapping[str, Any]) -> tuple[Pose2D, tuple[float, float]]:
        rng = self.np_random
        start = options.get("start", self.fixed_start)
        goal = options.get("goal", self.fixed_goal)
        if start is not None:
            start = Pose2D(*_pose_arg(start, 3, "start"))
        if goal is not None:
            goal = _pose_arg(goal, 2, "goal")
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
        for name, xy in (("start", (start.x, start.y)), ("goal", goal)):
            i, j = self.grid.world_to_index(xy[0], xy[1])
            if not bool(self.grid.contains_index(i, j)):
                raise NavigationEnvError(f"{name} {xy} lies outside the scene's map {self.grid.extent}")
        self._check_goal(start, goal)  # type: ignore[arg-type]
        return start, goal  # type: ignore[return-value]

    def _check_goal(self, start: Pose2D, goal: tuple[float, float]) -> None:
        """The goal must leave room for the chair and be reachable from the start.

        Raises:
            NavigationEnvError: naming the goal and the nearest obstacle, or the start it is cut off from.
        """
        fs = self.free_space
        half = self.spec_robot.body.width / 2
        i, j = self.grid.world_to_index(goal[0], goal[1])
        if fs.clearance[i, j] < half:
            name, dist = fs.nearest_obstacle(goal)
            raise NavigationEnvError(
                f"goal {tuple(goal)}: {max(dist, 0.0):.2f} m from {name!r}, the chair "
                f"({self.spec_robot.body.width} m wide) cannot stand there"
            )
        reach = self.robot_radius
        a = fs.label_near((start.x, start.y), reach)
        b = fs.label_near(goal, reach)
        if a == 0 or a != b:
            name, _ = fs.nearest_obstacle(goal)
            raise NavigationEnvError(
                f"goal {tuple(goal)} is not reachable from the start {(start.x, start.y)}: no passage "
                f"{2 * (half + PASS_MARGIN):.2f} m wide joins them (near the goal: {name!r})"
            )

    def _footprint_overlaps(self) -> list[str]:
        """Scene objects the chair's collision shapes penetrate where it stands now (no stepping)."""
        import pybullet as p

        p.performCollisionDetection(physicsClientId=self.client)
        hit = {
            self._body_names[c[2]]
            for c in p.getContactPoints(bodyA=self.robot.body, physicsClientId=self.client)
            if c[2] in self._body_names and c[8] < 0.0
        }
        return sorted(hit)

    def _sample_start(self, rng: np.random.Generator, goal: npt.NDArray[np.float64] | None) -> Pose2D:
        cells = self._start_cells
        if goal is not None:
            d = np.hypot(*(cells - goal).T)
            cells = cells[(d >= self.goal_distance[0]) & (d <= self.goal_distance[1])]
            if len(cells) == 0:
                raise NavigationEnvError(
                    f"no free start at {self.goal_distance} m from the goal {tuple(goal)}"
                )
        x, y = cells[int(rng.integers(len(cells)))]
        return Pose2D(float(x), float(y), float(rng.uniform(-math.pi, math.pi)))

    def _sample_goal(self, rng: np.random.Generator, start: Pose2D) -> tuple[float, float]:
        cells = self._start_cells
        d = np.hypot(cells[:, 0] - start.x, cells[:, 1] - start.y)
        cells = cells[(d >= self.goal_distance[0]) & (d <= self.goal_distance[1])]
        if len(cells) == 0:
            raise NavigationEnvError(f"no free goal at {self.goal_distance} m from the start {start}")
        x, y = cells[int(rng.integers(len(cells)))]
        return float(x), float(y)

    def _place_chair(self, start: Pose2D) -> None:
        import pybullet as p

        self._check_not_closed()
        p.restoreState(self._state_id, physicsClientId=self.client)
        q = p.getQuaternionFromEuler((0.0, 0.0, start.theta))
        # PyBullet's base frame is the inertial frame: place base_link by composing the offset
        pos, orn = p.multiplyTransforms((start.x, start.y, 0.0), q, *self._inertial)
        p.resetBasePositionAndOrientation(self.robot.body, pos, orn, physicsClientId=self.client)
        p.resetBaseVelocity(self.robot.body, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), physicsClientId=self.client)
        world = self._chair.world
        world.steps = 0  # scripted people restart their walks; stamps restart at 0
        if self._chair.bodies.moving:
            self._chair.bodies.update(self.client, 0.0)
        static = [n for n in self._footprint_overlaps() if self._chair.bodies.ids[n] not in self._people]
        if static:
            raise NavigationEnvError(
                f"start {(start.x, start.y, start.theta)}: the chair's footprint there overlaps "
                + ", ".join(repr(n) for n in static)
            )
        self._apply_dynamics(self.dynamics)
        for motor in (self.robot.left, self.robot.right):
            motor.reset()
        self.robot.set_motor_rpm(0.0, 0.0)
        for mount in self._chair.sonars:  # the runtime turns the sonar servos; each episode starts centred
            self.robot.set_servo_deg(mount, 0.0)
        self._chair.step(SETTLE_STEPS)

    def _apply_dynamics(self, d: EpisodeDynamics) -> None:
        """Give the simulated chair this episode's tyres, floor, payload, motors and sensor noise."""
        import pybullet as p

        from robchair.control import DiscretePlant

        c = self.client
        p.changeDynamics(self._chair.world.plane, -1, lateralFriction=d.floor_friction, physicsClientId=c)
        mass = self._base_mass + d.payload_kg
        inertia = [v * mass / self._base_mass for v in self._base_inertia]
        p.changeDynamics(self.robot.body, -1, mass=mass, localInertiaDiagonal=inertia, physicsClientId=c)
        for motor, nominal, kw, kx in zip(
            (self.robot.left, self.robot.right),
            self._nominal_plants,
            d.motor_omega_n_scale,
            d.motor_xi_scale,
            strict=True,
        ):
            plant = replace(nominal, omega_n=nominal.omega_n * kw, xi=nominal.xi * kx)
            motor.plant = DiscretePlant(plant, self.robot.motor_dt)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Start an episode: place the chair, pick the goal, clear the map, take the first sensor frame.

        Args:
            seed: Seeds ``self.np_random`` (start, goal, sensor noise).
            options: ``{"start": (x, y, yaw), "goal": (x, y)}`` (either optional) for this episode.
        """
        super().reset(seed=seed)
        self._map = None  # until the episode has started, step() refuses to run
        self._ended = False
        opts = dict(options or {})
        allowed = {"start", "goal"} | ({"room_seed"} if self.rooms_config is not None else set())
        unknown = set(opts) - allowed
        if unknown:
            raise NavigationEnvError(f"reset options {sorted(unknown)}: unknown (allowed: {sorted(allowed)})")
        if self.rooms_config is not None:
            self._next_floor(opts.get("room_seed"))
        start, goal = self._sample_start_goal(opts)
        self.start_pose, self.goal = start, goal
        # one child stream for all sensor noise, drawn after start and goal so they stay put
        self._sensor_rng = np.random.default_rng(int(self.np_random.integers(0, 2**63 - 1)))
        self.dynamics = self.randomization.sample(self.np_random)
        self._place_chair(start)
        d = self.dynamics
        self._noise.rng, self._noise.scale = self._sensor_rng, float(d.sensor_noise_scale)
        latency = min(round(d.command_latency_s * self._chair.world.physics_hz), self.substeps - 1)
        motors: Any = self._backend.motors
        motors.new_episode(d.tyre_radius_scale, latency)
        self._path = []
        self._steps = 0
        rt = self.runtime
        rt.reset(start, self._new_perception())
        if self.pose_source == "ground_truth":
            rt.odometry = GroundTruthLocalisation(self._chair)  # type: ignore[assignment]
        rt.start()
        # one cycle standing still: the runtime senses the start and the first observation shows it
        self._cycle(Command(0.0, 0.0))
        pose = self._pose()
        self._prev_distance = self._true_distance()
        return self._observation(pose), self._info(pose, False, False, None)

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        """Apply ``action`` for one agent period (``240 / agent_hz`` physics steps), sense, reward.

        Raises:
            NavigationEnvError: the action is not two finite numbers, or step before reset.
        """
        if self._map is None:
            raise NavigationEnvError("step() called before reset()")
        if self._ended:
            raise NavigationEnvError(
                "step() called after the episode terminated (goal reached or collision); call reset()"
            )
        self._check_not_closed()
        v, w = self._twist(action)
        cycle, contacts = self._cycle(Command(v, w))
        collided = bool(contacts)
        self._steps += 1
        pose = self._pose()
        distance = self._true_distance()
        reached = distance <= self.goal_tolerance
        terms = reward_terms(self._prev_distance, distance, collided, reached, self.weights)
        self._prev_distance = distance
        obs = self._observation(pose)
        info = self._info(pose, collided, reached, terms)
        info["safety"] = shield_report(cycle)
        info["command"] = (cycle.command.v, cycle.command.w)
        info["command_applied"] = (cycle.decision.v, cycle.decision.w)
        if collided:
            info["contacts"] = sorted(contacts)
        self._ended = bool(collided or reached)
        return obs, float(sum(terms.values())), self._ended, False, info

    def _cycle(self, command: Command) -> tuple[CycleResult, set[str]]:
        """One runtime cycle (sense, safety, write, one agent period of physics); contacts during it."""
        clock: Any = self._backend.clock
        clock.contacts = set()
        if self.map_memory == "frame":  # the map holds only what this cycle senses
            from mapping.vhv import VHVMap

            p = self.runtime.perception
            p.map = p.sonar_map = VHVMap(self.grid, tolerance=self.patch_cell)
        cycle = self.runtime.step(command)
        self._read_perception()
        return cycle, set(clock.contacts)

    def _next_floor(self, seed: Any) -> None:
        """Put the chair on the floor of ``seed`` (None: drawn from ``np_random`` in the split's range)."""
        from sim.rooms import generate_floor

        if seed is None:
            seed = self._room_range[int(self.np_random.integers(len(self._room_range)))]
        elif isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise NavigationEnvError(f"room_seed={seed!r}: expected a non-negative integer")
        if int(seed) == self.room_seed:
            return
        self.scene = generate_floor(int(seed), self.rooms_config).scene
        self._release_chair()
        self._setup_scene()
        self.room_seed = int(seed)

    def _twist(self, action: Any) -> tuple[float, float]:
        """The body twist (v m/s, w rad/s) an action asks for, within the drive's limits."""
        if self.action_type == "discrete":
            if not self.action_space.contains(action):
                raise NavigationEnvError(
                    f"action={action!r}: expected an integer in [0, {len(DISCRETE_ACTIONS)})"
                )
            action = DISCRETE_ACTIONS[int(action)]
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (2,) or not np.isfinite(a).all():
            raise NavigationEnvError(f"action={action!r}: expected two finite numbers in [-1, 1]")
        a = np.clip(a, -1.0, 1.0)
        return self.drive.limit(float(a[0]) * self.max_speed, float(a[1]) * self.max_yaw_rate)

    # ---- state -------------------------------------------------------------------------------

    def _pose(self) -> Pose2D:
        """The pose the chair believes now (ground truth or the runtime's odometry, per ``pose_source``)."""
        gt = self._chair.ground_truth_pose()  # raises SimulationDivergedError on a non-finite pose
        self._path.append((gt.x, gt.y))
        if self.pose_source == "ground_truth":
            return gt
        # bring the runtime's odometry up to the encoders now (the next cycle's update adds nothing)
        return self.runtime.odometry.update(*self._backend.motors.read_state().encoder_counts)

    def _true_distance(self) -> float:
        gt = self._chair.ground_truth_pose()
        return math.hypot(self.goal[0] - gt.x, self.goal[1] - gt.y)

    def own_occupancy(self) -> tuple[GridSpec, npt.NDArray[np.bool_]]:
        """The chair's own 2D map of this episode: cells holding structure in its height band.

        Built from the chair's sensors only (never the scene's ground truth), placed with
        ``pose_source``. Returns the grid and a copy of the ``(nx, ny)`` bool occupancy.
        """
        if self._occ is None:
            raise NavigationEnvError("own_occupancy() called before reset()")
        return self.grid, self._occ.copy()

    def contacts(self) -> list[str]:
        """Names of the scene objects the chair touches now (walking people included)."""
        return sorted(self._chair.contacts())

    def _read_perception(self) -> None:
        """What the runtime's perception stage and sensors gave in the last cycle, for the observation."""
        rt = self.runtime
        p = rt.perception
        self._map = p.map
        self._occ = p.occupancy_2d()
        if self.sonars_on and rt.last_sonars:
            rr = np.asarray([r for _, reading in rt.last_sonars for r in reading.ranges_m], dtype=np.float64)
            self._sonar_ranges = np.where(
                np.isfinite(rr), np.clip(rr, 0.0, self.sonar_max_range), self.sonar_max_range
            ).astype(np.float32)
        if self._laser is not None and rt.last_scan is not None:
            r = np.asarray(rt.last_scan.ranges, dtype=np.float64)
            m = self._laser.model
            # +inf: nothing within range_max; -inf: closer than range_min (an obstacle at the sensor)
            rr = np.where(np.isposinf(r), m.range_max, np.where(np.isneginf(r), 0.0, r))
            self._laser_ranges = np.clip(rr, 0.0, m.range_max).astype(np.float32)
        if self.depth_image and rt.last_depth_frame is not None:
            z = np.asarray(rt.last_depth_frame.points[..., 0], dtype=np.float64)
            self._depth = np.clip(np.nan_to_num(z, nan=0.0), 0.0, self._depth_max).astype(np.float32)

    def _observation(self, pose: Pose2D) -> dict[str, np.ndarray]:
        assert self._occ is not None
        dist, bearing = goal_in_robot_frame(pose, self.goal)
        ml, mr = self._backend.motors.read_state().speed_rpm
        v, w = self.drive.twist_from_rpm(ml, mr)  # what the encoders say
        obs: dict[str, np.ndarray] = {
            "occupancy": egocentric_patch(
                self._occ, self.grid, pose, self.patch_shape, self.patch_cell, self.patch_behind
            ),
            "goal": np.array([min(dist, self.max_goal_obs), bearing], dtype=np.float32),
            "velocity": np.clip(np.array([v, w], dtype=np.float32), -self._vel_high, self._vel_high),
        }
        if self.sonars_on:
            obs["sonar"] = self._sonar_ranges.copy()
        if self._laser is not None:
            obs["laser"] = self._laser_ranges.copy()
        if self.depth_image:
            obs["depth"] = self._depth.copy()
        if self.elevation_map:
            from mapping.derived import elevation

            top, _ = elevation(self._map)
            top = np.clip(np.nan_to_num(top - 0.0, nan=0.0), 0.0, ELEVATION_MAX).astype(np.float32)
            obs["elevation"] = egocentric_values(
                top, self.grid, pose, self.patch_shape, self.patch_cell, self.patch_behind
            )
        return obs

    def _info(
        self, pose: Pose2D, collided: bool, reached: bool, terms: dict[str, float] | None
    ) -> dict[str, Any]:
        gt = self.robot.pose2d()
        info: dict[str, Any] = {
            "distance": self._prev_distance,
            "collision": collided,
            "is_success": reached,
            "pose": (gt.x, gt.y, gt.theta),
            "pose_estimate": (pose.x, pose.y, pose.theta),
            "goal": self.goal,
            "sim_time": self._chair.world.time,
        }
        if terms is not None:
            info["reward_terms"] = terms
        info["dynamics"] = self.dynamics.as_dict()
        return info

    # ---- rendering / closing -----------------------------------------------------------------

    def render(self) -> npt.NDArray[np.uint8] | None:
        """``rgb_array``: top-down picture (uint8, (H, W, 3)) of the scene, the map, path, chair, goal.

        Light grey: the scene's surfaces in the chair's height band (ground truth); black: cells the
        episode's map holds as occupied; blue: the driven path; red: the chair's footprint; green: the
        goal and its tolerance circle. North (+y) is up, east (+x) to the right, 3 px per cell.
        """
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        return self._draw()

    def _draw(self, px: int = 3) -> npt.NDArray[np.uint8]:
        nx, ny = self.grid.shape
        img = np.full((nx, ny, 3), 255, dtype=np.uint8)
        img[self.free_space.occupied] = (200, 200, 200)
        if self._occ is not None:
            img[self._occ] = (0, 0, 0)
        ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
        u, v = self.grid.index_to_world(ii, jj)
        if self._map is not None:
            gx, gy = self.goal
            img[np.hypot(u - gx, v - gy) <= max(self.goal_tolerance, self.grid.cell_size)] = (0, 170, 0)
            if self._path:
                path = np.asarray(self._path)
                pi, pj = self.grid.world_to_index(path[:, 0], path[:, 1])
                ok = self.grid.contains_index(pi, pj)
                img[pi[ok], pj[ok]] = (40, 80, 255)
            gt = self.robot.pose2d()
            c, s = math.cos(gt.theta), math.sin(gt.theta)
            lx = c * (u - gt.x) + s * (v - gt.y)
            ly = -s * (u - gt.x) + c * (v - gt.y)
            b = self.spec_robot.body
            foot = (np.abs(lx - b.centre_x) <= b.depth / 2) & (np.abs(ly) <= b.width / 2)
            img[foot] = (220, 30, 30)
        # (i along x, j along y) -> rows = -y, columns = x
        pic = np.ascontiguousarray(np.transpose(img, (1, 0, 2))[::-1])
        return np.repeat(np.repeat(pic, px, axis=0), px, axis=1)

    def _release_chair(self) -> None:
        """Stop the runtime, close the devices, then the chair's physics."""
        try:
            self.runtime.stop()
            self._backend.close()
        finally:
            self._chair.close()

    def _check_not_closed(self) -> None:
        if self._closed:
            raise NavigationEnvError("the environment is closed")

    def close(self) -> None:
        """Release the PyBullet client (idempotent)."""
        chair = getattr(self, "_chair", None)
        if chair is not None and not self._closed:
            self._release_chair()
            self._closed = True


__all__ = [
    "DISCRETE_ACTIONS",
    "PATCH_BEHIND",
    "PATCH_CELL",
    "PATCH_SHAPE",
    "FreeSpace",
    "NavigationEnvError",
    "RewardWeights",
    "RobChairNavigationEnv",
    "decimated_depth_noise",
    "egocentric_patch",
    "egocentric_values",
    "goal_in_robot_frame",
    "navigation_reward",
    "patch_cell_centres",
    "planar_transform",
    "reward_terms",
]
