"""The safety layer between a command source and the motors: limits, stops, and a log of every stop.

Every cycle the runtime hands :meth:`SafetyLayer.filter` the wanted body twist (v m/s, w rad/s) and
what it knows about the world and itself (:class:`SafetyInputs`). The layer

1. stops (v = w = 0) when any stop condition holds, in this order of precedence:
   ``driver_fault`` (latched: only :meth:`SafetyLayer.reset` clears it), ``deadline_missed`` (the
   previous cycle overran its period, or this one outlived its deadline before writing),
   ``stale_sensor`` (a sensor gave nothing new for longer than ``stale_after_s``),
   ``deadman_released`` (joystick), ``obstacle_sonar`` / ``obstacle_map`` (an
   obstacle ahead closer than the stopping distance for the speed the chair would have), and, after
   the limits of 2., ``obstacle_swept`` (3.);
2. otherwise limits the twist: speed and yaw rate to the platform maximum (scaled uniformly so the
   motors stay within ``max_motor_rpm``, keeping the curve) and to the configured caps, then the
   change per cycle to the acceleration limits: of the body (``max_accel``, ``max_yaw_accel``) and of
   each wheel (``max_wheel_accel``, the ramp the motor speed loop follows without a loop-error stop).

Stopping distance grows with speed: ``d_stop(v) = margin + v * reaction_time + v**2 / (2 * brake_decel)``.
Obstacle distances are measured from the front of the chair (sonar ranges from the sonar face, map
distances from the footprint's front edge), so ``margin`` is the gap left when stopped. These two
distances look forward only and apply while the wanted or current speed is forward.

3. then checks the footprint the limited twist would sweep (:func:`swept_clearance`) against the
   obstacle points the perception keeps around the chair (``SafetyInputs.obstacles_xy``: its local
   map, laser scan and sonar arcs, beside and behind the chair too), for every motion: forward,
   reverse, an arc, or a turn in place, whose front corners (the footrests) swing out beside the
   chair. The sweep is the arc of constant curvature the twist would follow over its stopping time
   (the reaction time, then braking at ``brake_decel`` at the rim: ``2 brake_decel / b`` rad/s^2 in
   yaw). The clearance (the nearest point's distance to the footprint) may not fall below
   ``sweep_margin_m`` along the sweep, unless it is below already: then the motion may not lower it
   any further (so a chair beside a wall can always turn or drive away from it, or along it: it is
   never trapped). When the twist fails, it is scaled down along the same
   curve (to :data:`SWEEP_SCALES` of itself, the first that passes; a shorter stop needs less room);
   when none passes, the chair stops with ``obstacle_swept``. The scale is recorded in the decision
   (``SafetyDecision.swept_scale``).

The runtime adds stops found when the command is about to be written (:meth:`SafetyLayer.stop_now`):
a deadline or freshness limit passed while the cycle ran, or a gap since the last command longer than
the motor controller's watchdog (``controller_watchdog``: the controller has stopped the motors).

A stop is logged (``logging.warning``, or at :attr:`SafetyLayer.log_level`) and recorded in
:attr:`SafetyLayer.stops` once when it starts, with its reason and a detail text; it is not logged
again while the same reason persists.
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robchair.platform.config import ConfigTable, bounds, check_dataclass, load_dataclass
from robchair.platform.spec import RobChairSpec

log = logging.getLogger(__name__)


class StopReason(enum.StrEnum):
    DRIVER_FAULT = "driver_fault"
    DEADLINE_MISSED = "deadline_missed"
    STALE_SENSOR = "stale_sensor"
    DEADMAN_RELEASED = "deadman_released"
    OBSTACLE_SONAR = "obstacle_sonar"
    OBSTACLE_MAP = "obstacle_map"
    CONTROLLER_WATCHDOG = "controller_watchdog"
    OBSTACLE_SWEPT = "obstacle_swept"


#: the fractions of a twist the swept-footprint check tries, largest first, before it stops
SWEEP_SCALES = (1.0, 0.5, 0.25, 0.1)
#: a point closer than the margin already may come this much closer along a sweep (m): the rounding
#: of a motion that keeps its distance (driving parallel to a wall)
SWEEP_KEEP_TOL_M = 1e-6
#: the longest step between the sampled poses of a sweep, of any footprint point (m); at most
#: :data:`SWEEP_MAX_POSES` poses (then the step is longer, and the bound below wider)
SWEEP_STEP_M = 0.01
SWEEP_MAX_POSES = 64
#: the step of the coarse pass that sorts out the points far from the sweep, m
SWEEP_COARSE_STEP_M = 0.05


@dataclass(frozen=True)
class SafetyLimits:
    """Limits of the safety layer. Speeds default to the platform's maxima (set from the spec).

    Attributes:
        max_speed: |v| cap, m/s (the platform maximum is 0.62 m/s for 1000 RPM / 29, r = 0.172 m).
        max_yaw_rate: |w| cap, rad/s.
        max_accel: |dv/dt| while not stopping, m/s^2 (a comfortable value for a seated person).
        max_yaw_accel: |dw/dt|, rad/s^2.
        max_wheel_accel: |d/dt| of each wheel's rim speed ``v -+ w b / 2``, m/s^2. The Roboteq speed
            loop (SPEC 5 design, type 1) follows a ramp of ``a`` motor RPM/s ``a / (K k_i)`` RPM behind
            (plant gain K = 1, k_i = 3.2 /s on channel 2 in firmware 1.x units, 3.7 /s on channel 1);
            the controller stops a channel whose error stays above 250 RPM for 500 ms (``^CLERD`` level
            2, the manual's default, which the driver writes). 0.4 m/s^2 is 644 motor RPM/s
            (x 60 / (2 pi 0.172 m) x 29), a 201 RPM lag: 80 % of that threshold. The body limits alone
            let a wheel ramp at ``max_accel + max_yaw_accel b / 2`` = 0.935 m/s^2 (1505 RPM/s, a
            470 RPM lag), which trips the loop-error stop.
        brake_decel: deceleration assumed when braking, m/s^2 (for the stopping distance).
        reaction_time_s: delay before braking starts (one loop + controller + plant lag), s.
        margin_m: gap kept to an obstacle when stopped, m.
        sweep_margin_m: gap kept between the footprint and any obstacle point along the swept
            footprint of the commanded twist (beside and behind too), m. Small: the chair (0.64 m wide)
            passes doorways of 0.80 m, 8 cm each side.
        stale_after_s: a sensor older than this stops the chair, s.
    """

    max_speed: float = field(default=0.62, metadata=bounds(gt=0))
    max_yaw_rate: float = field(default=2.14, metadata=bounds(gt=0))
    max_accel: float = field(default=0.5, metadata=bounds(gt=0))
    max_yaw_accel: float = field(default=1.5, metadata=bounds(gt=0))
    max_wheel_accel: float = field(default=0.4, metadata=bounds(gt=0))
    brake_decel: float = field(default=0.8, metadata=bounds(gt=0))
    reaction_time_s: float = field(default=0.3, metadata=bounds(gt=0))
    margin_m: float = field(default=0.15, metadata=bounds(gt=0))
    sweep_margin_m: float = field(default=0.03, metadata=bounds(gt=0))
    stale_after_s: float = field(default=0.5, metadata=bounds(gt=0))

    def __post_init__(self) -> None:
        check_dataclass(self, "safety")

    @classmethod
    def from_spec(
        cls,
        spec: RobChairSpec,
        table: Mapping[str, Any] | ConfigTable | None = None,
        /,
        **overrides: float,
    ) -> SafetyLimits:
        """Speed caps from the platform (``DiffDrive.max_speed``, ``max_yaw_rate``), the rest default.

        Args:
            spec: The platform.
            table: A ``[safety]`` TOML table (a :class:`robchair.platform.config.ConfigTable` carries its file
                and path for the messages); a plain mapping is addressed as ``safety``.
            **overrides: Values that replace the table's (e.g. a sweep's parameters).

        Raises:
            ConfigError: an unknown key, a wrong type, a value <= 0, or a speed cap above the
                platform maximum (``<file>:<line>: safety.max_speed = 1.0: expected ...``).
        """
        from robchair.platform.kinematics import DiffDrive

        drive = DiffDrive(spec)
        if not isinstance(table, ConfigTable):
            table = ConfigTable(dict(table or {}), where="safety")
        base = {"max_speed": drive.max_speed, "max_yaw_rate": drive.max_yaw_rate}
        merged = ConfigTable({**base, **table.data, **overrides}, table.source, table.where)
        limits = load_dataclass(cls, merged)
        for key, cap, unit in (
            ("max_speed", drive.max_speed, "m/s"),
            ("max_yaw_rate", drive.max_yaw_rate, "rad/s"),
        ):
            if getattr(limits, key) > cap:
                raise merged.invalid(key, f"a finite number <= the platform maximum {cap:.3f} {unit}")
        return limits

    def stopping_distance(self, speed: float) -> float:
        """Distance needed to stop from ``speed`` m/s plus the margin, m."""
        v = abs(speed)
        return self.margin_m + v * self.reaction_time_s + v * v / (2.0 * self.brake_decel)


@dataclass(frozen=True)
class Footprint:
    """The chair's footprint: the rectangle ``rear_x <= x <= front_x``, ``|y| <= half_width`` in
    ``base_link`` (x forward, y left), m."""

    rear_x: float
    front_x: float
    half_width: float

    def __post_init__(self) -> None:
        if not (self.rear_x < self.front_x and self.half_width > 0):
            raise ValueError(f"footprint {self}: expected rear_x < front_x and half_width > 0")

    @classmethod
    def from_spec(cls, spec: RobChairSpec) -> Footprint:
        """The body box of the spec (``body.centre_x +- depth / 2``, ``width / 2``)."""
        b = spec.body
        return cls(b.centre_x - 0.5 * b.depth, b.centre_x + 0.5 * b.depth, 0.5 * b.width)

    @property
    def reach(self) -> float:
        """Distance from ``base_link`` to the farthest corner (the front corners: the footrests), m."""
        return math.hypot(max(abs(self.rear_x), abs(self.front_x)), self.half_width)

    def signed_distance(self, xy: np.ndarray) -> np.ndarray:
        """Signed distance (..., ) of points ``xy`` (..., 2) in ``base_link`` to the rectangle, m:
        Euclidean outside, minus the depth inside."""
        cx, hx = 0.5 * (self.front_x + self.rear_x), 0.5 * (self.front_x - self.rear_x)
        qx = np.abs(xy[..., 0] - cx) - hx
        qy = np.abs(xy[..., 1]) - self.half_width
        outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0))
        return np.asarray(outside + np.minimum(np.maximum(qx, qy), 0.0))


def sweep_poses(v: float, w: float, duration: float, n: int) -> np.ndarray:
    """Poses (n + 1, 3) ``(x, y, theta)`` at ``k duration / n`` along the constant twist ``(v, w)`` (m/s,
    rad/s) from the origin: the arc of radius ``v / w`` (a straight line for ``w = 0``, a turn in place
    for ``v = 0``)."""
    t = np.linspace(0.0, duration, n + 1)
    th = w * t
    if abs(w) > 1e-9:
        x, y = v / w * np.sin(th), v / w * (1.0 - np.cos(th))
    else:
        x, y = v * t, np.zeros_like(t)
    return np.stack([x, y, th], axis=1)


def swept_distances(xy: np.ndarray, v: float, w: float, duration: float, footprint: Footprint,
                    step_m: float = SWEEP_STEP_M, max_poses: int = SWEEP_MAX_POSES
                    ) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """Distances of obstacle points to the footprint swept by the twist ``(v, w)`` over ``duration`` s.

    The sweep is sampled at poses (:func:`sweep_poses`) so that no footprint point moves more than
    ``step_m`` between two of them (at most ``max_poses`` steps): a footprint point moves at most
    ``|v| + reach |w|`` m/s, so every pose between two samples is within half a step of one of them.

    Args:
        xy: obstacle points (N, 2) in ``base_link`` at the start, m.
        v, w: the twist, m/s and rad/s.
        duration: s (>= 0).
        footprint: the chair's.

    Returns:
        ``(d_min, d_start, bound)``: per point the smallest signed distance over the sampled poses
        (N,) and at the start (N,), m, and the sampling bound, m: the exact smallest distance over the
        continuous sweep lies in ``[d_min - bound, d_min]``.
    """
    n, bound = _sweep_steps(v, w, duration, footprint, step_m, max_poses)
    poses = sweep_poses(v, w, duration, n)
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    dx = xy[None, :, 0] - poses[:, 0:1]
    dy = xy[None, :, 1] - poses[:, 1:2]
    local = np.stack([c * dx + s * dy, c * dy - s * dx], axis=-1)  # (n + 1, N, 2) in each pose's frame
    d = footprint.signed_distance(local)
    return d.min(axis=0), d[0], bound


def _sweep_steps(v: float, w: float, duration: float, footprint: Footprint, step_m: float = SWEEP_STEP_M,
                 max_poses: int = SWEEP_MAX_POSES) -> tuple[int, float]:  # fmt: skip
    """The steps of :func:`swept_distances`' sampling and its bound (half a step), m."""
    length = (abs(v) + footprint.reach * abs(w)) * duration
    n = max(1, min(max_poses, math.ceil(length / step_m)))
    return n, 0.5 * length / n


