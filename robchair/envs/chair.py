"""The simulated chair as the navigation environment's runtime sees it: one episode's devices.

:func:`episode_backend` wraps a :class:`sim.backend.SimChair` into a :class:`hw.interfaces.Backend`
whose devices carry what an episode draws (domain randomisation, :mod:`sim.envs.randomization`):

* :class:`EpisodeMotors` - the simulated controller with this episode's tyres (a tyre ``k`` times
  the spec's radius drives the chair ``k`` times faster than commanded: the physics keeps the spec's
  radius and gets set points ``k`` times higher, and the encoders turn ``1 / k`` as far) and its
  command latency (a set point reaches the controller ``latency_steps`` physics steps late);
* :class:`EpisodeClock` - simulated time; sleeping advances the physics one step at a time, applies
  a latent set point when it is due, and collects the scene objects the chair touches in any step;
* sonar arrays, laser scanner and depth camera that draw their noise from the episode's stream, so
  the same seed gives the same episode however many episodes ran before.

:func:`build_chair` makes the chair and its backend for an environment, :func:`place_chair` starts an
episode on it (an exact reset, then the episode's dynamics). Beside them, what the environment reads
of the runtime: :func:`shield_report` (``info["safety"]``)
and :class:`GroundTruthLocalisation` (the physics' pose in place of odometry).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from hw.interfaces import DepthFrame, MotorState
from hw.messages import MotorFaults
from robchair.loop_types import CycleResult
from robchair.platform import frames
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import RobChairSpec
from sim.backend import SONAR_MOUNTS, SimBackend, SimChair, SimMotorController, SimSonarArray
from sim.envs.errors import NavigationEnvError
from sim.envs.geometry import decimated_depth_noise
from sim.envs.randomization import EpisodeDynamics
from sim.scene import Scene


@dataclass
class EpisodeNoise:
    """The episode's sensor-noise stream and scale, shared by the devices (replaced at each reset)."""

    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    scale: float = 1.0


class EpisodeMotors(SimMotorController):
    """Simulated motor controller with the episode's tyre radii and command latency."""

    def __init__(self, chair: SimChair) -> None:
        super().__init__(chair, None)
        self.tyre_scale = (1.0, 1.0)
        self.latency_steps = 0
        self.counts0 = (0, 0)
        self.pending: tuple[float, float, int] | None = None  # (left, right, physics step due)
        self._kept: tuple[tuple[int, int, bool], MotorState] | None = None  # (instant, state)

    def new_episode(self, tyre_scale: tuple[float, float], latency_steps: int) -> None:
        """Start an episode: tyres, latency, encoder origin; no set point pending, stop released."""
        self.tyre_scale = (float(tyre_scale[0]), float(tyre_scale[1]))
        self.latency_steps = int(latency_steps)
        self.counts0 = self.chair.robot.encoder_counts()
        self.pending = None
        self._kept = None
        self.release_stop()

    def set_speeds_rpm(self, left_rpm: float, right_rpm: float) -> None:
        self._check_open()
        kl, kr = self.tyre_scale
        due = self.chair.world.steps + self.latency_steps
        self.pending = (left_rpm * kl, right_rpm * kr, due)
        if self.latency_steps == 0:
            self.apply_due()

    def apply_due(self) -> None:
        """Hand the pending set point to the controller once its latency has passed."""
        p = self.pending
        if p is not None and self.chair.world.steps >= p[2]:
            self.pending = None
            super().set_speeds_rpm(p[0], p[1])

    def emergency_stop(self) -> None:
        self.pending = None
        super().emergency_stop()

    def read_state(self) -> MotorState:
        """The controller's state as :meth:`SimMotorController.read_state` gives it, seen through the
        episode's tyres; one reading per instant of the physics (the runtime's next cycle reads the
        state the observation read, nothing moved between them)."""
        self._check_open()
        chair = self.chair
        key = (chair.world.steps, instant(chair), self._estop)
        kept = self._kept
        if kept is not None and kept[0] == key:
            return kept[1]
        r = chair.robot
        (cl, cr), (l0, r0) = r.encoder_counts(), self.counts0
        kl, kr = self.tyre_scale
        ml, mr = r.wheel_speed_rpm()
        state = MotorState(
            stamp_ns=chair.world.now_ns(),
            encoder_counts=(l0 + round((cl - l0) / kl), r0 + round((cr - r0) / kr)),
            speed_rpm=(ml / kl, mr / kr),
            faults=_FAULTS[self._estop],
        )
        self._kept = (key, state)
        return state

    def read_state_reference(self) -> MotorState:
        """:meth:`read_state` through the simulated controller's own reading (the tested reference)."""
        state = super().read_state()
        (cl, cr), (l0, r0) = state.encoder_counts, self.counts0
        kl, kr = self.tyre_scale
        ml, mr = state.speed_rpm
        return replace(
            state,
            encoder_counts=(l0 + round((cl - l0) / kl), r0 + round((cr - r0) / kr)),
            speed_rpm=(ml / kl, mr / kr),
        )


