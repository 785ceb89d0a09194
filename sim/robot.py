"""The simulated RobChair: the URDF body in a :class:`sim.world.World`, motors, encoders, servos.

Motors. PyBullet's joint motors are ideal: a velocity target is reached in one step. The real wheel
motors are not: Appendix B measured a second-order open-loop step response (t_p ~ 0.4 s, 10-12 %
overshoot) with the chair on the floor, i.e. with the chair's inertia included. So each wheel runs
through :class:`robchair.platform.control.DiscretePlant` (the identified plant, exact ZOH discretisation, unit
DC gain: command RPM in, motor-shaft RPM out), and in closed-loop speed mode a
:class:`robchair.platform.control.DiscretePID` (gains by the pole-placement design of SPEC 5, derivative on
the measurement) in front of it: the same classes the Roboteq emulator runs, at the same controller rate
(:data:`robchair.platform.control.CONTROLLER_RATE_HZ`, 1 kHz), independent of the physics rate. Each physics
step runs the controller ticks that fall inside it (4 or 5 at 240 Hz physics); the first measures the
wheel's joint speed like the Roboteq measures its encoder, the others add the plant's change since then
(the wheel follows the plant exactly, see below), so no tick reuses a stale measurement. The plant's output
speed is applied as the wheel joint's velocity target with a high force limit, so the wheel follows
the identified dynamics exactly and PyBullet supplies only the contact with the floor (the alternative,
applying torque, would need a motor model the thesis does not give).

Encoders count quadrature x4 on the motor shaft (or the wheel, per ``spec.encoder_on``), signed
32-bit with wrap-around, from the wheel joint's accumulated angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from robchair.platform import frames
from robchair.platform.kinematics import DiffDrive, Pose2D, wrap_int32
from robchair.platform.spec import RobChairSpec
from sim import _wheel_kernels
from sim.errors import SimError, SimulationDivergedError
from sim.urdf import SERVO_MAX_TORQUE, SERVO_MAX_VELOCITY, WHEEL_JOINTS, apply_contact_dynamics, write_urdf
from sim.world import World

WHEEL_MAX_FORCE = 2000.0  # N m: high, so the wheel follows the plant's speed (see the module docstring)


@dataclass
class WheelMotor:
    """One wheel channel: optional discrete PID in front of the identified discrete plant.

    Attributes:
        channel: Roboteq channel (1 left, 2 right).
        plant: ``robchair.platform.control.DiscretePlant`` (command RPM -> shaft RPM).
        pid: ``robchair.platform.control.DiscretePID`` or None for open loop.
    """

    channel: int
    plant: Any
    pid: Any
    setpoint_rpm: float = 0.0
    command_rpm: float = 0.0
    output_rpm: float = 0.0
    closed_loop: bool = True

    def update(self, measured_rpm: float, ticks: int = 1) -> float:
        """Run ``ticks`` controller periods; returns the shaft speed (RPM) the plant produces.

        The first tick's PID sees ``measured_rpm``; later ticks see it plus the plant's change since.
        """
        start = self.output_rpm
        for _ in range(ticks):
            if self.closed_loop and self.pid is not None:
                measured = measured_rpm + (self.output_rpm - start)
                self.command_rpm = float(self.pid.update(self.setpoint_rpm, measured))
            else:
                self.command_rpm = self.setpoint_rpm
            self.output_rpm = float(self.plant.step(self.command_rpm))
        return self.output_rpm

    def reset(self) -> None:
        self.plant.reset()
        if self.pid is not None:
            self.pid.reset()
        self.setpoint_rpm = self.command_rpm = self.output_rpm = 0.0


def make_wheel_motors(
    spec: RobChairSpec,
    dt: float,
    closed_loop: bool = True,
    pid_gains: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None,
) -> tuple[WheelMotor, WheelMotor]:
    """The two wheel motors: plants identified from the spec's step responses, PIDs by design (SPEC 5)."""
    from robchair.platform.control import DiscretePID, DiscretePlant, identify_from_step_metrics
    from robchair.platform.control import pid_gains as design_gains

    motors = []
    for i, ch in enumerate((1, 2)):
        step = spec.step_for_channel(ch)
        plant = identify_from_step_metrics(step.t_r, step.t_p, step.M_p).plant
        # the design's gains without its python-control checks (tested in tests/robchair/test_control.py)
        kp, ki, kd = pid_gains[i] if pid_gains is not None else design_gains(plant)
        pid = DiscretePID(kp, ki, kd, dt, u_min=-spec.max_motor_rpm, u_max=spec.max_motor_rpm)
        motors.append(WheelMotor(ch, DiscretePlant(plant, dt), pid, closed_loop=closed_loop))
    return motors[0], motors[1]


