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
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from hw.interfaces import DepthFrame, MotorState
from sim.backend import SONAR_MOUNTS, SimBackend, SimChair, SimMotorController, SimSonarArray
from sim.envs.geometry import decimated_depth_noise


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

    def new_episode(self, tyre_scale: tuple[float, float], latency_steps: int) -> None:
        """Start an episode: tyres, latency, encoder origin; no set point pending, stop released."""
        self.tyre_scale = (float(tyre_scale[0]), float(tyre_scale[1]))
        self.latency_steps = int(latency_steps)
        self.counts0 = self.chair.robot.encoder_counts()
        self.pending = None
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
        state = super().read_state()
        (cl, cr), (l0, r0) = state.encoder_counts, self.counts0
        kl, kr = self.tyre_scale
        ml, mr = state.speed_rpm
        return replace(
            state,
            encoder_counts=(l0 + round((cl - l0) / kl), r0 + round((cr - r0) / kr)),
            speed_rpm=(ml / kl, mr / kr),
        )


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
        while w.steps < target:
            self.motors.apply_due()
            self.chair.step(1)
            self.contacts |= self.chair.contacts()


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
        ranges = arr.measure(self.chair.robot.link_transform(self.mount), 0.0, rng=self.noise.rng)
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
        pose = self.chair.robot.link_transform("laser_link")
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
