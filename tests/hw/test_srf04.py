"""SRF04 driver: echo timing, and the Arduino echo-width line protocol against its emulator."""

from __future__ import annotations

import math

import pytest

from hw.clock import ManualClock
from hw.errors import CommandError, DeviceClosedError, DeviceTimeoutError, ProtocolError
from hw.interfaces import Ranger
from hw.serial_lines import LineTransport
from hw.srf04 import SRF04, ArduinoEchoPins, ArduinoSRF04Emulator, EchoPins


class ScriptedPins:
    """Echo lines that return a scripted pulse width per trigger (a pin-level emulator)."""

    def __init__(self, widths):
        self.widths = list(widths)
        self.triggers = 0
        self.closed = False

    def trigger(self):
        self.triggers += 1

    def wait_echo_width_s(self, timeout_s):
        return self.widths.pop(0)

    def close(self):
        self.closed = True


def board(ranges, ids=(0, 1)):
    clock = ManualClock()
    emu = ArduinoSRF04Emulator(lambda sid, t: ranges[sid], clock, sonar_ids=ids)
    return clock, emu


def test_echo_width_over_58_us_per_cm_gives_the_range():
    pins = ScriptedPins([0.0058, 0.0174, 0.036])  # 100 cm, 300 cm (the rated maximum), no-echo pulse
    assert isinstance(pins, EchoPins)
    with SRF04(pins, clock=ManualClock()) as s:
        assert isinstance(s, Ranger)
        assert s.read().range_m == pytest.approx(1.0)
        assert s.read().range_m == pytest.approx(3.0)
        assert s.read().range_m == math.inf  # REP-117: no return
    assert pins.closed


@pytest.mark.parametrize("width_s", [0.018, 0.0245, 0.0299, 0.030, 0.036])
def test_echoes_beyond_the_rated_3_m_read_as_no_return(width_s):
    # 18-30 ms pulses used to read as 3.1-5.2 m, beyond what the SRF04 is rated to see
    with SRF04(ScriptedPins([width_s]), clock=ManualClock()) as s:
        assert s.read().range_m == math.inf


@pytest.mark.parametrize("width_s", [0.0, 0.00005, 0.0001, 0.00017])
def test_echoes_under_the_3_cm_minimum_read_as_invalid(width_s):
    # a pulse under 174 us (3 cm) is ring-down or crosstalk as often as an object: NaN, not 9 mm
    with SRF04(ScriptedPins([width_s]), clock=ManualClock()) as s:
        r = s.read()
        assert math.isnan(r.range_m) and r.min_range_m == 0.03


def test_no_pulse_at_all_raises_a_timeout_and_bad_widths_a_protocol_error():
    with SRF04(ScriptedPins([None, -1.0]), clock=ManualClock()) as s:
        with pytest.raises(DeviceTimeoutError, match="no echo pulse"):
            s.read()
        with pytest.raises(ProtocolError, match="echo width"):
            s.read()


def test_triggers_are_paced_by_the_minimum_cycle():
    clock = ManualClock()
    with SRF04(ScriptedPins([0.001] * 3), clock=clock, min_cycle_s=0.05) as s:
        stamps = [s.read().stamp_ns for _ in range(3)]
    assert stamps == [0, 50_000_000, 100_000_000]


def test_reading_a_closed_srf04_raises():
    with pytest.raises(DeviceClosedError, match="srf04"):
        SRF04(ScriptedPins([0.001])).read()


def test_inconsistent_timeouts_are_refused():
    with pytest.raises(CommandError, match="no_echo_width_s"):
        SRF04(ScriptedPins([]), no_echo_width_s=0.1, timeout_s=0.05)


# --- Arduino line protocol ------------------------------------------------------------------------------


def test_arduino_reports_echo_widths_that_become_ranges():
    clock, emu = board({0: 0.75, 1: math.nan})
    assert isinstance(emu, LineTransport)
    s0 = SRF04(ArduinoEchoPins(emu, 0, clock), clock=clock, name="front")
    s1 = SRF04(ArduinoEchoPins(emu, 1, clock), clock=clock, name="rear")
    with s0, s1:
        assert s0.read().range_m == pytest.approx(0.75)  # 75 cm * 58 = 4350 us on the wire
        assert s1.read().range_m == math.inf  # 36000 us: nothing in range
    assert emu.requests == [0, 1]


def test_the_wire_format_is_the_documented_one():
    _, emu = board({0: 0.5})
    emu.write(b"T 0\n")
    assert emu.readline() == b"E 0 2900\n"
    emu.write(b"T 7\n")  # not wired: no pulse
    assert emu.readline() == b"E 7 0\n"
    emu.write(b"hello\n")  # ignored by the sketch
    assert emu.readline() == b""


def test_garbled_and_foreign_lines_are_skipped_and_counted():
    clock, emu = board({0: 0.4, 1: 0.9})
    pins = ArduinoEchoPins(emu, 0, clock)
    with SRF04(pins, clock=clock) as s:
        emu.wrong_id_replies = 1
        assert s.read().range_m == pytest.approx(0.4)
        assert pins.ignored_lines == 1
        emu.garble_replies = 1  # the only reply is noise: nothing usable arrives
        with pytest.raises(DeviceTimeoutError):
            s.read()
        assert pins.ignored_lines == 2


def test_a_dropped_reply_times_out_in_simulated_time_and_the_next_read_works():
    clock, emu = board({0: 0.4})
    with SRF04(ArduinoEchoPins(emu, 0, clock, poll_s=0.005), clock=clock, timeout_s=0.07) as s:
        emu.drop_replies = 1
        t0 = clock.now_ns()
        with pytest.raises(DeviceTimeoutError, match="70 ms"):
            s.read()
        assert clock.now_ns() - t0 == 70_000_000
        assert s.read().range_m == pytest.approx(0.4)


def test_a_sonar_the_board_does_not_have_reads_as_silent():
    clock, emu = board({0: 0.4}, ids=(0,))
    with SRF04(ArduinoEchoPins(emu, 3, clock), clock=clock) as s:
        with pytest.raises(DeviceTimeoutError):
            s.read()


def test_sonar_ids_are_validated():
    clock, emu = board({0: 0.4})
    with pytest.raises(CommandError, match="sonar_id=16"):
        ArduinoEchoPins(emu, 16, clock)


@pytest.mark.hardware
def test_srf04_on_raspberry_pi_gpio_23_24_measures_something():
    from hw.srf04 import PigpioEchoPins

    with SRF04(PigpioEchoPins(trigger_gpio=23, echo_gpio=24)) as s:
        r = s.read()
        assert r.range_m == math.inf or 0.03 <= r.range_m <= 3.0
