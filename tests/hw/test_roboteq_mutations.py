"""The Roboteq driver's units and limits against hand values from the manual and the spec.

The controller here is :class:`tests.hw.test_roboteq_manual.ManualRoboteq` (written from the Roboteq
Advanced Digital Motor Controller user manual, not from the emulator or the driver), with currents that
are not zero and a configuration that differs from what the driver writes, so a unit error on either
side of the wire shows.
"""

from __future__ import annotations

import logging
import math

import pytest

from hw.clock import ManualClock
from hw.errors import CommandError, DeviceClosedError, DeviceFaultError, DeviceStateError, ProtocolError
from hw.interfaces import PIDConfig
from hw.roboteq import codec
from hw.roboteq.driver import RoboteqMDC2230
from hw.roboteq.settings import RoboteqProtections
from tests.hw.test_roboteq_manual import ManualRoboteq, opened


class LoadedRoboteq(ManualRoboteq):
    """A :class:`ManualRoboteq` whose motors draw current: ``?A`` answers ``A=125:-38``, and whose
    three temperatures differ: ``?T`` answers ``T=31:29:27``.

    Manual, ``?A`` (Read Motor Amps): one value per channel in 0.1 A, so 12.5 A and -3.8 A; ``?T``
    (Read Temperature): MCU, channel 1 and channel 2 heatsinks in whole degrees C.
    """

    def _execute(self, line: str) -> str:
        if line.upper().startswith("?A"):
            return "A=125:-38"
        if line.upper().startswith("?T"):
            return "T=31:29:27"
        return super()._execute(line)


@pytest.fixture
def fake():
    with LoadedRoboteq() as f:
        # not what the driver writes: the read-back below must come from the driver's own writes
        f.config.update({"MAC": [1, 1], "MDEC": [1, 1], "ALIM": [10, 10], "CLERD": [0, 0]})
        yield f


def test_voltages_are_read_in_tenths_of_a_volt_and_the_5v_output_in_millivolts(fake) -> None:
    """Manual, ``?V`` (Read Volts): ``V=241:244:4980`` is 24.1 V internal, 24.4 V battery and 4.980 V on
    the 5 V output (the first two in 0.1 V, the third in mV). ``ManualRoboteq`` answers exactly that."""
    drv = opened(fake)
    assert drv.read_voltages() == pytest.approx((24.1, 24.4, 4.98), abs=1e-9)
    drv.close()


def test_motor_currents_are_read_in_tenths_of_an_amp(fake) -> None:
    """Manual, ``?A`` (Read Motor Amps) in 0.1 A: ``A=125:-38`` is 12.5 A left and -3.8 A right."""
    drv = opened(fake)
    assert drv.read_amps() == pytest.approx((12.5, -3.8), abs=1e-9)
    drv.close()


def test_counts_speeds_temperatures_and_flags_are_read_field_by_field(fake) -> None:
    """Manual: ``?C`` absolute encoder counts per channel (``C=123456:-7890``), ``?S`` speed in RPM per
    channel (the set points 400 and -250 the controller follows), ``?T`` 31, 29, 27 degrees C (see
    :class:`LoadedRoboteq`), ``?FS`` f1 = serial mode, ``?FM`` f3 loop error on channel 1 and f2 motor
    stall on channel 2 (``FM=4:2``), ``~RWD`` one global value, ``~ALIM`` one value per channel."""
    drv = opened(fake)
    with fake._lock:
        fake.counts = [123456, -7890]
        fake.fm = [4, 2]
    assert drv.read_encoder_counts() == (123456, -7890)
    drv.set_speeds_rpm(400.0, -250.0)
    assert drv.read_speeds_rpm() == (400.0, -250.0)
    assert drv.read_temperatures() == (31.0, 29.0, 27.0)
    status = drv.read_status()
    assert status.serial_mode and status.names() == ["serial_mode"]
    ch1, ch2 = drv.read_motor_flags()
    assert ch1.names() == ["loop_error"] and ch2.names() == ["motor_stall"]
    assert drv.read_config("RWD") == (1000,)
    assert drv.read_config("ALIM") == (300, 300)
    drv.close()


