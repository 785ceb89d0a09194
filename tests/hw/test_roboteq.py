"""The real Roboteq driver, unchanged, against the emulator over a pseudo-terminal.

Motor time is simulated (a SyncedClock the test advances; the emulator catches up inside the
advance), so seconds of driving take milliseconds; reply deadlines are real time and kept short.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hw.errors import (
    CommandError,
    DeviceClosedError,
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceTimeoutError,
    ProtocolError,
)
from hw.interfaces import MotorController, MotorFaults, PIDConfig
from hw.roboteq import codec
from hw.roboteq.driver import RoboteqMDC2230
from hw.roboteq.emulator import RoboteqEmulator, SyncedClock
from hw.roboteq.gains import roboteq_gains
from robchair.platform import control
from robchair.platform.kinematics import DiffDrive, Odometry
from robchair.platform.spec import load_spec

TIMEOUT_S = 0.05  # reply deadline used in these tests (the pty answers in about a millisecond)


@pytest.fixture
def clock() -> SyncedClock:
    return SyncedClock()


@pytest.fixture
def emu(clock: SyncedClock):
    with RoboteqEmulator(clock=clock) as e:
        yield e


def _path(emu: RoboteqEmulator) -> str:
    """The started emulator's device path."""
    assert emu.device_path is not None
    return emu.device_path


@pytest.fixture
def drv(emu: RoboteqEmulator, clock: SyncedClock):
    d = RoboteqMDC2230(_path(emu), timeout_s=TIMEOUT_S, retries=2, clock=clock)
    d.open()
    yield d
    d.close()


def drive_for(drv: RoboteqMDC2230, clock: SyncedClock, left: float, right: float, seconds: float, hz=20.0):
    """Send the speeds every cycle (as the runtime does, keeping the watchdog fed) for ``seconds``."""
    for _ in range(round(seconds * hz)):
        drv.set_speeds_rpm(left, right)
        clock.advance(1.0 / hz)


def assert_stopped(emu: RoboteqEmulator) -> None:
    """The emulated controller was told to stop: zero set points and the emergency stop latched."""
    assert emu.setpoints_rpm == (0.0, 0.0)
    assert emu.estop
    texts = [t for _, t in emu.received]
    assert "!EX" in texts


def test_driver_satisfies_the_motor_controller_protocol(drv: RoboteqMDC2230) -> None:
    assert isinstance(drv, MotorController)


def test_open_stops_first_then_probes_firmware_and_configures_closed_loop_speed_mode(
    drv: RoboteqMDC2230, emu
) -> None:
    assert drv.firmware is not None and (drv.firmware.major, drv.firmware.minor) == (1, 3)
    assert drv.read_config("MMOD") == (1, 1)
    assert drv.read_config("EPPR") == (1000, 1000)
    assert drv.read_config("MXRPM") == (1000, 1000)
    assert drv.read_config("RWD") == (1000,)
    sent = [t for _, t in emu.received]
    assert sent[:4] == ["!S 1 0", "!S 2 0", "# C", "?FID"]  # zero and no telemetry before anything else
    assert sent.index("^ECHOF 0") < sent.index("^MMOD 1 1")  # the echo state is set explicitly
    assert "~MMOD" in sent and "~RWD" in sent  # the configuration is read back before activation
    assert "^MMOD 1 1" in sent and "^MMOD 2 1" in sent and "^RWD 1000" in sent


@pytest.mark.parametrize(
    ("firmware", "mult"),
    [("Roboteq v1.3 MDC2230 07/24/2013", 10), ("Roboteq v2.0 MDC2230 01/01/2020", 10**6)],
)
def test_pid_gains_round_trip_in_the_firmware_units_of_each_major_version(
    firmware: str, mult: int, clock
) -> None:
    left, right = PIDConfig(1.4, 3.7, 0.3), PIDConfig(1.1, 3.2, 0.2)
    with RoboteqEmulator(clock=clock, firmware=firmware) as emu:
        with RoboteqMDC2230(_path(emu), timeout_s=TIMEOUT_S, pid=(left, right)) as drv:
            assert drv.read_config("KP") == (round(1.4 * mult), round(1.1 * mult))
            assert drv.read_config("KI") == (round(3.7 * mult), round(3.2 * mult))
            assert drv.read_config("KD") == (round(0.3 * mult), round(0.2 * mult))
        # the emulator runs its PID with the decoded gains
        assert emu.config("KP", 1) == round(1.4 * mult)


