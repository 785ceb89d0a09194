"""The two wheels' motor controller ticks in one compiled call (numba).

:meth:`sim.robot.SimRobot._pre_step` runs 4 or 5 ticks of the 1 kHz controller per 240 Hz physics
step and wheel: a :class:`robchair.platform.control.DiscretePID` in front of a
:class:`robchair.platform.control.DiscretePlant`. In Python that is ~20 method calls per physics step,
about a fifth of the physics' CPU time (py-spy, light env). :meth:`CompiledWheels.ticks` runs the same
arithmetic, operation for operation in the same order (no fast-math, so the results are the Python
classes' bit for bit; the tests compare both), for both wheels in one call. The classes stay the
owners of the state: :func:`pack` reads their state (and their parameters, when the objects or gains
changed) into flat arrays, :func:`unpack` writes the state back.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from mapping._deps import announce_compilation
from robchair.platform.control import DiscretePID, DiscretePlant

# parameter columns (one row per wheel)
KP, KI, KD, DT, TAU_D, U_MIN, U_MAX, DOM, AW, T_T = range(10)
A00, A01, A10, A11, B0, B1, C0, C1, Q0, Q1, QB, HAS_PID = range(10, 22)
N_PARAMS = 22
# state columns
INTEGRAL, D, PREV, PREV_UNSET, SATURATED, U, X0, X1, PLANT_INTEGRAL, COMMAND, OUTPUT = range(11)
N_STATE = 11
_ANTI_WINDUP = {"conditional": 0.0, "back_calculation": 1.0, "none": 2.0}


@numba.njit(cache=True, nogil=True)
def _wheel_ticks(p, s, inputs, ticks):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    setpoint, measured, closed = inputs[0], inputs[1], inputs[2]
    for w in range(p.shape[0]):
        start = s[w, OUTPUT]
        for _ in range(ticks):
            if closed[w] != 0.0 and p[w, HAS_PID] != 0.0:
                y = measured[w] + (s[w, OUTPUT] - start)
                # DiscretePID.update
                e = setpoint[w] - y
                x = -y if p[w, DOM] != 0.0 else e
                if s[w, PREV_UNSET] != 0.0:
                    s[w, PREV] = x
                    s[w, PREV_UNSET] = 0.0
                a = p[w, TAU_D] / (p[w, TAU_D] + p[w, DT])
                s[w, D] = a * s[w, D] + p[w, KD] * (x - s[w, PREV]) / (p[w, TAU_D] + p[w, DT])
                s[w, PREV] = x
                pp = p[w, KP] * e
                i_new = s[w, INTEGRAL] + p[w, KI] * p[w, DT] * e
                u_raw = pp + i_new + s[w, D]
                u = min(max(u_raw, p[w, U_MIN]), p[w, U_MAX])
                if p[w, AW] == 0.0:
                    pushing_out = (u_raw > p[w, U_MAX] and e > 0) or (u_raw < p[w, U_MIN] and e < 0)
                    if not pushing_out:
                        s[w, INTEGRAL] = i_new
                    else:
                        u = min(max(pp + s[w, INTEGRAL] + s[w, D], p[w, U_MIN]), p[w, U_MAX])
                elif p[w, AW] == 1.0:
                    s[w, INTEGRAL] = i_new + (p[w, DT] / p[w, T_T]) * (u - u_raw)
                else:
                    s[w, INTEGRAL] = i_new
                s[w, SATURATED] = 1.0 if u != u_raw else 0.0
                s[w, U] = u
                s[w, COMMAND] = u
            else:
                s[w, COMMAND] = setpoint[w]
            # DiscretePlant.step
            cmd = s[w, COMMAND]
            x0, x1 = s[w, X0], s[w, X1]
            s[w, PLANT_INTEGRAL] += p[w, Q0] * x0 + p[w, Q1] * x1 + p[w, QB] * cmd
            s[w, X0] = p[w, A00] * x0 + p[w, A01] * x1 + p[w, B0] * cmd
            s[w, X1] = p[w, A10] * x0 + p[w, A11] * x1 + p[w, B1] * cmd
            s[w, OUTPUT] = p[w, C0] * s[w, X0] + p[w, C1] * s[w, X1]


def compiled_ok(motors: Any) -> bool:
    """Whether :meth:`CompiledWheels.ticks` can stand in for ``motors``' own ``update``: plain
    DiscretePID / DiscretePlant objects (not subclasses, no method replaced on the instance)."""
    for m in motors:
        if type(m.plant) is not DiscretePlant or "step" in m.plant.__dict__:
            return False
        if m.pid is not None and (type(m.pid) is not DiscretePID or "update" in m.pid.__dict__):
            return False
    return True


def pack(motors: Any, p: np.ndarray, s: np.ndarray, key: list[Any]) -> None:
    """Read the state of ``motors`` into ``s`` (n, N_STATE), and their parameters into ``p``
    (n, N_PARAMS) when ``key`` (the PID and plant objects, held so their ids stay theirs, and the
    PID's gains and limits; updated here) says they changed."""
    now = [(m.pid, m.plant, None if m.pid is None else (m.pid.kp, m.pid.ki, m.pid.kd, m.pid.u_min,
            m.pid.u_max, m.pid.tau_d, m.pid.anti_windup)) for m in motors]  # fmt: skip
    if now != key:
        key[:] = now
        for w, m in enumerate(motors):
            pl, pid = m.plant, m.pid
            p[w, A00:HAS_PID] = (pl._a00, pl._a01, pl._a10, pl._a11, pl._b0, pl._b1, pl._c0, pl._c1,
                                 pl._q0, pl._q1, pl._q_b)  # fmt: skip
            p[w, HAS_PID] = pid is not None
            if pid is not None:
                aw = _ANTI_WINDUP[pid.anti_windup]
                p[w, :A00] = (pid.kp, pid.ki, pid.kd, pid.dt, pid.tau_d, pid.u_min, pid.u_max,
                              pid.derivative_on_measurement, aw, pid.t_t)  # fmt: skip
    row: list[float] = []
    for m in motors:
        pl, pid = m.plant, m.pid
        if pid is None:
            row += (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        else:
            row += (pid.integral, pid._d, pid._prev, pid._prev_unset, pid.saturated, pid.u)
        row += (pl._x0, pl._x1, pl.integral, m.command_rpm, m.output_rpm)
    s.ravel()[:] = row


def unpack(motors: Any, s: np.ndarray) -> None:
    """Write the state ``s`` (n, N_STATE) back into ``motors``."""
    row = s.tolist()
    for m, r in zip(motors, row):
        pl, pid = m.plant, m.pid
        pl._x0, pl._x1, pl.integral = r[X0], r[X1], r[PLANT_INTEGRAL]
        m.command_rpm, m.output_rpm = r[COMMAND], r[OUTPUT]
        if pid is not None:
            pid.integral, pid._d, pid._prev, pid.u = r[INTEGRAL], r[D], r[PREV], r[U]
            pid._prev_unset, pid.saturated = r[PREV_UNSET] != 0.0, r[SATURATED] != 0.0


class CompiledWheels:
    """Scratch arrays and the parameter cache of the compiled ticks for one robot's two wheels."""

    def __init__(self) -> None:
        self.p = np.zeros((2, N_PARAMS))
        self.s = np.zeros((2, N_STATE))
        self.inputs = np.zeros((3, 2))  # set points, measured speeds, closed loop (1/0)
        self.key: list[Any] = []

    def ticks(self, motors: Any, measured_l: float, measured_r: float, ticks: int) -> tuple[float, float]:
        """Run ``ticks`` controller periods of both ``motors`` (``WheelMotor`` left, right) in one call,
        as each motor's ``update(measured, ticks)`` would; returns the output speeds (left, right), RPM."""
        announce_compilation(_MODULE, "wheel motor kernels")
        pack(motors, self.p, self.s, self.key)
        left, right = motors
        self.inputs.ravel()[:] = (left.setpoint_rpm, right.setpoint_rpm, measured_l, measured_r,
                                  left.closed_loop, right.closed_loop)  # fmt: skip
        _wheel_ticks(self.p, self.s, self.inputs, ticks)
        unpack(motors, self.s)
        return left.output_rpm, right.output_rpm


_MODULE = __import__(__name__, fromlist=["_"])
