"""Checks of the drive loop's write path that only a wrong loop fails, on a simulated clock.

The backend here is written by hand: a :class:`hw.clock.ManualClock` (time moves only when asked) and a
motor controller that records every speed command with the time it was written. Nothing waits on the
wall clock.
"""

from __future__ import annotations

import math

import pytest

from hw.clock import ManualClock
from hw.interfaces import Backend
from hw.messages import MotorState
from robchair.platform.safety import SafetyDecision, SafetyLayer, SafetyLimits
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


class DeadSonars:
    """A sonar array whose every read fails (HardwareError): it never gives fresh data."""

    def __init__(self, name: str) -> None:
        self.name = name

    def open(self) -> None: ...

    def close(self) -> None: ...

    def read(self):
        from hw.errors import HardwareError

        raise HardwareError(f"{self.name}: no answer")


class DeadCamera(DeadSonars):
    """A depth camera whose every read fails; ``max_inflight`` as a background-capture camera has it."""

    def __init__(self, name: str, max_inflight: int | None = None) -> None:
        super().__init__(name)
        if max_inflight is not None:
            self.max_inflight = max_inflight


def _dead_sensor_loop(spec, policy, *, sonars=(), camera=None, safety_enabled=True, **config):
    clock = ManualClock(start_ns=1_000_000_000)
    motors = RecordingMotors(clock)
    backend = Backend(name="dead-sensors", clock=clock, motors=motors, sonar_arrays=tuple(sonars),
                      depth_camera=camera)  # fmt: skip
    cfg = RuntimeConfig(rate_hz=10.0, **config)
    rt = Runtime(backend, PolicySource(policy), spec=spec, config=cfg, safety_enabled=safety_enabled)
    return rt, clock, motors


def _first_stop_cycle(rt: Runtime, cycles: int) -> tuple[int, list[tuple[str, str]]]:
    """Step ``cycles`` cycles; the index of the first cycle that recorded a stop and its stops."""
    rt.start()
    try:
        for _ in range(cycles):
            cycle = rt.step()
            if cycle.stops:
                return cycle.k, [(s.reason.value, s.detail) for s in cycle.stops]
        return -1, []
    finally:
        rt.stop()


def _drive(obs) -> tuple[float, float]:
    return 0.3, 0.0


@pytest.mark.parametrize(
    ("sonar_every", "first_stale_cycle"),
    [(1, 6), (3, 8)],
)
def test_a_sonar_array_that_never_answers_stops_the_chair_once_its_data_is_too_old(
    spec, sonar_every: int, first_stale_cycle: int
) -> None:
    """Hand computation (spec: ``stale_after_s`` 0.5 s; the runtime reads the sonars every
    ``sonar_every`` cycles, so a reading may be ``sonar_every - 1`` periods older than that): at 10 Hz
    cycle k runs 100 k ms after the start, the last fresh reading. Read every cycle the limit is 500 ms:
    cycle 5 (500 ms, not older) drives, cycle 6 (600 ms) stops. Read every 3rd cycle the limit is
    500 + 2 x 100 = 700 ms: cycle 7 drives, cycle 8 stops."""
    rt, _clock, motors = _dead_sensor_loop(
        spec, _drive, sonars=[DeadSonars("front")], sonar_every=sonar_every
    )
    k, stops = _first_stop_cycle(rt, 12)
    assert k == first_stale_cycle
    assert stops == [("stale_sensor", "no fresh data from front")]
    assert motors.written[k][1:] == (0.0, 0.0) and motors.written[k - 1][1] > 0.0


@pytest.mark.parametrize(
    ("max_inflight", "first_stale_cycle"),
    [(None, 11), (0, 11), (1, 16)],
)
def test_a_depth_camera_that_never_delivers_stops_the_chair_after_its_read_and_delivery_lag(
    spec, max_inflight: int | None, first_stale_cycle: int
) -> None:
    """Hand computation (spec: ``stale_after_s`` 0.5 s; the camera is read every ``camera_every`` = 5
    cycles and a background-capture camera delivers a frame ``max_inflight`` reads later, so a frame
    may be 5 x (1 + max_inflight) periods older than that): without background capture the limit is
    500 + 5 x 100 = 1000 ms (cycle 10 drives, cycle 11 stops); with one frame in flight 500 + 10 x 100
    = 1500 ms (cycle 15 drives, cycle 16 stops)."""
    camera = DeadCamera("kinect", max_inflight)
    rt, _clock, motors = _dead_sensor_loop(spec, _drive, camera=camera, camera_every=5, sonar_every=0)
    k, stops = _first_stop_cycle(rt, 20)
    assert k == first_stale_cycle
    assert stops == [("stale_sensor", "no fresh data from depth_camera")]
    assert motors.written[k - 1][1] > 0.0