def test_a_gain_that_does_not_fit_firmware_1x_is_refused_before_anything_is_written(drv, emu) -> None:
    n = len(emu.received)
    with pytest.raises(CommandError, match=r"kp=30.0 .*0\.\.255"):
        drv.configure_pid(PIDConfig(30.0, 1.0, 0.0), PIDConfig(1.0, 1.0, 0.0))
    assert len(emu.received) == n


def test_echo_off_is_handled_as_well_as_echo_on(clock) -> None:
    with RoboteqEmulator(clock=clock, echo=False) as emu:
        with RoboteqMDC2230(_path(emu), timeout_s=TIMEOUT_S, clock=clock) as drv:
            assert drv.read_config("MMOD") == (1, 1)
            drive_for(drv, clock, 200, 200, 1.0)
            assert drv.read_state().encoder_counts[0] > 0


def test_watchdog_of_zero_is_refused() -> None:
    with pytest.raises(CommandError, match="watchdog"):
        RoboteqMDC2230("/dev/null", watchdog_ms=0)


def test_using_the_driver_before_open_raises_device_closed(emu) -> None:
    d = RoboteqMDC2230(emu.device_path)
    with pytest.raises(DeviceClosedError, match="closed"):
        d.set_speeds_rpm(0, 0)


def test_unreachable_port_raises_disconnected_naming_the_port() -> None:
    with pytest.raises(DeviceDisconnectedError, match="/dev/does-not-exist"):
        RoboteqMDC2230("/dev/does-not-exist").open()


def test_commanded_speeds_produce_counts_that_odometry_turns_into_the_commanded_motion(
    drv, emu, clock
) -> None:
    spec = load_spec()
    dd = DiffDrive(spec)
    v, w = 0.3, 0.25
    left, right = dd.motor_rpm(v, w)
    odo = Odometry(spec)
    odo.update(*drv.read_state().encoder_counts)
    drive_for(drv, clock, left, right, 3.0)  # let the PID settle (closed-loop poles at -3.3 rad/s x2, -33)
    s0 = drv.read_state()
    p0 = odo.update(*s0.encoder_counts)
    window = 2.0
    drive_for(drv, clock, left, right, window)
    s1 = drv.read_state()
    p1 = odo.update(*s1.encoder_counts)
    # measured twist over the window, from odometry alone
    dtheta = p1.theta - p0.theta
    chord = math.hypot(p1.x - p0.x, p1.y - p0.y)
    arc = chord / (math.sin(dtheta / 2) / (dtheta / 2))  # arc length from the chord of a circular arc
    assert arc / window == pytest.approx(v, rel=0.01)
    assert dtheta / window == pytest.approx(w, rel=0.01)
    assert s1.speed_rpm == pytest.approx((left, right), abs=1.0)  # ?S rounds to whole RPM


def test_straight_run_distance_matches_the_closed_loop_lag_of_the_quantised_pid(drv, emu, clock) -> None:
    """x(t) of a ramped speed step through the closed loop T(s) is v (t - T_ramp - T_lag), with
    T_lag = -T'(0) for T(0) = 1."""
    spec = load_spec()
    dd = DiffDrive(spec)
    v = 0.4
    rpm, _ = dd.motor_rpm(v, 0.0)
    odo = Odometry(spec)
    odo.update(*drv.read_state().encoder_counts)
    duration = 6.0
    drive_for(drv, clock, rpm, rpm, duration)
    pose = odo.update(*drv.read_state().encoder_counts)
    lags = []
    for ch in (1, 2):
        step = spec.step_for_channel(ch)
        plant = control.identify_from_step_metrics(step.t_r, step.t_p, step.M_p).plant
        q = roboteq_gains(control.design_pid(plant), 1).quantised
        num, den = q.closed_loop_tf().num[0][0], q.closed_loop_tf().den[0][0]
        # T = N/D, T(0) = 1  ->  -T'(0) = (D'(0) - N'(0)) / D(0)
        lags.append((den[-2] - num[-2]) / den[-1])
    # the controller's ^MAC ramp delays a step by rpm / (2 MAC) more (a ramp lags by half its length)
    ramp_lag = rpm / (2.0 * drv.protections.accel_rpm_s)
    expected = v * (duration - sum(lags) / 2 - ramp_lag)
    assert pose.x == pytest.approx(expected, abs=0.01)
    # the two motors differ (SPEC 5), so their wheels lag by different distances: the heading
    # ends at (d_right - d_left) / b = v (lag_left - lag_right) / b
    assert pose.theta == pytest.approx(v * (lags[0] - lags[1]) / spec.wheel_separation, abs=2e-3)


