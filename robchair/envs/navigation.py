"""Goal navigation for the simulated RobChair as a Gymnasium environment (``RobChair/Navigation-v0`` ...).

The environment advances the chair's one drive loop, :class:`robchair.runtime.Runtime`, by one cycle per
agent step through :meth:`Runtime.step` with the agent's command, rather than being a ``CommandSource``
the runtime calls: Gymnasium's ``step`` is called by the agent and must return, so the environment has
to own the control flow (a command source would need the runtime to run on another thread or coroutine
and block there for every action), while a step method runs exactly the cycle ``Runtime.run`` runs -
sensors through the hardware interfaces, the perception stage, the safety layer, the write-time
checks and the observers - with no second loop to keep in step. What only a simulation can do (an exact
reset, contacts, the ground-truth pose, friction and payload) is asked of the simulated chair
(:class:`sim.backend.SimChair`); this package never calls the physics engine itself.

Usage::

    import gymnasium
    import sim.envs  # registers the RobChair/... ids

    env = gymnasium.make("RobChair/Navigation-v1", render_mode="rgb_array")
    obs, info = env.reset(seed=0)
    for _ in range(100):
        action = env.action_space.sample()  # (v, w) in [-1, 1]^2
        obs, reward, terminated, truncated, info = env.step(action)
        if info["safety"]["intervened"]:
            print("the safety layer changed the command:", info["safety"]["reason"])
        if terminated or truncated:
            obs, info = env.reset()
    picture = env.render()  # (H, W, 3) uint8 top-down map
    env.close()

The parts: :mod:`robchair.envs.arguments` (arguments and their checks), :mod:`robchair.envs.episodes`
(start and goal), :mod:`robchair.envs.observation` (spaces and observations), :mod:`robchair.envs.chair`
(the episode's devices behind the hardware interfaces, ``info["safety"]``), :mod:`robchair.envs.render`;
pure pieces in :mod:`sim.envs.rewards` (:func:`navigation_reward`) and :mod:`sim.envs.geometry`,
re-exported here.
"""

from __future__ import annotations

import logging
import math
from typing import Any, SupportsFloat

import gymnasium
import numpy as np
import numpy.typing as npt
from gymnasium.utils import EzPickle
from gymnasium.vector import AutoresetMode

from mapping.grid import GridSpec
from robchair.envs.arguments import AGENT_HZ, NavigationSettings, load_scene_arg
from robchair.envs.chair import GroundTruthLocalisation, build_chair, place_chair, shield_report
from robchair.envs.episodes import EpisodeSampler, check_reset_options, scene_grid
from robchair.envs.observation import (
    DISCRETE_ACTIONS,
    ObservationBuilder,
    action_space,
    action_to_twist,
    step_info,
)
from robchair.envs.render import top_down_picture
from robchair.loop_types import CycleResult
from robchair.perception import Perception
from robchair.platform.kinematics import DiffDrive, Pose2D
from robchair.platform.safety import SafetyLayer, SafetyLimits
from robchair.platform.spec import RobChairSpec, load_spec
from robchair.runtime import Runtime
from robchair.runtime_config import RuntimeConfig
from robchair.sources import Command
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

