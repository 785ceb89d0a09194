"""The simulated chair behind the hardware interfaces (DESIGN.md section 3): same Protocols as the drivers.

:class:`sim.chair.SimChair` bundles a :class:`sim.world.World`, the scene, the :class:`sim.robot.SimRobot`
and the simulated sensors. The devices below implement :mod:`hw.interfaces` over it, so the runtime
cannot tell it from the real chair:

* :class:`SimClock` - simulated time; ``sleep_until_ns`` *advances the physics* to that time (the
  runtime's loop therefore drives the simulation exactly as it waits for the real chair), serving
  the motor controller's serial watchdog on the way.
* :class:`SimMotorController` - closed-loop speed mode over the plant + PID motors, encoder counters,
  emergency stop (``!EX``: set points forced to 0 until ``!MG``), serial watchdog (``^RWD``).
* :class:`SimDepthCamera` - the simulated Kinect at ``kinect_link``'s current world pose, with
  background capture (``submit_read``).
* :class:`SimSonarArray` - three simulated sonars on the array's servo joint.

Powers only a simulation has (ground truth, contacts, teleport, an exact restart, friction and payload)
are domain-named methods of :class:`sim.chair.SimChair` (re-exported here).

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
from robchair.platform.config import ConfigSource, ConfigTable
from robchair.platform.spec import load_spec
from sim.chair import SONAR_MOUNTS, SONAR_NOISE_STD_M, SimChair, robot_radius
from sim.errors import SimError
from sim.scene import load_scene

__all__ = [
    "SONAR_MOUNTS",
    "SONAR_NOISE_STD_M",
    "SimBackend",
    "SimChair",
    "SimClock",
    "SimDepthCamera",
    "SimMotorController",
    "SimSonarArray",
    "backend_from_chair",
    "make_sim_backend",
    "robot_radius",
]


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
        from robchair.platform.control import DiscretePID

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
        ranges = self.chair.sonars[self.mount].finish(self.chair.sonar_raw(self.mount))
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
    :class:`sim.errors.SimError` (or the error class of a
    :class:`robchair.platform.config.ConfigTable`'s source, whose file and line the message then names),
    in the :mod:`robchair.platform.config` dialect.

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
        from robchair.platform.paths import SCENES

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