def instant(chair: SimChair) -> int:
    """The restart count of ``chair``: with its physics step it names an instant of the simulation
    (:meth:`sim.backend.SimChair.restart` sets the step count back to 0)."""
    return int(chair._restarts)


def se3_from_quat(pos: Any, q: Any) -> np.ndarray:
    """:func:`robchair.platform.frames.se3_from_quat` (4, 4) of a position and a quaternion ``(x, y, z,
    w)`` built in one array, the same values bit for bit (a sensor's pose every step).

    Raises:
        ValueError: the quaternion has zero length.
    """
    x, y, z, w = (float(c) for c in q)
    n = x * x + y * y + z * z + w * w
    if not n >= 1e-24:
        return frames.se3_from_quat(pos, q)  # raises its error
    s = 2.0 / n  # frames.matrix_from_quat's closed form, term for term
    px, py, pz = (float(c) for c in pos)
    return np.array([[1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w), px],
                     [s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w), py],
                     [s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y), pz],
                     [0.0, 0.0, 0.0, 1.0]])  # fmt: skip


def yaw_from_quat(q: Any) -> float:
    """:func:`robchair.platform.frames.yaw_from_quat` of ``(x, y, z, w)`` from the two matrix entries it
    reads, the same value bit for bit.

    Raises:
        ValueError: the quaternion has zero length.
    """
    x, y, z, w = (float(c) for c in q)
    n = x * x + y * y + z * z + w * w
    if not n >= 1e-24:
        return frames.yaw_from_quat(q)  # raises its error
    s = 2.0 / n
    return math.atan2(s * (x * y + z * w), 1.0 - s * (y * y + z * z))


#: the fault flags of a reading, by emergency stop (frozen: one instance serves every reading)
_FAULTS = {False: MotorFaults(emergency_stop=False), True: MotorFaults(emergency_stop=True)}


