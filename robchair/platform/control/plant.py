"""The identified wheel-motor plant: a second-order transfer function and its analytic step response.

Units: command RPM in, motor-shaft RPM out (see :mod:`robchair.platform.control`).

python-control is imported where a method needs it (:meth:`SecondOrderPlant.tf`,
:meth:`~SecondOrderPlant.ss`), not with the module: it pulls in scipy.signal and matplotlib (~1.7 s), which
the simulator, which only needs :meth:`~SecondOrderPlant.state_matrices`, does not use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from robchair.platform.errors import RobChairError

if TYPE_CHECKING:
    import control as ct


class ControlError(RobChairError, ValueError):
    """Invalid input to the control design (impossible step metrics, bad gains, unusable trace)."""


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
        import control as ct

        return ct.tf([self.b0], [1.0, self.a1, self.a0])

    def ss(self) -> ct.StateSpace:
        """The plant as a python-control state-space system (one input, one output)."""
        import control as ct

        return ct.tf2ss(self.tf())

    def state_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C) of x' = A x + B u, y = C x, shapes (2, 2), (2, 1), (1, 2): the controllable canonical
        form A = [[-a1, -a0], [1, 0]], B = [[1], [0]], C = [[0, b0]].

        The realisation :meth:`ss` gives (python-control's ``tf2ss`` without slycot is scipy's, which
        builds exactly these matrices, element for element), without importing python-control.
        """
        a = np.array([[-self.a1, -self.a0], [1.0, 0.0]])
        b = np.array([[1.0], [0.0]])
        c = np.array([[0.0, self.b0]])
        return a, b, c

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