def test_a_camera_read_every_cycle_and_a_dead_sonar_array_are_both_named_once_both_are_too_old(spec) -> None:
    """Sonars read every cycle (limit 500 ms) and the camera every cycle with nothing in flight (limit
    500 + 100 = 600 ms, hand computation as above): cycle 6 names the sonar array alone, and the stop
    persists (one record) while the camera joins it at cycle 7."""
    rt, _clock, _motors = _dead_sensor_loop(
        spec, _drive, sonars=[DeadSonars("front")], camera=DeadCamera("kinect"), camera_every=1
    )
    rt.start()
    stale = [rt._stale(rt.t0_ns + k * 100_000_000) for k in (5, 6, 7)]
    rt.stop()
    assert stale == [(), ("front",), ("front", "depth_camera")]


def test_sensors_that_go_stale_while_the_cycle_runs_are_caught_at_write_time(spec) -> None:
    """Two dead sonar arrays, read every cycle (limit 500 ms, hand computation above). Cycle 5 senses
    at 500 ms (not stale yet, the safety filter passes) and its command source takes 10 ms (simulated),
    inside the 125 ms deadline and the 300 ms watchdog; at write time the data are 510 ms old: the write
    is zero and the stop names both arrays."""
    clock_box: dict[str, ManualClock] = {}
    calls = {"n": 0}

    def policy(obs) -> tuple[float, float]:
        calls["n"] += 1
        if calls["n"] == 6:
            clock_box["clock"].advance(0.010)
        return 0.3, 0.0

    rt, clock, motors = _dead_sensor_loop(spec, policy, sonars=[DeadSonars("left"), DeadSonars("right")])
    clock_box["clock"] = clock
    k, stops = _first_stop_cycle(rt, 8)
    assert k == 5
    assert stops == [("stale_sensor", "no fresh data from left, right when writing")]
    assert motors.written[5] == (rt.t0_ns + 510_000_000, 0.0, 0.0)
    assert rt.result.watchdog_trips == 0


def test_a_cycle_that_writes_exactly_at_its_deadline_drives(spec) -> None:
    """Hand computation: the deadline of a 10 Hz cycle is its start + 100 ms + 0.25 x 100 ms = 125 ms;
    a command source that takes exactly 125 ms (simulated) writes on the deadline, which is not late."""
    clock_box: dict[str, ManualClock] = {}
    calls = {"n": 0}

    def policy(obs) -> tuple[float, float]:
        calls["n"] += 1
        if calls["n"] == 6:
            clock_box["clock"].advance(0.125)
        return 0.3, 0.0

    rt, clock, motors = _runtime(spec, policy)
    clock_box["clock"] = clock
    rt.start()
    cycles = [rt.step() for _ in range(6)]
    rt.stop()
    assert cycles[-1].stops == ()
    assert motors.written[5][1] > 0.0


@pytest.mark.parametrize(("pause_s", "trips"), [(0.2, 0), (0.2000001, 1)])
def test_a_gap_over_the_controller_watchdog_is_reported_as_the_controller_stopping(
    spec, pause_s: float, trips: int
) -> None:
    """The loop (safety layer off, so only the watchdog check acts) is held up ``pause_s`` between
    cycles 4 and 5: the gap between the two speed commands is 100 ms + the pause. Exactly the 300 ms
    watchdog of the controller: it still drives; 300.0001 ms: the controller has stopped the motors
    (the write is zero and one watchdog trip is counted, with the gap and the watchdog in the detail)."""
    rt, clock, motors = _dead_sensor_loop(spec, _drive, safety_enabled=False)
    rt.start()
    for _ in range(5):
        rt.step()
    clock.advance(pause_s)
    cycle = rt.step()
    rt.stop()
    assert rt.result.watchdog_trips == trips
    if trips:
        assert motors.written[5][1:] == (0.0, 0.0)
        assert [(s.reason.value, s.detail) for s in cycle.stops] == [
            ("controller_watchdog",
             "no speed command for 300 ms > controller watchdog 300 ms: the controller stopped the motors")
        ]  # fmt: skip
    else:
        assert motors.written[5][1] > 0.0 and cycle.stops == ()


