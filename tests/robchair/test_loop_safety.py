"""Safety of the drive loop itself, on the emulated chair in simulated time (the backend's SyncedClock:
every wait of the loop, the drivers and the emulators moves simulated time, nothing waits on the wall).

Each test reproduces a way the loop could drive without fresh information or without anyone commanding:
a sensing blackout longer than the freshness limit, an exception anywhere in the loop, and a controller
watchdog unrelated to the loop period.
"""

from __future__ import annotations

import re
import time

import pytest

from robchair.loop_types import Observer
from robchair.platform.errors import ConfigError, RobChairError
from robchair.platform.spec import load_spec
from robchair.run_output import run_to_dir
from robchair.runtime_config import RuntimeConfig
from robchair.sources import Observation, PolicySource
from sim.errors import SimError


@pytest.fixture(scope="module")
def spec():
    return load_spec()


def emulated(**cfg):
    from robchair.backends import get_backend

    return get_backend("emulated", {"timeout_s": 0.1, **cfg})


def _speed_commands(emu) -> list[tuple[int, int]]:
    """(arrival time ns, RPM) of every ``!S`` the emulated Roboteq received."""
    out = []
    for t, line in list(emu.received):
        m = re.fullmatch(r"!S (\d) (-?\d+)", line)
        if m:
            out.append((t, int(m.group(2))))
    return out


def test_a_cycle_that_outlived_its_freshness_limit_commands_zero(spec) -> None:
    # from t = 1 s the six SRF08s stay busy: each read waits out its 250 ms timeout, so one cycle
    # takes 1.5 s; what that cycle decided must not reach the motors
    backend = emulated()
    bus, emu = backend.extras["srf08_bus"], backend.extras["roboteq_emulator"]
    state: dict[str, int] = {}

    def policy(obs: Observation) -> tuple[float, float]:
        state.setdefault("t0", obs.stamp_ns)
        if obs.stamp_ns - state["t0"] >= 1_000_000_000 and "busy" not in state:
            for dev in bus.devices.values():
                dev.busy_until_ns = 2**62
            state["busy"] = len(_speed_commands(emu))
        return 0.3, 0.0

    res = run_to_dir(backend, PolicySource(policy), 1.6, None, spec=spec)
    after = _speed_commands(emu)[state["busy"] :]
    # the cycle that made the sonars busy writes its own command (2 lines); every later one is zero
    assert len(after) > 2
    assert all(rpm == 0 for _, rpm in after[2:]), after
    reasons = {s["reason"] for s in res.stops}
    # the blocked cycle is seen as late or stale at write time, or, when it also outlasted the controller
    # watchdog (2.5 periods) before that check, as the watchdog gap: each is a stop that names the blackout
    assert reasons & {"deadline_missed", "stale_sensor", "controller_watchdog"}
    assert "obstacle" not in " ".join(reasons)


@pytest.mark.parametrize(
    ("make_error", "where"),
    [
        (lambda: ValueError("policy gave up"), "command source"),
        (lambda: SimError("sonar died"), "sonar"),
        (lambda: OSError("disk full"), "observer"),
    ],
)
def test_an_exception_anywhere_in_the_loop_stops_the_motors_before_it_propagates(
    spec, make_error, where
) -> None:
    backend = emulated(sonars=False)
    emu = backend.extras["roboteq_emulator"]

    class Array:
        name = "sonar_array_left"

        def __init__(self) -> None:
            self.fail = False

        def open(self) -> None: ...

        def close(self) -> None: ...

        def read(self):
            if self.fail:
                raise make_error()
            from hw.interfaces import SonarArrayReading

            return SonarArrayReading(time.monotonic_ns(), (float("nan"),) * 3, 90.0)

    arr = Array()
    if where == "sonar":
        backend.sonar_arrays = (arr,)
    state = {"fail": False}

    class Recorder(Observer):
        def after_cycle(self, runtime, cycle) -> None:
            if state["fail"]:
                raise make_error()

    def policy(obs: Observation) -> tuple[float, float]:
        if obs.pose.x > 0.3:
            if where == "sonar":
                arr.fail = True
            elif where == "observer":
                state["fail"] = True
            else:
                raise make_error()
        return 0.6, 0.0

    with pytest.raises(RobChairError, match=where) as info:
        run_to_dir(backend, PolicySource(policy), 6.0, None, spec=spec, observers=[Recorder()])
    assert "\n" not in str(info.value) and type(make_error()).__name__ in str(info.value)
    assert emu.setpoints_rpm == (0.0, 0.0)
    assert emu.estop  # zero speeds first, then the emergency stop


def test_a_watchdog_outside_one_and_a_half_to_ten_loop_periods_is_refused(spec) -> None:
    with pytest.raises(ConfigError, match=r"watchdog_ms = 50.*100 ms"):
        run_to_dir(emulated(sonars=False, watchdog_ms=50), PolicySource(lambda o: (0.0, 0.0)), 0.5, None,
                   spec=spec)  # fmt: skip
    with pytest.raises(ConfigError, match=r"watchdog_ms = 1500.*100 ms"):
        run_to_dir(emulated(sonars=False, watchdog_ms=1500), PolicySource(lambda o: (0.0, 0.0)), 0.5, None,
                   spec=spec)  # fmt: skip


def test_the_controller_watchdog_follows_the_loop_and_a_trip_is_a_stop(spec) -> None:
    backend = emulated(sonars=False)
    emu = backend.extras["roboteq_emulator"]
    calls = {"n": 0}

    def stalling_policy(obs: Observation) -> tuple[float, float]:
        calls["n"] += 1
        if calls["n"] == 12:
            backend.clock.advance(2.0)  # the policy stalls for 2 s (of the motors' simulated time)
        return 0.3, 0.0

    res = run_to_dir(backend, PolicySource(stalling_policy), 4.0, None, spec=spec,
                     config=RuntimeConfig(rate_hz=10.0))  # fmt: skip
    assert 150 <= backend.motors.watchdog_ms <= 300  # 1.5-3 periods of the 10 Hz loop
    assert emu.watchdog_trips >= 1
    assert "controller_watchdog" in [s["reason"] for s in res.stops]
    assert res.metrics()["controller"] == {
        "watchdog_ms": backend.motors.watchdog_ms,
        "watchdog_trips": emu.watchdog_trips,
    }
    # nothing commanded the motors for 2 s: the controller stopped them within its watchdog period
    stall = [p for p in res.poses if p[0] > 0.9]
    x_at_stall = stall[0][1]
    x_after = next(p[1] for p in res.poses if p[0] > 3.0)
    assert x_after - x_at_stall < 0.25