def test_open_writes_the_protections_in_the_controllers_units(fake) -> None:
    """Hand values (spec: wheel radius 0.172 m, separation 0.58 m, gear 29; safety defaults: max_accel
    0.5 m/s^2, max_yaw_accel 1.5 rad/s^2, brake_decel 0.8 m/s^2; the ramps 1.5x above them):

    * one wheel's acceleration (0.5 + 1.5 * 0.29) m/s^2 = 0.935 m/s^2 is
      0.935 * 60 / (2 pi 0.172) * 29 = 1505.4 motor RPM/s, times 1.5 = 2258.1 RPM/s; ``^MAC`` is in
      0.1 RPM/s (manual): 22581;
    * braking (0.8 + 0.435) m/s^2 = 1.235 m/s^2 gives 2982.6 RPM/s: ``^MDEC`` 29826;
    * ``^ALIM`` is in 0.1 A (manual): the MDC2230's 30 A rating (datasheet, 2 x 30 A) is 300;
    * ``^CLERD`` 2 is the manual's "500 ms at error > 250" detection level.
    """
    drv = opened(fake)
    cfg = fake.config
    for name, want in (("MAC", 22581), ("MDEC", 29826)):
        assert all(abs(v - want) <= 1 for v in cfg[name]), (name, cfg[name])
    assert cfg["ALIM"] == [300, 300]
    assert cfg["CLERD"] == [2, 2]
    assert cfg["MXRPM"] == [1000, 1000]  # spec: max_motor_rpm = 1000
    drv.close()


def test_speeds_up_to_the_maximum_are_written_and_just_above_are_refused(fake) -> None:
    """Spec: ``max_motor_rpm = 1000``. +-1000 RPM is written as ``!S 1 1000`` / ``!S 2 -1000``; 1000.6
    (which would round to 1001) and 1001 RPM are refused before anything reaches the controller."""
    drv = opened(fake)
    drv.set_speeds_rpm(1000.0, -1000.0)
    assert fake.received[-2:] == ["!S 1 1000", "!S 2 -1000"]
    for bad in (1000.6, 1001.0, -1001.0):
        drv.release_stop()
        n = len(fake.received)
        with pytest.raises(CommandError, match="1000 RPM"):
            drv.set_speeds_rpm(bad, 0.0)
        assert not any(line.startswith("!S 1 100") for line in fake.received[n:])
        assert fake.effective == (0, 0)  # refused after stopping
    drv.close()


def test_the_driver_refuses_a_maximum_outside_the_manuals_mxrpm_range() -> None:
    """Manual, ``^MXRPM``: 10 to 65000 RPM."""
    for bad in (9, 65001):
        with pytest.raises(CommandError, match="max_rpm"):
            RoboteqMDC2230("/dev/null", max_rpm=bad)
    assert math.isfinite(RoboteqMDC2230("/dev/null", max_rpm=10).max_rpm)


# --- the protections, without a controller --------------------------------------------------------


class _Spec:
    """A chair whose numbers make the ramps easy by hand: 60 / (2 pi r) = 1 wheel RPM per m/s
    (r = 30 / pi m), gear ratio 10, half the wheel separation 1 m."""

    wheel_radius = 30.0 / math.pi
    wheel_separation = 2.0
    gear_ratio = 10.0


class _Limits:
    max_accel = 1.0  # m/s^2
    max_yaw_accel = 2.0  # rad/s^2
    brake_decel = 3.0  # m/s^2


def test_the_ramps_are_the_wheel_accelerations_in_motor_rpm_per_second_with_half_again_headroom() -> None:
    """Hand computation from the formula in ``RoboteqProtections.from_spec``'s docstring:

    * accelerating wheel: (max_accel 1 + max_yaw_accel 2 x half separation 1) = 3 m/s^2, x 1 wheel RPM
      per m/s x gear 10 = 30 motor RPM/s, x 1.5 headroom = 45 RPM/s; ``^MAC`` in 0.1 RPM/s (manual): 450;
    * braking wheel: (brake_decel 3 + 2 x 1) = 5 m/s^2 -> 50 RPM/s -> 75 RPM/s; ``^MDEC`` 750;
    * ``^ALIM`` 12.5 A in 0.1 A (manual): 125; ``^CLERD`` the default level 2.
    """
    p = RoboteqProtections.from_spec(_Spec(), _Limits(), amps_limit_a=12.5)
    assert (p.accel_rpm_s, p.decel_rpm_s, p.amps_limit_a) == pytest.approx((45.0, 75.0, 12.5), abs=1e-9)
    assert p.config_items() == {"MAC": 450, "MDEC": 750, "ALIM": 125, "CLERD": 2}


