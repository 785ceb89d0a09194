"""The whole simulated chair: world, scene, robot and sensors, and what only a simulation can do.

:class:`SimChair` bundles a :class:`sim.world.World`, the scene, the :class:`sim.robot.SimRobot` and the
simulated sensors (:mod:`sim.kinect`, :mod:`sim.sonar`, :mod:`sim.laser`). :mod:`sim.backend` puts the
hardware interfaces over it.

Powers only a simulation has are domain-named methods of :class:`SimChair`: ``ground_truth_pose``,
``ground_truth_transform``, ``contacts``, ``footprint_overlaps``, ``teleport``, ``restart`` (an exact
reset) and ``set_floor_friction`` (with :meth:`sim.robot.SimRobot.set_payload_kg` and
:meth:`sim.robot.SimRobot.scale_motor_plants` for domain randomisation).
"""

from __future__ import annotations

import math
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from hw.interfaces import DepthFrame
from robchair.platform.frames import quat_from_yaw
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import RobChairSpec, load_spec
from sim.crowd import Footprint
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
        self._restarts = 0  # with the physics step, names an instant (sonar casts, mirror syncs)
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
            # the static scene bodies' bounding boxes ((lo, hi) by body), made when first needed
            self._static_boxes: dict[int, tuple[list[float], list[float]]] | None = None
            b = self.spec.body  # what the scripted people keep clear of (sim.crowd)
            self._footprint = Footprint(b.centre_x - 0.5 * b.depth, b.centre_x + 0.5 * b.depth, 0.5 * b.width)
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
                self.mirror.step_counter = self._mirror_stamp
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
            from sim.sonar import SonarGroup

            self.sonar_group = SonarGroup(self.sonars)
            self._sonar_mounts = list(self.sonars)
            # the sonar mounts' world poses at the instant named (physics step, restarts)
            self._sonar_now: tuple[Any, dict[str, np.ndarray]] | None = None
            if laser:
                from sim.laser import LaserSim

                robot = self.robot
                self.laser = LaserSim(
                    self.world.client,
                    mirror=self.mirror,
                    noise=noise,
                    rng=np.random.default_rng(ss.spawn(1)[0]),
                    pose=lambda: robot.link_transform("laser_link"),
                    clock=_WorldClock(self.world),
                )
        except BaseException:
            self.world.close()
            raise

    def _ghost_people(self) -> None:
        """Scripted people are teleported along their walks (kinematic, mass 0): a collision with the
        chair would fling it away. They keep clear of the chair by the social force model
        (:mod:`sim.crowd`), and pass through it where they still touch it; every sensor sees them."""
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
        self._advance(n, None, None)

    def step_collecting_contacts(self, n: int, before: Any = None) -> set[str]:
        """:meth:`step` ``n`` times, calling ``before()`` ahead of each step; the names of the scene
        objects the chair touched after any of the steps (:meth:`contacts`)."""
        hits: set[str] = set()
        self._advance(n, before, hits)
        return hits

    def _advance(self, n: int, before: Any, hits: set[str] | None) -> None:
        if n <= 0:
            return
        if self.bodies.moving and self.captures_in_flight:
            for fut in self.captures_in_flight:
                fut.result()
            self.captures_in_flight.clear()
        t0 = time.perf_counter()
        world, moving = self.world, self.bodies.moving
        near = self._contact_candidates(n) if hits is not None else []
        for _ in range(n):
            if before is not None:
                before()
            if moving:
                pose = self.robot.pose2d()
                self.bodies.update(world.client, world.time, (self._footprint, (pose.x, pose.y, pose.theta)))
            world.step(1)
            if hits is not None and (near or moving):
                hits |= self._contacts_among(near)
        self.timing["physics"] += time.perf_counter() - t0

    #: Fastest the chair can move, m/s, with a wide margin (its top speed is about a third of it): the
    #: reach of :meth:`_contact_candidates` over an interval.
    _REACH_SPEED_M_S = 5.0
    #: Margin for PyBullet's contact threshold and rounding, m.
    _REACH_MARGIN_M = 0.25

    def _contact_candidates(self, n: int) -> list[int]:
        """The static scene bodies the chair could touch in the next ``n`` physics steps.

        A contact needs the two bodies' bounding boxes to overlap (PyBullet's broadphase), so a body
        whose box stays farther from the chair's box than the chair can travel in ``n`` steps
        (:data:`_REACH_SPEED_M_S`) plus :data:`_REACH_MARGIN_M` has no contact point in them: only the
        others are queried, pair by pair (the floor, always touched by the wheels, is never named).
        """
        import pybullet as p

        c, robot = self.world.client, self.robot.body
        n_links = p.getNumJoints(robot, physicsClientId=c)
        boxes = [p.getAABB(robot, link, physicsClientId=c) for link in range(-1, n_links)]
        reach = self._REACH_MARGIN_M + self._REACH_SPEED_M_S * n / self.world.physics_hz
        lo = [min(b[0][i] for b in boxes) - reach for i in range(3)]
        hi = [max(b[1][i] for b in boxes) + reach for i in range(3)]
        static = self._static_boxes
        if static is None:
            moving = {body for body, _ in self.bodies.moving}
            static = self._static_boxes = {}
            for body in self._body_names:
                if body in moving:
                    continue
                nk = p.getNumJoints(body, physicsClientId=c)
                links = [p.getAABB(body, k, physicsClientId=c) for k in range(-1, nk)]
                static[body] = (
                    [min(b[0][i] for b in links) for i in range(3)],
                    [max(b[1][i] for b in links) for i in range(3)],
                )
        return [
            body
            for body, (blo, bhi) in static.items()
            if all(blo[i] <= hi[i] and bhi[i] >= lo[i] for i in range(3))
        ]

    def _contacts_among(self, near: list[int]) -> set[str]:
        """:meth:`contacts` asked of the bodies ``near`` (:meth:`_contact_candidates`) and the walkers."""
        import pybullet as p

        c, robot, names = self.world.client, self.robot.body, self._body_names
        hit = {names[b] for b in near if p.getContactPoints(bodyA=robot, bodyB=b, physicsClientId=c)}
        for body, _ in self.bodies.moving:
            if body in names and p.getClosestPoints(robot, body, 0.0, physicsClientId=c):
                hit.add(names[body])
        return hit

    def sonar_raw(self, mount: str) -> np.ndarray:
        """Raw first echoes (3,) (m, unquantised, NaN = none) of the sonar array on ``mount`` now.

        The first array read at a physics step casts every array's beams in one batched call
        (:class:`sim.sonar.SonarGroup`); the others read theirs from it.
        """
        stamp = (self.world.steps, self._restarts)
        kept = self._sonar_now
        if kept is not None and kept[0] == stamp:  # nothing moved since the instant's first read
            now = kept[1]
        else:
            now = self.robot.link_transforms(self._sonar_mounts)  # every array's mount in one query
            self._sonar_now = (stamp, now)
        return self.sonar_group.raw(mount, now[mount], stamp, lambda: now)

    def _mirror_stamp(self) -> Any:
        """What names the state of the ray-casting mirror's world (its ``step_counter``).

        Scripted people move only in :meth:`step`, so the physics step names it (one sync per step
        serves every sensor). Without them every scene body is static (mass 0, never teleported) and
        the chair, the only body that moves, is left out of the mirror: the mirror's world changes
        only when :meth:`restart` replaces the chair's body, so the restart count names it and the
        mirror is synced once per episode instead of re-reading every body's pose each step.
        """
        if self.bodies.moving:
            return self.world.steps
        return -1 - self._restarts  # never equal to a step count

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
        self._sonar_now = None  # moved without a physics step: the mounts' poses are read again

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
        self._restarts += 1
        if self.bodies.moving:
            self.bodies.reset()
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


