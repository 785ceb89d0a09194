"""Discrete time: the sampled PID and the exactly discretised plant the simulator and emulator run.

Only :func:`sampled_loop` needs python-control (imported there): :class:`DiscretePlant` discretises with
scipy's matrix exponential, so a simulation does not pay python-control's import (~1.7 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from robchair.platform.control.plant import ControlError, SecondOrderPlant

if TYPE_CHECKING:
    from robchair.platform.control.design import PIDDesign

CONTROLLER_RATE_HZ = 1000.0
"""Default sample rate (Hz) of the discrete PID and plant used by the simulator and emulators."""


@dataclass(frozen=True)
class SampledLoop:
    """Closed-loop poles of the sampled loop (:class:`DiscretePID` on :class:`DiscretePlant`).

    Attributes:
        dt: Sample time, s.
        z_poles: Poles in the z plane.
        s_equivalent: ln(z) / dt, the continuous poles they correspond to (principal branch).
        max_abs_z: Spectral radius; the loop is stable when it is below 1.
    """

    dt: float
    z_poles: np.ndarray = field(compare=False)
    s_equivalent: np.ndarray = field(compare=False)
    max_abs_z: float

    @property
    def stable(self) -> bool:
        return self.max_abs_z < 1.0


def sampled_loop(
    plant: SecondOrderPlant, kp: float, ki: float, kd: float, dt: float, tau_d: float = 0.0
) -> SampledLoop:
    """Poles of the loop the simulator and emulators run, computed in the z domain with python-control.

    The plant is discretised exactly (ZOH, ``control.c2d``); the PID is the z-transfer function of
    :class:`DiscretePID`'s difference equations: K_p + K_i dt z / (z - 1) + K_d (z - 1) / ((tau_d + dt) z -
    tau_d). This is the check the thesis recommends after each change of the non-dominant pole p: a
    continuous design is stable for any p > 0, but a large p (a large K_d) destabilises the *sampled* loop.
    """
    import control as ct

    from robchair.platform.control.design import _sort_poles

    if not (math.isfinite(dt) and dt > 0):
        raise ControlError(f"dt = {dt!r}: expected a sample time > 0 s")
    pz = ct.c2d(plant.tf(), dt, method="zoh")
    z = ct.tf([1.0, 0.0], [1.0], dt)
    c = kp + ki * dt * z / (z - 1) + kd * (z - 1) / ((tau_d + dt) * z - tau_d)
    zp = np.asarray(ct.poles(ct.feedback(c * pz, 1)), dtype=complex)
    # a pole exactly at the origin (no filter) has no continuous equivalent: report it as -inf
    with np.errstate(divide="ignore"):
        s_eq = np.log(zp) / dt
    return SampledLoop(dt=dt, z_poles=zp, s_equivalent=_sort_poles(s_eq), max_abs_z=float(np.max(np.abs(zp))))


def zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of x' = A x + B u over ``dt`` s: (A_d, B_d), shapes (n, n)
    and (n, m) for A (n, n) and B (n, m).

    The upper rows of expm([[A, B], [0, 0]] dt), the computation ``scipy.signal.cont2discrete`` does
    for ``control.c2d(..., method="zoh")`` (the same matrix, so the same result bit for bit), with only
    ``scipy.linalg`` imported.
    """
    from scipy.linalg import expm

    n, m = a.shape[0], b.shape[1]
    em = np.vstack((np.hstack((a, b)), np.hstack((np.zeros((m, n)), np.zeros((m, m))))))
    ms = expm(dt * em)[:n, :]
    return ms[:, :n], ms[:, n:]