def swept_clearance(xy: np.ndarray, v: float, w: float, duration: float, footprint: Footprint) -> float:
    """A lower bound on the smallest distance between the points ``xy`` (N, 2, ``base_link``) and the
    footprint swept by ``(v, w)`` over ``duration`` s, m: within the sampling bound of
    :func:`swept_distances` (half of :data:`SWEEP_STEP_M`, more for a sweep longer than
    :data:`SWEEP_MAX_POSES` steps); inf without points."""
    if len(xy) == 0:
        return math.inf
    d_min, _, bound = swept_distances(np.asarray(xy, dtype=float), v, w, duration, footprint)
    return float(d_min.min()) - bound


@dataclass(frozen=True)
class SafetyInputs:
    """What the runtime knows this cycle. None = no such sensor / no information.

    Attributes:
        stamp_ns: time of this cycle.
        sonar_distance_m: nearest obstacle ahead seen by the sonars (fused), from the chair's front.
        map_distance_m: nearest occupied 2D-map cell in the corridor ahead, from the chair's front.
        deadline_missed: the previous cycle overran its period.
        stale_sensors: names of sensors whose newest reading is older than ``stale_after_s``.
        driver_fault: text of a motor-driver fault, if one happened.
        deadman: joystick dead-man button state (None when no joystick drives).
        obstacles_xy: obstacle points (N, 2) in ``base_link`` in the chair's height band, all around
            it (the perception's local map, laser scan and sonar arcs), m; None: no swept-footprint
            check.
    """

    stamp_ns: int = 0
    sonar_distance_m: float | None = None
    map_distance_m: float | None = None
    deadline_missed: bool = False
    stale_sensors: tuple[str, ...] = ()
    driver_fault: str | None = None
    deadman: bool | None = None
    obstacles_xy: np.ndarray | None = None