#: Angular spacing of the chair's sonar rays, deg: 1102 rays per sonar instead of 4413 at 1 deg (the
#: casts were a quarter of an env step). Against the 1-degree beam over 800 random poses in the office
#: scene, 99 % of the readings up to 1 m (what the fusion accepts) are within one SRF08 step (1 cm) and
#: 0.4-0.6 % miss a thin edge at the beam's rim (a later reading finds it); beyond 1 m, 99 % are within
#: 3 cm. tests/sim/test_sonar_sim.py bounds it. :class:`sim.sonar.SonarArraySim` itself keeps 1 deg.
CHAIR_SONAR_RAY_SPACING_DEG = 2.0


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
            ray_spacing_deg=CHAIR_SONAR_RAY_SPACING_DEG,
            name=mount,
        )
    return out


class _WorldClock:
    """The stamps of the chair's own devices: simulated time (sleeping is the runtime's business)."""

    def __init__(self, world: World) -> None:
        self.world = world

    def now_ns(self) -> int:
        return self.world.now_ns()

    def sleep_until_ns(self, t_ns: int) -> None:
        raise SimError("the chair's device clock does not advance time; the runtime's SimClock does")


def robot_radius(spec: RobChairSpec) -> float:
    """Radius (m) of the circle about base_link that holds the chair's footprint."""
    b = spec.body
    xs = (b.centre_x - b.depth / 2, b.centre_x + b.depth / 2)
    return float(max(math.hypot(x, b.width / 2) for x in xs))