def test_the_ramps_are_rounded_to_a_tenth_of_an_rpm_per_second() -> None:
    """``^MAC``/``^MDEC`` are in 0.1 RPM/s (manual), so the ramps keep one decimal: with max_accel
    1.00001 m/s^2 the acceleration is (1.00001 + 2) x 10 x 1.5 = 45.00015 RPM/s, written 45.0."""

    class Limits(_Limits):
        max_accel = 1.00001

    p = RoboteqProtections.from_spec(_Spec(), Limits())
    assert p.accel_rpm_s == 45.0
    assert p.amps_limit_a == 30.0  # default: the MDC2230's 30 A rating (datasheet, 2 x 30 A)


def test_the_default_limits_are_the_safety_layers_defaults() -> None:
    """Safety defaults (SPEC): max_accel 0.5 m/s^2, max_yaw_accel 1.5 rad/s^2, brake_decel 0.8 m/s^2.
    With the easy chair: (0.5 + 1.5) x 10 x 1.5 = 30.0 RPM/s and (0.8 + 1.5) x 10 x 1.5 = 34.5 RPM/s."""
    p = RoboteqProtections.from_spec(_Spec())
    assert (p.accel_rpm_s, p.decel_rpm_s) == pytest.approx((30.0, 34.5), abs=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "items"),
    [
        # round half away from a truncation: 2258.06 RPM/s is 22580.6 tenths, written 22581
        ({"accel_rpm_s": 2258.06, "decel_rpm_s": 2982.64}, {"MAC": 22581, "MDEC": 29826}),
        ({"amps_limit_a": 1.0}, {"ALIM": 10}),  # manual: ^ALIM 10..3000 (1 A .. 300 A)
        ({"amps_limit_a": 300.0}, {"ALIM": 3000}),
        ({"accel_rpm_s": 50000.0, "decel_rpm_s": 50000.0}, {"MAC": 500000, "MDEC": 500000}),
        ({"loop_error_detection": 1}, {"CLERD": 1}),
        ({"loop_error_detection": 3}, {"CLERD": 3}),
    ],
)
def test_protections_are_written_in_tenths_and_the_manuals_bounds_are_accepted(kwargs, items) -> None:
    """Manual: ``^MAC``/``^MDEC`` in 0.1 RPM/s, 0..500000; ``^ALIM`` in 0.1 A, 10..3000; ``^CLERD`` 0..3.
    The defaults are 1000 RPM/s (10000), 30 A (300) and level 2."""
    want = {"MAC": 10000, "MDEC": 10000, "ALIM": 300, "CLERD": 2, **items}
    assert RoboteqProtections(**kwargs).config_items() == want


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"accel_rpm_s": 0.0}, "accel_rpm_s=0.0: expected a finite number > 0"),
        ({"decel_rpm_s": -1.0}, "decel_rpm_s=-1.0: expected a finite number > 0"),
        ({"amps_limit_a": math.nan}, "amps_limit_a=nan: expected a finite number > 0"),
        ({"accel_rpm_s": math.inf}, "accel_rpm_s=inf"),
        ({"decel_rpm_s": "10"}, "decel_rpm_s='10'"),
        ({"loop_error_detection": 0}, "loop_error_detection=0: expected 1, 2 or 3"),
        ({"loop_error_detection": 4}, "loop_error_detection=4"),
        ({"amps_limit_a": 0.94}, r"\^ALIM 9 outside the manual's 10..3000"),
        ({"amps_limit_a": 300.1}, r"\^ALIM 3001 outside the manual's 10..3000"),
        ({"accel_rpm_s": 50000.1}, r"\^MAC 500001 outside the manual's 0..500000"),
        ({"decel_rpm_s": 50000.1}, r"\^MDEC 500001 outside"),
    ],
)
def test_protections_outside_the_manuals_ranges_are_refused_naming_the_value(kwargs, message) -> None:
    """Manual ranges: ``^MAC``/``^MDEC`` 0..500000 (0.1 RPM/s), ``^ALIM`` 10..3000 (0.1 A); ``^CLERD``
    0 would switch off the loop-error flag the driver stops on, so only 1..3 are taken."""
    with pytest.raises(CommandError, match=f"^RoboteqProtections[.:] ?{message}"):
        RoboteqProtections(**kwargs)