class FailingMotors(RecordingMotors):
    """Recording motors whose ``fail_at``-th speed command (counted from 1) raises a HardwareError."""

    def __init__(self, clock: ManualClock, fail_at: int) -> None:
        super().__init__(clock)
        self.fail_at = fail_at
        self.calls = 0

    def set_speeds_rpm(self, left_rpm: float, right_rpm: float) -> None:
        from hw.errors import HardwareError

        self.calls += 1
        if self.calls == self.fail_at:
            raise HardwareError("serial link lost")
        super().set_speeds_rpm(left_rpm, right_rpm)


def test_a_speed_command_the_driver_refuses_latches_a_driver_fault_named_by_its_error(spec) -> None:
    """SPEC/safety layer: a driver fault stops the chair and is latched. The 4th speed command raises
    ``HardwareError("serial link lost")``: that cycle's decision is zero with the stop
    ``driver_fault: HardwareError: serial link lost``, the run's driver fault is that text, the
    emergency stop is sent, and every later cycle writes zero."""
    clock = ManualClock(start_ns=1_000_000_000)
    motors = FailingMotors(clock, fail_at=4)
    rt = Runtime(Backend(name="failing", clock=clock, motors=motors), PolicySource(_drive), spec=spec,
                 config=RuntimeConfig(rate_hz=10.0, stop_on_driver_fault=False))  # fmt: skip
    rt.start()
    cycles = [rt.step() for _ in range(6)]
    rt.stop()
    fault = "HardwareError: serial link lost"
    assert [(s.reason.value, s.detail) for s in cycles[3].stops] == [("driver_fault", fault)]
    assert cycles[3].stops[0].stamp_ns == rt.t0_ns + 300_000_000  # stamped at the failed write
    assert (cycles[3].decision.v, cycles[3].decision.w) == (0.0, 0.0)
    assert cycles[3].fault == fault and rt.result.driver_fault == fault
    assert motors.estops >= 1
    assert [w[1:] for w in motors.written[3:]] == [(0.0, 0.0), (0.0, 0.0)]  # latched: zero from then on


def test_a_stopped_chair_held_up_longer_than_the_watchdog_is_no_watchdog_trip(spec) -> None:
    """A zero command leaves both wheels at rest: the controller's watchdog has nothing to stop, so a
    500 ms pause (over the 300 ms watchdog) after it counts no trip (safety layer off: the check alone)."""
    rt, clock, _motors = _dead_sensor_loop(spec, lambda obs: (0.0, 0.0), safety_enabled=False)
    rt.start()
    rt.step()
    clock.advance(0.5)
    rt.step()
    rt.stop()
    assert rt.result.watchdog_trips == 0


def test_a_pivot_on_the_left_wheel_still_counts_for_the_watchdog(spec) -> None:
    """v = 0.29 m/s, w = 1 rad/s: the left wheel turns at v - w x 0.58 / 2 = 0 (spec: wheel separation
    0.58 m), the right one at 0.58 m/s. The right motor runs, so a 500 ms pause before the next command
    is a watchdog trip (the controller stopped it), safety layer off."""
    rt, clock, motors = _dead_sensor_loop(spec, lambda obs: (0.29, 1.0), safety_enabled=False)
    rt.start()
    rt.step()
    assert motors.written[0][1] == 0.0 and motors.written[0][2] > 0.0
    clock.advance(0.5)
    rt.step()
    rt.stop()
    assert rt.result.watchdog_trips == 1


def _held_up(spec, policy, hold_s: float, cycle: int = 5, **kwargs):
    """A 10 Hz loop whose command source takes ``hold_s`` (simulated) in cycle ``cycle``; runs it."""
    clock_box: dict[str, ManualClock] = {}
    calls = {"n": 0}

    def held(obs) -> tuple[float, float]:
        calls["n"] += 1
        if calls["n"] == cycle + 1:
            clock_box["clock"].advance(hold_s)
        return policy(obs)

    rt, clock, motors = _dead_sensor_loop(spec, held, **kwargs)
    clock_box["clock"] = clock
    rt.start()
    cycles = [rt.step() for _ in range(cycle + 1)]
    rt.stop()
    return rt, motors, cycles[-1]


