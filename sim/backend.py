"""The simulated chair behind the hardware interfaces (DESIGN.md section 3): same Protocols as the drivers.

:class:`SimChair` bundles a :class:`sim.world.World`, the scene, the :class:`sim.robot.SimRobot` and the
simulated sensors (:mod:`sim.kinect` and :mod:`sim.sonar`). The devices below implement
:mod:`hw.interfaces` over it, so the runtime cannot tell it from the real chair:

* :class:`SimClock` - simulated time; ``sleep_until_ns`` *advances the physics* to that time (the
  runtime's loop therefore drives the simulation exactly as it waits for the real chair), serving
  the motor controller's serial watchdog on the way.
* :class:`SimMotorController` - closed-loop speed mode over the plant + PID motors, encoder counters,
  emergency stop (``!EX``: set points forced to 0 until ``!MG``), serial watchdog (``^RWD``).
* :class:`SimDepthCamera` - the simulated Kinect at ``kinect_link``'s current world pose, with
  background capture (``submit_read``).
* :class:`SimSonarArray` - three simulated sonars on the array's servo joint.

Powers only a simulation has are domain-named methods of :class:`SimChair`: ``ground_truth_pose``,
``ground_truth_transform``, ``contacts``, ``footprint_overlaps``, ``teleport``, ``restart`` (an exact
reset) and ``set_floor_friction`` (with :meth:`sim.robot.SimRobot.set_payload_kg` and
:meth:`sim.robot.SimRobot.scale_motor_plants` for domain randomisation).

:func:`make_sim_backend` builds all of it from a config mapping (what :mod:`robchair.backends` passes).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hw.interfaces import (
    Backend,
    DepthFrame,
    Device,
    MotorFaults,
    MotorState,
    PIDConfig,
    SonarArrayReading,
)
from robchair.config import ConfigSource, ConfigTable
from robchair.frames import quat_from_yaw
from robchair.kinematics import Pose2D
from robchair.spec import RobChairSpec, load_spec
from sim.errors import SimError
from sim.robot import SimRobot
from sim.scene import Scene, SceneBodies, build_scene, load_scene
from sim.world import World

SONAR_MOUNTS = ("sonar_array_left", "sonar_array_right")
# hw convention for sonar servos (mapping.sonar.servo_command_deg): 0..180 deg, the spec's
# sonar_arrays.servo_centre_deg = facing forward; the URDF joint is 0 = forward
# (spec.sonar_arrays.joint_angle converts)
SONAR_NOISE_STD_M = 0.005  # before the SRF08's rounding to whole centimetres (its +-1 cm resolution)


class SimChair:
    """World + scene + robot + sensors: the whole simulated chair.

    Args:
        spec: Platform spec (None: the default).
        scene: A :class:`sim.scene.Scene`, a scene file path, or None for an empty floor.
        start: Initial (x, y, yaw).
        sensor: Kinect model name (``kinect2``, ``kinect2-hd``, ``kinect2-qhd``, ``kinect1``) or None.
        sonars: Build the two simulated sonar arrays.
        seed: Seeds every noise generator (camera and sonars get independent child streams).
        camera_backend: ``"raycast"`` (Open3D/Embree) or ``"pybullet"`` (PyBullet's renderer).
        noise: Sensor noise on/off.
        raycast_threads: Embree threads for the shared mirror (0 = all cores).
        tyre_radius_error: Standard deviation of each tyre's true radius relative to the spec's
            (drawn from the seed; default 0.2 %, a tyre-pressure-sized error). The odometry assumes
            the spec's radius, so this is what makes the odometry drift as on the real chair; 0 = none.
        laser: Build the simulated Hokuyo URG-04LX (:class:`sim.laser.LaserSim`) on ``laser_link``.
    """

    def __init__(
        self,
        spec: RobChairSpec | None = None,
        scene: Scene | str | Path | None = None,
        start: tuple[float, float, float] = (0.0, 0.0, 0.0),
        sensor: str | None = "kinect2",
        sonars: bool = True,
        seed: int = 0,
        camera_backend: str = "raycast",
        noise: bool = True,
        raycast_threads: int = 0,
        tyre_radius_error: float = 0.002,
        laser: bool = False,
    ) -> None:
        self.spec = spec if spec is not None else load_spec()
        self.timing = {"physics": 0.0, "kinect_capture": 0.0, "sonar": 0.0}  # wall s per component
        self.captures_in_flight: list[Future[DepthFrame]] = []
        self.capture_pool: ThreadPoolExecutor | None = None
        self.world = World()
        try:
            self.scene = load_scene(scene) if isinstance(scene, str | Path) else scene
            self.bodies = (
                build_scene(self.scene, self.world.client) if self.scene is not None else SceneBodies()
            )
            if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
                raise SimError(f"seed={seed!r}: expected a non-negative integer")
            ss = np.random.SeedSequence(int(seed))
            cam_seed, sonar_seed, tyre_seed = ss.spawn(3)
            if not (math.isfinite(tyre_radius_error) and 0 <= tyre_radius_error < 0.1):
                raise SimError(f"tyre_radius_error={tyre_radius_error!r}: expected a fraction in [0, 0.1)")
            scale = 1.0 + tyre_radius_error * np.random.default_rng(tyre_seed).standard_normal(2)
            self.wheel_radius_scale = (float(scale[0]), float(scale[1]))
            self.robot = SimRobot(self.world, self.spec, start, wheel_radius_scale=self.wheel_radius_scale)
            self._body_names = {v: k for k, v in self.bodies.ids.items()}  # scene bodies never change
            self._ghost_people()
            self.mirror: Any = None
            self.kinect: Any = None
            self.sonars: dict[str, Any] = {}
            self.laser: Any = None
            if sensor is not None or sonars or laser:
                from sim.raycast import MeshMirror

                # the chair never sees itself: its sensors sit outside its body, and leaving it out
                # avoids rebuilding the ray-casting scene every frame as the chair moves
                self.mirror = MeshMirror(
                    self.world.client, exclude_bodies=(self.robot.body,), nthreads=raycast_threads
                )
                # scripted people move only in step(): one sync per physics step serves every sensor
                world = self.world
                self.mirror.step_counter = lambda: world.steps
                self.mirror.bodies_fixed = True  # scene bodies are created once, never replaced
            if sensor is not None:
                from sim.kinect import KinectSim

                self.kinect = KinectSim(
                    self.world.client,
                    sensor,
                    backend=camera_backend,
                    noise=noise,
                    rng=np.random.default_rng(cam_seed),
                    mirror=self.mirror,
                    exclude_bodies=(self.robot.body,),
                )
            if sonars:
                self.sonars = _make_sonars(self, np.random.default_rng(sonar_seed), noise)
            if laser:
                from sim.laser import LaserSim

                robot = self.robot
                self.laser = LaserSim(
                    self.world.client,
                    mirror=self.mirror,
                    noise=noise,
                    rng=np.random.default_rng(ss.spawn(1)[0]),
                    pose=lambda: robot.link_transform("laser_link"),
                    clock=SimClock(self),
                )
        except BaseException:
            self.world.close()
            raise

    def _ghost_people(self) -> None:
        """Scripted people are teleported along their walks (kinematic, mass 0): a collision with the
        chair would fling it away. They pass through the chair instead; every sensor still sees them."""
        import pybullet as p

        c = self.world.client
        for body, _ in self.bodies.moving:
            for link in range(-1, p.getNumJoints(self.robot.body, physicsClientId=c)):
                p.setCollisionFilterPair(self.robot.body, body, link, -1, 0, physicsClientId=c)

    def step(self, n: int = 1) -> None:
        """Advance the physics by ``n`` steps, moving the scripted people first.

        Scripted people never move while a depth frame is being captured in the background: those
        captures are waited for first (so a threaded run sees what a serial one sees).
        """
        if n <= 0:
            return
        if self.bodies.moving and self.captures_in_flight:
            for fut in self.captures_in_flight:
                fut.result()
            self.captures_in_flight.clear()
        t0 = time.perf_counter()
        for _ in range(n):
            if self.bodies.moving:
                self.bodies.update(self.world.client, self.world.time)
            self.world.step(1)
        self.timing["physics"] += time.perf_counter() - t0

    def kinect_pose(self) -> np.ndarray:
        """World <- kinect_link (ground truth, from the physics)."""
        return self.robot.link_transform("kinect_link")

    # --- powers only a simulation has (ground truth, contacts, teleport) ---------------------------

    def ground_truth_pose(self) -> Pose2D:
        """Planar pose (x, y, yaw) of ``base_link`` in ``map`` from the physics.

        Raises:
            SimulationDivergedError: the physics produced a non-finite pose.
        """
        return self.robot.pose2d()

    def ground_truth_transform(self) -> np.ndarray:
        """``T_map_base_link`` (4, 4) from the physics (roll and pitch included)."""
        return self.robot.link_transform("base_link")

    def contacts(self) -> set[str]:
        """Names of the scene objects the chair touches now (walking people, which pass through the
        chair, count when they overlap it)."""
        import pybullet as p

        c = self.world.client
        names = self._body_names
        hit = {
            names[pt[2]]
            for pt in p.getContactPoints(bodyA=self.robot.body, physicsClientId=c)
            if pt[2] in names
        }
        for body, _ in self.bodies.moving:
            if body in names and p.getClosestPoints(self.robot.body, body, 0.0, physicsClientId=c):
                hit.add(names[body])
        return hit

    def teleport(self, pose: Pose2D | tuple[float, float, float]) -> None:
        """Place the chair at rest at ``pose`` (x, y, yaw in ``map``): base, velocities, motors reset."""
        import pybullet as p

        x, y, yaw = (pose.x, pose.y, pose.theta) if isinstance(pose, Pose2D) else pose
        c = self.world.client
        dyn = p.getDynamicsInfo(self.robot.body, -1, physicsClientId=c)
        pos, orn = p.multiplyTransforms((x, y, 0.0), quat_from_yaw(yaw), tuple(dyn[3]), tuple(dyn[4]))
        p.resetBasePositionAndOrientation(self.robot.body, pos, orn, physicsClientId=c)
        p.resetBaseVelocity(self.robot.body, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), physicsClientId=c)
        for motor in (self.robot.left, self.robot.right):
            motor.reset()
        self.robot.set_motor_rpm(0.0, 0.0)

    def restart(self, pose: Pose2D | tuple[float, float, float]) -> None:
        """Restart the simulation at time 0 with the chair at rest at ``pose`` (x, y, yaw in ``map``).

        An exact reset, unlike a restored physics snapshot: the chair's body is replaced by a new one
        (:meth:`sim.robot.SimRobot.respawn`: joints, contact cache, mass, motors, servo targets and
        the controller's tick phase all as built), the clock restarts at 0 and scripted people stand
        where their walks begin. What the simulation does next depends on nothing that ran before.
        Captures still in flight are waited for first.
        """
        x, y, yaw = (pose.x, pose.y, pose.theta) if isinstance(pose, Pose2D) else pose
        for fut in self.captures_in_flight:
            fut.result()
        self.captures_in_flight.clear()
        old = self.robot.body
        self.robot.respawn((float(x), float(y), float(yaw)))
        new = self.robot.body
        if new != old:  # the sensors leave the chair's own body out by its id
            for holder in (self.mirror, self.kinect, getattr(self.kinect, "mirror", None)):
                ex = getattr(holder, "exclude_bodies", None)
                if isinstance(ex, set):
                    ex.discard(old)
                    ex.add(new)
        self._ghost_people()
        self.world.steps = 0
        if self.bodies.moving:
            self.bodies.update(self.world.client, 0.0)

    def footprint_overlaps(self) -> list[str]:
        """Static scene objects the chair's collision shapes penetrate where it stands (no stepping).

        Walking people, which pass through the chair, are left out.
        """
        import pybullet as p

        c = self.world.client
        p.performCollisionDetection(physicsClientId=c)
        names = self._body_names
        people = {body for body, _ in self.bodies.moving}
        hit = {
            names[pt[2]]
            for pt in p.getContactPoints(bodyA=self.robot.body, physicsClientId=c)
            if pt[2] in names and pt[2] not in people and pt[8] < 0.0
        }
        return sorted(hit)

    def set_floor_friction(self, mu: float) -> None:
        """The floor's lateral friction coefficient (what the tyres grip with)."""
        import pybullet as p

        if not (math.isfinite(mu) and mu > 0):
            raise SimError(f"floor friction {mu!r}: expected a finite coefficient > 0")
        p.changeDynamics(self.world.plane, -1, lateralFriction=float(mu), physicsClientId=self.world.client)

    def close(self) -> None:
        for fut in self.captures_in_flight:
            fut.cancel()
        self.captures_in_flight.clear()
        if self.capture_pool is not None:
            self.capture_pool.shutdown(wait=True)
            self.capture_pool = None
        self.world.close()


def _make_sonars(chair: SimChair, rng: np.random.Generator, noise: bool) -> dict[str, Any]:
    """One simulated SRF08 three-sonar array per sonar mount (:mod:`sim.sonar`), sharing the mirror."""
    from sim.sonar import SonarArraySim

    out = {}
    for mount, child in zip(SONAR_MOUNTS, rng.spawn(len(SONAR_MOUNTS))):
        out[mount] = SonarArraySim(
            chair.world.client,
            "srf08",
            mirror=chair.mirror,
            rng=child,
            noise_std_m=SONAR_NOISE_STD_M if noise else 0.0,
            name=mount,
        )
    return out


class SimClock:
    """Simulated time of a :class:`SimChair`; sleeping advances the physics (whole 240 Hz steps).

    With ``motors``, their serial watchdog is served while sleeping: set points fall to zero at the
    physics step where the watchdog period since the last speed command ends (as a Roboteq's ``^RWD``).
    """

    def __init__(self, chair: SimChair, motors: SimMotorController | None = None) -> None:
        self.chair = chair
        self.motors = motors

    def now_ns(self) -> int:
        return self.chair.world.now_ns()

    def sleep_until_ns(self, t_ns: int) -> None:
        """Step the physics until simulated time reaches ``t_ns`` (rounded up to the next step)."""
        w = self.chair.world
        target_steps = -(-int(t_ns) * w.physics_hz // 1_000_000_000)  # ceil
        m = self.motors
        if m is not None and m.watchdog_ms is not None and m.moving:
            trip = m.last_command_step + math.ceil(m.watchdog_ms * w.physics_hz / 1000.0)
            if w.steps <= trip < target_steps:
                self.chair.step(trip - w.steps)
                m.watchdog_trip()
        if target_steps > w.steps:
            self.chair.step(target_steps - w.steps)


class SimMotorController(Device):
    """:class:`hw.interfaces.MotorController` over the simulated wheel motors (closed-loop speed mode)."""

    name = "sim-motors"

    def __init__(self, chair: SimChair, watchdog_ms: int | None = None) -> None:
        if watchdog_ms is not None and (isinstance(watchdog_ms, bool) or not isinstance(watchdog_ms, int)
                                        or watchdog_ms < 1):  # fmt: skip
            raise SimError(f"watchdog_ms={watchdog_ms!r}: expected a whole number of ms >= 1, or None")
        self.chair = chair
        self._estop = False
        self.watchdog_ms = watchdog_ms
        self.watchdog_trips = 0  # times the watchdog stopped the motors
        self.last_command_step = 0  # physics step of the last speed command
        self.moving = False  # the last set point was not zero

    def watchdog_trip(self) -> None:
        """The watchdog period passed without a speed command: stop the motors (count it)."""
        self.watchdog_trips += 1
        self.moving = False
        self.chair.robot.set_motor_rpm(0.0, 0.0)

    def close(self) -> None:
        if self._is_open:
            self.chair.robot.set_motor_rpm(0.0, 0.0)
        super().close()

    def set_speeds_rpm(self, left_rpm: float, right_rpm: float) -> None:
        self._check_open()
        if self._estop:
            left_rpm = right_rpm = 0.0
        self.last_command_step = self.chair.world.steps
        self.moving = left_rpm != 0.0 or right_rpm != 0.0
        self.chair.robot.set_motor_rpm(left_rpm, right_rpm)

    def read_state(self) -> MotorState:
        self._check_open()
        r = self.chair.robot
        return MotorState(
            stamp_ns=self.chair.world.now_ns(),
            encoder_counts=r.encoder_counts(),
            speed_rpm=r.wheel_speed_rpm(),
            faults=MotorFaults(emergency_stop=self._estop),
        )

    def configure_pid(self, left: PIDConfig, right: PIDConfig) -> None:
        """Replace both channels' PID gains (continuous units, as the control module designs them)."""
        from robchair.control import DiscretePID

        self._check_open()
        r = self.chair.robot
        for motor, cfg in ((r.left, left), (r.right, right)):
            motor.pid = DiscretePID(
                cfg.kp, cfg.ki, cfg.kd, r.motor_dt, u_min=-r.spec.max_motor_rpm, u_max=r.spec.max_motor_rpm
            )

    def emergency_stop(self) -> None:
        self._estop = True
        self.chair.robot.set_motor_rpm(0.0, 0.0)

    def release_stop(self) -> None:
        self._estop = False


class SimDepthCamera(Device):
    """:class:`hw.interfaces.DepthCamera`: the simulated Kinect at the chair's ``kinect_link``.

    Besides :meth:`read`, :meth:`submit_read` captures in the background (with ``threaded``): up to
    :attr:`max_inflight` frames (two with the ray caster, one with PyBullet's renderer, which is not
    thread-safe) are captured on other cores while the physics goes on. The ray-casting mirror is
    synced and each frame's random words are drawn on the calling thread in frame order, and scripted
    people wait for captures in flight (:meth:`SimChair.step`), so every frame is the one a serial
    run captures.

    Args:
        chair: the simulated chair.
        threaded: capture on background threads (False: :meth:`submit_read` captures at once).
    """

    def __init__(self, chair: SimChair, threaded: bool = True) -> None:
        if chair.kinect is None:
            raise SimError("this simulated chair has no depth camera (sensor=None)")
        self.chair = chair
        self.name = f"sim-{chair.kinect.model.name}"
        self.frame_id: str = chair.kinect.frame_id
        self.max_inflight = 2 if chair.kinect.backend == "raycast" else 1
        self.threaded = threaded
        self._lock = threading.Lock()

    def link_to_frame(self) -> np.ndarray:
        """``T_kinect_link_frame`` (4, 4): where the frames' ``frame_id`` sits on the camera."""
        return np.asarray(self.chair.kinect.output_pose(np.eye(4)), dtype=float)

    def _capture(self, pose: np.ndarray, stamp: int, bits: Any = None) -> DepthFrame:
        t0 = time.perf_counter()
        frame: DepthFrame = self.chair.kinect.capture(pose, stamp_ns=stamp, noise_bits=bits)
        with self._lock:  # two capture threads add to the same total
            self.chair.timing["kinect_capture"] += time.perf_counter() - t0
        return frame

    def read(self) -> DepthFrame:
        self._check_open()
        return self._capture(self.chair.kinect_pose(), self.chair.world.now_ns())

    def submit_read(self) -> Future[DepthFrame]:
        """Start capturing a frame at the camera's current pose; the future holds the frame."""
        self._check_open()
        chair = self.chair
        pose, stamp = chair.kinect_pose(), chair.world.now_ns()
        if not self.threaded:
            done: Future[DepthFrame] = Future()
            done.set_result(self._capture(pose, stamp))
            return done
        if chair.capture_pool is None:
            chair.capture_pool = ThreadPoolExecutor(self.max_inflight, thread_name_prefix="kinect")
        if chair.mirror is not None:
            chair.mirror.sync()  # here, so the capture thread's own sync finds nothing to do
        bits = chair.kinect.noise_bits()  # in frame order, on this thread
        fut = chair.capture_pool.submit(self._capture, pose, stamp, bits)
        chair.captures_in_flight = [f for f in chair.captures_in_flight if not f.done()]
        chair.captures_in_flight.append(fut)
        return fut


class SimSonarArray(Device):
    """:class:`hw.interfaces.SonarArray`: three simulated sonars on a servo joint of the chair."""

    def __init__(self, chair: SimChair, mount: str) -> None:
        if mount not in chair.sonars:
            raise SimError(f"this simulated chair has no sonar array {mount!r}")
        self.chair, self.mount = chair, mount
        self.name = f"sim-{mount}"
        self.has_servo = True
        model = chair.sonars[mount].model
        self.min_range_m, self.max_range_m = model.min_range_m, model.max_range_m
        self.field_of_view_rad = model.field_of_view_rad
        self._arrays = chair.spec.sonar_arrays  # servo convention (centre angle) of the platform

    def set_servo_deg(self, angle_deg: float) -> None:
        """Servo angle in the hardware convention: 0..180 deg, ``spec.sonar_arrays.servo_centre_deg``
        (90) = facing along the mount's x axis."""
        self._check_open()
        if not math.isfinite(angle_deg):
            raise SimError(f"{self.name}: servo angle must be finite, got {angle_deg!r}")
        self.chair.robot.set_servo_deg(self.mount, math.degrees(self._arrays.joint_angle(angle_deg)))

    def servo_deg(self) -> float:
        return self._arrays.servo_deg(math.radians(self.chair.robot.servo_deg(self.mount)))

    def read(self) -> SonarArrayReading:
        self._check_open()
        t0 = time.perf_counter()
        # the link pose already includes the servo's turn, so the sonar model gets servo angle 0
        ranges = self.chair.sonars[self.mount].measure(self.chair.robot.link_transform(self.mount), 0.0)
        self.chair.timing["sonar"] += time.perf_counter() - t0
        return SonarArrayReading(
            stamp_ns=self.chair.world.now_ns(), ranges_m=ranges, servo_angle_deg=self.servo_deg()
        )


@dataclass
class SimBackend(Backend):
    """A :class:`Backend` that owns its :class:`SimChair` (``chair``: ground truth for tests and the
    runner) and shuts its physics client down after the devices close."""

    chair: SimChair | None = None

    def close(self) -> None:
        try:
            super().close()
        finally:
            if self.chair is not None:
                self.chair.close()


def backend_from_chair(chair: SimChair, watchdog_ms: int | None = None, threaded: bool = True) -> SimBackend:
    """Wrap a :class:`SimChair` into an :class:`hw.interfaces.Backend` (closing it closes the chair).

    ``watchdog_ms``: the motor controller's serial watchdog (None: none). ``threaded``: the depth
    camera captures on background threads.
    """
    motors = SimMotorController(chair, watchdog_ms)
    return SimBackend(
        name="sim",
        clock=SimClock(chair, motors),
        motors=motors,
        sonar_arrays=tuple(SimSonarArray(chair, m) for m in SONAR_MOUNTS if m in chair.sonars),
        depth_camera=SimDepthCamera(chair, threaded) if chair.kinect is not None else None,
        chair=chair,
    )


_CONFIG_KEYS = {
    "scene",
    "scenario",
    "sensor",
    "sonars",
    "seed",
    "start",
    "camera_backend",
    "noise",
    "spec",
    "tyre_radius_error",
    "watchdog_ms",
}


def make_sim_backend(config: Mapping[str, Any] | ConfigTable | None = None) -> SimBackend:
    """The simulated chair as a :class:`Backend` (the ``"sim"`` entry of :mod:`robchair.backends`).

    Config keys (all optional): ``scenario`` (name or path: scene, start pose, sensor, seed from it),
    ``scene`` (name or path), ``sensor`` (Kinect model, or None / ``"none"``), ``sonars`` (bool),
    ``seed`` (int),
    ``tyre_radius_error`` (fraction, default 0.002; 0 = tyres exactly as the spec),
    ``watchdog_ms`` (motor controller watchdog, ms; default none),
    ``start`` ([x, y, yaw]), ``camera_backend`` (``raycast``/``pybullet``), ``noise`` (bool), ``spec``
    (path of a platform TOML). An unknown key or a bad ``start`` / ``watchdog_ms`` raises
    :class:`sim.errors.SimError` (or the error class of a :class:`robchair.config.ConfigTable`'s source,
    whose file and line the message then names), in the :mod:`robchair.config` dialect.

    The returned backend has the underlying :class:`SimChair` as ``backend.chair`` (for ground truth).
    """
    table = (
        config
        if isinstance(config, ConfigTable)
        else ConfigTable(dict(config or {}), ConfigSource(error=SimError), "sim")
    )
    table.keys(_CONFIG_KEYS)
    cfg = dict(table.data)
    spec = load_spec(cfg["spec"]) if cfg.get("spec") else load_spec()
    kw: dict[str, Any] = {}
    if cfg.get("scenario"):
        from sim.scene import load_scenario

        sc = load_scenario(cfg["scenario"], robot_radius=robot_radius(spec))
        kw.update(scene=sc.scene, start=sc.start, sensor=sc.sensor, sonars=sc.sonars, seed=sc.seed)
    if cfg.get("scene"):
        from robchair.paths import SCENES

        s = Path(cfg["scene"])
        kw["scene"] = load_scene(s if s.is_file() else SCENES / f"{cfg['scene']}.toml")
    for k in ("sensor", "sonars", "seed", "camera_backend", "noise", "tyre_radius_error"):
        if k in cfg:
            kw[k] = cfg[k]
    if isinstance(kw.get("sensor"), str) and kw["sensor"].lower() == "none":
        kw["sensor"] = None  # TOML has no null: "none" means no depth camera
    if "start" in cfg:
        kw["start"] = table.vector("start", 3)
    watchdog = table.integer("watchdog_ms", None, ge=1) if cfg.get("watchdog_ms") is not None else None
    return backend_from_chair(SimChair(spec, **kw), watchdog)


def robot_radius(spec: RobChairSpec) -> float:
    """Radius (m) of the circle about base_link that holds the chair's footprint."""
    b = spec.body
    xs = (b.centre_x - b.depth / 2, b.centre_x + b.depth / 2)
    return float(max(math.hypot(x, b.width / 2) for x in xs))