class SimRobot:
    """RobChair in a world: drive it with motor RPM set points, read encoders, poses and servos.

    Args:
        world: The physics world.
        spec: Platform spec.
        start: Initial (x, y, yaw) of ``base_link`` on the floor.
        motor_rate_hz: Rate of the motor controller (plant + PID), Hz; default
            :data:`robchair.platform.control.CONTROLLER_RATE_HZ` (the Roboteq's 1 kHz, as the emulator
            runs it).
        closed_loop: Closed-loop speed mode (PID) or open loop (the command goes straight to the plant).
        wheel_radius_scale: True tyre radii relative to the spec (see :func:`sim.urdf.build_urdf`); the
            encoders and everything downstream keep assuming the spec's radius.
    """

    def __init__(
        self,
        world: World,
        spec: RobChairSpec,
        start: tuple[float, float, float] = (0.0, 0.0, 0.0),
        motor_rate_hz: int | None = None,
        closed_loop: bool = True,
        wheel_radius_scale: tuple[float, float] = (1.0, 1.0),
    ) -> None:
        self.world, self.spec, self.client = world, spec, world.client
        self.drive = DiffDrive(spec)
        from robchair.platform.control import CONTROLLER_RATE_HZ

        rate = motor_rate_hz or int(CONTROLLER_RATE_HZ)
        if not (isinstance(rate, int) and rate > 0):
            raise SimError(f"motor_rate_hz={rate!r}: expected a whole number of Hz > 0")
        self.motor_rate_hz = rate
        self.motor_dt = 1.0 / rate
        self.wheel_radius_scale = wheel_radius_scale
        self._load_body(start)
        self.left, self.right = make_wheel_motors(spec, self.motor_dt, closed_loop)
        # the identified plants (scale_motor_plants and respawn start from them)
        self.nominal_plants = (self.left.plant.plant, self.right.plant.plant)
        self._apply_wheel_targets(0.0, 0.0)
        self._step_count = 0
        #: run both wheels' controller ticks in one compiled call (:mod:`sim._wheel_kernels`, the
        #: arithmetic of ``WheelMotor.update`` bit for bit); False runs the Python classes
        self.compiled_motors = True
        self._compiled = _wheel_kernels.CompiledWheels()
        world.add_pre_step(self._pre_step)

    def _load_body(self, start: tuple[float, float, float]) -> None:
        """Load the chair's URDF body at ``start`` (joints at their zero angles, servos held at 0)."""
        import pybullet as p

        q = frames.quat_from_yaw(start[2])
        self.body = p.loadURDF(
            str(write_urdf(self.spec, wheel_radius_scale=self.wheel_radius_scale)),
            basePosition=(start[0], start[1], 0.0),
            baseOrientation=q,
            flags=p.URDF_USE_INERTIA_FROM_FILE,
            physicsClientId=self.client,
        )
        self.joints: dict[str, int] = {}
        self.links: dict[str, int] = {}
        for i in range(p.getNumJoints(self.body, physicsClientId=self.client)):
            info = p.getJointInfo(self.body, i, physicsClientId=self.client)
            self.joints[info[1].decode()] = i
            self.links[info[12].decode()] = i
        self.wheel_ids = tuple(self.joints[j] for j in WHEEL_JOINTS)
        apply_contact_dynamics(self.client, self.body, self.spec, floor=self.world.plane)
        # the base's PyBullet frame is its inertial frame; keep the offset to report base_link itself
        dyn = p.getDynamicsInfo(self.body, -1, physicsClientId=self.client)
        self._inertial = (tuple(dyn[3]), tuple(dyn[4]))
        self._inertial_inv = p.invertTransform(dyn[3], dyn[4])
        self.base_mass = float(dyn[0])
        self.base_inertia = tuple(float(v) for v in dyn[2])
        self.servo_joints = {
            name: self.joints[m.joint.name] for name, m in self.spec.mounts.items() if m.joint is not None
        }
        for jid in self.servo_joints.values():
            p.setJointMotorControl2(
                self.body,
                jid,
                p.POSITION_CONTROL,
                targetPosition=0.0,
                force=SERVO_MAX_TORQUE,
                maxVelocity=SERVO_MAX_VELOCITY,
                physicsClientId=self.client,
            )

    def respawn(self, pose: tuple[float, float, float]) -> None:
        """Replace the chair by a new body at rest at ``pose`` (x, y, yaw of ``base_link``), as built.

        The old body goes with everything the physics engine remembers of it (its contact cache
        among them, which ``restoreState`` keeps); the new one has its joints at zero angle and speed,
        the URDF's mass, servos held at 0, and the motors start from rest with the identified plants
        (PID gains kept, its state cleared) and the controller's tick phase restarted. What follows is
        therefore independent of what the chair did before. The body's id may change.
        """
        import pybullet as p

        p.removeBody(self.body, physicsClientId=self.client)
        self._load_body(pose)
        for motor, plant in zip((self.left, self.right), self.nominal_plants, strict=True):
            motor.plant = type(motor.plant)(plant, self.motor_dt)
            motor.reset()
        self._apply_wheel_targets(0.0, 0.0)
        self._step_count = 0

    def set_payload_kg(self, payload_kg: float) -> None:
        """Carry ``payload_kg`` on the seat: the base's mass grows by it, its inertia in proportion."""
        import pybullet as p

        if not (math.isfinite(payload_kg) and payload_kg >= 0):
            raise SimError(f"payload_kg={payload_kg!r}: expected a finite mass >= 0")
        mass = self.base_mass + float(payload_kg)
        inertia = [v * mass / self.base_mass for v in self.base_inertia]
        p.changeDynamics(self.body, -1, mass=mass, localInertiaDiagonal=inertia, physicsClientId=self.client)

    def scale_motor_plants(self, omega_n_scale: tuple[float, float], xi_scale: tuple[float, float]) -> None:
        """Give each wheel motor the identified plant with ``omega_n`` and ``xi`` scaled (left, right).

        The plant's state starts from rest: call this between episodes, not while driving.
        """
        from dataclasses import replace

        from robchair.platform.control import DiscretePlant

        for motor, nominal, kw, kx in zip(
            (self.left, self.right), self.nominal_plants, omega_n_scale, xi_scale, strict=True
        ):
            if not (math.isfinite(kw) and kw > 0 and math.isfinite(kx) and kx > 0):
                raise SimError(f"motor plant scales omega_n x{kw!r}, xi x{kx!r}: expected finite numbers > 0")
            motor.plant = DiscretePlant(replace(nominal, omega_n=nominal.omega_n * kw, xi=nominal.xi * kx),
                                        self.motor_dt)  # fmt: skip

    # -- motors --------------------------------------------------------------------------------------
    def set_closed_loop(self, closed: bool) -> None:
        self.left.closed_loop = self.right.closed_loop = closed

    def set_motor_rpm(self, left_rpm: float, right_rpm: float) -> None:
        """Motor-shaft speed set points (clipped to +-max_motor_rpm)."""
        for v, n in ((left_rpm, "left_rpm"), (right_rpm, "right_rpm")):
            if not math.isfinite(v):
                raise SimError(f"{n} must be finite, got {v!r}")
        lim = self.spec.max_motor_rpm
        self.left.setpoint_rpm = float(np.clip(left_rpm, -lim, lim))
        self.right.setpoint_rpm = float(np.clip(right_rpm, -lim, lim))

    def wheel_speed_rpm(self) -> tuple[float, float]:
        """Measured motor-shaft speeds (left, right) from the wheel joints' velocities."""
        import pybullet as p

        states = p.getJointStates(self.body, self.wheel_ids, physicsClientId=self.client)
        return (self.drive.wheel_to_rpm(states[0][1]), self.drive.wheel_to_rpm(states[1][1]))

    def _apply_wheel_targets(self, left_rpm: float, right_rpm: float) -> None:
        import pybullet as p

        p.setJointMotorControlArray(
            self.body,
            self.wheel_ids,
            p.VELOCITY_CONTROL,
            targetVelocities=[self.drive.rpm_to_wheel(left_rpm), self.drive.rpm_to_wheel(right_rpm)],
            forces=[WHEEL_MAX_FORCE, WHEEL_MAX_FORCE],
            physicsClientId=self.client,
        )

    def _pre_step(self) -> None:
        # controller ticks k at k / motor_rate_hz that fall in [n, n + 1) / physics_hz (integer arithmetic)
        n, rate, hz = self._step_count, self.motor_rate_hz, self.world.physics_hz
        ticks = (n + 1) * rate // hz - n * rate // hz
        if ticks:
            ml, mr = self.wheel_speed_rpm()
            motors = (self.left, self.right)
            if self.compiled_motors and _wheel_kernels.compiled_ok(motors):
                self._apply_wheel_targets(*self._compiled.ticks(motors, ml, mr, ticks))
            else:
                self._apply_wheel_targets(self.left.update(ml, ticks), self.right.update(mr, ticks))
        self._step_count += 1

    def encoder_counts(self) -> tuple[int, int]:
        """Signed 32-bit quadrature x4 counters (left, right) from the accumulated wheel angles."""
        import pybullet as p

        states = p.getJointStates(self.body, self.wheel_ids, physicsClientId=self.client)
        left, right = (wrap_int32(math.floor(self.drive.wheel_angle_to_counts(s[0]))) for s in states)
        return left, right

    # -- poses ---------------------------------------------------------------------------------------
    def base_pose(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """World pose (position, quaternion xyzw) of ``base_link``; raises if the physics diverged."""
        import pybullet as p

        pos, orn = p.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
        pos, orn = p.multiplyTransforms(pos, orn, *self._inertial_inv)
        if not all(map(math.isfinite, (*pos, *orn))):  # plain floats: no arrays for 7 numbers
            raise SimulationDivergedError(
                f"the chair's pose became non-finite at t = {self.world.time:.4f} s (position {pos})"
            )
        return tuple(pos), tuple(orn)  # type: ignore[return-value]

    def pose2d(self) -> Pose2D:
        """Ground-truth planar pose (x, y, yaw) of ``base_link``."""
        pos, orn = self.base_pose()
        return Pose2D(pos[0], pos[1], frames.yaw_from_quat(orn))

    def link_pose(self, name: str) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """World pose of a URDF link frame (``kinect_link``, ``sonar_array_left``, ...)."""
        import pybullet as p

        if name == "base_link":
            return self.base_pose()
        if name not in self.links:
            raise SimError(f"robot has no link {name!r} (links: {', '.join(sorted(self.links))})")
        st = p.getLinkState(
            self.body, self.links[name], computeForwardKinematics=True, physicsClientId=self.client
        )
        return tuple(st[4]), tuple(st[5])  # type: ignore[return-value]

    def link_transform(self, name: str) -> np.ndarray:
        """4x4 world <- link transform."""
        pos, orn = self.link_pose(name)
        return frames.se3_from_quat(pos, orn)

    def link_transforms(self, names: list[str]) -> dict[str, np.ndarray]:
        """``{name: 4x4 world <- link}`` of URDF links (not ``base_link``) from one PyBullet query: the
        values :meth:`link_transform` gives one by one, bit for bit."""
        import pybullet as p

        missing = [n for n in names if n not in self.links]
        if missing:
            raise SimError(f"robot has no link {missing[0]!r} (links: {', '.join(sorted(self.links))})")
        states = p.getLinkStates(
            self.body, [self.links[n] for n in names], computeForwardKinematics=True,
            physicsClientId=self.client,
        )  # fmt: skip
        return {n: frames.se3_from_quat(st[4], st[5]) for n, st in zip(names, states, strict=True)}

    # -- servos --------------------------------------------------------------------------------------
    def set_servo_deg(self, mount: str, angle_deg: float) -> None:
        """Command a sonar-array servo (clipped to its joint limits)."""
        import pybullet as p

        if mount not in self.servo_joints:
            raise SimError(f"no servo on {mount!r} (servos: {', '.join(sorted(self.servo_joints))})")
        if not math.isfinite(angle_deg):
            raise SimError(f"servo angle for {mount!r} must be finite, got {angle_deg!r}")
        j = self.spec.mounts[mount].joint
        assert j is not None
        target = float(np.clip(math.radians(angle_deg), j.lower, j.upper))
        p.setJointMotorControl2(
            self.body,
            self.servo_joints[mount],
            p.POSITION_CONTROL,
            targetPosition=target,
            force=SERVO_MAX_TORQUE,
            maxVelocity=SERVO_MAX_VELOCITY,
            physicsClientId=self.client,
        )

    def servo_deg(self, mount: str) -> float:
        """Current servo angle, degrees."""
        import pybullet as p

        if mount not in self.servo_joints:
            raise SimError(f"no servo on {mount!r} (servos: {', '.join(sorted(self.servo_joints))})")
        return math.degrees(
            p.getJointState(self.body, self.servo_joints[mount], physicsClientId=self.client)[0]
        )

    def contact_normal_forces(self, plane: int) -> dict[str, float]:
        """Sum of normal contact forces (N) between each robot link and ``plane`` (for load checks)."""
        import pybullet as p

        names = {v: k for k, v in self.links.items()}
        names[-1] = "base_link"
        out: dict[str, float] = {}
        for c in p.getContactPoints(self.body, plane, physicsClientId=self.client):
            n = names[c[3]]
            out[n] = out.get(n, 0.0) + c[9]
        return out
