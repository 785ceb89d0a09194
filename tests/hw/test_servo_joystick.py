"""Servo (serial line protocol and PWM) and the Arduino joystick against their emulators."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hw.clock import ManualClock
from hw.errors import CommandError, DeviceClosedError, DeviceFaultError, DeviceTimeoutError
from hw.interfaces import Joystick, Servo
from hw.joystick import ArduinoJoystickEmulator, SerialJoystick, checksum, format_line, parse_line
from hw.servo import ArduinoServoEmulator, PwmServo, SerialServo
from hw.sonar_array import RangerSonarArray

# --- serial servo -----------------------------------------------------------------------------------------


def test_serial_servo_moves_and_the_board_acknowledges_whole_degrees():
    emu = ArduinoServoEmulator((0, 1))
    with SerialServo(emu, 1, clock=ManualClock()) as s:
        assert isinstance(s, Servo)
        assert emu.angles[1] == 90  # the known starting angle sent on open
        s.set_angle_deg(42.4)
        assert emu.angles[1] == 42 and s.angle_deg() == 42.0
    assert emu.commands == [(1, 90), (1, 42)]


def test_serial_servo_clamps_or_refuses_out_of_range_angles():
    emu = ArduinoServoEmulator()
    with SerialServo(emu, clock=ManualClock()) as s:
        s.set_angle_deg(200.0)
        assert emu.angles[0] == 180
        s.set_angle_deg(-5.0)
        assert emu.angles[0] == 0
        with pytest.raises(CommandError, match="not finite"):
            s.set_angle_deg(math.nan)
    with SerialServo(emu, clock=ManualClock(), out_of_range="refuse", limits_deg=(20, 160)) as s:
        with pytest.raises(CommandError, match=r"outside the limits 20\.\.160"):
            s.set_angle_deg(170.0)
        assert emu.angles[0] == 90


def test_serial_servo_retries_a_lost_acknowledge_then_gives_up():
    emu = ArduinoServoEmulator()
    clock = ManualClock()
    with SerialServo(emu, clock=clock, retries=1, reply_timeout_s=0.1) as s:
        emu.drop_replies = 1
        s.set_angle_deg(30.0)
        assert s.angle_deg() == 30.0
        emu.drop_replies = 2
        t0 = clock.now_ns()
        with pytest.raises(DeviceTimeoutError, match="2 tries"):
            s.set_angle_deg(60.0)
        assert clock.now_ns() - t0 == 200_000_000
        assert s.angle_deg() == 30.0  # unacknowledged: the last known angle stays


def test_a_refusal_from_the_board_is_a_device_fault():
    emu = ArduinoServoEmulator()
    with SerialServo(emu, clock=ManualClock()) as s:
        emu.refuse_next = "overcurrent"
        with pytest.raises(DeviceFaultError, match="overcurrent"):
            s.set_angle_deg(10.0)


def test_a_servo_the_board_does_not_have_is_refused_on_open():
    with pytest.raises(DeviceFaultError, match="no such servo"):
        SerialServo(ArduinoServoEmulator((0,)), 3, clock=ManualClock()).open()


def test_sonar_array_turns_its_servo_and_reports_the_angle():
    class Fixed:
        name = "fixed"

        def open(self):
            pass

        def close(self):
            pass

        def read(self):
            from hw.interfaces import RangeReading

            return RangeReading(0, 0.5, 0.03, 6.0, 1.0)

    emu = ArduinoServoEmulator()
    clock = ManualClock()
    with RangerSonarArray([Fixed(), Fixed(), Fixed()], SerialServo(emu, clock=clock), clock=clock) as arr:
        arr.set_servo_deg(120.0)
        r = arr.read()
        assert r.servo_angle_deg == 120.0 and emu.angles[0] == 120


# --- PWM servo ----------------------------------------------------------------------------------------------


class RecordingPwm:
    def __init__(self):
        self.widths: list[float] = []
        self.closed = False

    def set_pulse_width_us(self, width_us):
        self.widths.append(width_us)

    def close(self):
        self.closed = True


def test_pwm_servo_maps_angle_linearly_onto_pulse_width():
    pwm = RecordingPwm()
    with PwmServo(pwm, min_pulse_us=1000.0, max_pulse_us=2000.0) as s:
        s.set_angle_deg(0.0)
        s.set_angle_deg(45.0)
        s.set_angle_deg(500.0)  # clamped to 180
        assert s.angle_deg() == 180.0
    assert pwm.widths == [1500.0, 1000.0, 1250.0, 2000.0]
    assert pwm.closed


def test_pwm_servo_refuses_when_asked_and_rejects_bad_limits():
    with PwmServo(RecordingPwm(), out_of_range="refuse") as s, pytest.raises(CommandError, match="-1"):
        s.set_angle_deg(-1.0)
    with pytest.raises(CommandError, match="limits_deg"):
        PwmServo(RecordingPwm(), limits_deg=(0.0, 200.0))
    with pytest.raises(DeviceClosedError):
        PwmServo(RecordingPwm()).set_angle_deg(10.0)


# --- joystick -----------------------------------------------------------------------------------------------


def test_joystick_line_format_round_trips():
    line = format_line(1023, 0, True)
    body = "J 1023 0 1"
    assert line == f"{body} {sum(body.encode()) % 256:02X}\n".encode()
    assert parse_line(line) is not None
    s = parse_line(line)
    assert s is not None and (s.x_raw, s.y_raw, s.deadman) == (1023, 0, True)


@given(x=st.integers(0, 1023), y=st.integers(0, 1023), b=st.booleans())
def test_every_valid_sample_round_trips_through_the_wire(x, y, b):
    s = parse_line(format_line(x, y, b))
    assert s is not None and (s.x_raw, s.y_raw, s.deadman) == (x, y, b)


@pytest.mark.parametrize(
    "bad",
    [
        b"J 512 512 1 00\n",  # wrong checksum
        b"J 1024 512 1 " + checksum("J 1024 512 1").encode() + b"\n",  # out of ADC range
        b"J 512 512 2 " + checksum("J 512 512 2").encode() + b"\n",  # button not 0/1
        b"J 512 512\n",  # cut line
        b"J -5 512 1 " + checksum("J -5 512 1").encode() + b"\n",  # negative
        b"\xffJ 512 512 1 \x00\n",  # noise
        b"",
    ],
)
def test_garbled_lines_are_rejected(bad):
    assert parse_line(bad) is None


def test_joystick_reads_normalised_axes_while_the_deadman_is_held():
    clock = ManualClock()
    emu = ArduinoJoystickEmulator()
    with SerialJoystick(emu, clock=clock) as js:
        assert isinstance(js, Joystick)
        emu.set(1023, 0, True)
        emu.emit(3)
        r = js.read()
        assert (r.forward, r.turn, r.deadman) == (1.0, -1.0, True)  # (0 - 512) / 511 clipped to -1
        emu.set(512 + 20, 512 - 10, True)  # |20/511| < 0.05: inside the dead zone
        emu.emit()
        r = js.read()
        assert (r.forward, r.turn) == (0.0, 0.0)
        emu.set(767, 512, True)
        emu.emit()
        assert js.read().forward == pytest.approx(255 / 511)


def test_releasing_the_deadman_gives_a_zero_command():
    clock = ManualClock()
    emu = ArduinoJoystickEmulator()
    with SerialJoystick(emu, clock=clock) as js:
        emu.set(1023, 1023, False)
        emu.emit()
        r = js.read()
        assert (r.forward, r.turn, r.deadman) == (0.0, 0.0, False)


def test_a_stale_joystick_gives_a_zero_command_with_the_deadman_released():
    clock = ManualClock()
    emu = ArduinoJoystickEmulator()
    with SerialJoystick(emu, clock=clock, stale_after_s=0.2) as js:
        assert js.read().deadman is False  # nothing received yet
        emu.set(1023, 512, True)
        emu.emit()
        assert js.read().forward == 1.0
        clock.advance(0.15)
        assert js.read().forward == 1.0  # 150 ms old: still fresh
        clock.advance(0.1)
        r = js.read()  # 250 ms old: stale
        assert (r.forward, r.turn, r.deadman) == (0.0, 0.0, False)
        assert r.stamp_ns == 0  # the time of the last valid line
        assert js.stale_reads == 2


def test_garbled_lines_on_the_wire_never_move_the_chair():
    clock = ManualClock()
    emu = ArduinoJoystickEmulator()
    with SerialJoystick(emu, clock=clock) as js:
        emu.set(600, 512, True)
        emu.emit()
        emu.emit_raw(b"J 1023 1023 1 00\n")  # bad checksum after the good line
        emu.emit_raw(b"\x00\xffJ 10")
        r = js.read()
        assert r.forward == pytest.approx(88 / 511)  # the good line still rules
        assert js.rejected_lines == 2
    assert emu.closed


def test_joystick_settings_are_validated():
    with pytest.raises(CommandError, match="deadzone"):
        SerialJoystick(ArduinoJoystickEmulator(), deadzone=1.5)


def test_a_failing_serial_line_is_a_device_io_error_naming_the_joystick():
    from hw.errors import DeviceIOError

    class Unplugged(ArduinoJoystickEmulator):
        @property
        def in_waiting(self):
            raise OSError(5, "Input/output error")

    with SerialJoystick(Unplugged(), clock=ManualClock(), name="joystick") as js:
        with pytest.raises(DeviceIOError, match="joystick: serial line failed"):
            js.read()