@dataclass(frozen=True)
class StopRecord:
    stamp_ns: int
    reason: StopReason
    detail: str


@dataclass(frozen=True)
class SafetyDecision:
    v: float
    w: float
    stop: StopReason | None = None
    detail: str = ""
    limited: bool = False  # the twist was changed by a speed or acceleration limit, or the sweep
    #: the fraction of the limited twist the swept-footprint check let through (None: no check ran)
    swept_scale: float | None = None


def _default_wheel_separation() -> float:
    from robchair.platform.spec import load_spec

    return load_spec().wheel_separation


def _default_footprint() -> Footprint:
    from robchair.platform.spec import load_spec

    return Footprint.from_spec(load_spec())


@dataclass
class SafetyLayer:
    """Stateful filter: remembers the last output (for acceleration limits) and the latched fault.

    ``wheel_separation`` (m, the platform's; default the default spec's) turns the body twist into the
    wheel rim speeds ``max_wheel_accel`` bounds; ``footprint`` (default the default spec's body) is
    what the swept-footprint check moves.
    """

    limits: SafetyLimits = field(default_factory=SafetyLimits)
    wheel_separation: float = field(default_factory=_default_wheel_separation)
    footprint: Footprint = field(default_factory=_default_footprint)
    stops: list[StopRecord] = field(default_factory=list)
    #: ``logging`` level of the line each new stop logs (WARNING on a chair; the Gymnasium envs and the
    #: benchmarks, where stops are part of learning and are counted in ``info["safety"]``, use INFO)
    log_level: int = logging.WARNING
    _v: float = 0.0
    _w: float = 0.0
    _fault: str | None = None
    _active: StopReason | None = None

    def reset(self) -> None:
        """Forget the latched driver fault and the last output (after the operator cleared a fault)."""
        self._v = self._w = 0.0
        self._fault = None
        self._active = None

    def _stop_reason(self, v_want: float, inputs: SafetyInputs) -> tuple[StopReason, str] | None:
        if inputs.driver_fault is not None:
            self._fault = inputs.driver_fault
        if self._fault is not None:
            return StopReason.DRIVER_FAULT, self._fault
        if inputs.deadline_missed:
            return StopReason.DEADLINE_MISSED, "the previous control cycle overran its period"
        if inputs.stale_sensors:
            return StopReason.STALE_SENSOR, f"no fresh data from {', '.join(inputs.stale_sensors)}"
        if inputs.deadman is False:
            return StopReason.DEADMAN_RELEASED, "joystick dead-man button released"
        if v_want > 0.0 or self._v > 0.0:
            # the faster of the wanted and the current speed decides how far ahead must be clear
            d_stop = self.limits.stopping_distance(max(v_want, self._v))
            for reason, dist in (
                (StopReason.OBSTACLE_SONAR, inputs.sonar_distance_m),
                (StopReason.OBSTACLE_MAP, inputs.map_distance_m),
            ):
                if dist is not None and math.isfinite(dist) and dist < d_stop:
                    return reason, f"obstacle at {dist:.2f} m ahead < stopping distance {d_stop:.2f} m"
        return None

    def stopping_time(self, v: float, w: float) -> float:
        """Time the twist ``(v, w)`` keeps going after it is commanded, s: the reaction time, then
        braking at ``brake_decel`` (rim deceleration: ``2 brake_decel / b`` rad/s^2 in yaw), the slower
        of the two (a constant-curvature stop)."""
        lim = self.limits
        yaw_decel = 2.0 * lim.brake_decel / self.wheel_separation
        return lim.reaction_time_s + max(abs(v) / (2.0 * lim.brake_decel), abs(w) / (2.0 * yaw_decel))

    def sweep_scale(self, v: float, w: float, xy: np.ndarray) -> tuple[float, str]:
        """The largest of :data:`SWEEP_SCALES` ``k`` whose twist ``(k v, k w)`` sweeps clear of the
        obstacle points ``xy`` (N, 2, ``base_link``) over its stopping time (module docstring), or 0;
        and a text naming the nearest point of the full twist's sweep (empty when it passes)."""
        lim, fp = self.limits, self.footprint
        pts = np.asarray(xy, dtype=float).reshape(-1, 2)
        if len(pts) == 0 or (v == 0.0 and w == 0.0):
            return 1.0, ""
        # only points the footprint can reach within the full twist's stop can matter
        reach = fp.reach + abs(v) * self.stopping_time(v, w) + lim.sweep_margin_m + SWEEP_STEP_M
        from robchair.platform._safety_kernels import within_reach  # numba: imported when first needed

        near = within_reach(pts, reach * reach)  # pts[einsum("ij,ij->i", pts, pts) <= reach**2]
        if len(near) == 0:
            return 1.0, ""
        d0 = self.footprint.signed_distance(near)
        # a point inside the footprint at the start is the chair's own or a map error: it cannot be
        # driven away from, and is left to the obstacle stops
        near, d0 = near[d0 > 0.0], d0[d0 > 0.0]
        if len(near) == 0:
            return 1.0, ""
        c0 = float(d0.min())
        why = ""
        for k in SWEEP_SCALES:
            vk, wk = k * v, k * w
            t_stop = self.stopping_time(vk, wk)
            # coarse poses first: a point whose coarse bound clears the margin by the fine bound cannot
            # fail the fine test; the fine poses only for the rest (the same decision, for less work)
            d_c, _, bound_c = swept_distances(near, vk, wk, t_stop, fp, step_m=SWEEP_COARSE_STEP_M)
            bound_f = _sweep_steps(vk, wk, t_stop, fp)[1]
            need = near[d_c - bound_c < lim.sweep_margin_m + bound_f]
            if len(need) == 0:
                return k, why
            d_min, _, bound = swept_distances(need, vk, wk, t_stop, fp)
            j = int(np.argmin(d_min))
            # clear by the margin (with the sampling bound), or, closer already, no closer than now
            if d_min[j] >= min(lim.sweep_margin_m + bound, c0 - SWEEP_KEEP_TOL_M):
                return k, why
            if not why:
                why = (
                    f"footprint swept by (v, w) = ({v:.2f} m/s, {w:.2f} rad/s) comes within "
                    f"{max(0.0, d_min[j] - bound):.3f} m of an obstacle at ({need[j, 0]:.2f}, "
                    f"{need[j, 1]:.2f}) m (clearance now {c0:.3f} m)"
                )
        return 0.0, why

    def stop_now(self, stamp_ns: int, reason: StopReason, detail: str) -> SafetyDecision:
        """Stop this cycle for ``reason`` (found after :meth:`filter`, when the command is written)."""
        return self._stop(stamp_ns, reason, detail)

    def _stop(self, stamp_ns: int, reason: StopReason, detail: str) -> SafetyDecision:
        if reason != self._active:
            self.stops.append(StopRecord(stamp_ns, reason, detail))
            log.log(self.log_level, "safety stop: %s (%s)", reason.value, detail)
        self._active = reason
        self._v = self._w = 0.0
        return SafetyDecision(0.0, 0.0, reason, detail)

    def filter(self, v: float, w: float, inputs: SafetyInputs, dt: float) -> SafetyDecision:
        """Return the twist to command this cycle (``dt`` = loop period, s)."""
        if not (math.isfinite(v) and math.isfinite(w)):
            # a broken command source is a fault of the software driving the chair: stop
            self._fault = f"non-finite command v={v}, w={w}"
            stop: tuple[StopReason, str] | None = (StopReason.DRIVER_FAULT, self._fault)
        else:
            stop = self._stop_reason(v, inputs)
        if stop is not None:
            return self._stop(inputs.stamp_ns, *stop)
        lim = self.limits
        v_out = min(max(v, -lim.max_speed), lim.max_speed)
        w_out = min(max(w, -lim.max_yaw_rate), lim.max_yaw_rate)
        # keep both wheels within the platform: |v| / max_speed + |w| / max_yaw_rate <= 1
        load = abs(v_out) / lim.max_speed + abs(w_out) / lim.max_yaw_rate
        if load > 1.0:
            v_out, w_out = v_out / load, w_out / load
        dv_max, dw_max = lim.max_accel * dt, lim.max_yaw_accel * dt
        v_out = min(max(v_out, self._v - dv_max), self._v + dv_max)
        w_out = min(max(w_out, self._w - dw_max), self._w + dw_max)
        # each wheel's change: shrink the step (dv, dw) from the last output, keeping its direction
        dv, dw = v_out - self._v, w_out - self._w
        wheel_step = abs(dv) + abs(dw) * 0.5 * self.wheel_separation  # the faster-changing wheel
        if wheel_step > lim.max_wheel_accel * dt:
            k = lim.max_wheel_accel * dt / wheel_step
            v_out, w_out = self._v + k * dv, self._w + k * dw
        # the acceleration clamps move v and w separately and can leave the diamond again: the wheel
        # speed limit is a hard one, so it wins over the acceleration limits
        load = abs(v_out) / lim.max_speed + abs(w_out) / lim.max_yaw_rate
        if load > 1.0:
            v_out, w_out = v_out / load, w_out / load
        scale: float | None = None
        detail = ""
        if inputs.obstacles_xy is not None:
            scale, detail = self.sweep_scale(v_out, w_out, inputs.obstacles_xy)
            if scale == 0.0:
                return self._stop(inputs.stamp_ns, StopReason.OBSTACLE_SWEPT, detail)
            v_out, w_out = scale * v_out, scale * w_out
        self._active = None
        limited = not (math.isclose(v_out, v, abs_tol=1e-12) and math.isclose(w_out, w, abs_tol=1e-12))
        self._v, self._w = v_out, w_out
        return SafetyDecision(v_out, w_out, None, detail, limited, scale)