# --- !G motor commands, ^RWD, malformed answers -----------------------------------------------------


def test_go_commands_span_the_manuals_minus_1000_to_1000_and_nothing_else(fake) -> None:
    """Manual, ``!G`` (Go to Speed): -1000..1000 per channel. Both ends are written as typed; 1001,
    -1001 and a bool are refused naming the channel (``True`` is an int in Python, not a command)."""
    drv = opened(fake)
    drv.set_commands(1000, -1000)
    assert fake.received[-2:] == ["!G 1 1000", "!G 2 -1000"]
    drv.set_commands(-1000, 1000)
    assert fake.received[-2:] == ["!G 1 -1000", "!G 2 1000"]
    for left, right, message in (
        (1001, 0, "!G left=1001 is not an integer in -1000..1000"),
        (0, -1001, "!G right=-1001 is not an integer in -1000..1000"),
        (True, 0, "!G left=True is not an integer in -1000..1000"),
        (0, 2.0, "!G right=2.0 is not an integer in -1000..1000"),
    ):
        drv.release_stop()
        n = len(fake.received)
        with pytest.raises(CommandError) as info:
            drv.set_commands(left, right)  # type: ignore[arg-type]
        assert str(info.value) == message
        assert not any(line.startswith("!G") for line in fake.received[n:])  # refused before writing
        assert fake.effective == (0, 0)
    drv.close()


COMMANDS = {"S": RoboteqMDC2230.set_speeds_rpm, "G": RoboteqMDC2230.set_commands}


@pytest.mark.parametrize("kind", ["S", "G"])
def test_only_an_active_controller_is_moved_and_zero_is_always_allowed(fake, kind) -> None:
    """Lifecycle (the driver's contract, REP-2003 style): zero may be sent in any open state, motion
    only when active. Either channel non-zero is motion, for ``!S`` (RPM) and ``!G`` alike."""
    send = COMMANDS[kind]
    drv = opened(fake)
    drv.deactivate()
    send(drv, 0, 0)
    assert fake.received[-2:] == [f"!{kind} 1 0", f"!{kind} 2 0"]
    for left, right in ((0, 300), (300, 0)):
        with pytest.raises(DeviceStateError):
            send(drv, left, right)
    drv.close()


@pytest.mark.parametrize("kind", ["S", "G"])
def test_a_host_stall_counts_as_a_watchdog_trip_only_while_a_wheel_was_commanded_to_move(fake, kind) -> None:
    """Manual, ``^RWD``: with no command for the watchdog period (1000 ms here) the controller stops
    the motors; that only matters when they were moving. A 1.5 s gap after (300, 0) or (0, 300) is a
    trip each (the driver zeroes both channels first); after (0, 0) it is none."""
    send = COMMANDS[kind]
    clk = ManualClock()
    drv = opened(fake, clock=clk)
    trips = 0
    for left, right, moving in ((300, 0, True), (0, 0, False), (0, 300, True), (0, 0, False)):
        send(drv, left, right)
        clk.advance(1.5)
        n = len(fake.received)
        send(drv, left, right)
        trips += moving
        assert drv.watchdog_trips == trips, (left, right)
        sent = fake.received[n:]
        want = [f"!{kind} 1 {left}", f"!{kind} 2 {right}"]
        assert sent == (["!S 1 0", "!S 2 0", *want] if moving else want)
    drv.close()


