"""Checks of the drive loop's write path that only a wrong loop fails, on a simulated clock.

The backend here is written by hand: a :class:`hw.clock.ManualClock` (time moves only when asked) and a
motor controller that records every speed command with the time it was written. Nothing waits on the
wall clock.
"""

from __future__ import annotations

import pytest

from hw.clock import ManualClock
from hw.interfaces import Backend
from hw.messages import MotorState
from robchair.platform.spec import load_spec
from robchair.runtime import Runtime
from robchair.runtime_config import RuntimeConfig
from robchair.sources import Command, PolicySource


class RecordingMotors:
    """A motor controller with a 300 ms watchdog that records ``(clock ns, left, right)`` per command."""

    name = "recording-motors"
    watchdog_ms = 300  # 3 periods of the 10 Hz loop: inside the 1.5-10 periods the runtime accepts

    def __init__(self, clock: ManualClock) -> None:
        self.clock = clock
        self.written: list[tuple[int, float, float]] = []
        self.estops = 0

    def open(self) -> None: ...

    def close(self) -> None: ...

    def set_speeds_rpm(self, left_rpm: float, right_rpm: float) -> None:
        self.written.append((self.clock.now_ns(), left_rpm, right_rpm))

    def read_state(self) -> MotorState:
        return MotorState(self.clock.now_ns(), (0, 0), (0.0, 0.0))

    def emergency_stop(self) -> None:
        self.estops += 1

    def release_stop(self) -> None: ...

    def configure_pid(self, left: object, right: object) -> None: ...


@pytest.fixture(scope="module")
def spec():
    return load_spec()


def _runtime(spec, policy) -> tuple[Runtime, ManualClock, RecordingMotors]:
    clock = ManualClock(start_ns=1_000_000_000)
    motors = RecordingMotors(clock)
    backend = Backend(name="recording", clock=clock, motors=motors)
    rt = Runtime(backend, PolicySource(policy), spec=spec, config=RuntimeConfig(rate_hz=10.0))
    return rt, clock, motors


def test_a_cycle_late_at_write_time_but_inside_the_watchdog_writes_zero(spec) -> None:
    """The write-time deadline check alone stops a late cycle.

    Hand computation: at 10 Hz the period is 100 ms and ``deadline_slack`` 0.25 allows 25 ms, so a cycle
    that started at ``t`` must write by ``t + 125 ms``. The command source of cycle 5 takes 130 ms
    (simulated): the write comes 5 ms late, while the gap since the previous command is 100 + 130 =
    230 ms, under the 300 ms controller watchdog. No sensor exists, so nothing is stale: only the
    deadline check at write time can stop this cycle.
    """
    calls = {"n": 0}
    clock_box: dict[str, ManualClock] = {}

    def policy(obs) -> tuple[float, float]:
        calls["n"] += 1
        if calls["n"] == 6:
            clock_box["clock"].advance(0.130)
        return 0.3, 0.0

    rt, clock, motors = _runtime(spec, policy)
    clock_box["clock"] = clock
    rt.start()
    for _ in range(5):
        rt.step()
    assert all(left > 0 and right > 0 for _, left, right in motors.written[1:5])  # driving before
    n = len(motors.written)
    cycle = rt.step()
    t_write, left, right = motors.written[n]
    assert (left, right) == (0.0, 0.0)
    assert [s.reason.value for s in cycle.stops] == ["deadline_missed"]
    assert rt.result.watchdog_trips == 0
    assert t_write - motors.written[n - 1][0] < RecordingMotors.watchdog_ms * 1_000_000
    rt.stop()


def test_a_cycle_on_time_at_write_time_drives(spec) -> None:
    """The same loop with a command source that takes 120 ms (5 ms inside the 125 ms deadline of the
    hand computation above) keeps driving: the check stops late cycles only."""
    calls = {"n": 0}
    clock_box: dict[str, ManualClock] = {}

    def policy(obs) -> tuple[float, float]:
        calls["n"] += 1
        if calls["n"] == 6:
            clock_box["clock"].advance(0.120)
        return 0.3, 0.0

    rt, clock, motors = _runtime(spec, policy)
    clock_box["clock"] = clock
    rt.start()
    for _ in range(6):
        cycle = rt.step()
    _, left, right = motors.written[-1]
    assert left > 0 and right > 0
    assert cycle.stops == ()
    rt.stop()


def test_a_command_given_to_step_is_written_as_wheel_rpm_of_the_spec(spec) -> None:
    """0.31 m/s straight ahead is 0.31 / 0.172 m wheel radius * 29 (gear ratio) * 60 / (2 pi)
    = 499.1 motor RPM per wheel (spec: wheel radius 0.172 m, gear 29:1), once the 0.5 m/s^2 ramp of the
    safety layer reached it."""
    rt, _clock, motors = _runtime(spec, lambda obs: (0.0, 0.0))
    rt.start()
    for _ in range(12):
        rt.step(Command(0.31, 0.0))
    _, left, right = motors.written[-1]
    assert left == pytest.approx(499.1, abs=0.5)
    assert right == pytest.approx(499.1, abs=0.5)
    rt.stop()


def test_a_20_hz_loop_with_a_far_wall_reads_no_phantom_obstacle(spec) -> None:
    """Every emulated SRF08 hears a wall at 3 m, beyond the 2 m range setting (2.021 m: SRF08 datasheet,
    range register 46 = (46 + 1) x 43 mm), so every reading is "no echo" (+inf, REP-117). Fired
    sooner than 65 ms after an earlier ping (datasheet: fire every 65 ms or slower), a sonar would hear
    that ping's 3 m echo early: one ranging (11.9 ms) later it reads as 3 - 343 x 0.0119 / 2 = 0.96 m,
    a phantom obstacle inside the range setting (README, "Sonar timing")."""
    from robchair.backends import get_backend
    from robchair.run_output import run_to_dir

    backend = get_backend("emulated", {"timeout_s": 0.1, "sonar_range_m": 3.0})
    bus = backend.extras["srf08_bus"]  # type: ignore[attr-defined]
    seen: list[float] = []

    def policy(obs) -> tuple[float, float]:
        seen.extend(r for reading in obs.sonars for r in reading.ranges_m)
        return 0.2, 0.0

    res = run_to_dir(backend, PolicySource(policy), 1.0, None, spec=spec, config=RuntimeConfig(rate_hz=20.0))
    assert len(seen) >= 6 * 19
    assert all(r == float("inf") for r in seen), sorted(set(seen))
    assert bus.stale_echoes == 0
    assert res.stops == [] and res.min_sonar_distance_m is None