class EpisodeClock:
    """Simulated time; sleeping steps the physics, applies latent set points and records contacts."""

    def __init__(self, chair: SimChair, motors: EpisodeMotors) -> None:
        self.chair = chair
        self.motors = motors
        self.contacts: set[str] = set()

    def now_ns(self) -> int:
        return self.chair.world.now_ns()

    def sleep_until_ns(self, t_ns: int) -> None:
        """Step the physics until ``t_ns`` (rounded up to a whole step), one step at a time."""
        w = self.chair.world
        target = -(-int(t_ns) * w.physics_hz // 1_000_000_000)
        if w.steps < target:
            # a set point waits only from set_speeds_rpm to its due step: without one no step looks
            before = self.motors.apply_due if self.motors.pending is not None else None
            self.contacts |= self.chair.step_collecting_contacts(target - w.steps, before)


class EpisodeSonarArray(SimSonarArray):
    """A simulated sonar array drawing its noise from the episode's stream."""

    def __init__(self, chair: SimChair, mount: str, noise: EpisodeNoise) -> None:
        super().__init__(chair, mount)
        self.noise = noise
        self.nominal_std_m = float(chair.sonars[mount].noise_std_m)

    def read(self) -> Any:
        from hw.interfaces import SonarArrayReading

        self._check_open()
        arr = self.chair.sonars[self.mount]
        arr.noise_std_m = self.nominal_std_m * self.noise.scale
        ranges = arr.finish(self.chair.sonar_raw(self.mount), rng=self.noise.rng)
        return SonarArrayReading(
            stamp_ns=self.chair.world.now_ns(), ranges_m=ranges, servo_angle_deg=self.servo_deg()
        )


class EpisodeLaser:
    """The simulated Hokuyo on ``laser_link``, noise from the episode's stream."""

    name = "sim-laser"

    def __init__(self, chair: SimChair, laser: Any, noise: EpisodeNoise, accuracy_sigmas: float) -> None:
        self.chair, self.laser, self.noise = chair, laser, noise
        self.accuracy_sigmas = accuracy_sigmas
        self.frame_id = laser.frame_id

    def open(self) -> None:
        self.laser.open()

    def close(self) -> None:
        self.laser.close()

    def read(self) -> Any:
        self.laser.accuracy_sigmas = self.accuracy_sigmas / max(self.noise.scale, 1e-6)
        pose = se3_from_quat(*self.chair.robot.link_pose("laser_link"))  # link_transform's matrix
        return self.laser.scan(pose, self.chair.world.now_ns(), rng=self.noise.rng)


class EpisodeDepthCamera:
    """The simulated Kinect (possibly decimated), noise from the episode's stream.

    A decimated camera renders clean geometry and gets the model's axial noise
    (:func:`sim.envs.geometry.decimated_depth_noise`); at full resolution the model's own noise applies.
    """

    def __init__(self, chair: SimChair, noise: EpisodeNoise, own_noise: bool) -> None:
        self.chair, self.noise, self.own_noise = chair, noise, own_noise
        self.name = f"sim-{chair.kinect.model.name}"
        self.frame_id: str = chair.kinect.frame_id
        self._open = False

    def open(self) -> None:
        self._open = True

    def close(self) -> None:
        self._open = False

    def link_to_frame(self) -> np.ndarray:
        """``T_kinect_link_frame`` (4, 4)."""
        return np.asarray(self.chair.kinect.output_pose(np.eye(4)), dtype=float)

    def read(self) -> DepthFrame:
        chair = self.chair
        frame: DepthFrame = chair.kinect.capture(
            chair.kinect_pose(), stamp_ns=chair.world.now_ns(), rng=self.noise.rng
        )
        if self.own_noise:
            pts = decimated_depth_noise(frame.points, chair.kinect.model, self.noise.rng, self.noise.scale)
            frame = replace(frame, points=pts)
        return frame


@dataclass
class EpisodeBackend(SimBackend):
    """The simulated chair with the episode's devices; ``laser_scanner`` is read by the runtime."""

    laser_scanner: Any = None

    def devices(self) -> list[Any]:
        devs = super().devices()
        if self.laser_scanner is not None:
            devs.append(self.laser_scanner)
        return devs


def episode_backend(
    chair: SimChair, noise: EpisodeNoise, *, laser: Any = None, own_depth_noise: bool = False,
    laser_accuracy_sigmas: float = 3.0,
) -> EpisodeBackend:  # fmt: skip
    """The opened backend of an environment's chair (the chair is closed by its owner, not here)."""
    motors = EpisodeMotors(chair)
    backend = EpisodeBackend(
        name="sim",
        clock=EpisodeClock(chair, motors),
        motors=motors,
        sonar_arrays=tuple(EpisodeSonarArray(chair, m, noise) for m in SONAR_MOUNTS if m in chair.sonars),
        depth_camera=EpisodeDepthCamera(chair, noise, own_depth_noise) if chair.kinect is not None else None,  # type: ignore[arg-type]
        chair=None,
        laser_scanner=EpisodeLaser(chair, laser, noise, laser_accuracy_sigmas) if laser is not None else None,
    )
    backend.open()
    return backend


def shield_report(cycle: CycleResult) -> dict[str, Any]:
    """``info["safety"]``: whether and why the safety layer changed the agent's command in a cycle.

    Returns ``{"intervened": bool, "reason": str | None}``; the reason is the stop reason and its
    detail (e.g. ``"obstacle_map: obstacle at 0.31 m ahead < stopping distance 0.35 m"``), or
    ``"limited: ..."`` when a speed or acceleration limit changed the twist.
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

    Duck-types :class:`robchair.platform.kinematics.Odometry` for the runtime: ``update`` ignores the
    encoder counts and returns the simulated chair's true planar pose.
    """

    def __init__(self, chair: SimChair) -> None:
        self.chair = chair
        self._kept: tuple[tuple[int, int], Pose2D] | None = None
        self.pose = self.now()
        self.distance = 0.0

    def now(self) -> Pose2D:
        """The chair's true pose now (:meth:`SimChair.ground_truth_pose`), read once per instant of
        the physics: the environment's step and the runtime's next cycle share it.

        Raises:
            SimulationDivergedError: the physics produced a non-finite pose.
        """
        key = (self.chair.world.steps, instant(self.chair))
        kept = self._kept
        if kept is not None and kept[0] == key:
            return kept[1]
        pos, orn = self.chair.robot.base_pose()  # SimChair.ground_truth_pose, without the rotation matrix
        pose = Pose2D(pos[0], pos[1], yaw_from_quat(orn))
        self._kept = (key, pose)
        return pose

    def update(self, *_counts: Any) -> Pose2D:
        """The true pose now (the distance driven accumulates)."""
        pose = self.now()
        self.distance += math.hypot(pose.x - self.pose.x, pose.y - self.pose.y)
        self.pose = pose
        return pose


LASER_ACCURACY_SIGMAS = 3.0  # the datasheet's +- accuracy is this many standard deviations (sim.laser)


def build_chair(spec: RobChairSpec, scene: Scene, *, sensor: str | None, decimation: int, sonars: bool,
                laser: bool, noise: bool, camera_backend: str,
                ) -> tuple[SimChair, EpisodeNoise, EpisodeBackend, dict[str, np.ndarray]]:  # fmt: skip
    """An environment's simulated chair and its opened backend.

    Args:
        spec: the platform spec.
        scene: the scene.
        sensor: Kinect model name (``kinect2``, ``kinect1``) or None; decimated ``decimation`` times
            (fewer rays over the same field of view: the same camera at a lower resolution).
        decimation: the Kinect's decimation (1 = full resolution).
        sonars, laser, noise, camera_backend: as :class:`sim.backend.SimChair`.

    Returns:
        The chair, the episode's noise stream (replaced at each reset), the backend, and the sensor
        frames beyond the spec's mounts (``{frame_id: T_base_frame}``) for the perception stage.
    """
    model: Any = None
    if sensor is not None:
        from sim.kinect import get_model

        base = get_model(sensor)
        model = replace(base, name=f"{base.name}/{decimation}", width=max(1, base.width // decimation),
                        height=max(1, base.height // decimation))  # fmt: skip
    chair = SimChair(spec, scene, (0.0, 0.0, 0.0), sensor=model, sonars=sonars, seed=0,
                     camera_backend=camera_backend, noise=noise,
                     tyre_radius_error=0.0,  # drawn per episode instead (domain randomisation)
                     # one Embree thread: an env casts a few thousand rays a step, where a thread pool
                     # costs more than it gains, and the workers of a vector env each get their own core
                     raycast_threads=1, laser=laser)  # fmt: skip
    try:
        # The Kinect models' lateral noise is in pixels of the full image (1.6 px for the v2); applied
        # to a decimated image it would be `decimation` times too wide and smear the floor into
        # obstacles. A decimated camera therefore renders clean geometry and gets the axial noise
        # (see decimated_depth_noise); at full resolution the model's own noise applies unchanged.
        own_noise = noise and model is not None and decimation > 1
        if own_noise:
            chair.kinect.noise = False
        ep_noise = EpisodeNoise()
        backend = episode_backend(chair, ep_noise, laser=chair.laser, own_depth_noise=own_noise,
                                  laser_accuracy_sigmas=LASER_ACCURACY_SIGMAS)  # fmt: skip
        frames: dict[str, np.ndarray] = {}
        if chair.kinect is not None and chair.kinect.frame_id not in spec.mounts:
            t_link = spec.mounts["kinect_link"].transform()
            frames[chair.kinect.frame_id] = t_link @ chair.kinect.output_pose(np.eye(4))
    except BaseException:
        chair.close()
        raise
    return chair, ep_noise, backend, frames


def place_chair(chair: SimChair, start: Pose2D, dynamics: EpisodeDynamics, settle_steps: int) -> None:
    """Start an episode: the chair at rest at ``start`` with the episode's floor, payload and motors.

    :meth:`sim.backend.SimChair.restart` is an exact reset (a new chair body, the clock at 0), so an
    episode depends only on its seed and actions, never on the episodes before it. The chair then
    settles ``settle_steps`` physics steps with zero command.

    Raises:
        NavigationEnvError: the chair's collision footprint at ``start`` overlaps a scene object
            (named, with the start).
    """
    chair.restart(start)
    static = chair.footprint_overlaps()
    if static:
        raise NavigationEnvError(
            f"start {(start.x, start.y, start.theta)}: the chair's footprint there overlaps "
            + ", ".join(repr(n) for n in static)
        )
    chair.set_floor_friction(dynamics.floor_friction)
    chair.robot.set_payload_kg(dynamics.payload_kg)
    chair.robot.scale_motor_plants(dynamics.motor_omega_n_scale, dynamics.motor_xi_scale)
    chair.step(settle_steps)