def test_encoder_counters_wrap_as_signed_32_bit_and_odometry_follows(emu, clock) -> None:
    emu.set_encoder_counts(2**31 - 100, -(2**31) + 100)
    drv = RoboteqMDC2230(emu.device_path, timeout_s=TIMEOUT_S, retries=2, clock=clock)
    drv.open()
    spec = load_spec()
    odo = Odometry(spec)
    odo.update(*drv.read_state().encoder_counts)
    drive_for(drv, clock, 300, -300, 1.0)
    c = drv.read_state().encoder_counts
    assert c[0] < 0 < c[1]  # both wrapped
    pose = odo.update(*c)
    assert pose.theta < 0  # turning right, as commanded, not a jump of 2**32 counts


def test_one_dropped_reply_is_retried_and_the_command_goes_through(drv, emu, clock) -> None:
    emu.inject(drop=1)
    drv.set_speeds_rpm(100, 100)
    assert drv.n_retries == 1
    assert emu.setpoints_rpm == (100.0, 100.0)
    assert not emu.estop


def test_replies_dropped_beyond_the_retries_time_out_after_stopping_the_motors(drv, emu, clock) -> None:
    drive_for(drv, clock, 300, 300, 0.5)
    emu.inject(drop=3)
    with pytest.raises(DeviceTimeoutError, match=r"\?C.*3 tries"):
        drv.read_state()
    assert_stopped(emu)
    assert drv.stop_reason is not None
    with pytest.raises(DeviceFaultError, match="--release-stop"):
        drv.set_speeds_rpm(100, 100)
    drv.release_stop()
    drv.set_speeds_rpm(100, 100)
    assert emu.setpoints_rpm == (100.0, 100.0)


def test_unsolicited_lines_are_ignored_and_answers_are_routed_by_name(drv, emu) -> None:
    emu.emit("A=55:60")  # e.g. telemetry the controller was set to stream
    emu.emit("+")  # a stray acknowledgement is not an answer to a query either
    assert drv.read_config("EPPR") == (1000, 1000)
    assert drv.n_retries == 0


def test_one_garbled_line_is_retried(drv, emu) -> None:
    emu.inject(garble=1)
    assert drv.read_config("MMOD") == (1, 1)
    assert drv.n_retries == 1


def test_garbled_beyond_the_retries_raises_protocol_error_after_stopping(drv, emu, clock) -> None:
    drive_for(drv, clock, 300, 300, 0.5)
    emu.inject(garble=3)
    with pytest.raises(ProtocolError, match="garbled"):
        drv.read_state()
    assert_stopped(emu)


def test_a_reply_within_the_deadline_is_accepted(drv, emu) -> None:
    emu.inject(delay_n=1, delay_s=TIMEOUT_S / 5)
    assert drv.read_config("RWD") == (1000,)
    assert drv.n_retries == 0


def test_delays_past_the_deadline_on_every_try_time_out_after_stopping(drv, emu, clock) -> None:
    drive_for(drv, clock, -200, 200, 0.5)
    emu.inject(delay_n=3, delay_s=TIMEOUT_S * 5)  # the first late answer comes after the last try gave up
    with pytest.raises(DeviceTimeoutError, match="no answer"):
        drv.read_state()
    assert_stopped(emu)


def test_late_answers_of_failed_tries_are_not_taken_for_later_answers(drv, emu) -> None:
    emu.inject(delay_n=1, delay_s=TIMEOUT_S * 1.5)
    assert drv.read_config("EPPR") == (1000, 1000)  # first try late, second answers
    assert drv.read_config("MXRPM") == (1000, 1000)  # the late EPPR line is not mistaken for this


