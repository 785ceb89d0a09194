"""What the drive loop and its observers share: the hook protocol and the result types.

:class:`Observer` is the base of the hooks the loop (:class:`robchair.runtime.Runtime`) calls
(dm_control-style lifecycle); :class:`LoopView` is what an observer may read of the loop;
:class:`CycleResult` is what one cycle did and :class:`RunResult` what a run did (its
:meth:`RunResult.metrics` is the ``metrics.json`` schema). The loop and the observers
(:mod:`robchair.observers`) both import this module and not each other.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from hw.interfaces import Backend, MotorState, SonarArrayReading
from robchair.perception import Perception
from robchair.platform.kinematics import DiffDrive, Pose2D
from robchair.platform.safety import SafetyDecision, StopRecord
from robchair.platform.spec import RobChairSpec
from robchair.sources import Command


class LoopView(Protocol):
    """What an observer may read of the loop (:class:`robchair.runtime.Runtime` has all of it).

    Attributes:
        backend: the opened backend the loop drives.
        spec: the platform spec.
        drive: twist <-> wheel RPM of the spec.
        perception: the perception stage (maps, poses of the sensors).
        sonar_names: names of the backend's sonar arrays, in its order.
        t0_ns: the backend clock's time at the start of the run, ns.
        last_sonars: this cycle's sonar readings, ``(name, reading)``.
        last_depth_frame: this cycle's depth frame, or None.
        last_scan: this cycle's laser scan, or None.
        observers: the loop's observers, in call order.
    """

    backend: Backend
    spec: RobChairSpec
    drive: DiffDrive
    perception: Perception
    sonar_names: list[str]
    t0_ns: int
    last_sonars: list[tuple[str, SonarArrayReading]]
    last_depth_frame: Any
    last_scan: Any

    @property
    def observers(self) -> Sequence[Observer]: ...


class Observer:
    """Base class with empty hooks; an exception raised in a hook stops the chair and ends the run."""

    def episode_start(self, runtime: LoopView) -> None:
        """Called once, after the first motor reading and before the first cycle."""

    def before_cycle(self, runtime: LoopView, k: int) -> None:
        """Called at the start of cycle ``k`` (before any sensor is read)."""

    def after_cycle(self, runtime: LoopView, cycle: CycleResult) -> None:
        """Called after the cycle's command was written."""

    def episode_end(self, runtime: LoopView, result: RunResult) -> None:
        """Called once at the end of the run (the chair has been commanded to stop)."""


@dataclass(frozen=True)
class CycleResult:
    """What one cycle did (returned by :meth:`robchair.runtime.Runtime.step`).

    Attributes:
        k: cycle index from 0.
        stamp_ns: the cycle's time on the backend clock.
        pose: odometry pose at the start of the cycle.
        command: the twist the command source (or the caller) asked for.
        decision: what was written, after the safety layer and the write-time checks.
        intervened: the safety layer changed the command (stopped or limited it).
        stops: stop events that began in this cycle.
        done: the command source has finished, or a driver fault ended the run.
        fault: text of a driver fault, if any.
        motor_state: the motor controller's reading at the start of the cycle (None if it failed).
    """

    k: int
    stamp_ns: int
    pose: Pose2D
    command: Command
    decision: SafetyDecision
    intervened: bool
    stops: tuple[StopRecord, ...]
    done: bool
    fault: str | None = None
    motor_state: MotorState | None = None


@dataclass
class RunResult:
    """What a run did; :meth:`metrics` is the ``metrics.json`` schema, the same for every backend."""

    backend: str
    safety_enabled: bool = True
    cycles: int = 0
    sim_time_s: float = 0.0
    loop_wall_s: float = 0.0
    loop_cpu_s: float = 0.0  # the process's CPU seconds (every thread) over the loop
    deadline_misses: int = 0
    max_overrun_s: float = 0.0
    final_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    distance_m: float = 0.0
    route_completed: bool | None = None
    max_cross_track_m: float | None = None
    stops: list[dict[str, Any]] = field(default_factory=list)
    driver_fault: str | None = None
    error: str | None = None
    limited_cycles: int = 0
    min_sonar_distance_m: float | None = None  # nearest obstacle ahead the sonars reported
    min_map_distance_m: float | None = None  # nearest depth point ahead in the height band
    map_frames: int = 0
    watchdog_ms: int | None = None
    watchdog_trips: int = 0
    poses: list[tuple[float, float, float, float]] = field(default_factory=list)  # (t, x, y, theta)
    extra: dict[str, Any] = field(default_factory=dict)  # observers' sections (sim ground truth ...)
    maps: dict[str, Any] = field(default_factory=dict)  # the perception's maps (and observers')
    paths: dict[str, np.ndarray] = field(default_factory=dict)  # (N, 3) x, y, yaw per cycle; "t" ns
    out_dir: Path | None = None  # the run folder, when one was written
    exception: BaseException | None = None  # what ended the run early (raised after the folder was written)

    def metrics(self) -> dict[str, Any]:
        """The ``metrics.json`` document (one schema: keys a backend cannot fill are null)."""
        counts: dict[str, int] = {}
        for s in self.stops:
            counts[s["reason"]] = counts.get(s["reason"], 0) + 1
        m: dict[str, Any] = {
            "backend": self.backend,
            "status": "error" if self.error else "ok",
            "error": self.error,
            "cycles": self.cycles,
            "sim_time_s": self.sim_time_s,
            "real_time_factor": self.sim_time_s / self.loop_wall_s if self.loop_wall_s > 0 else None,
            "wall_time_s": {"loop": self.loop_wall_s},
            "cpu_time_s": {"loop": self.loop_cpu_s},
            "deadline_misses": self.deadline_misses,
            "max_overrun_s": self.max_overrun_s,
            "final_pose": list(self.final_pose),
            "route": {
                "goal_reached": self.route_completed,
                "distance_travelled_m": self.distance_m,  # odometry; the sim replaces it by the truth
                "odometry_distance_m": self.distance_m,
                "max_cross_track_m": self.max_cross_track_m,
            },
            "safety": {
                "enabled": self.safety_enabled,
                "stops": self.stops,
                "stop_counts": counts,
                "limited_cycles": self.limited_cycles,
                "min_sonar_distance_m": self.min_sonar_distance_m,
                "min_map_distance_m": self.min_map_distance_m,
            },
            "controller": {"watchdog_ms": self.watchdog_ms, "watchdog_trips": self.watchdog_trips},
            "driver_fault": self.driver_fault,
            "collisions": None,
            "odometry_drift": None,
            "map": {"depth_frames": self.map_frames},
        }
        for k, v in self.extra.items():
            if isinstance(v, dict) and isinstance(m.get(k), dict):
                m[k] = {**m[k], **v}
            else:
                m[k] = v
        return m