@pytest.mark.parametrize(
    ("hold_s", "detail"),
    [
        (0.130, "the cycle outlived its deadline by 5 ms before writing"),
        (0.1305, "the cycle outlived its deadline by 6 ms before writing"),
        (0.125000001, "the cycle outlived its deadline by 0 ms before writing"),
    ],
)
def test_a_late_write_names_how_late_it_was(spec, hold_s: float, detail: str) -> None:
    """Hand computation: the deadline is the cycle start + 125 ms (10 Hz, slack 0.25). A command source
    of 130 ms is 5 ms late; 130.5 ms is 5.5 ms late, printed to the millisecond as 6 (round half to
    even); 125.000001 ms is 1 ns late: late all the same (stopped), printed as 0 ms."""
    _rt, motors, cycle = _held_up(spec, _drive, hold_s)
    assert [(s.reason.value, s.detail) for s in cycle.stops] == [("deadline_missed", detail)]
    assert cycle.stops[0].stamp_ns == motors.written[5][0] and motors.written[5][1:] == (0.0, 0.0)


def test_a_late_zero_command_is_written_without_a_stop(spec) -> None:
    """The write-time checks guard motion only (safety layer: a stop is a zero command): a cycle that
    asks for (0, 0) and writes 5 ms late (130 ms command source, deadline 125 ms) records no stop."""
    _rt, motors, cycle = _held_up(spec, lambda obs: (0.0, 0.0), 0.130)
    assert cycle.stops == () and motors.written[5][1:] == (0.0, 0.0)


def test_a_turn_in_place_written_late_is_stopped(spec) -> None:
    """A pure turn (v = 0, w = 0.5 rad/s) is motion too: written 5 ms late it is stopped."""
    _rt, motors, cycle = _held_up(spec, lambda obs: (0.0, 0.5), 0.130)
    assert [s.reason.value for s in cycle.stops] == ["deadline_missed"]
    assert motors.written[5][1:] == (0.0, 0.0)


def test_two_gaps_over_the_watchdog_count_two_trips_and_the_gap_is_printed_to_the_millisecond(spec) -> None:
    """Safety layer off. Held up 301.5 ms after cycle 4: a gap of 100 + 301.5 = 401.5 ms, printed as 402
    (round half to even); the chair drives again in cycle 6, and a second 500 ms hold-up after it is a
    second trip (600 ms), counted though not recorded again as a new stop."""
    rt, clock, motors = _dead_sensor_loop(spec, _drive, safety_enabled=False)
    rt.start()
    for _ in range(5):
        rt.step()
    clock.advance(0.3015)
    first = rt.step()
    rt.step()
    clock.advance(0.5)
    second = rt.step()
    rt.stop()
    assert rt.result.watchdog_trips == 2
    assert first.stops[0].detail.startswith("no speed command for 402 ms > controller watchdog 300 ms")
    assert second.stops == ()  # the same reason persists (safety layer off): recorded once (safety docs)
    assert first.stops[0].stamp_ns == motors.written[5][0]


class OverSpeedSafety(SafetyLayer):
    """A safety layer that passes (5 m/s, 1 rad/s) (far over the platform): the write must cap it."""

    def filter(self, v: float, w: float, inputs: object, dt: float) -> SafetyDecision:  # type: ignore[override]
        return SafetyDecision(5.0, 1.0)


def test_the_write_caps_the_wheels_at_the_motor_limit_and_reports_the_capped_twist(spec) -> None:
    """Spec: 1000 motor RPM through 29:1 on 0.172 m wheels is a wheel speed of 1000 / 29 x 2 pi / 60 x
    0.172 = 0.62110 m/s; wheel separation 0.58 m. Whatever the safety layer passes, here (5, 1): the
    wheels would need 5 -+ 0.29 m/s, so the twist is scaled by 0.62110 / 5.29, keeping the curve: the
    right motor at exactly 1000 RPM, the left at 1000 x 4.71 / 5.29 = 890.36 RPM, and the cycle's
    decision is the scaled twist."""
    clock = ManualClock(start_ns=1_000_000_000)
    motors = RecordingMotors(clock)
    safety = OverSpeedSafety(SafetyLimits.from_spec(spec), spec.wheel_separation)
    rt = Runtime(Backend(name="over", clock=clock, motors=motors), PolicySource(_drive), spec=spec,
                 config=RuntimeConfig(rate_hz=10.0), safety=safety)  # fmt: skip
    rt.start()
    cycle = rt.step()
    rt.stop()
    k = 1000 / 29 * 2 * math.pi / 60 * 0.172 / 5.29
    assert motors.written[0][1:] == pytest.approx((1000.0 * 4.71 / 5.29, 1000.0), abs=1e-9)
    assert (cycle.decision.v, cycle.decision.w) == pytest.approx((5.0 * k, 1.0 * k), abs=1e-12)
