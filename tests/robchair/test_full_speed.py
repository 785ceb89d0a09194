"""The chair driven at its own limits: full speed, hard turns and reversals never trip a controller check.

Two checks of the Roboteq stand in the way of full-speed driving: the driver refuses a speed beyond
``max_rpm`` (1000 RPM, Table 9.1), and the controller stops a channel whose closed-loop error stays
above a threshold (``^CLERD``; Roboteq user manual V1.8, "Closed Loop Speed Mode, Error Detection and
Protection": level 2, the default the driver writes, is "500ms and Error > 250"). The expectations
below are those two numbers, written by hand from the table and the manual.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from hw.messages import JoystickReading
from robchair.platform.kinematics import DiffDrive
from robchair.platform.safety import SafetyInputs, SafetyLayer, SafetyLimits
from robchair.platform.spec import load_spec
from robchair.route import Route
from robchair.run_output import run_to_dir
from robchair.runtime_config import RuntimeConfig
from robchair.sources import JoystickSource

MAX_RPM = 1000  # Table 9.1: the motor's maximum, the driver's !S range
CLERD_2_RPM, CLERD_2_S = 250.0, 0.5  # manual: level 2 = "500ms and Error > 250"
DT = 0.1  # the runtime's default 10 Hz cycle


@pytest.fixture(scope="module")
def spec():
    return load_spec()


def _loop_error_trips(spec, rpm_per_cycle: np.ndarray) -> list[str]:
    """Run each channel's SPEC 5 speed loop (firmware 1.x gains, 1 kHz, as the controller) on set points
    held for one 10 Hz cycle each; return the channels whose error broke the manual's level-2 rule."""
    from hw.roboteq.gains import gains_from_roboteq, roboteq_gains
    from robchair.platform import control as c

    tripped = []
    for ch in (1, 2):
        step = spec.step_for_channel(ch)
        plant = c.identify_from_step_metrics(step.t_r, step.t_p, step.M_p).plant
        fw = roboteq_gains(c.design_pid(plant), 1)
        kp, ki, kd = gains_from_roboteq(fw.kp, fw.ki, fw.kd, firmware_major=1)
        pid = c.DiscretePID(kp, ki, kd, 0.001, u_min=-MAX_RPM, u_max=MAX_RPM)
        motor = c.DiscretePlant(plant, 0.001)
        y, above = 0.0, 0.0
        for r in rpm_per_cycle[:, ch - 1]:
            for _ in range(round(DT / 0.001)):
                y = float(motor.step(pid.update(r, y)))
                above = above + 0.001 if abs(r - y) > CLERD_2_RPM else 0.0
                if above > CLERD_2_S:
                    tripped.append(f"channel {ch} at set point {r:.0f} RPM")
                    break
            if tripped and tripped[-1].startswith(f"channel {ch}"):
                break
    return tripped


def _safety_rpm(spec, wanted: list[tuple[float, float]]) -> np.ndarray:
    """The motor set points (left, right) the default safety layer gives for each wanted twist."""
    layer = SafetyLayer(SafetyLimits.from_spec(spec))  # the default platform: the spec under test
    drive = DiffDrive(spec)
    return np.array([drive.motor_rpm(*drive.limit(*_filtered(layer, v, w))) for v, w in wanted])


def _filtered(layer: SafetyLayer, v: float, w: float) -> tuple[float, float]:
    d = layer.filter(v, w, SafetyInputs(), DT)
    return d.v, d.w


@pytest.mark.parametrize(
    "manoeuvre",
    [
        # (wanted v, w as fractions of the platform maxima, cycles)
        [(1.0, 0.0, 40), (0.0, 1.0, 40)],  # full speed ahead, then spin left (the joystick hard left)
        [(1.0, 0.0, 40), (-1.0, 0.0, 60)],  # full speed ahead, then full reverse
        [(0.0, 1.0, 40), (0.0, -1.0, 60)],  # spin left, then spin right
        [(1.0, 1.0, 40), (1.0, -1.0, 60)],  # full deflection, swung from left to right
    ],
    ids=["ahead-spin", "ahead-reverse", "spin-spin", "swing"],
)
def test_the_safety_layers_output_never_trips_the_loop_error_detection_the_driver_configures(
    spec, manoeuvre
) -> None:
    drive = DiffDrive(spec)
    wanted = [(f * drive.max_speed, t * drive.max_yaw_rate) for f, t, n in manoeuvre for _ in range(n)]
    rpm = _safety_rpm(spec, wanted)
    assert np.abs(rpm).max() <= MAX_RPM
    assert np.abs(rpm).max() > 0.9 * MAX_RPM  # the manoeuvre does reach full speed
    assert _loop_error_trips(spec, rpm) == []


def _speed_commands(emu) -> list[int]:
    """RPM of every ``!S`` the emulated Roboteq received."""
    return [int(m.group(1)) for _, line in list(emu.received) if (m := re.fullmatch(r"!S \d (-?\d+)", line))]


def emulated():
    from robchair.backends import get_backend

    return get_backend("emulated", {"sonars": False})


def test_a_route_at_0_75_m_s_with_a_left_corner_completes_on_the_emulated_chair(spec) -> None:
    # 3 m straight, then 2 m to the left, asked faster than the chair can go (0.62 m/s)
    from robchair.route import PurePursuit

    route = Route(waypoints=((0.0, 0.0), (3.0, 0.0), (3.0, 2.0)), speed=0.75, lookahead_m=0.6)
    backend = emulated()
    emu = backend.extras["roboteq_emulator"]
    res = run_to_dir(backend, PurePursuit(route, DiffDrive(spec)), 30.0, None, spec=spec)
    assert res.driver_fault is None, res.driver_fault
    assert [s["reason"] for s in res.stops if s["reason"] != "controller_watchdog"] == []
    assert res.route_completed
    commands = _speed_commands(emu)
    assert max(abs(r) for r in commands) == MAX_RPM  # it did drive at full speed


class SweptJoystick:
    """A joystick held at full deflection while its turn axis sweeps from hard right to hard left."""

    def __init__(self, cycles: int) -> None:
        self.turns = iter(np.linspace(-1.0, 1.0, cycles))
        self.k = 0

    def read(self) -> JoystickReading:
        self.k += 1
        return JoystickReading(stamp_ns=self.k, forward=1.0, turn=float(next(self.turns, 1.0)), deadman=True)


@pytest.mark.slow  # 400 cycles through the serial emulator: about a minute on a loaded machine
def test_a_full_deflection_joystick_sweep_never_trips_the_rpm_check_on_the_emulated_chair(spec) -> None:
    # before the exact limit, 7 of these 400 cycles asked for 1000.0000000000002 RPM
    drive = DiffDrive(spec)
    backend = emulated()
    emu = backend.extras["roboteq_emulator"]
    source = JoystickSource(SweptJoystick(400), drive.max_speed, drive.max_yaw_rate)
    res = run_to_dir(backend, source, 40.0, None, spec=spec, config=RuntimeConfig(rate_hz=10.0))
    assert res.driver_fault is None, res.driver_fault
    commands = _speed_commands(emu)
    assert max(abs(r) for r in commands) == MAX_RPM
    assert res.cycles >= 400