def test_an_unplugged_port_raises_disconnected_and_the_watchdog_stops_the_motors(drv, emu, clock) -> None:
    drive_for(drv, clock, 300, 300, 0.5)
    emu.disconnect()
    with pytest.raises(DeviceDisconnectedError, match="failed"):
        drv.set_speeds_rpm(300, 300)
    assert drv.stop_reason is not None
    # nothing reaches the controller any more; its own watchdog must stop the motors
    clock.advance(1.1)
    assert emu.setpoints_rpm == (0.0, 0.0)
    assert emu.watchdog_trips == 1


def test_a_fault_flag_stops_the_motors_and_raises_with_the_flag_names(drv, emu, clock) -> None:
    drive_for(drv, clock, 300, 300, 0.5)
    emu.raise_fault(MotorFaults(overheat=True, undervoltage=True))
    with pytest.raises(DeviceFaultError, match=r"overheat.*undervoltage"):
        drv.read_state()
    assert_stopped(emu)


def test_a_motor_flag_meaning_the_motor_does_not_follow_stops_and_raises(drv, emu, clock) -> None:
    drive_for(drv, clock, 300, 300, 0.5)
    emu.set_motor_flags(2, codec.MotorFlags(amps_limit=True))  # informational: no fault
    drv.read_state()
    emu.set_motor_flags(2, codec.MotorFlags(loop_error=True))  # e.g. the right encoder came off
    with pytest.raises(DeviceFaultError, match=r"right motor flags \['loop_error'\]"):
        drv.read_state()
    assert_stopped(emu)


def test_go_commands_are_a_fraction_of_max_rpm_in_closed_loop(drv, emu) -> None:
    drv.set_commands(500, -250)
    assert emu.setpoints_rpm == (500.0, -250.0)  # ^MXRPM = 1000
    with pytest.raises(CommandError, match="1001"):
        drv.set_commands(1001, 0)
    assert_stopped(emu)


def test_non_finite_or_too_fast_speed_stops_then_raises(drv, emu, clock) -> None:
    drive_for(drv, clock, 300, 300, 0.5)
    with pytest.raises(CommandError, match="right_rpm=nan"):
        drv.set_speeds_rpm(100, float("nan"))
    assert_stopped(emu)
    drv.release_stop()
    with pytest.raises(CommandError, match="left_rpm=1500"):
        drv.set_speeds_rpm(1500, 0)


def test_watchdog_stops_the_motors_when_only_queries_arrive(drv, emu, clock) -> None:
    drv.set_speeds_rpm(400, 400)
    for _ in range(9):  # 0.9 s of queries: below the 1 s watchdog, the set points stay
        clock.advance(0.1)
        drv.read_state()
    assert emu.setpoints_rpm == (400.0, 400.0)
    for _ in range(3):  # queries do not refresh the watchdog: past 1 s it trips
        clock.advance(0.1)
        drv.read_state()
    assert emu.setpoints_rpm == (0.0, 0.0)
    assert emu.watchdog_trips == 1
    assert [s.reason for s in emu.stops] == ["watchdog"]
    clock.advance(3.0)
    assert max(abs(s) for s in drv.read_state().speed_rpm) < 5.0  # the motors have run down


def test_emergency_stop_and_release(drv, emu, clock) -> None:
    drive_for(drv, clock, 300, 300, 0.5)
    drv.emergency_stop()
    assert emu.setpoints_rpm == (0.0, 0.0) and emu.estop
    drv.release_stop()
    assert not emu.estop
    drv.set_speeds_rpm(50, 50)
    assert emu.setpoints_rpm == (50.0, 50.0)


def test_an_emergency_stop_latched_by_an_earlier_session_is_released_only_when_asked(emu, clock) -> None:
    with RoboteqMDC2230(emu.device_path, timeout_s=TIMEOUT_S) as first:
        first.emergency_stop()
    second = RoboteqMDC2230(emu.device_path, timeout_s=TIMEOUT_S)
    with pytest.raises(DeviceFaultError, match=r"emergency stop is latched.*--release-stop"):
        second.open()
    assert emu.estop
    with RoboteqMDC2230(emu.device_path, timeout_s=TIMEOUT_S, release_on_open=True) as third:
        assert not emu.estop
        assert not third.read_state().faults.any


def test_status_and_motor_flags_are_decoded(drv, emu) -> None:
    assert drv.read_status().names() == ["serial_mode"]
    emu.set_motor_flags(2, codec.MotorFlags(loop_error=True, amps_limit=True))
    fm_left, fm_right = drv.read_motor_flags()
    assert fm_left.names() == []
    assert fm_right.names() == ["amps_limit", "loop_error"] and fm_right.any_fault