def test_the_watchdog_period_is_written_read_back_and_kept_armed(fake) -> None:
    """Manual, ``^RWD``: 0..65000 ms, 0 disabling the watchdog. The driver writes 1..65000 (both ends)
    and reads the value back (``~RWD``); 0, 65001 and a read-only session are refused, a controller that keeps
    its old value is a fault."""
    drv = opened(fake)
    drv.set_watchdog_ms(250)
    assert fake.received[-2:] == ["^RWD 250", "~RWD"]
    assert fake.config["RWD"] == [250] and drv.watchdog_ms == 250
    drv.set_watchdog_ms(1)
    assert fake.config["RWD"] == [1]
    drv.set_watchdog_ms(65000)
    assert fake.config["RWD"] == [65000]
    for bad in (0, 65001, True, 100.0):
        with pytest.raises(CommandError, match=r"1\.\.65000 ms"):
            drv.set_watchdog_ms(bad)  # type: ignore[arg-type]
    fake.ignore_writes.add("RWD")
    with pytest.raises(DeviceFaultError, match=r"RWD=65000 \(written 300\)"):
        drv.set_watchdog_ms(300)
    drv.close()
    ro = opened(fake, configure=False)
    n = len(fake.received)
    with pytest.raises(DeviceStateError, match=r"read-only session: \^RWD is not written"):
        ro.set_watchdog_ms(500)
    assert not any(line.startswith("^RWD") for line in fake.received[n:])
    ro.close()


@pytest.mark.parametrize(("query", "answer"), [("?C", "C=1:2:3"), ("?S", "S=7")])
def test_an_answer_with_the_wrong_number_of_channels_is_retried(fake, query, answer) -> None:
    """Manual: ``?C`` and ``?S`` answer one value per channel, two on the MDC2230; another count is a
    malformed answer, retried like a garbled line, and the next (good) answer is used."""
    drv = opened(fake)
    with fake._lock:
        fake.counts = [11, -22]
    fake.plan(query, ("answer", answer))
    got = drv.read_encoder_counts() if query == "?C" else drv.read_speeds_rpm()
    assert got == ((11, -22) if query == "?C" else (0.0, 0.0))
    assert drv.n_retries == 1
    drv.close()


@pytest.mark.parametrize(
    ("query", "answer", "method", "want"),
    [
        ("?V", "V=241:244", "read_voltages", (24.1, 24.4, 4.98)),
        ("?A", "A=1:2:3", "read_amps", (12.5, -3.8)),
        ("?T", "T=30:28", "read_temperatures", (31.0, 29.0, 27.0)),
        ("?FF", "FF=0:0", "read_faults_word", 0),
        ("?FF", "FF=70000", "read_faults_word", 0),  # beyond the manual's 16-bit flag word
    ],
)
def test_a_reading_with_the_wrong_number_of_fields_is_retried(fake, query, answer, method, want) -> None:
    """Manual: ``?V`` has three fields (internal, battery, 5 V output), ``?A`` one per channel, ``?T``
    three (MCU and the two heatsinks), ``?FF`` one 16-bit word. Another count, or a word beyond 65535,
    is malformed and retried; the good answers are
    those of :class:`LoadedRoboteq` and the manual's ``V=241:244:4980``."""
    drv = opened(fake)
    fake.plan(query, ("answer", answer))
    assert getattr(drv, method)() == pytest.approx(want, abs=1e-9)
    assert drv.n_retries == 1
    drv.close()


def test_the_startup_configuration_flag_is_a_fault_only_when_it_appears_during_the_session() -> None:
    """Manual, ``?FF`` f8 (128): "default configuration loaded at startup". Set already when the session
    opens it says nothing new; appearing later it means the controller restarted and lost the
    configuration the driver wrote."""
    with ManualRoboteq(ff=128) as booted_default:
        drv = opened(booted_default)
        assert drv.read_faults().startup_config
        drv.close()
    with ManualRoboteq() as fake:
        drv = opened(fake)
        fake.reboot(default_config=True)
        with pytest.raises(DeviceFaultError) as info:
            drv.read_faults()
        assert str(info.value) == (
            "Roboteq restarted during the session (?FF=128: default configuration loaded at startup); "
            "its configuration is lost: close and open again"
        )
        drv.close()


def _unopened(fid: str | None) -> RoboteqMDC2230:
    drv = RoboteqMDC2230("/dev/null")
    drv.firmware = None if fid is None else codec.parse_firmware_id(fid)
    return drv


