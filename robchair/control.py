"""Wheel-motor control: step-response identification, PID pole placement, discrete PID and plant.

This is the chain of the thesis's Appendix B (SPEC.md section 5) as code. python-control does every
transfer-function computation (closed loops, poles, margins, step metrics); scipy does the fits.

Units. The plant maps the open-loop *command* to the motor *shaft speed*, both in RPM: the command is
expressed as the shaft speed it would give in steady state (Roboteq open-loop power level x max RPM /
1000, assuming speed is proportional to power), so the identified plant has unit DC gain and
``b0 = omega_n**2 = a0``. PID gains therefore map RPM of error to RPM of command: K_p is dimensionless,
K_i is in 1/s and K_d in s.

Rates. :data:`CONTROLLER_RATE_HZ` = 1000 Hz is the default sample rate of :class:`DiscretePID` and
:class:`DiscretePlant` for the simulator and the Roboteq emulator. Assumption: the MDC2230's speed loop
runs at about 1 kHz (the exact rate is not in the sources at hand). At 1 kHz the sampled loop stays
within 0.75 % of the step of the continuous design after the first 10 ms (tested); at 100 Hz the
deviation grows to about 8 %, because the error is first order in the sample time.

Where this implementation differs from the thesis (SPEC.md section 6), and why:

1. Erratum 1, eq. (9.0.3): the thesis prints ``omega_n = xi * sigma``. By definition
   ``sigma = xi * omega_n`` (the real part of the poles), so ``omega_n = sigma / xi``
   (= omega_d / sqrt(1 - xi**2)). The printed formula gives a plant whose step response peaks at the
   wrong time (tests show the peak time is then not t_p); the corrected one reproduces t_p and M_p.
2. Erratum 2, eq. (9.0.8): the printed K_i and K_d are swapped. Matching the coefficients of
   ``s**3 + (K_d b0 + a1) s**2 + (K_p b0 + a0) s + K_i b0 = (s + p)(s**2 + 2 xi_w omega_w s + omega_w**2)``
   gives ``K_d = (2 xi_w omega_w + p - a1) / b0``, ``K_p = (omega_w**2 + 2 xi_w omega_w p - a0) / b0`` and
   ``K_i = p omega_w**2 / b0``. :func:`design_pid` checks every design by computing the closed-loop poles
   with python-control; the printed gains put them elsewhere.
3. Erratum 3: the measured rise time t_r is not used by the identification (it has only two parameters,
   fixed by t_p and M_p) and the model does not reproduce it. :func:`identify_from_step_metrics` reports
   the residual for two rise-time definitions: 0-100 % (Ogata's definition for underdamped systems,
   ``t_r = (pi - beta) / omega_d`` with ``beta = arccos(xi)``) and 10-90 %. For the thesis's motors the
   model rise times are 1.6-2.0x (0-100 %) and 1.1-1.4x (10-90 %) the measured ones (motor 1: 0.279 and
   0.187 s vs 0.1365 s; motor 2: 0.247 and 0.167 s vs 0.1524 s), so the real motors start faster than a
   second-order model with that t_p and M_p can; :func:`identify_from_trace` fits a raw trace instead.

Also beyond the thesis: an optional DC gain K in the plant (for raw traces), an optional dead time in
the trace fit, a discrete PID with saturation, anti-windup and a filtered derivative, exact
zero-order-hold discretisation of the plant, and conversion of the gains to Roboteq firmware units.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import control as ct
import numpy as np
import numpy.typing as npt

from robchair.errors import RobChairError

CONTROLLER_RATE_HZ = 1000.0
"""Default sample rate (Hz) of the discrete PID and plant used by the simulator and emulators."""

THESIS_XI_W = 1.0
THESIS_OMEGA_W = 3.3  # rad/s
THESIS_P_FACTOR = 10.0  # p = 10 xi_w omega_w


class ControlError(RobChairError, ValueError):
    """Invalid input to the control design (impossible step metrics, bad gains, unusable trace)."""


# ----------------------------------------------------------------------------------------------- plant


@dataclass(frozen=True)
class SecondOrderPlant:
    """G(s) = K omega_n^2 / (s^2 + 2 xi omega_n s + omega_n^2) = b0 / (s^2 + a1 s + a0).

    Attributes:
        omega_n: Natural frequency, rad/s (> 0).
        xi: Damping ratio (> 0).
        gain: DC gain K (1 for the thesis's identification: command and speed both in RPM).
    """

    omega_n: float
    xi: float
    gain: float = 1.0

    def __post_init__(self) -> None:
        for name in ("omega_n", "xi", "gain"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ControlError(f"SecondOrderPlant.{name} = {v!r}: expected a finite number > 0")

    @property
    def b0(self) -> float:
        return self.gain * self.omega_n**2

    @property
    def a1(self) -> float:
        return 2.0 * self.xi * self.omega_n

    @property
    def a0(self) -> float:
        return self.omega_n**2

    @property
    def sigma(self) -> float:
        """Decay rate xi omega_n (1/s): minus the real part of underdamped poles."""
        return self.xi * self.omega_n

    @property
    def omega_d(self) -> float:
        """Damped frequency omega_n sqrt(1 - xi^2), rad/s (0 when not underdamped)."""
        return self.omega_n * math.sqrt(1.0 - self.xi**2) if self.xi < 1.0 else 0.0

    @property
    def peak_time(self) -> float:
        """Time of the first peak pi / omega_d, s (inf when not underdamped)."""
        return math.pi / self.omega_d if self.xi < 1.0 else math.inf

    @property
    def overshoot(self) -> float:
        """Maximum overshoot fraction exp(-pi xi / sqrt(1 - xi^2)) (0 when not underdamped)."""
        return math.exp(-math.pi * self.xi / math.sqrt(1.0 - self.xi**2)) if self.xi < 1.0 else 0.0

    @property
    def rise_time_0_100(self) -> float:
        """Ogata's 0-100 % rise time (pi - arccos(xi)) / omega_d, s (inf when not underdamped)."""
        if self.xi >= 1.0:
            return math.inf
        return (math.pi - math.acos(self.xi)) / self.omega_d

    @property
    def rise_time_10_90(self) -> float:
        """Time from 10 % to 90 % of the final value on the analytic step response, s."""
        return _crossing_time(self, 0.9) - _crossing_time(self, 0.1)

    def tf(self) -> ct.TransferFunction:
        """The plant as a python-control transfer function."""
        return ct.tf([self.b0], [1.0, self.a1, self.a0])

    def ss(self) -> ct.StateSpace:
        """The plant as a python-control state-space system (one input, one output)."""
        return ct.tf2ss(self.tf())

    def step(self, t: npt.ArrayLike) -> np.ndarray:
        """Analytic unit-step response at times ``t`` (s); zero for t < 0."""
        return step_response_2nd(np.asarray(t, dtype=float), self.omega_n, self.xi, self.gain)

    def __str__(self) -> str:
        return (
            f"G(s) = {self.b0:.4g} / (s^2 + {self.a1:.4g} s + {self.a0:.4g})"
            f"  [omega_n = {self.omega_n:.4f} rad/s, xi = {self.xi:.4f}, K = {self.gain:.4g}]"
        )


def step_response_2nd(t: np.ndarray, omega_n: float, xi: float, gain: float = 1.0) -> np.ndarray:
    """Closed-form unit-step response of K omega_n^2 / (s^2 + 2 xi omega_n s + omega_n^2).

    Covers the underdamped, critically damped and overdamped cases; zero for t < 0.
    """
    tt = np.maximum(t, 0.0)
    wn = omega_n
    if abs(xi - 1.0) < 1e-7:
        y = 1.0 - np.exp(-wn * tt) * (1.0 + wn * tt)
    elif xi < 1.0:
        wd = wn * math.sqrt(1.0 - xi * xi)
        beta = math.acos(xi)
        y = 1.0 - np.exp(-xi * wn * tt) * np.sin(wd * tt + beta) / math.sqrt(1.0 - xi * xi)
    else:
        root = math.sqrt(xi * xi - 1.0)
        s1 = -wn * (xi - root)  # slow pole
        s2 = -wn * (xi + root)  # fast pole
        y = 1.0 + (s2 * np.exp(s1 * tt) - s1 * np.exp(s2 * tt)) / (s1 - s2)
    return np.where(t < 0.0, 0.0, gain * y)


def _crossing_time(plant: SecondOrderPlant, fraction: float) -> float:
    """First time the analytic step response reaches ``fraction`` of its final value (bisection)."""
    from scipy.optimize import brentq

    hi = 1.0 / plant.omega_n
    while step_response_2nd(np.array([hi]), plant.omega_n, plant.xi)[0] < fraction:
        hi *= 2.0
    # The response rises monotonically until the first peak, so the first crossing is unique below it.
    f = lambda x: float(step_response_2nd(np.array([x]), plant.omega_n, plant.xi)[0]) - fraction  # noqa: E731
    return float(brentq(f, 0.0, min(hi, plant.peak_time), xtol=1e-14, rtol=1e-14))


# ----------------------------------------------------------------------------------------- identification


@dataclass(frozen=True)
class Identification:
    """A plant identified from step metrics (t_r, t_p, M_p), with the unexplained rise time.

    Attributes:
        plant: The identified plant (unit DC gain).
        t_r_measured: The measured rise time, s (None when not given).
        t_p: Peak time used, s.
        M_p: Overshoot used.
        t_r_model_0_100: The model's 0-100 % rise time (pi - beta) / omega_d, s.
        t_r_model_10_90: The model's 10-90 % rise time, s.
        rise_time_residual_0_100: measured - model (0-100 %), s (NaN without a measured t_r).
        rise_time_residual_10_90: measured - model (10-90 %), s (NaN without a measured t_r).
    """

    plant: SecondOrderPlant
    t_r_measured: float | None
    t_p: float
    M_p: float
    t_r_model_0_100: float
    t_r_model_10_90: float
    rise_time_residual_0_100: float
    rise_time_residual_10_90: float

    @property
    def rise_time_residual(self) -> float:
        """The residual for Ogata's 0-100 % definition (the one that goes with t_p and M_p), s."""
        return self.rise_time_residual_0_100


def identify_from_step_metrics(t_r: float | None, t_p: float, M_p: float) -> Identification:
    """Identify the second-order plant from a step's peak time and overshoot (SPEC 5, errata 1 and 3).

    omega_d = pi / t_p; xi = -ln M_p / sqrt(pi^2 + ln^2 M_p); sigma = -(omega_d / pi) ln M_p;
    omega_n = sigma / xi. The rise time does not enter (two parameters, two equations); its residual
    against the model is reported.

    Args:
        t_r: Measured rise time, s, or None.
        t_p: Measured peak time, s (> 0).
        M_p: Measured overshoot fraction (0 < M_p < 1).

    Raises:
        ControlError: A metric is out of range.
    """
    if not (math.isfinite(t_p) and t_p > 0):
        raise ControlError(f"t_p = {t_p!r}: expected a peak time > 0 s")
    if not (math.isfinite(M_p) and 0.0 < M_p < 1.0):
        raise ControlError(
            f"M_p = {M_p!r}: expected an overshoot fraction strictly between 0 and 1 "
            "(a second-order step that overshoots; give 0.1 for 10 %)"
        )
    if t_r is not None and not (math.isfinite(t_r) and 0.0 < t_r):
        raise ControlError(f"t_r = {t_r!r}: expected a rise time > 0 s (or none)")
    omega_d = math.pi / t_p
    ln_mp = math.log(M_p)
    xi = -ln_mp / math.sqrt(math.pi**2 + ln_mp**2)
    sigma = -(omega_d / math.pi) * ln_mp
    omega_n = sigma / xi  # erratum 1: the thesis prints xi * sigma
    plant = SecondOrderPlant(omega_n=omega_n, xi=xi)
    tr100 = plant.rise_time_0_100
    tr1090 = plant.rise_time_10_90
    nan = float("nan")
    return Identification(
        plant=plant,
        t_r_measured=t_r,
        t_p=t_p,
        M_p=M_p,
        t_r_model_0_100=tr100,
        t_r_model_10_90=tr1090,
        rise_time_residual_0_100=(t_r - tr100) if t_r is not None else nan,
        rise_time_residual_10_90=(t_r - tr1090) if t_r is not None else nan,
    )


@dataclass(frozen=True)
class TraceFit:
    """A plant fitted to a recorded step trace by least squares.

    Attributes:
        plant: Fitted plant (omega_n, xi, DC gain K).
        delay: Fitted dead time between the command step and the response, s.
        t_step: Time of the command step, s.
        u_step: Size of the command step (command units).
        y_initial: Output before the step (baseline).
        rms_residual: RMS of (measured - model) over the samples used (output units).
        n_samples: Samples used.
        n_dropped_nonfinite: Samples dropped because t, u or y was NaN or inf.
        metrics: Identification from the fitted plant's t_p, M_p, with the trace's own 10-90 % rise
            time when it could be read from the data.
    """

    plant: SecondOrderPlant
    delay: float
    t_step: float
    u_step: float
    y_initial: float
    rms_residual: float
    n_samples: int
    n_dropped_nonfinite: int
    metrics: Identification | None = None


def identify_from_trace(
    t: npt.ArrayLike,
    u: npt.ArrayLike,
    y: npt.ArrayLike,
    fit_delay: bool = True,
    fit_gain: bool = True,
) -> TraceFit:
    """Fit K, omega_n, xi (and a dead time) to a recorded open-loop step trace.

    The command must be a single step (two levels, one change). The model is
    ``y(t) = y0 + K du step_2nd(t - t_step - delay)``; scipy.optimize.least_squares minimises the
    sample residuals, starting from the plant identified from the trace's own peak time and
    overshoot (or a critically damped guess when it does not overshoot).

    Args:
        t: Sample times, s, strictly increasing after dropping non-finite samples.
        u: Command (e.g. RPM setpoint in open loop).
        y: Measured speed (same units as the command for a unit-gain plant).
        fit_delay: Fit a dead time >= 0 as well.
        fit_gain: Fit the DC gain K (else K = 1).

    Raises:
        ControlError: Too few samples, times not increasing, no single step in the command, or the
            fit fails.
    """
    from scipy.optimize import least_squares

    t_a, u_a, y_a = (np.asarray(a, dtype=float).ravel() for a in (t, u, y))
    if not (t_a.shape == u_a.shape == y_a.shape):
        raise ControlError(f"trace columns differ in length: t {t_a.size}, u {u_a.size}, y {y_a.size}")
    ok = np.isfinite(t_a) & np.isfinite(u_a) & np.isfinite(y_a)
    n_drop = int(t_a.size - ok.sum())
    t_a, u_a, y_a = t_a[ok], u_a[ok], y_a[ok]
    if t_a.size < 10:
        raise ControlError(f"trace has {t_a.size} finite samples: expected at least 10")
    if np.any(np.diff(t_a) <= 0):
        raise ControlError("trace time column is not strictly increasing")
    u_lo = float(u_a[0])
    tol = 1e-6 * max(float(np.max(np.abs(u_a))), 1e-12)
    moved = np.flatnonzero(np.abs(u_a - u_lo) > tol)
    if moved.size == 0:
        raise ControlError("trace command is not a single step: it never changes (expected one step)")
    k_step = int(moved[0])
    u_hi = float(u_a[k_step])
    bad = np.flatnonzero(np.abs(u_a[k_step:] - u_hi) > tol)
    if bad.size:
        raise ControlError(
            "trace command is not a single step: it changes again at "
            f"t = {float(t_a[k_step + bad[0]]):.6g} s after the step at t = {float(t_a[k_step]):.6g} s"
        )
    du = u_hi - u_lo
    t_step = float(t_a[k_step])
    y0 = float(np.mean(y_a[:k_step]))
    after = t_a >= t_step
    ta, ya = t_a[after] - t_step, y_a[after] - y0
    if ta[-1] <= 0:
        raise ControlError("trace ends at the step: record the response after it")

    # Initial guess from the data's own peak and overshoot.
    y_final = float(np.median(ya[ta >= 0.8 * ta[-1]]))
    k0 = y_final / du if fit_gain else 1.0
    if not (np.isfinite(k0) and k0 > 0):
        raise ControlError(
            f"trace response has final value {y_final!r} for a step of {du!r}: expected the same sign"
        )
    ipk = int(np.argmax(ya * np.sign(du)))
    mp0 = (ya[ipk] - y_final) / y_final if y_final != 0 else 0.0
    if 0.005 < mp0 < 0.95 and ta[ipk] > 0:
        guess = identify_from_step_metrics(None, float(ta[ipk]), float(mp0)).plant
        wn0, xi0 = guess.omega_n, guess.xi
    else:
        # No overshoot: a critically damped guess that reaches 63 % where the data does.
        i63 = int(np.argmax(ya * np.sign(du) >= 0.63 * abs(y_final)))
        wn0, xi0 = 2.15 / max(float(ta[i63]), ta[1] if ta.size > 1 else 1.0), 1.0

    def unpack(x: np.ndarray) -> tuple[float, float, float, float]:
        wn, xi = float(np.exp(x[0])), float(np.exp(x[1]))
        k = float(np.exp(x[2])) if fit_gain else 1.0
        d = float(x[3]) if fit_delay else 0.0
        return wn, xi, k, d

    def residual(x: np.ndarray) -> np.ndarray:
        wn, xi, k, d = unpack(x)
        return step_response_2nd(ta - d, wn, xi, k) * du - ya

    x0 = [math.log(wn0), math.log(xi0), math.log(k0)]
    lo = [-np.inf, math.log(1e-3), -np.inf]
    hi = [np.inf, math.log(20.0), np.inf]
    if fit_delay:
        x0.append(0.0)
        lo.append(0.0)
        hi.append(0.5 * float(ta[-1]))
    x0_a = np.clip(np.asarray(x0), np.asarray(lo) + 1e-12, np.asarray(hi) - 1e-12)
    res = least_squares(residual, x0_a, bounds=(lo, hi), x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    if not res.success:
        raise ControlError(f"trace fit did not converge: {res.message}")
    wn, xi, k, d = unpack(res.x)
    plant = SecondOrderPlant(omega_n=wn, xi=xi, gain=k)
    rms = float(np.sqrt(np.mean(res.fun**2)))
    metrics = None
    if xi < 1.0:
        metrics = identify_from_step_metrics(
            _trace_rise_time_10_90(ta, ya, y_final), plant.peak_time, plant.overshoot
        )
    return TraceFit(
        plant=plant,
        delay=d,
        t_step=t_step,
        u_step=du,
        y_initial=y0,
        rms_residual=rms,
        n_samples=int(ta.size),
        n_dropped_nonfinite=n_drop,
        metrics=metrics,
    )


def _trace_rise_time_10_90(t: np.ndarray, y: np.ndarray, y_final: float) -> float | None:
    """10-90 % rise time read from the data by linear interpolation (None if it never gets there)."""
    s = y * np.sign(y_final)
    f = abs(y_final)
    times = []
    for frac in (0.1, 0.9):
        idx = np.flatnonzero(s >= frac * f)
        if idx.size == 0 or idx[0] == 0:
            return None
        i = int(idx[0])
        times.append(float(np.interp(frac * f, [s[i - 1], s[i]], [t[i - 1], t[i]])))
    return times[1] - times[0] if times[1] > times[0] else None


def read_step_trace(path: Path | str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Read a step trace CSV with a header naming time, command and speed columns.

    Accepted header names (case-insensitive): time: ``time``, ``t``, ``time_s``; command: ``command``,
    ``u``, ``command_rpm``, ``setpoint``; speed: ``speed``, ``y``, ``speed_rpm``, ``rpm``. Rows with a
    non-numeric or non-finite value are dropped and counted.

    Returns:
        (t, u, y, n_dropped).

    Raises:
        ControlError: The file has no usable header.
        OSError: The file cannot be read.
    """
    aliases = {
        "t": ("time", "t", "time_s"),
        "u": ("command", "u", "command_rpm", "setpoint", "setpoint_rpm"),
        "y": ("speed", "y", "speed_rpm", "rpm"),
    }
    p = Path(path)
    with p.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ControlError(f"trace file {str(p)!r} is empty: expected a header time,command,speed")
    header = [h.strip().lower() for h in rows[0]]
    cols = {}
    for key, names in aliases.items():
        hits = [i for i, h in enumerate(header) if h in names]
        if not hits:
            raise ControlError(
                f"trace file {str(p)!r}: header {rows[0]!r} has no {names[0]!r} column (accepted: {names})"
            )
        cols[key] = hits[0]
    out: dict[str, list[float]] = {"t": [], "u": [], "y": []}
    dropped = 0
    for row in rows[1:]:
        if not row or all(not c.strip() for c in row):
            continue
        try:
            vals = {k: float(row[i]) for k, i in cols.items()}
        except (ValueError, IndexError):
            dropped += 1
            continue
        if not all(math.isfinite(v) for v in vals.values()):
            dropped += 1
            continue
        for k, v in vals.items():
            out[k].append(v)
    return np.array(out["t"]), np.array(out["u"]), np.array(out["y"]), dropped


def write_step_trace(path: Path | str, t: npt.ArrayLike, u: npt.ArrayLike, y: npt.ArrayLike) -> None:
    """Write a step trace CSV (header ``time,command,speed``) that :func:`read_step_trace` reads back."""
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time", "command", "speed"])
        for row in zip(np.asarray(t, float), np.asarray(u, float), np.asarray(y, float)):
            w.writerow([repr(float(v)) for v in row])


# ---------------------------------------------------------------------------------------------- design


@dataclass(frozen=True)
class Margins:
    """Loop margins of C(s) G(s) (python-control stability_margins).

    gain_margin is a factor (inf when the phase never crosses -180 deg); phase_margin_deg in degrees;
    the crossover frequencies in rad/s (NaN when there is none). Names follow python-control.
    """

    gain_margin: float
    phase_margin_deg: float
    stability_margin: float  # minimum distance of the Nyquist curve from -1
    phase_crossover: float  # rad/s where the phase crosses -180 deg (the gain-margin frequency)
    gain_crossover: float  # rad/s where |L| = 1 (the phase-margin frequency)


@dataclass(frozen=True)
class StepMetrics:
    """Step metrics of a system (python-control step_info; times in s, overshoot in %)."""

    rise_time: float
    settling_time: float
    overshoot_pct: float
    peak: float
    peak_time: float
    steady_state: float


@dataclass(frozen=True)
class PIDDesign:
    """A PID G_c(s) = K_p + K_i / s + K_d s designed by pole placement for a second-order plant.

    Attributes:
        kp, ki, kd: Gains (RPM of command per RPM of error; K_i in 1/s, K_d in s).
        plant: The plant designed for.
        xi_w, omega_w, p: Design parameters: dominant damping, natural frequency (rad/s), extra pole.
        designed_poles: Roots of (s + p)(s^2 + 2 xi_w omega_w s + omega_w^2), sorted.
        achieved_poles: Poles of python-control's feedback(C G, 1), sorted the same way.
        margins: Gain and phase margins of the loop C G.
        closed_loop: Step metrics of the closed loop (reference to speed).
        open_loop: Step metrics of the plant alone.
    """

    kp: float
    ki: float
    kd: float
    plant: SecondOrderPlant
    xi_w: float
    omega_w: float
    p: float
    designed_poles: np.ndarray = field(compare=False)
    achieved_poles: np.ndarray = field(compare=False)
    margins: Margins
    closed_loop: StepMetrics
    open_loop: StepMetrics

    def controller_tf(self, tau_d: float = 0.0) -> ct.TransferFunction:
        """C(s) = K_p + K_i / s + K_d s / (tau_d s + 1) (tau_d = 0: the ideal PID of the design)."""
        return pid_tf(self.kp, self.ki, self.kd, tau_d)

    def closed_loop_tf(self, tau_d: float = 0.0) -> ct.TransferFunction:
        """Reference-to-speed closed loop C G / (1 + C G)."""
        return ct.feedback(self.controller_tf(tau_d) * self.plant.tf(), 1)

    @property
    def max_pole_error(self) -> float:
        """max |achieved - designed| / |designed| over the poles, paired to minimise it."""
        return pole_mismatch(self.achieved_poles, self.designed_poles)


def pid_tf(kp: float, ki: float, kd: float, tau_d: float = 0.0) -> ct.TransferFunction:
    """Parallel PID as a transfer function; a derivative filter when ``tau_d > 0``."""
    if tau_d > 0:
        # (kp + ki/s + kd s/(tau s + 1)) over the common denominator s (tau s + 1)
        num = [kp * tau_d + kd, kp + ki * tau_d, ki]
        return ct.tf(num, [tau_d, 1.0, 0.0])
    return ct.tf([kd, kp, ki], [1.0, 0.0])


def pole_placement_gains(
    plant: SecondOrderPlant, xi_w: float, omega_w: float, p: float
) -> tuple[float, float, float]:
    """(K_p, K_i, K_d) matching the closed-loop characteristic polynomial (SPEC 5, erratum 2)."""
    b0, a1, a0 = plant.b0, plant.a1, plant.a0
    kp = (omega_w**2 + 2.0 * xi_w * omega_w * p - a0) / b0
    ki = p * omega_w**2 / b0
    kd = (2.0 * xi_w * omega_w + p - a1) / b0
    return kp, ki, kd


def design_pid(
    plant: SecondOrderPlant,
    xi_w: float = THESIS_XI_W,
    omega_w: float = THESIS_OMEGA_W,
    p: float | None = None,
) -> PIDDesign:
    """Design a PID by pole placement and check it with python-control.

    Args:
        plant: The motor plant.
        xi_w: Damping ratio of the dominant closed-loop poles (thesis 1.0).
        omega_w: Their natural frequency, rad/s (thesis 3.3).
        p: The extra real pole at s = -p; default 10 xi_w omega_w (thesis).

    Raises:
        ControlError: A design parameter is not a finite positive number.
    """
    if p is None:
        p = THESIS_P_FACTOR * xi_w * omega_w
    for name, v in (("xi_w", xi_w), ("omega_w", omega_w), ("p", p)):
        if not (math.isfinite(v) and v > 0):
            raise ControlError(f"{name} = {v!r}: expected a finite number > 0 (a stable closed-loop pole)")
    kp, ki, kd = pole_placement_gains(plant, xi_w, omega_w, p)
    designed = designed_poles(xi_w, omega_w, p)
    return _evaluate(kp, ki, kd, plant, xi_w, omega_w, p, designed)


def designed_poles(xi_w: float, omega_w: float, p: float) -> np.ndarray:
    """Roots of (s + p)(s^2 + 2 xi_w omega_w s + omega_w^2) in closed form, sorted like achieved poles.

    Closed form rather than ``np.roots`` because the thesis's xi_w = 1 gives a double root, which a
    polynomial root finder only resolves to about sqrt(machine epsilon).
    """
    disc = complex(xi_w * xi_w - 1.0) ** 0.5
    pair = [-xi_w * omega_w + omega_w * disc, -xi_w * omega_w - omega_w * disc]
    return _sort_poles(np.array([-p, *pair], dtype=complex))


def evaluate_gains(plant: SecondOrderPlant, kp: float, ki: float, kd: float) -> PIDDesign:
    """Evaluate arbitrary PID gains on ``plant`` (poles, margins, step metrics) as a :class:`PIDDesign`.

    ``designed_poles`` are then the achieved ones, and xi_w, omega_w, p are NaN.
    """
    cl = ct.feedback(pid_tf(kp, ki, kd) * plant.tf(), 1)
    achieved = _sort_poles(np.asarray(ct.poles(cl)))
    nan = float("nan")
    return _evaluate(kp, ki, kd, plant, nan, nan, nan, achieved)


def _evaluate(
    kp: float,
    ki: float,
    kd: float,
    plant: SecondOrderPlant,
    xi_w: float,
    omega_w: float,
    p: float,
    designed: np.ndarray,
) -> PIDDesign:
    g = plant.tf()
    loop = pid_tf(kp, ki, kd) * g
    cl = ct.feedback(loop, 1)
    achieved = _sort_poles(np.asarray(ct.poles(cl)))
    gm, pm, sm, wpc, wgc, _wms = ct.stability_margins(loop)
    margins = Margins(
        gain_margin=_nan_if_none(gm),
        phase_margin_deg=_nan_if_none(pm),
        stability_margin=_nan_if_none(sm),
        phase_crossover=_nan_if_none(wpc),
        gain_crossover=_nan_if_none(wgc),
    )
    stable = bool(np.all(achieved.real < 0))
    return PIDDesign(
        kp=kp,
        ki=ki,
        kd=kd,
        plant=plant,
        xi_w=xi_w,
        omega_w=omega_w,
        p=p,
        designed_poles=designed,
        achieved_poles=achieved,
        margins=margins,
        closed_loop=_step_metrics(cl) if stable else _unstable_metrics(),
        open_loop=_step_metrics(g),
    )


def _nan_if_none(v: Any) -> float:
    return float("nan") if v is None else float(v)


def pole_mismatch(poles: np.ndarray, reference: np.ndarray) -> float:
    """Largest relative distance |p - r| / |r| between two pole sets, under the best pairing.

    Sorting alone can pair a pole with the wrong partner when a double pole splits into a complex pair,
    so every pairing is tried (closed loops here have three poles).
    """
    from itertools import permutations

    a = np.asarray(poles, dtype=complex)
    r = np.asarray(reference, dtype=complex)
    if a.shape != r.shape:
        raise ControlError(f"pole sets differ in size: {a.size} vs {r.size}")
    scale = np.where(np.abs(r) > 0, np.abs(r), 1.0)
    if a.size > 7:
        return float(np.max(np.abs(_sort_poles(a) - _sort_poles(r)) / scale))
    return float(min(np.max(np.abs(a[list(perm)] - r) / scale) for perm in permutations(range(a.size))))


def _sort_poles(p: np.ndarray) -> np.ndarray:
    """Sort poles by real part, then imaginary part, so designed and achieved line up."""
    p = np.asarray(p, dtype=complex)
    return p[np.lexsort((p.imag, np.round(p.real, 9)))]


def _step_metrics(sys: ct.LTI) -> StepMetrics:
    """step_info on a time grid long enough for the slowest pole to settle (python-control's automatic
    horizon can stop before a slow closed loop reaches 90 %)."""
    poles = np.asarray(ct.poles(sys))
    decay = float(np.min(-poles.real)) if poles.size else 1.0
    if not decay > 0:
        return _unstable_metrics()
    fastest = float(np.max(np.abs(poles))) if poles.size else 1.0
    t_end = 12.0 / decay
    n = int(min(max(6000, 20 * t_end * fastest), 20_000))
    info = ct.step_info(sys, T=np.linspace(0.0, t_end, n))
    return StepMetrics(
        rise_time=float(info["RiseTime"]),
        settling_time=float(info["SettlingTime"]),
        overshoot_pct=float(info["Overshoot"]),
        peak=float(info["Peak"]),
        peak_time=float(info["PeakTime"]),
        steady_state=float(info["SteadyStateValue"]),
    )


def _unstable_metrics() -> StepMetrics:
    nan = float("nan")
    return StepMetrics(nan, nan, nan, nan, nan, nan)


# ------------------------------------------------------------------------------------- discrete time


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


class DiscretePID:
    """A sampled PID with output saturation, anti-windup and a filtered derivative.

    At each sample k: e = r - y; P = K_p e; I += K_i dt e (backward Euler); D from a first-order filtered
    derivative (backward Euler of K_d s / (tau_d s + 1)) of the error, or of -y with
    ``derivative_on_measurement`` (no derivative kick on setpoint steps); u = P + I + D, saturated to
    [u_min, u_max].

    Anti-windup: ``"conditional"`` (default) skips the integration when the output is saturated and the
    error would drive it further into saturation; ``"back_calculation"`` feeds (u_sat - u) / t_t back
    into the integrator (t_t defaults to sqrt(T_i T_d) with T_i = K_p / K_i, T_d = K_d / K_p, or dt).

    Args:
        kp, ki, kd: Gains (continuous-time units: K_i in 1/s, K_d in s).
        dt: Sample time, s (default 1 / CONTROLLER_RATE_HZ).
        u_min, u_max: Output limits.
        tau_d: Derivative filter time constant, s (0 = plain backward difference).
        derivative_on_measurement: Differentiate -y instead of the error.
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
        derivative_on_measurement: bool = False,
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
        """A discrete PID with the gains of ``design``; keyword arguments as for the constructor."""
        return cls(design.kp, design.ki, design.kd, dt=dt, **kwargs)

    def reset(self, integral: float = 0.0, previous: float = 0.0) -> None:
        """Set the integral term and the derivative memory.

        Args:
            integral: Integral term (e.g. the current command, for a bumpless start).
            previous: The differentiated signal at the previous sample: the error, or -measurement with
                ``derivative_on_measurement``. The default 0 means "at rest at zero", like a continuous
                system with zero initial conditions, so a setpoint step on the first update gives the
                same derivative kick as the continuous PID. Pass the current value to start without a kick.
        """
        self.integral = float(integral)
        self._d = 0.0
        self._prev = float(previous)
        self.saturated = False
        self.u = 0.0

    def update(self, setpoint: float, measurement: float) -> float:
        """One sample: return the (saturated) command for this setpoint and measured value."""
        e = setpoint - measurement
        x = -measurement if self.derivative_on_measurement else e
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
        sysc = plant.ss()
        ac, bc, cc = (np.asarray(m, dtype=float) for m in (sysc.A, sysc.B, sysc.C))
        n = ac.shape[0]
        # Augment with q' = y so the ZOH discretisation also gives the exact integral of the output.
        a_aug = np.zeros((n + 1, n + 1))
        a_aug[:n, :n] = ac
        a_aug[n, :n] = cc.ravel()
        b_aug = np.concatenate([bc.ravel(), [0.0]])[:, None]
        c_aug = np.concatenate([cc.ravel(), [0.0]])[None, :]
        sysd = ct.c2d(ct.ss(a_aug, b_aug, c_aug, 0.0), dt, method="zoh")
        ad, bd = np.asarray(sysd.A, dtype=float), np.asarray(sysd.B, dtype=float).ravel()
        self.A = ad[:n, :n]
        self.B = bd[:n]
        self.C = cc.ravel()
        self._q_row = ad[n, :n]
        self._q_b = float(bd[n])
        self.integral = 0.0
        # Steady state per unit input of the continuous realisation: x_ss = -A^-1 B.
        self._x_per_u = -np.linalg.solve(np.asarray(sysc.A, float), np.asarray(sysc.B, float).ravel())
        self.reset()

    @property
    def output(self) -> float:
        """Current output y[k] (before the next input is applied)."""
        return float(self.C @ self.x)

    def reset(self, y0: float = 0.0) -> None:
        """Put the plant at rest at output ``y0`` (the steady state for a constant input y0 / K).

        Also zeroes :attr:`integral`.
        """
        self.x = self._x_per_u * (y0 / self.plant.gain)
        self.integral = 0.0

    def step(self, u: float) -> float:
        """Hold input ``u`` for one sample; return the output at the end of the sample."""
        self.integral += float(self._q_row @ self.x) + self._q_b * u
        self.x = self.A @ self.x + self.B * u
        return float(self.C @ self.x)

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
        previous = self.pid._prev if self.pid is not None else 0.0
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


# ----------------------------------------------------------------------------------------- Roboteq


@dataclass(frozen=True)
class RoboteqGains:
    """PID gains in Roboteq firmware units and what they do once quantised.

    Attributes:
        kp, ki, kd: Integer firmware values (``^KP``/``^KI``/``^KD`` in 1.x, same names in 2.x).
        firmware_major: 1 or 2.
        multiplier: 10 (1.x) or 1,000,000 (2.x).
        scale: Units conversion from our RPM-based gains to the firmware's normalised gains.
        effective: The continuous gains the integers stand for, (kp, ki, kd).
        quantised: Evaluation of ``effective`` on the plant (achieved poles, margins, step metrics).
        designed_poles: The poles the unquantised design places.
    """

    kp: int
    ki: int
    kd: int
    firmware_major: int
    multiplier: int
    scale: float
    effective: tuple[float, float, float]
    quantised: PIDDesign
    designed_poles: np.ndarray = field(default_factory=lambda: np.zeros(0), compare=False)

    @property
    def max_pole_shift(self) -> float:
        """Largest |quantised pole - designed pole| / |designed pole|, poles paired to minimise it."""
        return pole_mismatch(self.quantised.achieved_poles, self.designed_poles)


FIRMWARE_MULTIPLIER = {1: 10, 2: 1_000_000}
FIRMWARE_RANGE = {1: (0, 255), 2: (0, 2**31 - 1)}


def roboteq_gains(design: PIDDesign, firmware_major: int = 1, scale: float = 1.0) -> RoboteqGains:
    """Convert a design's gains to Roboteq integers and evaluate the quantised controller.

    Assumptions on units (the Roboteq manuals give the integer encodings, not the loop's internals):

    * The firmware's speed PID runs on normalised quantities: the speed command and the encoder speed are
      both scaled to +-1000 at the configured max RPM (``^MXRPM``), and the PID output is the power
      command in +-1000. Our plant input is the open-loop command expressed as the RPM it gives in
      steady state, i.e. power / 1000 x max RPM, the same normalisation as the error. So a gain of ours
      equals the firmware gain times ``scale`` = 1 when ``^MXRPM`` is the motor's max RPM (1000) and
      full power gives max RPM. Pass ``scale`` = (output full scale / input full scale) otherwise.
    * The integral and derivative gains are continuous-time gains (1/s and s) as in our design: the
      firmware's 1 kHz loop scales them by its own sample time.
    * Firmware 1.x stores each gain as an integer 0-255 = gain x 10 (resolution 0.1); 2.x stores
      gain x 1,000,000.

    Args:
        design: The PID design.
        firmware_major: 1 or 2.
        scale: Multiplies the gains before the encoding (see above).

    Raises:
        ControlError: Unknown firmware, a negative gain, or a gain beyond the firmware's range.
    """
    if firmware_major not in FIRMWARE_MULTIPLIER:
        raise ControlError(f"firmware_major = {firmware_major!r}: expected 1 or 2")
    if not (math.isfinite(scale) and scale > 0):
        raise ControlError(f"scale = {scale!r}: expected a finite number > 0")
    mult = FIRMWARE_MULTIPLIER[firmware_major]
    lo, hi = FIRMWARE_RANGE[firmware_major]
    ints = []
    for name, g in (("kp", design.kp), ("ki", design.ki), ("kd", design.kd)):
        raw = g * scale * mult
        q = round(raw)
        if q < lo or q > hi:
            raise ControlError(
                f"Roboteq firmware {firmware_major}.x cannot hold {name} = {g:.6g} (x{mult} = {raw:.6g}): "
                f"the integer must be in {lo}..{hi}; change omega_w / p, or use firmware 2.x"
            )
        ints.append(int(q))
    effective = tuple(v / mult / scale for v in ints)
    quantised = evaluate_gains(design.plant, *effective)
    return RoboteqGains(
        kp=ints[0],
        ki=ints[1],
        kd=ints[2],
        firmware_major=firmware_major,
        multiplier=mult,
        scale=scale,
        effective=(effective[0], effective[1], effective[2]),
        quantised=quantised,
        designed_poles=design.designed_poles,
    )


def gains_from_roboteq(
    kp: int, ki: int, kd: int, firmware_major: int = 1, scale: float = 1.0
) -> tuple[float, float, float]:
    """Inverse of :func:`roboteq_gains`' encoding: firmware integers -> continuous gains."""
    if firmware_major not in FIRMWARE_MULTIPLIER:
        raise ControlError(f"firmware_major = {firmware_major!r}: expected 1 or 2")
    m = FIRMWARE_MULTIPLIER[firmware_major]
    return (kp / m / scale, ki / m / scale, kd / m / scale)
