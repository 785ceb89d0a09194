"""The simulator and the emulated controller run the motor loop without python-control (issue 20: its
import costs ~1.7 s of a first simulated second), and what they compute instead is python-control's result
bit for bit."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from robchair.platform import control as rc
from robchair.platform.spec import default_spec

ROOT = Path(__file__).resolve().parents[2]

# What `robchair sim` imports and builds before its first simulated second (the CLI, the scenario runner,
# the simulated backend and robot with its compiled wheel loop), then the wheel motors themselves.
_SIM_START = """
import sys
import robchair.cli, robchair.commands.sim, robchair.scenario, robchair.runtime
import sim.backend, sim.robot, sim._wheel_kernels, robchair.platform.control
from robchair.platform.spec import default_spec
left, right = sim.robot.make_wheel_motors(default_spec(), 1e-3)
left.plant.step(100.0)
print(sorted(m for m in ("control", "scipy.signal", "scipy.optimize", "matplotlib") if m in sys.modules))
"""


def test_the_simulated_wheel_motors_are_built_without_importing_python_control() -> None:
    """Breaks when a module on the simulator's path imports ``control`` at module level again (as
    ``sim._wheel_kernels`` did through ``robchair.platform.control``) or the motors use it; or when
    identifying the motors' plants finds the model's 10-90 % rise time, which they do not need, by
    scipy's root finder again (importing scipy.optimize, ~0.1 s of CPU a process)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", _SIM_START], env=env, capture_output=True, text=True,
                         timeout=120, check=True, cwd=ROOT)  # fmt: skip
    assert res.stdout.strip().splitlines()[-1] == "[]", res.stdout


def test_the_importing_subprocess_sees_python_control_when_a_module_imports_it() -> None:
    """The check above can fail: the same subprocess reports ``control`` once something imports it."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    code = _SIM_START.replace("left, right =", "import control\nleft, right =")
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=120, check=True, cwd=ROOT)  # fmt: skip
    assert "'control'" in res.stdout.strip().splitlines()[-1]


@pytest.mark.parametrize("ch", [1, 2])
def test_the_simulator_gains_are_the_designs(ch: int) -> None:
    step = default_spec().step_for_channel(ch)
    plant = rc.identify_from_step_metrics(step.t_r, step.t_p, step.M_p).plant
    d = rc.design_pid(plant)
    assert rc.pid_gains(plant) == (d.kp, d.ki, d.kd)
    d = rc.design_pid(plant, xi_w=0.7, omega_w=5.0, p=40.0)
    assert rc.pid_gains(plant, xi_w=0.7, omega_w=5.0, p=40.0) == (d.kp, d.ki, d.kd)


@pytest.mark.parametrize("kw", [{"xi_w": 0.0}, {"omega_w": float("nan")}, {"p": -1.0}])
def test_pid_gains_refuses_what_design_pid_refuses(kw: dict[str, Any]) -> None:
    plant = rc.SecondOrderPlant(omega_n=20.0, xi=0.6)
    with pytest.raises(rc.ControlError, match="expected a finite number > 0"):
        rc.design_pid(plant, **kw)
    with pytest.raises(rc.ControlError, match="expected a finite number > 0"):
        rc.pid_gains(plant, **kw)


@pytest.mark.parametrize(("omega_n", "xi", "gain"), [(21.7, 0.43, 1.0), (9.0, 1.0, 1.0), (3.0, 2.5, 0.8)])
def test_state_matrices_are_python_controls_realisation(omega_n: float, xi: float, gain: float) -> None:
    plant = rc.SecondOrderPlant(omega_n=omega_n, xi=xi, gain=gain)
    sys_ = plant.ss()
    a, b, c = plant.state_matrices()
    for mine, theirs in ((a, sys_.A), (b, sys_.B), (c, sys_.C)):
        assert mine.shape == np.shape(theirs)
        assert np.array_equal(mine, np.asarray(theirs, dtype=float))


@pytest.mark.parametrize("dt", [1e-3, 1.0 / 240.0, 0.05])
def test_the_discrete_plant_is_python_controls_zoh_discretisation_bit_for_bit(dt: float) -> None:
    """:class:`DiscretePlant` used ``control.c2d(control.ss(...), dt, method="zoh")``; :func:`zoh` gives the
    same matrices, so the simulator's wheel speeds did not change."""
    import control as ct

    plant = rc.SecondOrderPlant(omega_n=21.7, xi=0.43)
    sysc = plant.ss()
    ac, bc, cc = (np.asarray(m, dtype=float) for m in (sysc.A, sysc.B, sysc.C))
    a_aug = np.zeros((3, 3))
    a_aug[:2, :2] = ac
    a_aug[2, :2] = cc.ravel()
    b_aug = np.concatenate([bc.ravel(), [0.0]])[:, None]
    c_aug = np.concatenate([cc.ravel(), [0.0]])[None, :]
    sysd = ct.c2d(ct.ss(a_aug, b_aug, c_aug, 0.0), dt, method="zoh")
    ad, bd = rc.discrete.zoh(a_aug, b_aug, dt)
    assert np.array_equal(ad, np.asarray(sysd.A, dtype=float))
    assert np.array_equal(bd, np.asarray(sysd.B, dtype=float))
    dp = rc.DiscretePlant(plant, dt)
    assert np.array_equal(dp.A, np.asarray(sysd.A, dtype=float)[:2, :2])
    assert np.array_equal(dp.B, np.asarray(sysd.B, dtype=float)[:2, 0])
    assert dp._q_b == float(np.asarray(sysd.B)[2, 0])


# What `robchair run --backend emulated` builds before its loop: the Roboteq emulator's two motor channels
# (their default firmware gains) and the real driver's PID configuration.
_EMULATED_START = """
import sys
from hw.roboteq.emulator import RoboteqEmulator
from robchair.backends import design_pid_configs
from robchair.platform.spec import default_spec
emu = RoboteqEmulator(default_spec())
design_pid_configs(default_spec())
print(sorted(m for m in ("control", "scipy.signal", "scipy.optimize", "matplotlib") if m in sys.modules))
"""


def test_the_emulated_controller_and_the_drivers_pid_are_built_without_importing_python_control() -> None:
    """Breaks when the emulator's default gains or the driver's PID configuration come from
    ``design_pid`` again (python-control and what it imports: about 2 s of CPU of an emulated run)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", _EMULATED_START], env=env, capture_output=True, text=True,
                         timeout=120, check=True, cwd=ROOT)  # fmt: skip
    assert res.stdout.strip().splitlines()[-1] == "[]", res.stdout


@pytest.mark.parametrize("firmware_major", [1, 2])
@pytest.mark.parametrize("ch", [1, 2])
def test_the_emulator_and_driver_gains_are_the_designs(ch: int, firmware_major: int) -> None:
    """The emulator's firmware integers are roboteq_gains(design_pid(plant)); the driver's PID is
    design_pid's gains."""
    from hw.roboteq.emulated_motors import _plant_and_default_gains
    from hw.roboteq.gains import roboteq_gains
    from robchair.backends import design_pid_configs

    step = default_spec().step_for_channel(ch)
    plant, gains = _plant_and_default_gains(step.t_r, step.t_p, step.M_p, firmware_major)
    d = rc.design_pid(rc.identify_from_step_metrics(step.t_r, step.t_p, step.M_p).plant)
    fw = roboteq_gains(d, firmware_major)
    assert gains == (fw.kp, fw.ki, fw.kd) and plant == d.plant
    pid = design_pid_configs(default_spec())[ch - 1]
    assert (pid.kp, pid.ki, pid.kd) == (d.kp, d.ki, d.kd)
