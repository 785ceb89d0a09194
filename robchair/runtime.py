"""The runtime: the one fixed-rate loop that senses, maps, decides, passes the safety layer and drives.

The same loop drives the simulated chair, the emulated one and the real one
(:mod:`robchair.backends`); it only sees :class:`hw.interfaces.Backend`. One cycle ``k``, scheduled at
``t_k = t_0 + k / rate_hz`` on the backend's clock:

1. **sense**: motor state -> odometry; every ``sonar_every`` cycles each sonar array, every
   ``camera_every`` cycles the depth camera, every cycle the laser scanner, each into the perception
   stage (:class:`robchair.perception.Perception`: maps, corridor distances);
2. **decide**: the command source (route follower, joystick, policy) or the command given to
   :meth:`Runtime.step` gives a body twist (v, w);
3. **safety**: :class:`robchair.platform.safety.SafetyLayer` limits or stops it;
4. **write**: at the moment of writing, the freshness of every sensor and the cycle's deadline are
   checked again (a cycle that outlived them commands zero), as is the gap since the last command
   against the controller's watchdog (a gap longer than the watchdog means it tripped: a stop reason);
   then twist -> wheel RPM (:class:`robchair.platform.kinematics.DiffDrive`) -> ``set_speeds_rpm`` (every
   cycle: only commands feed the controller's watchdog);
5. **observers** (:mod:`robchair.observers`) are called; then the loop **waits** for ``t_{k+1}``. A
   cycle that ends after its period plus ``deadline_slack`` is a missed deadline: the next cycle stops
   the chair and the schedule restarts from now (no catch-up burst).

Any exception in a cycle (sensor, perception, command source, observer, motors) stops the motors
(zero speeds, then the emergency stop) before it propagates, as :class:`LoopAborted` naming the stage
and the cause. A driver fault (:class:`hw.errors.HardwareError` from the motors or fault flags) stops
the chair, is latched by the safety layer and ends the run.

Single-step use (a Gymnasium env, a test)::

    rt = Runtime(backend, source, ...)   # backend already opened
    rt.start()
    while not done:
        cycle = rt.step(Command(v, w))    # or rt.step() to ask the command source
    result = rt.stop()

The observers' hook, what they read of the loop and the result types are in :mod:`robchair.loop_types`;
a run into a run folder (the recording observers, ``metrics.json``) is :func:`robchair.run_output.run_to_dir`.
"""

from __future__ import annotations

import logging
import time
import weakref
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from hw.errors import HardwareError
from hw.interfaces import Backend, MotorState, SonarArrayReading
from hw.laser_scan import scan_to_points
from hw.messages import MotorFaults
from robchair.loop_types import CycleResult, Observer, RunResult
from robchair.perception import Perception
from robchair.platform.errors import ConfigError, RobChairError, StopSignal
from robchair.platform.kinematics import DiffDrive, Odometry, Pose2D
from robchair.platform.safety import (
    Footprint,
    SafetyDecision,
    SafetyInputs,
    SafetyLayer,
    SafetyLimits,
    StopReason,
)
from robchair.platform.spec import RobChairSpec
from robchair.route import PurePursuit
from robchair.runtime_config import RuntimeConfig, check_duration_s
from robchair.runtime_helpers import _has_servo, _min_or, _planar
from robchair.sources import Command, CommandSource, Observation

__all__ = ["LoopAborted", "Runtime"]

log = logging.getLogger(__name__)

#: The started, not yet stopped runtimes of this process (for :func:`halt_running_loops`).
_RUNNING: weakref.WeakSet[Runtime] = weakref.WeakSet()


def halt_running_loops(cause: BaseException) -> None:
    """Zero speeds, then the emergency stop, on every started and not yet stopped runtime.

    For a stop signal that cannot be raised where it arrived (:func:`robchair.cli.stop_signals_raise`
    defers one that arrives while numba compiles): the motors stop now, the exception comes later and
    finds the loop halted. Call it only from the thread that runs the loops, outside their driver calls.
    """
    for runtime in list(_RUNNING):
        if runtime._started and not runtime._stopped:
            runtime._halt(cause)


DEPTH_CAMERA = "depth_camera"
_NO_FAULTS = MotorFaults()
WATCHDOG_PERIODS_MIN = 1.5
WATCHDOG_PERIODS_MAX = 10.0


class LoopAborted(RobChairError):
    """An exception inside a cycle ended the run; the motors were stopped before this was raised."""


