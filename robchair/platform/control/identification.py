"""Plant identification: from a step's peak time and overshoot (SPEC 5), or by fitting a recorded trace."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from robchair.platform.control.plant import ControlError, SecondOrderPlant, step_response_2nd


@dataclass(frozen=True)
class Identification:
    """A plant identified from step metrics (t_r, t_p, M_p), with the unexplained rise time.

    Attributes:
        plant: The identified plant (unit DC gain).
        t_r_measured: The measured rise time, s (None when not given).
        t_p: Peak time used, s.
        M_p: Overshoot used.
        t_r_model_0_100: The model's 0-100 % rise time (pi - beta) / omega_d, s.
        t_r_model_10_90: The model's 10-90 % rise time, s: found by root finding (scipy's ``brentq``) on
            first read and kept. The simulator identifies its motors' plants and never reads it; its
            processes then do not import scipy.optimize (~0.1 s of CPU).
        rise_time_residual_0_100: measured - model (0-100 %), s (NaN without a measured t_r).
        rise_time_residual_10_90: measured - model (10-90 %), s (NaN without a measured t_r).
    """

    plant: SecondOrderPlant
    t_r_measured: float | None
    t_p: float
    M_p: float
    t_r_model_0_100: float
    rise_time_residual_0_100: float

    @functools.cached_property
    def t_r_model_10_90(self) -> float:
        return self.plant.rise_time_10_90

    @property
    def rise_time_residual_10_90(self) -> float:
        return (self.t_r_measured - self.t_r_model_10_90) if self.t_r_measured is not None else float("nan")

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
    return Identification(
        plant=plant,
        t_r_measured=t_r,
        t_p=t_p,
        M_p=M_p,
        t_r_model_0_100=tr100,
        rise_time_residual_0_100=(t_r - tr100) if t_r is not None else float("nan"),
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
        r_squared: Coefficient of determination 1 - SS_res / SS_tot of the fit over the samples used.
        relative_residual: ``rms_residual`` over the size of the fitted output step |K du| (so 0.02
            means the model misses the data by 2 % of the step, RMS).
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
    r_squared: float = float("nan")
    relative_residual: float = float("nan")


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
    _check_response(y_a[:k_step], y_final, du)
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
    ss_tot = float(np.sum((ya - np.mean(ya)) ** 2))
    r2 = 1.0 - float(np.sum(res.fun**2)) / ss_tot if ss_tot > 0 else float("nan")
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
        r_squared=r2,
        relative_residual=rms / abs(k * du),
        n_samples=int(ta.size),
        n_dropped_nonfinite=n_drop,
        metrics=metrics,
    )


def _check_response(y_before: np.ndarray, y_change: float, du: float) -> None:
    """Refuse a trace whose speed does not move with the command step.

    The response counts as absent when the settled change (median of the last 20 % of the trace minus
    the baseline) is below five standard deviations of the speed before the step, or below 2 % of the
    command step (both in the trace's units; with no samples before the step only the second test).
    """
    noise = float(np.std(y_before)) if y_before.size >= 3 else 0.0
    floor = max(5.0 * noise, 0.02 * abs(du))
    if not abs(y_change) > floor:
        raise ControlError(
            f"trace has no response: the speed settles {y_change:.4g} from its level before the command "
            f"step of {du:.4g}, within {floor:.3g} (5 x the noise before the step, or 2 % of the step); "
            "check that the speed column belongs to the commanded motor"
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
