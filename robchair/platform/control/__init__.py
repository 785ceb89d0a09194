"""Wheel-motor control: step-response identification, PID pole placement, discrete PID and plant.

This is the chain of the thesis's Appendix B (SPEC.md section 5) as code. python-control does every
transfer-function computation (closed loops, poles, margins, step metrics); scipy does the fits.

Units. The plant maps the open-loop *command* to the motor *shaft speed*, both in RPM: the command is
expressed as the shaft speed it would give in steady state (Roboteq open-loop power level x max RPM /
1000, assuming speed is proportional to power), so the identified plant has unit DC gain and
``b0 = omega_n**2 = a0``. PID gains therefore map RPM of error to RPM of command: K_p is dimensionless,
K_i is in 1/s and K_d in s.

Rates. :data:`CONTROLLER_RATE_HZ` = 1000 Hz is the rate at which the simulator (``sim.robot``) and
the Roboteq emulator run :class:`DiscretePID` on :class:`DiscretePlant`, the same classes at the same
rate, whatever the physics or host loop rate. Assumption: the MDC2230's speed loop runs at about 1 kHz
(the exact rate is not in the sources at hand). At 1 kHz the sampled loop stays within 0.75 % of the
step of the continuous design after the first 10 ms (tested); at 100 Hz the deviation grows to about
8 %, because the error is first order in the sample time.

Derivative. :class:`DiscretePID` differentiates the measurement, not the error, by default (set-point
weight 0 on the derivative term). With derivative on error every set-point step multiplies into a
K_d / dt impulse that drives the +-1000 command into saturation, and the sampled loop then rises
(10-90 %) in 0.53-0.54 s (motor 1; 0.62-0.64 s motor 2) where the design's C G / (1 + C G) says
0.94 s (1.02 s). Derivative on measurement keeps the designed closed-loop poles (the characteristic
polynomial does not depend on where the derivative acts); its reference path (K_p + K_i / s) G /
(1 + C G) rises in 0.527 s (0.620 s), and so does the sampled loop at 1 kHz at every step size
(tested). ``derivative_on_measurement=False`` gives the textbook PID.

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
the trace fit with its quality (R^2, residual relative to the step), refusal of traces that cannot be
a speed step in the declared units (:mod:`robchair.platform.control.identification`), a discrete PID with
saturation, anti-windup and a filtered derivative, and exact zero-order-hold discretisation of the
plant. The Roboteq register encoding of the gains lives beside the driver, in ``hw.roboteq.gains``.

Modules: :mod:`~robchair.platform.control.plant` (the second-order plant),
:mod:`~robchair.platform.control.identification` (step metrics and trace fits),
:mod:`~robchair.platform.control.traces` (trace files), :mod:`~robchair.platform.control.design`
(pole placement, margins), :mod:`~robchair.platform.control.discrete` (the sampled loop) and
:mod:`~robchair.platform.control.rootlocus` (root locus through python-control).

Importing this package does not import python-control: the functions that use it import it (it costs
~1.7 s, most of it scipy.signal and matplotlib), so the simulator, which runs :class:`DiscretePID` on
:class:`DiscretePlant` with the gains of :func:`pid_gains`, starts without it.
"""

from __future__ import annotations

from robchair.platform.control.design import (
    THESIS_OMEGA_W,
    THESIS_P_FACTOR,
    THESIS_XI_W,
    Margins,
    PIDDesign,
    StepMetrics,
    design_pid,
    designed_poles,
    evaluate_gains,
    pid_gains,
    pid_tf,
    pole_mismatch,
    pole_placement_gains,
)
from robchair.platform.control.discrete import (
    CONTROLLER_RATE_HZ,
    DiscretePID,
    DiscretePlant,
    MotorModel,
    SampledLoop,
    sampled_loop,
)
from robchair.platform.control.identification import (
    Identification,
    TraceFit,
    identify_from_step_metrics,
    identify_from_trace,
)
from robchair.platform.control.plant import ControlError, SecondOrderPlant, step_response_2nd
from robchair.platform.control.rootlocus import open_loop_poles_and_zeros, root_locus
from robchair.platform.control.traces import (
    COMMAND_UNITS,
    SPEED_UNITS,
    TIME_UNITS,
    TraceUnits,
    check_trace_gain,
    fit_step_trace,
    normalise_trace,
    read_step_trace,
    write_step_trace,
)

__all__ = [
    "COMMAND_UNITS",
    "CONTROLLER_RATE_HZ",
    "SPEED_UNITS",
    "THESIS_OMEGA_W",
    "THESIS_P_FACTOR",
    "THESIS_XI_W",
    "TIME_UNITS",
    "ControlError",
    "DiscretePID",
    "DiscretePlant",
    "Identification",
    "Margins",
    "MotorModel",
    "PIDDesign",
    "SampledLoop",
    "SecondOrderPlant",
    "StepMetrics",
    "TraceFit",
    "TraceUnits",
    "check_trace_gain",
    "design_pid",
    "designed_poles",
    "evaluate_gains",
    "fit_step_trace",
    "identify_from_step_metrics",
    "identify_from_trace",
    "normalise_trace",
    "open_loop_poles_and_zeros",
    "pid_gains",
    "pid_tf",
    "pole_mismatch",
    "pole_placement_gains",
    "read_step_trace",
    "root_locus",
    "sampled_loop",
    "step_response_2nd",
    "write_step_trace",
]