class Runtime:
    """The loop over an *opened* backend.

    Args:
        backend: sim, emulated or real (:func:`robchair.backends.get_backend`), already opened.
        source: the command source (may be None when every :meth:`step` is given a command).
        spec: platform spec (default: load it).
        config: loop settings.
        safety: the safety layer (default: limits from the spec).
        perception: the perception stage (default: one with default maps).
        observers: called at the lifecycle hooks, in order.
        start_pose: pose of the odometry at the start (e.g. a scenario's start in ``map``).
        safety_enabled: False passes commands through (wheel limits only), for ground-truth studies;
            exceptions and driver faults still stop the chair.

    Raises:
        ConfigError: the motor controller's watchdog is outside 1.5-10 loop periods.
    """

    def __init__(self, backend: Backend, source: CommandSource | None = None, *,
                 spec: RobChairSpec | None = None, config: RuntimeConfig | None = None,
                 safety: SafetyLayer | None = None, perception: Perception | None = None,
                 observers: Sequence[Observer] = (), start_pose: Pose2D | None = None,
                 safety_enabled: bool = True) -> None:  # fmt: skip
        from robchair.platform.spec import load_spec

        self.backend = backend
        self.source = source
        self.spec = spec if spec is not None else load_spec()
        self.config = config or RuntimeConfig()
        self.drive = DiffDrive(self.spec)
        self.safety = (
            safety
            if safety is not None
            else SafetyLayer(
                SafetyLimits.from_spec(self.spec), self.spec.wheel_separation, Footprint.from_spec(self.spec)
            )
        )
        self.safety_enabled = bool(safety_enabled)
        self.perception = (
            perception if perception is not None else Perception(self.spec, map_kind=self.config.map_kind)
        )
        self.observers = list(observers)
        self.odometry = Odometry(self.spec, start_pose)
        self.period_ns = round(1e9 / self.config.rate_hz)
        self.watchdog_ms: int | None = getattr(backend.motors, "watchdog_ms", None)
        if self.watchdog_ms is not None:
            periods = self.watchdog_ms * 1e6 / self.period_ns
            if not WATCHDOG_PERIODS_MIN <= periods <= WATCHDOG_PERIODS_MAX:
                p_ms = self.period_ns / 1e6
                raise ConfigError(
                    f"controller watchdog_ms = {self.watchdog_ms} is {periods:.2f} periods of the "
                    f"{p_ms:g} ms loop ({self.config.rate_hz:g} Hz); expected {WATCHDOG_PERIODS_MIN:g}-"
                    f"{WATCHDOG_PERIODS_MAX:g} periods ({WATCHDOG_PERIODS_MIN * p_ms:g}-"
                    f"{WATCHDOG_PERIODS_MAX * p_ms:g} ms)"
                )
        names = [getattr(a, "name", f"sonar_array_{i}") for i, a in enumerate(backend.sonar_arrays)]
        self.sonar_names = [n.removeprefix("sim-") for n in names]
        self.result = RunResult(backend=backend.name, safety_enabled=self.safety_enabled,
                                watchdog_ms=self.watchdog_ms)  # fmt: skip
        self.k = 0
        self.t0_ns = 0
        self.last_sonars: list[tuple[str, SonarArrayReading]] = []
        self.last_depth_frame: Any = None
        self.last_scan: Any = None
        self._last_fresh: dict[str, int] = {}
        self._next_ns = 0
        self._missed = False
        self._fault: str | None = None
        self._last_motion_ns: int | None = None  # time of the last non-zero speed command
        self._stage = "start"
        self._started = False
        self._stopped = False
        self._halted = False  # zero speeds and the emergency stop were sent after an exception
        self._halt_ok = False  # ... and both were acknowledged
        self._wall0 = 0.0
        self._cpu0 = 0.0

    # --- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        """Take the first motor reading, start the schedule and call the observers' episode start."""
        if self._started:
            raise RobChairError("runtime already started")
        self._started = True
        _RUNNING.add(self)
        self._guard("motors", self._start)

    def _start(self) -> None:
        clock = self.backend.clock
        warm_up = getattr(self.perception, "warm_up", None)
        if warm_up is not None:  # compiled kernels load before the clock starts, not in cycle 0
            self._stage = "perception (warm-up)"
            warm_up()
            self._stage = "motors"
        self.t0_ns = self._next_ns = clock.now_ns()
        for name in (*self.sonar_names, DEPTH_CAMERA):
            self._last_fresh[name] = self.t0_ns
        state, self._fault = self._read_motors()
        if state is not None:
            self.odometry.update(*state.encoder_counts)
        bind = getattr(self.source, "bind", None)
        if bind is not None:  # a stage that reads the loop's perception (the assistance)
            self._stage = "command source"
            bind(self)
        self._wall0 = time.perf_counter()
        self._cpu0 = time.process_time()
        self._stage = "observer"
        for ob in self.observers:
            ob.episode_start(self)
        self._next_ns = clock.now_ns()  # cycle 0's period starts after the observers' setup (a bag opened)

    def step(self, command: Command | None = None) -> CycleResult:
        """Run one cycle (sense, decide, safety, write, observers, wait for the next cycle's time).

        Args:
            command: the twist to drive this cycle; None asks the command source.

        Raises:
            LoopAborted: anything raised inside the cycle (after the motors were stopped).
        """
        if not self._started or self._stopped:
            raise RobChairError("runtime not running: call start() first (and not after stop())")
        return self._guard(self._stage, self._cycle, command)  # type: ignore[no-any-return]

    def stop(self) -> RunResult:
        """Command zero, finish perception and call the observers' episode end; returns the result.

        Safe to call more than once and after an aborted cycle.
        """
        if self._stopped:
            return self.result
        self._stopped = True
        _RUNNING.discard(self)
        res = self.result
        try:
            if self._fault is None and self._started:
                try:
                    self.backend.motors.set_speeds_rpm(0.0, 0.0)
                except HardwareError as exc:
                    res.driver_fault = f"{type(exc).__name__}: {exc}"
        finally:
            res.loop_wall_s = time.perf_counter() - self._wall0 if self._started else 0.0
            res.loop_cpu_s = time.process_time() - self._cpu0 if self._started else 0.0
            try:
                self.perception.close()
            finally:
                self._finish_result()
                for ob in self.observers:
                    ob.episode_end(self, res)
        return res

    def reset(self, start_pose: Pose2D | None = None, perception: Perception | None = None) -> None:
        """Make the runtime ready for a new episode (call :meth:`start` next).

        Stops the current episode if it runs, then starts a fresh result, odometry at ``start_pose``,
        an unlatched safety layer with an empty stop log, and (if given) a new perception stage. The
        chair itself is not moved: a simulated chair is placed first (``SimChair.restart``: exact).
        """
        if self._started and not self._stopped:
            self.stop()
        if perception is not None:
            self.perception = perception
        self.odometry = Odometry(self.spec, start_pose)
        self.safety.reset()
        self.safety.stops.clear()
        self.result = RunResult(backend=self.backend.name, safety_enabled=self.safety_enabled,
                                watchdog_ms=self.watchdog_ms)  # fmt: skip
        self.k = 0
        self.last_sonars, self.last_depth_frame, self.last_scan = [], None, None
        self._last_fresh.clear()
        self._missed, self._fault, self._last_motion_ns = False, None, None
        self._stage, self._started, self._stopped, self._halted = "start", False, False, False

    def run(self, duration_s: float) -> RunResult:
        """Run for ``duration_s`` seconds of the backend's clock, until the source is done or a driver
        fault ends it; the chair is stopped however the run ends."""
        duration_s = check_duration_s(duration_s)
        n_cycles = max(1, round(duration_s * self.config.rate_hz))
        end_ns = None
        try:
            self.start()
            end_ns = self.t0_ns + round(duration_s * 1e9)
            for _ in range(n_cycles):
                cycle = self.step()
                if cycle.done or self.backend.clock.now_ns() >= end_ns:
                    break
        except BaseException as exc:
            self.result.error = f"{type(exc).__name__}: {exc}"
            if self._started and not self._halted:  # raised between cycles: stop the motors first
                self._halt(exc)
            elif isinstance(exc, StopSignal):  # halted already (by the signal handler, see cli.py)
                exc.motors_stopped = self._halt_ok
            raise
        finally:
            self.stop()
        return self.result

    # --- one cycle ------------------------------------------------------------------------------

    def _guard(self, stage: str, fn: Any, *args: Any) -> Any:
        try:
            return fn(*args)
        except BaseException as exc:
            stage = self._stage
            self._halt(exc)
            if isinstance(exc, LoopAborted | KeyboardInterrupt | SystemExit):
                raise
            t = (self.backend.clock.now_ns() - self.t0_ns) / 1e9 if self.t0_ns else 0.0
            raise LoopAborted(
                f"{stage} failed in cycle {self.k} (t = {t:.2f} s): {type(exc).__name__}: {exc}; "
                "motors commanded to zero and emergency-stopped"
            ) from exc

    def _halt(self, cause: BaseException) -> None:
        """Zero speeds, then the emergency stop, after ``cause`` ended the run (a StopSignal learns
        whether both were sent)."""
        self._halted = True
        self._halt_ok = False
        motors, ok = self.backend.motors, True
        try:
            motors.set_speeds_rpm(0.0, 0.0)
        except Exception as exc:
            ok = False
            log.error("zero speed command failed: %s", exc)
        try:
            motors.emergency_stop()
        except Exception as exc:
            ok = False
            log.error("emergency stop could not be confirmed: %s", exc)
        self._halt_ok = ok
        if isinstance(cause, StopSignal):
            cause.motors_stopped = ok

    def _cycle(self, command: Command | None) -> CycleResult:
        clock = self.backend.clock
        res = self.result
        k = self.k
        cycle_start = self._next_ns
        self._stage = "observer"
        for ob in self.observers:
            ob.before_cycle(self, k)
        now = clock.now_ns()
        self._stage = "motors"
        state, motor_fault = self._read_motors()
        self._fault = self._fault or motor_fault
        pose = self.odometry.update(*state.encoder_counts) if state is not None else self.odometry.pose
        self._sense(k, now, pose)
        p = self.perception
        sonar_d = p.sonar_distance_m()
        map_d = p.depth_distance_m(pose)
        res.min_sonar_distance_m = _min_or(res.min_sonar_distance_m, sonar_d)
        res.min_map_distance_m = _min_or(res.min_map_distance_m, map_d)
        dists = [d for d in (sonar_d, map_d) if d is not None]
        if command is None:
            if self.source is None:
                raise RobChairError("no command given and the runtime has no command source")
            self._stage = "command source"
            obs = Observation(now, pose, state, tuple(r for _, r in self.last_sonars),
                              min(dists) if dists else None)  # fmt: skip
            try:
                command = self.source.command(obs)
            except HardwareError as exc:  # the joystick failed: treat it as a released dead-man
                log.warning("command source failed: %s", exc)
                command = Command(0.0, 0.0, deadman=False)
        n_stops = len(self.safety.stops)
        dt = self.period_ns / 1e9
        self._stage = "safety layer"
        if self.safety_enabled:
            inputs = SafetyInputs(
                stamp_ns=now,
                sonar_distance_m=sonar_d,
                map_distance_m=map_d,
                deadline_missed=self._missed,
                stale_sensors=self._stale(now),
                driver_fault=self._fault,
                deadman=command.deadman,
                obstacles_xy=p.obstacle_points_base(pose),
            )
            decision = self.safety.filter(command.v, command.w, inputs, dt)
        elif self._fault is not None:
            decision = self.safety.filter(0.0, 0.0, SafetyInputs(stamp_ns=now, driver_fault=self._fault), dt)
        else:
            decision = SafetyDecision(*self.drive.limit(command.v, command.w))
        res.limited_cycles += decision.limited
        self._stage = "motors"
        decision = self._write(decision, cycle_start, dt)
        intervened = decision.stop is not None or decision.limited
        new_stops = tuple(self.safety.stops[n_stops:])
        if isinstance(self.source, PurePursuit):
            cte = self.source.cross_track_error(pose)
            res.max_cross_track_m = max(res.max_cross_track_m or 0.0, cte)
        res.poses.append(((now - self.t0_ns) / 1e9, pose.x, pose.y, pose.theta))
        res.cycles = k + 1
        done = bool(command.done)
        if self._fault is not None:
            res.driver_fault = self._fault
            self._stop_hard()
            if self.config.stop_on_driver_fault:
                log.error("run ended by a driver fault: %s", self._fault)
                done = True
        cycle = CycleResult(k, now, pose, command, decision, intervened, new_stops, done, self._fault, state)
        self._stage = "observer"
        for ob in self.observers:
            ob.after_cycle(self, cycle)
        self._stage = "clock"
        self.k += 1
        end = clock.now_ns()
        self._next_ns = cycle_start + self.period_ns
        overrun = end - self._next_ns
        self._missed = overrun > round(self.period_ns * self.config.deadline_slack)
        if self._missed:
            res.deadline_misses += 1
            res.max_overrun_s = max(res.max_overrun_s, overrun / 1e9)
            log.warning("cycle %d overran its period by %.1f ms", k, overrun / 1e6)
            self._next_ns = end  # restart the schedule from now: no burst of catch-up cycles
        if not done:
            clock.sleep_until_ns(self._next_ns)
        return cycle

    def _sense(self, k: int, now: int, pose: Pose2D) -> None:
        cfg, b, p = self.config, self.backend, self.perception
        self.last_sonars = []
        if cfg.sonar_every and k % cfg.sonar_every == 0:
            for name, arr in zip(self.sonar_names, b.sonar_arrays):
                self._stage = f"sonar array {name}"
                try:
                    r = arr.read()
                except HardwareError as exc:
                    log.info("%s: read failed: %s", name, exc)
                    continue
                failing = getattr(arr, "consecutive_errors", (0, 0, 0))
                if all(c > 0 for c in failing):
                    continue  # every sonar of the array failed this time: no fresh data
                self._last_fresh[name] = now
                self.last_sonars.append((name, r))
                self._stage = "perception (sonar)"
                servo = p.add_sonar(name, r, pose)
                if servo is not None and _has_servo(arr):
                    self._stage = f"sonar array {name} servo"
                    arr.set_servo_deg(servo)
        cam = b.depth_camera
        if cam is not None and cfg.camera_every and k % cfg.camera_every == 0:
            self._stage = "depth camera"
            try:
                frame = p.take_depth(cam, pose)
            except HardwareError as exc:
                log.info("depth camera: %s", exc)
                frame = None
            if frame is not None:
                self._last_fresh[DEPTH_CAMERA] = min(now, frame.stamp_ns) if frame.stamp_ns else now
                self.last_depth_frame = frame
                self.result.map_frames += 1
        laser = getattr(b, "laser_scanner", None)  # a backend with a laser carries it by this name
        if laser is not None:
            self._stage = "laser scanner"
            try:
                scan = laser.read()
            except HardwareError as exc:
                log.info("laser scanner: %s", exc)
            else:
                self.last_scan = scan
                self._stage = "perception (laser)"
                p.add_scan(scan.frame_id, scan_to_points(scan), pose)

    def _read_motors(self) -> tuple[MotorState | None, str | None]:
        try:
            state = self.backend.motors.read_state()
        except HardwareError as exc:
            return None, f"{type(exc).__name__}: {exc}"
        if state.faults != _NO_FAULTS and state.faults.any:  # no flag set: nothing to name
            return state, f"motor controller fault flags {state.faults.names()}"
        return state, None

    def _stale(self, now_ns: int) -> tuple[str, ...]:
        limit = round(self.safety.limits.stale_after_s * 1e9)
        cfg = self.config
        out = []
        if cfg.sonar_every:
            sonar_limit = limit + (cfg.sonar_every - 1) * self.period_ns
            out = [n for n in self.sonar_names if now_ns - self._last_fresh.get(n, now_ns) > sonar_limit]
        cam = self.backend.depth_camera
        if cam is not None and cfg.camera_every:
            # read every camera_every cycles, delivered max_inflight reads later: allow for that
            lag = cfg.camera_every * (1 + int(getattr(cam, "max_inflight", 0)))
            if now_ns - self._last_fresh.get(DEPTH_CAMERA, now_ns) > limit + lag * self.period_ns:
                out.append(DEPTH_CAMERA)
        return tuple(out)

    def _write(self, decision: SafetyDecision, cycle_start_ns: int, dt: float) -> SafetyDecision:
        """Check the watchdog gap, the deadline and freshness *now*, then write the wheel speeds."""
        now = self.backend.clock.now_ns()
        wants_motion = decision.v != 0.0 or decision.w != 0.0
        if self._fault is None:
            wd = self.watchdog_ms
            if wd is not None and self._last_motion_ns is not None and now - self._last_motion_ns > wd * 1e6:
                gap_ms = (now - self._last_motion_ns) / 1e6
                self.result.watchdog_trips += 1
                decision = self.safety.stop_now(
                    now, StopReason.CONTROLLER_WATCHDOG,
                    f"no speed command for {gap_ms:.0f} ms > controller watchdog {wd} ms: the controller "
                    "stopped the motors",
                )  # fmt: skip
            if self.safety_enabled and wants_motion:
                late = now - (
                    cycle_start_ns + self.period_ns + round(self.period_ns * self.config.deadline_slack)
                )
                stale = self._stale(now)
                if late > 0:
                    decision = self.safety.stop_now(
                        now, StopReason.DEADLINE_MISSED,
                        f"the cycle outlived its deadline by {late / 1e6:.0f} ms before writing",
                    )  # fmt: skip
                elif stale:
                    decision = self.safety.stop_now(
                        now, StopReason.STALE_SENSOR, f"no fresh data from {', '.join(stale)} when writing"
                    )
        left, right = 0.0, 0.0
        if self._fault is None:
            # the one exact wheel limit: the safety layer's speed diamond can round a full-speed twist
            # to one ulp above the motor cap, which the motor driver must refuse
            v, w = self.drive.limit(decision.v, decision.w)
            if (v, w) != (decision.v, decision.w):
                decision = replace(decision, v=v, w=w)
            left, right = self.drive.motor_rpm(v, w)
        try:
            self.backend.motors.set_speeds_rpm(left, right)
        except HardwareError as exc:
            self._fault = f"{type(exc).__name__}: {exc}"
            decision = self.safety.filter(0.0, 0.0, SafetyInputs(stamp_ns=now, driver_fault=self._fault), dt)
            return decision
        self._last_motion_ns = now if (left != 0.0 or right != 0.0) else None
        return decision

    def _stop_hard(self) -> None:
        try:
            self.backend.motors.emergency_stop()
        except HardwareError as exc:
            log.error("emergency stop could not be confirmed: %s", exc)

    def _finish_result(self) -> None:
        res = self.result
        clock = self.backend.clock
        res.sim_time_s = (clock.now_ns() - self.t0_ns) / 1e9 if self._started else 0.0
        pose = self.odometry.pose
        res.final_pose = (pose.x, pose.y, pose.theta)
        res.distance_m = self.odometry.distance
        if isinstance(self.source, PurePursuit):
            res.route_completed = self.source.done
        res.stops = [
            {"t_s": (s.stamp_ns - self.t0_ns) / 1e9, "reason": s.reason.value, "detail": s.detail}
            for s in self.safety.stops
        ]
        p = self.perception
        res.maps["odometry"] = p.map
        for name, m in getattr(p, "pose_maps", {}).items():  # odometry, matched, ground truth
            res.maps[name.replace("-", "_")] = m
        res.extra.setdefault("map", {})["kind"] = getattr(p, "map_kind", None)
        if p.sonar_map is not p.map:
            res.maps["sonar"] = p.sonar_map
        ms = np.asarray(p.map_ms) if p.map_ms else np.array([np.nan])
        res.extra["frames"] = dict(p.stats)
        res.extra["mapping_ms_per_frame_median"] = float(np.median(ms)) if p.map_ms else None
        res.extra["mapping_ms_total"] = float(np.sum(ms)) if p.map_ms else 0.0
        res.extra["mapping_s_by_layer"] = dict(getattr(p, "layer_s", {}))
        zoom = getattr(p, "zoom", None)
        if zoom is not None and zoom.fine is not None:
            res.maps["zoom"] = zoom.fine
            res.extra["zoom"] = {"region_m": list(zoom.region), "cell_size_m": zoom.fine_cell_size,
                                 "structures": zoom.fine.n_structures}  # fmt: skip
        matcher = getattr(p, "matcher", None)
        if matcher is not None:
            mm = np.asarray(p.match_ms) if p.match_ms else np.array([np.nan])
            res.extra["matching"] = {
                "pose": p.pose,
                "frames": len(p.match_ms),
                "accepted": p.stats["matches_accepted"],
                "rejected": dict(sorted(matcher.rejections.items())),
                "ms_per_frame_median": float(np.median(mm)) if p.match_ms else None,
                "ms_per_frame_p90": float(np.percentile(mm, 90)) if p.match_ms else None,
                "t_map_odom_final": [float(v) for v in _planar(p.t_map_odom)],
            }
        poses = np.asarray(res.poses, dtype=np.float64).reshape(-1, 4)
        res.paths["odometry"] = poses[:, 1:]
        trips = getattr(self.backend.motors, "watchdog_trips", None)
        if isinstance(trips, int):  # the controller counts its own trips (simulated chair)
            res.watchdog_trips = max(res.watchdog_trips, trips)