def test_voltages_and_amps_are_scaled_to_volts_and_amps(drv, emu) -> None:
    internal, battery, five = drv.read_voltages()
    assert internal == pytest.approx(emu.battery_v - 0.3)  # the emulator's internal supply sits 0.3 V lower
    assert battery == pytest.approx(emu.battery_v)
    assert five == pytest.approx(4.98)
    assert drv.read_amps() == (0.0, 0.0)


def test_emulator_answers_unknown_or_malformed_commands_with_minus(emu) -> None:
    import os

    import serial

    with serial.Serial(emu.device_path, timeout=0.5) as port:
        port.write(b"?NOPE\r!S 3 10\r^RWD 70000\r")
        data = b""
        while data.count(b"\r") < 6:
            chunk = port.read(1) + port.read(port.in_waiting)  # what has arrived, not 64 bytes or the timeout
            assert chunk, f"emulator stopped answering after {data!r}"
            data += chunk
    lines, _ = codec.split_lines(data)
    # each character is echoed as it arrives, so the echoes may run ahead of the answers
    assert [ln for ln in lines if ln != "-"] == ["?NOPE", "!S 3 10", "^RWD 70000"]
    assert lines.count("-") == 3
    assert os.path.exists(emu.device_path)


class ScriptedPort:
    """A serial-like transport: answers each command line with scripted bytes, delivered in chunks.

    ``chunks`` gives the sizes in which received bytes are handed to ``read`` (cycled), so a reply
    can be split anywhere, as a USB serial port may split it.
    """

    def __init__(self, answers: dict[str, bytes], chunks: list[int], echo: bool) -> None:
        self.answers, self.chunks, self.echo = answers, chunks, echo
        self.buf = b""
        self.k = 0
        self.written: list[bytes] = []

    def write(self, data: bytes) -> int:
        self.written.append(data)
        for line in data.split(b"\r")[:-1]:
            self.buf += (line + b"\r" if self.echo else b"") + self.answers.get(line.decode(), b"-\r")
        return len(data)

    @property
    def in_waiting(self) -> int:
        return len(self.buf)

    def read(self, size: int = 1) -> bytes:
        n = min(size, self.chunks[self.k % len(self.chunks)])
        self.k += 1
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def reset_input_buffer(self) -> None:
        self.buf = b""

    def close(self) -> None:
        pass


ANSWERS = {
    "?FID": b"FID=Roboteq v1.3 MDC2230 07/24/2013\r",
    "?C": b"T=12:13\rC=-5:2147483647\r",  # an unsolicited telemetry line first
    "?FF": b"FF=0\r",
    "!S 1 0": b"+\r",
    "!S 2 0": b"+\r",
}


@given(chunks=st.lists(st.integers(1, 9), min_size=1, max_size=8), echo=st.booleans())
@settings(max_examples=60, deadline=None)
def test_replies_split_into_any_chunks_are_reassembled_with_or_without_echo(chunks, echo) -> None:
    port = ScriptedPort(ANSWERS, chunks, echo)
    drv = RoboteqMDC2230(port, configure=False, timeout_s=0.5)
    drv.open()
    assert drv.firmware is not None and drv.firmware.major == 1
    assert drv._ints(codec.query("C"), 2) == (-5, 2**31 - 1)
    assert drv.n_retries == 0
    drv.close()
    assert port.written[-2:] == [b"!S 1 0\r", b"!S 2 0\r"]  # close() stops the motors


def test_a_received_line_is_stamped_with_its_arrival_not_the_last_motor_tick(drv, emu, clock) -> None:
    """The emulator's record says when a line arrived on its clock. The motors advance in 1 ms ticks:
    a line that arrives 0.6 ms after a tick must not carry that tick's stamp (a stop that followed a
    signal within a millisecond was once stamped before it, and taken for a missing stop)."""
    clock.advance(0.0106)  # 10.6 ms: the motors stand at the 10 ms tick
    t_before = clock.now_ns()
    drv.set_speeds_rpm(0.0, 0.0)
    stamps = [t for t, line in list(emu.received) if line in ("!S 1 0", "!S 2 0")]
    assert stamps[-2:] == [t_before, t_before]