def test_gains_are_encoded_within_the_manuals_register_range_of_each_firmware() -> None:
    """Manual V1.8: ``^KP/^KI/^KD`` 0..255 as gain x10 on 1.x, so 0 and 25.5 fit and 25.6 (256) does
    not; V2.0: 0..2,000,000,000 as gain x1,000,000, so 2000 fits and 2000.000001 does not."""
    v1 = _unopened("Roboteq v1.3 MDC2230 07/24/2013")
    assert v1.firmware_gains(PIDConfig(0.0, 25.5, 1.2)) == (0, 255, 12)
    for label, cfg in (
        ("kp", PIDConfig(25.6, 0, 0)),
        ("ki", PIDConfig(0, -0.1, 0)),
        ("kd", PIDConfig(0, 0, 25.6)),
    ):
        with pytest.raises(CommandError, match=f"^PID {label}="):
            v1.firmware_gains(cfg)
    with pytest.raises(
        CommandError, match=r"^PID ki=nan does not fit firmware 1\.x \(x10 must lie in 0\.\.255\)$"
    ):
        v1.firmware_gains(PIDConfig(0, math.nan, 0))
    v2 = _unopened("Roboteq v2.0 MDC2230 01/01/2019")
    assert v2.firmware_gains(PIDConfig(2000.0, 0.0, 0.5)) == (2_000_000_000, 0, 500_000)
    with pytest.raises(CommandError, match=r"^PID kp="):
        v2.firmware_gains(PIDConfig(2000.000001, 0, 0))


def test_gains_need_a_known_firmware() -> None:
    """The gain units depend on the firmware's major version (manual V1.8 vs V2.0): none probed yet, or
    a major version the manuals do not describe, is refused with a message that says which."""
    with pytest.raises(DeviceClosedError) as closed:
        _unopened(None).firmware_gains(PIDConfig(1, 1, 0))
    assert str(closed.value) == "roboteq-mdc2230: firmware unknown until configure() has probed ?FID"
    with pytest.raises(CommandError) as unknown:
        _unopened("Roboteq v3.1 X").firmware_gains(PIDConfig(1, 1, 0))
    assert str(unknown.value) == "firmware 'Roboteq v3.1 X': no known gain encoding for major version 3"


def test_the_largest_sixteen_bit_fault_word_is_read_and_a_larger_one_is_refused(caplog) -> None:
    """Manual (firmware 2.x): ``?FF`` is an unsigned 16-bit word, so 65535 is a valid answer (accepted,
    never refused as garbled) and 65536 is malformed: refused on every try, naming the
    word and the range.

    The driver's retry log says why each try failed: a reply later than the 0.1 s timeout (the fake's
    thread not scheduled in time on a loaded machine) is a ``timeout`` retry, not a refusal, so the count
    of every retry (``n_retries``) is not what is asserted here."""
    with ManualRoboteq() as fake:
        drv = opened(fake)
        fake.plan("?FF", ("answer", "FF=65535"))
        with caplog.at_level(logging.DEBUG, logger="hw.roboteq.transactions"):
            assert drv.read_faults_word() == 65535
        said = [r.getMessage() for r in caplog.records]
        assert [m for m in said if m.startswith("Roboteq ?FF: garbled")] == [], said
        fake.plan("?FF", ("answer", "FF=65536"), times=10)
        with pytest.raises(ProtocolError, match=r"flag word 65536 outside 0\.\.65535"):
            drv.read_faults_word()
        drv.close()


class _FineLimits(_Limits):
    """Limits whose ramps do not fall on a tenth: (1.0082 + 2) x 10 x 1.5 = 45.123 RPM/s and
    (3.0082 + 2) x 10 x 1.5 = 75.123 RPM/s."""

    max_accel = 1.0082
    brake_decel = 3.0082


def test_each_ramp_is_kept_to_one_decimal_of_an_rpm_per_second() -> None:
    """``^MAC``/``^MDEC`` count 0.1 RPM/s (manual): 45.123 and 75.123 RPM/s are kept as 45.1 and 75.1,
    not 45 / 75 (whole RPM/s) nor 45.12 / 75.12."""
    p = RoboteqProtections.from_spec(_Spec(), _FineLimits())
    assert (p.accel_rpm_s, p.decel_rpm_s) == (45.1, 75.1)