class DiscretePID:
    """A sampled PID with output saturation, anti-windup and a filtered derivative.

    At each sample k: e = r - y; P = K_p e; I += K_i dt e (backward Euler); D from a first-order filtered
    derivative (backward Euler of K_d s / (tau_d s + 1)) of -y (``derivative_on_measurement``, the
    default) or of the error; u = P + I + D, saturated to [u_min, u_max].

    Why the derivative acts on the measurement by default: on the error, every set-point step r enters
    the D term as K_d r / dt for one sample (29,000 RPM for the thesis's K_d = 0.29 s and a 100 RPM step
    at 1 kHz), far beyond the +-1000 command, so the command saturates on every step and the loop's
    reference response is no longer the linear one the design computes. On the measurement the set point
    reaches the command through P and I only (set-point weight 0 on D, Astrom & Hagglund); the poles,
    and so the disturbance rejection, are those of the design, and the sampled loop's step response is
    the design's :meth:`~robchair.platform.control.PIDDesign.closed_loop_tf` at every step size.

    Anti-windup: ``"conditional"`` (default) skips the integration when the output is saturated and the
    error would drive it further into saturation; ``"back_calculation"`` feeds (u_sat - u) / t_t back
    into the integrator (t_t defaults to sqrt(T_i T_d) with T_i = K_p / K_i, T_d = K_d / K_p, or dt).

    Args:
        kp, ki, kd: Gains (continuous-time units: K_i in 1/s, K_d in s).
        dt: Sample time, s (default 1 / CONTROLLER_RATE_HZ).
        u_min, u_max: Output limits.
        tau_d: Derivative filter time constant, s (0 = plain backward difference).
        derivative_on_measurement: Differentiate -y (default) instead of the error.
        anti_windup: ``"conditional"``, ``"back_calculation"`` or ``"none"``.
        t_t: Tracking time constant for back-calculation, s.
    """

    def __init__(
        self,
        kp: float,
        ki: float,
        kd: float,
        dt: float = 1.0 / CONTROLLER_RATE_HZ,
        u_min: float = -math.inf,
        u_max: float = math.inf,
        tau_d: float = 0.0,
        derivative_on_measurement: bool = True,
        anti_windup: str = "conditional",
        t_t: float | None = None,
    ) -> None:
        for name, v in (("kp", kp), ("ki", ki), ("kd", kd)):
            if not math.isfinite(v):
                raise ControlError(f"DiscretePID {name} = {v!r}: expected a finite gain")
        if not (math.isfinite(dt) and dt > 0):
            raise ControlError(f"DiscretePID dt = {dt!r}: expected a sample time > 0 s")
        if not (math.isfinite(tau_d) and tau_d >= 0):
            raise ControlError(f"DiscretePID tau_d = {tau_d!r}: expected a filter time constant >= 0 s")
        if not u_min < u_max or math.isnan(u_min) or math.isnan(u_max):
            raise ControlError(
                f"DiscretePID limits u_min = {u_min!r}, u_max = {u_max!r}: expected u_min < u_max"
            )
        if anti_windup not in ("conditional", "back_calculation", "none"):
            raise ControlError(
                f"DiscretePID anti_windup = {anti_windup!r}: "
                "expected 'conditional', 'back_calculation' or 'none'"
            )
        self.kp, self.ki, self.kd, self.dt = float(kp), float(ki), float(kd), float(dt)
        self.u_min, self.u_max, self.tau_d = float(u_min), float(u_max), float(tau_d)
        self.derivative_on_measurement = derivative_on_measurement
        self.anti_windup = anti_windup
        if t_t is None:
            t_t = math.sqrt((kp / ki) * (kd / kp)) if (ki > 0 and kd > 0 and kp > 0) else dt
        if not (math.isfinite(t_t) and t_t > 0):
            raise ControlError(f"DiscretePID t_t = {t_t!r}: expected a tracking time constant > 0 s")
        self.t_t = float(t_t)
        self.reset()

    @classmethod
    def from_design(
        cls, design: PIDDesign, dt: float = 1.0 / CONTROLLER_RATE_HZ, **kwargs: Any
    ) -> DiscretePID:
        """A discrete PID with the gains and derivative placement of ``design``; keyword arguments as for
        the constructor."""
        kwargs.setdefault("derivative_on_measurement", design.derivative_on_measurement)
        return cls(design.kp, design.ki, design.kd, dt=dt, **kwargs)

    def reset(self, integral: float = 0.0, previous: float | None = None) -> None:
        """Set the integral term and the derivative memory.

        Args:
            integral: Integral term (e.g. the current command, for a bumpless start).
            previous: The differentiated signal at the previous sample: -measurement with
                ``derivative_on_measurement``, else the error. None: with the derivative on the
                measurement, take the first update's measurement (no kick when a controller starts or
                gets new gains on a turning motor); on the error, 0 ("at rest at zero", like a continuous
                system with zero initial conditions, so a set-point step on the first update gives the
                continuous PID's derivative kick).
        """
        self.integral = float(integral)
        self._d = 0.0
        self._prev_unset = previous is None and self.derivative_on_measurement
        self._prev = 0.0 if previous is None else float(previous)
        self.saturated = False
        self.u = 0.0

    def update(self, setpoint: float, measurement: float) -> float:
        """One sample: return the (saturated) command for this setpoint and measured value."""
        e = setpoint - measurement
        x = -measurement if self.derivative_on_measurement else e
        if self._prev_unset:
            self._prev, self._prev_unset = x, False
        a = self.tau_d / (self.tau_d + self.dt)
        self._d = a * self._d + self.kd * (x - self._prev) / (self.tau_d + self.dt)
        self._prev = x
        p = self.kp * e
        i_new = self.integral + self.ki * self.dt * e
        u_raw = p + i_new + self._d
        u = min(max(u_raw, self.u_min), self.u_max)
        if self.anti_windup == "conditional":
            pushing_out = (u_raw > self.u_max and e > 0) or (u_raw < self.u_min and e < 0)
            if not pushing_out:
                self.integral = i_new
            else:
                u = min(max(p + self.integral + self._d, self.u_min), self.u_max)
        elif self.anti_windup == "back_calculation":
            self.integral = i_new + (self.dt / self.t_t) * (u - u_raw)
        else:
            self.integral = i_new
        self.saturated = u != u_raw
        self.u = u
        return u