OCC_Z_MIN = 0.10  # m: above the floor's depth noise, like the runner's occupancy band
SETTLE_STEPS = 12  # physics steps with zero command after placing the chair


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
    resolution, the two three-sonar arrays and/or the Hokuyo laser) are inserted into a
    variable-height-voxel map of the episode, whose 2D occupancy in the chair's height band gives the
    observation.

    Every step is one cycle of the chair's runtime (:meth:`robchair.runtime.Runtime.step`): the same
    loop that drives the emulated and the real chair reads the sensors through the hardware
    interfaces, maps them in the perception stage (:class:`robchair.perception.Perception`), passes
    the agent's command through the safety layer (:class:`robchair.platform.safety.SafetyLayer`, on unless
    ``safety=False``) and writes the wheel speeds; the physics advances while the runtime waits for
    its next cycle. ``info["safety"]`` says whether and why the safety layer changed the command
    (``{"intervened": bool, "reason": str | None}``, e.g. ``"obstacle_map: obstacle at 0.31 m ahead
    < stopping distance 0.35 m"``), ``info["command"]`` and ``info["command_applied"]`` give the
    twist asked for and the one written.

    ## Action Space

    ``Box(-1, 1, (2,), float32)``: ``[v, w]`` normalised; ``v * max_speed`` m/s forward speed and
    ``w * max_yaw_rate`` rad/s yaw rate (counter-clockwise), both by default the kinematic limits of
    :class:`robchair.platform.kinematics.DiffDrive` (0.62 m/s, 2.14 rad/s); the pair is then scaled down
    uniformly so no motor exceeds its maximum RPM. Actions outside the box are clipped; non-finite
    actions raise :class:`NavigationEnvError`. With ``action_type="discrete"``: ``Discrete(5)``, the
    normalised pairs of :data:`DISCRETE_ACTIONS` (0 stop, 1 forward at 0.3, 2 forward at 0.7, 3 turn
    left on the spot at 0.5, 4 turn right at 0.5; times ``max_speed`` and ``max_yaw_rate``).

    ## Observation Space

    ``Dict``:

    | key       | space                                 | meaning                                          |
    |-----------|---------------------------------------|--------------------------------------------------|
    | occupancy | Box(0, 1 or 2, patch_shape, uint8)    | egocentric occupancy patch, 1 = occupied         |
    | goal      | Box([0, -pi], [max_goal_obs, pi])     | goal distance (m), bearing (rad), robot frame    |
    | velocity  | Box(-1.5 x limits, 1.5 x limits)      | measured (v m/s, w rad/s) from the wheel speeds  |
    | sonar     | Box(0, max range, (6,)) (sonars only) | left then right array ranges, no echo = max      |
    | laser     | Box(0, 4, (682,)) (laser only)        | Hokuyo ranges (m), none = 4, too close = 0       |
    | depth     | Box(0, max range, (H, W)) (option)    | the Kinect's depth (m) along its axis, 0 = none  |
    | elevation | Box(0, 2.5, patch_shape) (option)     | egocentric highest structure per cell (m)        |

    The occupancy patch (default 64x64 cells of 10 cm) has row ``i`` forward (row 0 is 1.6 m behind
    ``base_link``) and column ``j`` to the left (centred), see :func:`egocentric_patch`. A cell is
    occupied when the episode's map holds a structure overlapping [0.10 m, chair height]: a table top
    counts, the floor does not. With ``map_kind="thesis"`` (default; the ``-v0``/``-v1`` ids) the map is
    the thesis's accumulate-only VHV map and cells never observed are 0. With ``map_kind="probabilistic"``
    (the ``-v2`` ids) it is :class:`mapping.probabilistic.ProbabilisticVHV` (free space along the rays,
    people who walk past cleared) and the patch is three-valued: 0 free (free evidence over at least
    half the band), 1 occupied, 2 unknown (never seen, or outside the map). A planar laser and the
    sonars clear thin slabs only, so with the light sensors most of the band stays unknown; the
    Kinect's rays make it free. The map keeps every frame of the episode
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
    ``reset`` raise :class:`NavigationEnvError` naming the point and the obstacle. Every reset builds a
    new chair body in the physics (:meth:`sim.backend.SimChair.restart`, no restored snapshot), so an
    episode depends on its seed and actions only, never on the episodes before it.

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
       :meth:`sim.backend.SimChair.contacts`) (``info["collision"]``, names in ``info["contacts"]``).
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
    ``room_seed`` picks one; ``walkers`` people walk on it), ``laser`` (the Hokuyo URG-04LX) and
    ``safety`` (False: the agent's command reaches the motors unchanged, for ground-truth studies).
    :class:`robchair.envs.arguments.NavigationSettings` checks them all. ``render()`` returns a
    top-down picture of the episode's map, the scene, the path, the chair and the goal;
    ``render_mode="foxglove"`` (with ``live_port``, default 8765) serves every step live over a Foxglove
    WebSocket instead (:mod:`robchair.envs.live`).
    """

    metadata: dict[str, Any] = {  # noqa: RUF012
        # foxglove: the episodes served live over a Foxglove WebSocket (robchair.envs.live)
        "render_modes": ["rgb_array", "foxglove"],
        "render_fps": AGENT_HZ,
        # vector envs reset a finished sub-env on the step after it ended (a step after the end raises)
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        """See the class docstring for the keyword arguments (:class:`NavigationSettings` checks them).

        Raises:
            NavigationEnvError: an unknown keyword or a bad value, named with what was expected.
        """
        EzPickle.__init__(self, render_mode, **kwargs)
        kwargs = dict(kwargs)
        live_port = kwargs.pop("live_port", None)
        from robchair.envs.live import check_live, open_live

        check_live(render_mode, live_port)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise NavigationEnvError(
                f"render_mode={render_mode!r}: expected None or one of {self.metadata['render_modes']}"
            )
        known = NavigationSettings.__dataclass_fields__
        unknown = sorted(set(kwargs) - set(known))
        if unknown:
            raise NavigationEnvError(f"unknown argument(s) {unknown}; expected some of {sorted(known)}")
        s = self.settings = NavigationSettings(**kwargs)
        self.render_mode = render_mode
        assert isinstance(s.randomization, DomainRandomization)  # normalised by NavigationSettings
        self.randomization = s.randomization
        self.action_type = s.action_type
        self.safety_enabled = bool(s.safety)
        self.depth_image, self.elevation_map = bool(s.depth_image), bool(s.elevation_map)
        self.rooms_config: Any = s.floor_config()
        self.room_seed: int | None = None
        scene = s.scene
        if self.rooms_config is not None:
            from sim import rooms as _rooms

            self._room_range = _rooms.TRAIN_SEEDS if s.room_seeds == "train" else _rooms.EVAL_SEEDS
            self.room_seed = self._room_range[0]
            scene = _rooms.generate_floor(self.room_seed, self.rooms_config).scene
        self.metadata = {**self.metadata, "render_fps": s.agent_hz}
        self.spec_robot = s.spec if isinstance(s.spec, RobChairSpec) else load_spec(s.spec)
        self.drive = DiffDrive(self.spec_robot)
        self.scene = load_scene_arg(scene)
        self.sensor, self.sonars_on, self.noise = s.sensor, bool(s.sonars), bool(s.noise)
        self.laser_on = bool(s.laser)
        self.agent_hz = s.agent_hz
        from sim.world import PHYSICS_HZ

        self.substeps = PHYSICS_HZ // s.agent_hz
        self.goal_distance = s.goal_distance
        self.goal_tolerance = s.goal_tolerance
        self.pose_source, self.map_memory, self.map_kind = s.pose_source, s.map_memory, s.map_kind
        self.patch_shape, self.patch_cell, self.patch_behind = s.patch_shape, s.patch_cell, s.patch_behind
        self.max_speed = float(s.max_speed) if s.max_speed is not None else self.drive.max_speed
        self.max_yaw_rate = float(s.max_yaw_rate) if s.max_yaw_rate is not None else self.drive.max_yaw_rate
        self.weights = s.reward_weights if s.reward_weights is not None else RewardWeights()
        self.fixed_start, self.fixed_goal = s.start, s.goal
        self.band = (OCC_Z_MIN, float(self.spec_robot.body.height))
        from sim.backend import robot_radius

        self.robot_radius = robot_radius(self.spec_robot)
        self.action_space = action_space(s.action_type)  # type: ignore[assignment]
        self._setup_scene()
        self._map: Any = None
        self._occ: npt.NDArray[np.bool_] | None = None
        self._codes: npt.NDArray[np.int8] | None = None  # OccupancyGrid codes of a probabilistic map
        self._sensor_rng = np.random.default_rng(0)
        self._path: list[tuple[float, float]] = []
        self.start_pose = Pose2D()
        self.goal = (0.0, 0.0)
        self._prev_distance = 0.0
        self.dynamics = EpisodeDynamics()
        self._ended = False
        self.live = None
        try:
            self.live = open_live(render_mode, live_port)  # last: a server runs only for a built env
        except NavigationEnvError:
            self.close()  # the port is in use: release the chair built above
            raise

    # ---- construction ------------------------------------------------------------------------

    def _setup_scene(self) -> None:
        """Grid, free space, the simulated chair, its runtime and the spaces for ``self.scene``."""
        self.grid = scene_grid(self.scene, self.patch_cell)
        fs = self.fixed_start
        anchor = (fs[0], fs[1]) if fs is not None else None
        self.sampler = EpisodeSampler(self.scene, self.grid, self.band, self.spec_robot, self.robot_radius,
                                      self.goal_distance, anchor=anchor)  # fmt: skip
        self.free_space: FreeSpace = self.sampler.free_space
        self._build_chair()
        x0, x1, y0, y1 = self.grid.extent
        max_goal = math.hypot(x1 - x0, y1 - y0)
        if self.rooms_config is not None:  # one box for every floor the generator can draw
            max_goal = float(self.rooms_config.max_extent)
        chair = self.chair
        sonar_max = max((a.model.max_range_m for a in chair.sonars.values()), default=None)
        self.obs_builder = ObservationBuilder(
            self.grid, self.patch_shape, self.patch_cell, self.patch_behind, self.drive, max_goal,
            sonar_max_range=float(sonar_max) if sonar_max is not None else None,
            laser_model=chair.laser.model if chair.laser is not None else None,
            depth_model=chair.kinect.model if self.depth_image else None,
            elevation=self.elevation_map, three_valued=self.map_kind == "probabilistic",
        )  # fmt: skip
        self.observation_space = self.obs_builder.space  # type: ignore[assignment]
        self.max_goal_obs = self.obs_builder.max_goal_obs

    def _build_chair(self) -> None:
        """The simulated chair, its devices behind the hardware interfaces and the runtime over them."""
        st = self.settings
        self.chair, self._noise, self._backend, self._frames = build_chair(
            self.spec_robot, self.scene, sensor=self.sensor, decimation=st.kinect_decimation,
            sonars=self.sonars_on, laser=self.laser_on, noise=self.noise, camera_backend=st.camera_backend,
        )  # fmt: skip
        self.robot = self.chair.robot
        self._truth = GroundTruthLocalisation(self.chair)
        self.runtime = Runtime(
            self._backend,
            spec=self.spec_robot,
            config=RuntimeConfig(rate_hz=float(self.agent_hz), camera_every=1, sonar_every=1),
            perception=self._new_perception(),
            # a stop is part of what the agent learns from (info["safety"]): INFO, not a warning per stop
            safety=SafetyLayer(SafetyLimits.from_spec(self.spec_robot), log_level=logging.INFO),
            safety_enabled=self.safety_enabled,
        )
        self._closed = False

    def _new_perception(self) -> Perception:
        """The runtime's perception stage for an episode: one map of the scene's grid for every sensor,
        of ``map_kind`` (the thesis's accumulate-only VHV map, or the probabilistic one with free space,
        clearing and unknown); the observation is its occupancy in the height band."""
        return Perception(
            self.spec_robot,
            grid=self.grid,
            sonar_map=None,
            band=self.band,
            frames=self._frames,
            tolerance=self.patch_cell,
            map_kind=self.map_kind,
        )

    # ---- episode -----------------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Start an episode: place the chair, pick the goal, clear the map, take the first sensor frame.

        Args:
            seed: Seeds ``self.np_random`` (start, goal, sensor noise, the episode's dynamics).
            options: ``{"start": (x, y, yaw), "goal": (x, y)}`` (either optional) for this episode;
                ``"room_seed"`` on generated floors.

        Raises:
            NavigationEnvError: an unknown option, or a start or goal the chair cannot use.
        """
        super().reset(seed=seed)
        self._map = None  # until the episode has started, step() refuses to run
        self._ended = False
        opts = check_reset_options(options, self.rooms_config is not None)
        if self.rooms_config is not None:
            self._next_floor(opts.get("room_seed"))
        start, goal = self.sampler.sample(
            self.np_random,
            opts.get("start", self.fixed_start),
            opts.get("goal", self.fixed_goal),
            self.goal_tolerance,
        )
        self.start_pose, self.goal = start, goal
        # one child stream for all sensor noise, drawn after start and goal so they stay put
        self._sensor_rng = np.random.default_rng(int(self.np_random.integers(0, 2**63 - 1)))
        self.dynamics = d = self.randomization.sample(self.np_random)
        self._check_not_closed()
        place_chair(self.chair, start, d, SETTLE_STEPS)
        self._noise.rng, self._noise.scale = self._sensor_rng, float(d.sensor_noise_scale)
        latency = min(round(d.command_latency_s * self.chair.world.physics_hz), self.substeps - 1)
        motors: Any = self._backend.motors
        motors.new_episode(d.tyre_radius_scale, latency)
        self._path = []
        self._steps = 0
        rt = self.runtime
        rt.reset(start, self._new_perception())
        if self.live is not None:
            self.live.attach(rt)
        self._truth = GroundTruthLocalisation(self.chair)  # the true pose, read once per physics instant
        if self.pose_source == "ground_truth":
            rt.odometry = self._truth  # type: ignore[assignment]
        rt.start()
        # one cycle standing still: the runtime senses the start and the first observation shows it
        self._cycle(Command(0.0, 0.0))
        # read once: the physics stands still until the next cycle (raises SimulationDivergedError on a
        # non-finite pose)
        gt = self._truth.now()
        pose = self._pose(gt)
        self._prev_distance = self._true_distance(gt)
        return self._observation(pose), self._info(gt, pose, False, False, None)

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], SupportsFloat, bool, bool, dict[str, Any]]:
        """One runtime cycle with the action's twist (one agent period of physics), then reward and info.

        Raises:
            NavigationEnvError: the action is not an action of the space, or step before reset or
                after the episode terminated.
        """
        if self._map is None:
            raise NavigationEnvError("step() called before reset()")
        if self._ended:
            raise NavigationEnvError(
                "step() called after the episode terminated (goal reached or collision); call reset()"
            )
        self._check_not_closed()
        v, w = self.action_twist(action)
        cycle, contacts = self._cycle(Command(v, w))
        collided = bool(contacts)
        self._steps += 1
        # read once: the physics stands still until the next cycle (raises SimulationDivergedError on a
        # non-finite pose)
        gt = self._truth.now()
        pose = self._pose(gt)
        distance = self._true_distance(gt)
        reached = distance <= self.goal_tolerance
        terms = reward_terms(self._prev_distance, distance, collided, reached, self.weights)
        self._prev_distance = distance
        obs = self._observation(pose)
        info = self._info(gt, pose, collided, reached, terms)
        info["safety"] = shield_report(cycle)
        info["command"] = (cycle.command.v, cycle.command.w)
        info["command_applied"] = (cycle.decision.v, cycle.decision.w)
        if collided:
            info["contacts"] = sorted(contacts)
        self._ended = bool(collided or reached)
        return obs, float(sum(terms.values())), self._ended, False, info

    def action_twist(self, action: Any) -> tuple[float, float]:
        """The body twist (v m/s, w rad/s) ``action`` asks for (before the safety layer).

        Raises:
            NavigationEnvError: not an action of the action space.
        """
        return action_to_twist(action, self.action_space, self.drive, self.max_speed, self.max_yaw_rate)

    def _cycle(self, command: Command) -> tuple[CycleResult, set[str]]:
        """One runtime cycle (sense, safety, write, one agent period of physics); contacts during it."""
        clock: Any = self._backend.clock
        clock.contacts = set()
        p = self.runtime.perception
        if self.map_memory == "frame":  # the map holds only what this cycle senses
            p.map = p.sonar_map = p.new_map()
        cycle = self.runtime.step(command)
        rt = self.runtime
        self._map = p.map
        three = self.map_kind == "probabilistic"  # one pass over the map: occupied where the code is 100
        self._codes = p.occupancy_2d() if three else None
        self._occ = self._codes == 100 if self._codes is not None else p.occupied_2d()
        self.obs_builder.take_readings(rt.last_sonars, rt.last_scan, rt.last_depth_frame)
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

    # ---- state -------------------------------------------------------------------------------

    def _pose(self, gt: Pose2D) -> Pose2D:
        """The pose the chair believes now (ground truth or the runtime's odometry, per ``pose_source``)."""
        self._path.append((gt.x, gt.y))
        if self.pose_source == "ground_truth":
            return gt
        # bring the runtime's odometry up to the encoders now (the next cycle's update adds nothing)
        return self.runtime.odometry.update(*self._backend.motors.read_state().encoder_counts)

    def _true_distance(self, gt: Pose2D) -> float:
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
        return sorted(self.chair.contacts())

    def _observation(self, pose: Pose2D) -> dict[str, np.ndarray]:
        assert self._occ is not None
        rpm = self._backend.motors.read_state().speed_rpm
        return self.obs_builder.observation(self._occ, self._map, pose, self.goal, rpm, codes=self._codes)

    def _info(
        self, gt: Pose2D, pose: Pose2D, collided: bool, reached: bool, terms: dict[str, float] | None
    ) -> dict[str, Any]:
        return step_info(gt, pose, self._prev_distance, collided, reached, self.goal, self.chair.world.time,
                         terms, self.dynamics)  # fmt: skip

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
        if self.live is not None:  # every step is already on the live server
            return None
        episode = None
        if self._map is not None:
            pose = self.chair.ground_truth_pose()
            episode = (self.goal, self.goal_tolerance, self._path, pose, self.spec_robot.body)
        return top_down_picture(self.grid, self.free_space.occupied, self._occ, episode)

    def _release_chair(self) -> None:
        """Stop the runtime, close the devices, then the chair's physics."""
        try:
            self.runtime.stop()
            self._backend.close()
        finally:
            self.chair.close()

    def _check_not_closed(self) -> None:
        if self._closed:
            raise NavigationEnvError("the environment is closed")

    def close(self) -> None:
        """Stop the runtime and release the physics (idempotent)."""
        chair = getattr(self, "chair", None)
        if chair is not None and not self._closed:
            try:
                self._release_chair()
            finally:
                self._closed = True
                live = getattr(self, "live", None)
                if live is not None:
                    live.close()


__all__ = [
    "AGENT_HZ",
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
