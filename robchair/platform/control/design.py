"""PID design by pole placement (SPEC 5, erratum 2), checked with python-control: poles, margins, steps.

python-control is imported by the functions that use it, not with the module (it costs ~1.7 s, most of it
scipy.signal and matplotlib): :func:`pid_gains`, the gains alone, is what the simulator needs.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from robchair.platform.control.plant import ControlError, SecondOrderPlant

if TYPE_CHECKING:
    import control as ct

THESIS_XI_W = 1.0
THESIS_OMEGA_W = 3.3  # rad/s
THESIS_P_FACTOR = 10.0  # p = 10 xi_w omega_w


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
        closed_loop: Step metrics of the closed loop from reference to speed, for the structure
            ``derivative_on_measurement`` names (NaN when unstable). Simulated on first access and
            kept: each costs a step response of several thousand samples, and most evaluations (the
            firmware-quantised gains of :func:`hw.roboteq.gains.roboteq_gains`) never read them.
        open_loop: Step metrics of the plant alone (first access, as ``closed_loop``).
        derivative_on_measurement: The derivative acts on the measured speed only (set-point weight 0
            on the D term, as :class:`~robchair.platform.control.DiscretePID` runs by default), so the
            reference path is (K_p + K_i / s) G / (1 + C G); False: on the error, C G / (1 + C G). The poles,
            margins and gains are the same either way; only the zeros of the reference path differ.
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
    derivative_on_measurement: bool = True

    @functools.cached_property
    def closed_loop(self) -> StepMetrics:
        if not bool(np.all(self.achieved_poles.real < 0)):
            return _unstable_metrics()
        return _step_metrics(
            reference_tf(self.kp, self.ki, self.kd, self.plant, 0.0, self.derivative_on_measurement)
        )

    @functools.cached_property
    def open_loop(self) -> StepMetrics:
        return _step_metrics(self.plant.tf())

    def controller_tf(self, tau_d: float = 0.0) -> ct.TransferFunction:
        """C(s) = K_p + K_i / s + K_d s / (tau_d s + 1) (tau_d = 0: the ideal PID of the design)."""
        return pid_tf(self.kp, self.ki, self.kd, tau_d)

    def closed_loop_tf(
        self, tau_d: float = 0.0, derivative_on_measurement: bool | None = None
    ) -> ct.TransferFunction:
        """Reference-to-speed closed loop (default: the structure of :attr:`derivative_on_measurement`).

        Derivative on the error: C G / (1 + C G). On the measurement: (K_p + K_i / s) G / (1 + C G).
        """
        dom = (
            self.derivative_on_measurement if derivative_on_measurement is None else derivative_on_measurement
        )
        return reference_tf(self.kp, self.ki, self.kd, self.plant, tau_d, dom)

    @property
    def max_pole_error(self) -> float:
        """max |achieved - designed| / |designed| over the poles, paired to minimise it."""
        return pole_mismatch(self.achieved_poles, self.designed_poles)


def pid_tf(kp: float, ki: float, kd: float, tau_d: float = 0.0) -> ct.TransferFunction:
    """Parallel PID as a transfer function; a derivative filter when ``tau_d > 0``."""
    import control as ct

    if tau_d > 0:
        # (kp + ki/s + kd s/(tau s + 1)) over the common denominator s (tau s + 1)
        num = [kp * tau_d + kd, kp + ki * tau_d, ki]
        return ct.tf(num, [tau_d, 1.0, 0.0])
    return ct.tf([kd, kp, ki], [1.0, 0.0])


def reference_tf(
    kp: float,
    ki: float,
    kd: float,
    plant: SecondOrderPlant,
    tau_d: float = 0.0,
    derivative_on_measurement: bool = True,
) -> ct.TransferFunction:
    """Reference-to-speed transfer function of the loop, for either placement of the derivative."""
    import control as ct

    g = plant.tf()
    c = pid_tf(kp, ki, kd, tau_d)
    if not derivative_on_measurement:
        return ct.feedback(c * g, 1)
    if tau_d == 0.0:
        # exact polynomials: b0 (K_p s + K_i) / (s^3 + (K_d b0 + a1) s^2 + (K_p b0 + a0) s + K_i b0)
        b0, a1, a0 = plant.b0, plant.a1, plant.a0
        return ct.tf([b0 * kp, b0 * ki], [1.0, kd * b0 + a1, kp * b0 + a0, ki * b0])
    c_ref = ct.tf([kp, ki], [1.0, 0.0])
    return ct.minreal(c_ref * ct.feedback(g, c), verbose=False)


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
    derivative_on_measurement: bool = True,
) -> PIDDesign:
    """Design a PID by pole placement and check it with python-control.

    Args:
        plant: The motor plant.
        xi_w: Damping ratio of the dominant closed-loop poles (thesis 1.0).
        omega_w: Their natural frequency, rad/s (thesis 3.3).
        p: The extra real pole at s = -p; default 10 xi_w omega_w (thesis).
        derivative_on_measurement: Structure the closed-loop step metrics describe (see
            :class:`PIDDesign`); the gains and poles do not depend on it.

    Raises:
        ControlError: A design parameter is not a finite positive number.
    """
    if p is None:
        p = THESIS_P_FACTOR * xi_w * omega_w
    kp, ki, kd = pid_gains(plant, xi_w, omega_w, p)
    designed = designed_poles(xi_w, omega_w, p)
    return _evaluate(kp, ki, kd, plant, xi_w, omega_w, p, designed, derivative_on_measurement)


def pid_gains(
    plant: SecondOrderPlant,
    xi_w: float = THESIS_XI_W,
    omega_w: float = THESIS_OMEGA_W,
    p: float | None = None,
) -> tuple[float, float, float]:
    """(K_p, K_i, K_d) of :func:`design_pid` for the same arguments, without its python-control checks
    (closed-loop poles, margins, step metrics): what the simulator needs to run the loop.

    Raises:
        ControlError: A design parameter is not a finite positive number.
    """
    if p is None:
        p = THESIS_P_FACTOR * xi_w * omega_w
    for name, v in (("xi_w", xi_w), ("omega_w", omega_w), ("p", p)):
        if not (math.isfinite(v) and v > 0):
            raise ControlError(f"{name} = {v!r}: expected a finite number > 0 (a stable closed-loop pole)")
    return pole_placement_gains(plant, xi_w, omega_w, p)


def designed_poles(xi_w: float, omega_w: float, p: float) -> np.ndarray:
    """Roots of (s + p)(s^2 + 2 xi_w omega_w s + omega_w^2) in closed form, sorted like achieved poles.

    Closed form rather than ``np.roots`` because the thesis's xi_w = 1 gives a double root, which a
    polynomial root finder only resolves to about sqrt(machine epsilon).
    """
    disc = complex(xi_w * xi_w - 1.0) ** 0.5
    pair = [-xi_w * omega_w + omega_w * disc, -xi_w * omega_w - omega_w * disc]
    return _sort_poles(np.array([-p, *pair], dtype=complex))


def evaluate_gains(
    plant: SecondOrderPlant, kp: float, ki: float, kd: float, derivative_on_measurement: bool = True
) -> PIDDesign:
    """Evaluate arbitrary PID gains on ``plant`` (poles, margins, step metrics) as a :class:`PIDDesign`.

    ``designed_poles`` are then the achieved ones, and xi_w, omega_w, p are NaN.
    """
    import control as ct

    cl = ct.feedback(pid_tf(kp, ki, kd) * plant.tf(), 1)
    achieved = _sort_poles(np.asarray(ct.poles(cl)))
    nan = float("nan")
    return _evaluate(kp, ki, kd, plant, nan, nan, nan, achieved, derivative_on_measurement)


def _evaluate(
    kp: float,
    ki: float,
    kd: float,
    plant: SecondOrderPlant,
    xi_w: float,
    omega_w: float,
    p: float,
    designed: np.ndarray,
    derivative_on_measurement: bool = True,
) -> PIDDesign:
    import control as ct

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
        derivative_on_measurement=derivative_on_measurement,
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
    import control as ct

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