class DiscretePlant:
    """Exact zero-order-hold discretisation of a :class:`SecondOrderPlant`, stepped sample by sample.

    x[k+1] = A_d x[k] + B_d u[k]; y[k] = C x[k]. :meth:`step` holds ``u`` for one sample and returns the
    output at the end of it. Units as the plant: command RPM in, shaft RPM out.

    The plant also integrates its output exactly (an extra integrator state in the same ZOH
    discretisation): :attr:`integral` is the time integral of the output (RPM x s), so
    ``integral / 60`` is the number of shaft revolutions turned, which the simulator and the Roboteq
    emulator turn into encoder counts without integration error.

    Args:
        plant: The continuous plant.
        dt: Sample time, s (default 1 / CONTROLLER_RATE_HZ).
    """

    def __init__(self, plant: SecondOrderPlant, dt: float = 1.0 / CONTROLLER_RATE_HZ) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ControlError(f"DiscretePlant dt = {dt!r}: expected a sample time > 0 s")
        self.plant = plant
        self.dt = float(dt)
        ac, bc, cc = plant.state_matrices()
        n = ac.shape[0]
        # Augment with q' = y so the ZOH discretisation also gives the exact integral of the output.
        a_aug = np.zeros((n + 1, n + 1))
        a_aug[:n, :n] = ac
        a_aug[n, :n] = cc.ravel()
        b_aug = np.concatenate([bc.ravel(), [0.0]])[:, None]
        ad, bd = zoh(a_aug, b_aug, dt)
        bd = bd.ravel()
        self.A = ad[:n, :n]
        self.B = bd[:n]
        self.C = cc.ravel()
        self._q_row = ad[n, :n]
        self._q_b = float(bd[n])
        if n != 2:
            raise ControlError(f"DiscretePlant: expected a second-order realisation, got {n} states")
        # The 1 kHz loop runs 2 x (PID + plant) per tick in the simulator and the emulators: scalar float
        # arithmetic on the 2-state system is ~10x cheaper than numpy's 2x2 products per call.
        self._a00, self._a01, self._a10, self._a11 = (float(v) for v in self.A.ravel())
        self._b0, self._b1 = float(self.B[0]), float(self.B[1])
        self._c0, self._c1 = float(self.C[0]), float(self.C[1])
        self._q0, self._q1 = float(self._q_row[0]), float(self._q_row[1])
        self.integral = 0.0
        # Steady state per unit input of the continuous realisation: x_ss = -A^-1 B.
        self._x_per_u = -np.linalg.solve(ac, bc.ravel())
        self.reset()

    @property
    def x(self) -> np.ndarray:
        """State vector x[k], shape (2,) (a copy)."""
        return np.array([self._x0, self._x1])

    @x.setter
    def x(self, value: npt.ArrayLike) -> None:
        v = np.asarray(value, dtype=float).ravel()
        self._x0, self._x1 = float(v[0]), float(v[1])

    @property
    def output(self) -> float:
        """Current output y[k] (before the next input is applied)."""
        return self._c0 * self._x0 + self._c1 * self._x1

    def reset(self, y0: float = 0.0) -> None:
        """Put the plant at rest at output ``y0`` (the steady state for a constant input y0 / K).

        Also zeroes :attr:`integral`.
        """
        self.x = self._x_per_u * (y0 / self.plant.gain)
        self.integral = 0.0

    def step(self, u: float) -> float:
        """Hold input ``u`` for one sample; return the output at the end of the sample."""
        x0, x1 = self._x0, self._x1
        self.integral += self._q0 * x0 + self._q1 * x1 + self._q_b * u
        self._x0 = self._a00 * x0 + self._a01 * x1 + self._b0 * u
        self._x1 = self._a10 * x0 + self._a11 * x1 + self._b1 * u
        return self._c0 * self._x0 + self._c1 * self._x1

    def simulate(self, u: npt.ArrayLike) -> np.ndarray:
        """Step through a whole input sequence; returns the outputs after each sample."""
        return np.array([self.step(float(v)) for v in np.asarray(u, dtype=float).ravel()])


class MotorModel:
    """One wheel motor as the simulator and the Roboteq emulator run it: DiscretePID + DiscretePlant.

    The PID output (the open-loop command, RPM-equivalent) is limited to +-max_motor_rpm, the full scale
    of the controller's power command. In open loop the setpoint is the command itself.

    Args:
        plant: Motor plant.
        design: PID design (gains) or None for open loop only.
        max_motor_rpm: Command full scale.
        dt: Sample time, s.
        closed_loop: Start in closed-loop speed mode.
        tau_d: Derivative filter time constant of the PID, s.
    """

    def __init__(
        self,
        plant: SecondOrderPlant,
        design: PIDDesign | None = None,
        max_motor_rpm: float = 1000.0,
        dt: float = 1.0 / CONTROLLER_RATE_HZ,
        closed_loop: bool = True,
        tau_d: float = 0.0,
    ) -> None:
        self.plant = DiscretePlant(plant, dt)
        self.max_motor_rpm = float(max_motor_rpm)
        self.dt = self.plant.dt
        self.pid: DiscretePID | None = None
        if design is not None:
            self.pid = DiscretePID.from_design(
                design, dt=self.dt, u_min=-self.max_motor_rpm, u_max=self.max_motor_rpm, tau_d=tau_d
            )
        if closed_loop and self.pid is None:
            raise ControlError("MotorModel: closed_loop=True needs a PID design")
        self.closed_loop = closed_loop
        self.command = 0.0

    @property
    def speed_rpm(self) -> float:
        return self.plant.output

    @property
    def revolutions(self) -> float:
        """Shaft revolutions turned since the last reset (exact integral of the speed)."""
        return self.plant.integral / 60.0

    def set_gains(self, kp: float, ki: float, kd: float) -> None:
        """Replace the PID gains (keeps the integral so a running motor does not jump)."""
        integral = self.pid.integral if self.pid is not None else 0.0
        tau = self.pid.tau_d if self.pid is not None else 0.0
        previous = self.pid._prev if self.pid is not None and not self.pid._prev_unset else None
        self.pid = DiscretePID(
            kp, ki, kd, dt=self.dt, u_min=-self.max_motor_rpm, u_max=self.max_motor_rpm, tau_d=tau
        )
        self.pid.reset(integral=integral, previous=previous)

    def tick(self, setpoint_rpm: float) -> float:
        """Advance one sample with the given setpoint (closed loop) or command (open loop); return speed."""
        if self.closed_loop:
            assert self.pid is not None
            u = self.pid.update(setpoint_rpm, self.plant.output)
        else:
            u = min(max(setpoint_rpm, -self.max_motor_rpm), self.max_motor_rpm)
        self.command = u
        return self.plant.step(u)

    def advance(self, setpoint_rpm: float, duration: float) -> float:
        """Run ``round(duration / dt)`` samples with a constant setpoint; return the final speed."""
        n = max(0, round(duration / self.dt))
        y = self.plant.output
        for _ in range(n):
            y = self.tick(setpoint_rpm)
        return y

    def reset(self) -> None:
        self.plant.reset()
        if self.pid is not None:
            self.pid.reset()
        self.command = 0.0
