"""SRF08 driver against the SRF08 I2C-bus emulator, and the three-sonar array built on it."""

from __future__ import annotations

import errno
import logging
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hw.clock import ManualClock
from hw.emulators.srf08 import BusyMode, SRF08Bus
from hw.errors import CommandError, DeviceClosedError, DeviceIOError, DeviceTimeoutError, HardwareError
from hw.interfaces import Ranger, SonarArray
from hw.sonar_array import RangerSonarArray
from hw.srf08 import SRF08, change_address, range_for_register, range_register_for, scan


class Scene:
    """Scripted ranges per address (metres); NaN = nothing in front."""

    def __init__(self, **by_addr: float) -> None:
        self.ranges = {int(k[1:], 16): v for k, v in by_addr.items()}
        self.calls: list[tuple[int, int]] = []

    def __call__(self, address: int, stamp_ns: int) -> float:
        self.calls.append((address, stamp_ns))
        return self.ranges.get(address, math.nan)


def make(busy_mode=BusyMode.FF, **ranges):
    clock = ManualClock()
    scene = Scene(**ranges)
    bus = SRF08Bus(clock, scene, addresses=sorted(scene.ranges) or [0x70], busy_mode=busy_mode)
    return clock, scene, bus


def test_driver_reads_centimetre_ranges_from_the_emulator():
    clock, _, bus = make(x70=0.5, x71=1.234, x72=math.nan)
    with (
        SRF08(bus, 0x70, clock=clock) as a,
        SRF08(bus, 0x71, clock=clock) as b,
        SRF08(bus, 0x72, clock=clock) as c,
    ):
        assert isinstance(a, Ranger)
        assert a.read().range_m == 0.50
        assert b.read().range_m == 1.23  # the device rounds to whole centimetres
        r = c.read()
        assert r.range_m == math.inf  # echo 0 = no echo: REP-117 +inf
        assert r.min_range_m == 0.03 and r.max_range_m == 6.0


@pytest.mark.parametrize("mode", [BusyMode.FF, BusyMode.NACK])
def test_polling_waits_out_the_65_ms_ranging_in_both_busy_styles(mode):
    clock, _, bus = make(busy_mode=mode, x70=0.8)
    with SRF08(bus, 0x70, clock=clock, wait="poll", poll_interval_s=0.005) as s:
        t0 = clock.now_ns()
        assert s.read().range_m == 0.80
        # 65 ms ranging, 5 ms polls: ready at the 13th poll, i.e. exactly 65 ms later
        assert clock.now_ns() - t0 == 65_000_000
        assert s.busy_polls == 13


def test_sleep_mode_waits_the_ranging_time_and_then_needs_no_busy_poll():
    clock, _, bus = make(busy_mode=BusyMode.NACK, x70=0.8)
    with SRF08(bus, 0x70, clock=clock, wait="sleep") as s:
        t0 = clock.now_ns()
        assert s.read().range_m == 0.80
        assert clock.now_ns() - t0 == 65_000_000
        assert s.busy_polls == 0


@settings(max_examples=60, deadline=None)
@given(r_cm=st.integers(1, 1100), mode=st.sampled_from([BusyMode.FF, BusyMode.NACK]))
def test_any_range_within_the_setting_reads_back_to_the_centimetre(r_cm, mode):
    clock, _, bus = make(busy_mode=mode, x70=r_cm / 100.0)
    with SRF08(bus, 0x70, clock=clock) as s:
        r = s.read().range_m
        # under the 3 cm minimum an echo is ring-down: invalid (REP-117 NaN)
        assert math.isnan(r) if r_cm < 3 else r == r_cm / 100.0


def test_a_lower_range_register_shortens_ranging_and_cuts_far_echoes():
    assert range_for_register(24) == pytest.approx(1.075)  # datasheet: 24 gives about 1 m
    assert range_for_register(255) == pytest.approx(11.008)
    assert range_register_for(1.0) == 23  # 23 * 43 + 43 = 1032 mm is the smallest covering 1 m
    clock, scene, bus = make(x70=1.2)
    with SRF08(bus, 0x70, clock=clock, max_range_m=1.0) as s:
        assert bus.devices[0x70].range_register == 23
        t0 = clock.now_ns()
        assert s.read().range_m == math.inf  # 1.2 m is beyond 1.032 m: not heard
        assert clock.now_ns() - t0 == 10_000_000  # 65 ms * 24/256 = 6.09 ms -> ready at the 2nd 5 ms poll
        scene.ranges[0x70] = 0.9
        assert s.read().range_m == 0.90


def test_gain_is_written_to_register_one_and_validated():
    clock, _, bus = make(x70=0.5)
    with SRF08(bus, 0x70, clock=clock, gain=10) as s:
        assert bus.devices[0x70].gain == 10
        s.set_gain(0)
        assert bus.devices[0x70].gain == 0
        with pytest.raises(CommandError, match="gain=32"):
            s.set_gain(32)
    with pytest.raises(CommandError, match="gain=-1"):
        SRF08(bus, 0x70, gain=-1)


def test_microsecond_and_inch_commands_use_the_datasheet_units():
    clock, _, bus = make(x70=0.5)
    with SRF08(bus, 0x70, clock=clock) as s:
        s.start_ranging(0x52)
        assert s.read_range_cm() == round(2 * 0.5 / 343.0 * 1e6)  # 2915 us of flight
        s.start_ranging(0x50)
        assert s.read_range_cm() == 20  # 0.5 m / 25.4 mm = 19.7 in


def test_several_echoes_fill_registers_four_onwards():
    clock = ManualClock()
    bus = SRF08Bus(clock, lambda a, t: [2.0, 0.4, 1.1], addresses=[0x70])
    with SRF08(bus, 0x70, clock=clock) as s:
        assert s.read().range_m == 0.40
        assert bus.read_i2c_block_data(0x70, 4, 4) == [0, 110, 0, 200]


def test_a_transient_io_error_is_retried_and_a_persistent_one_raises():
    clock, _, bus = make(x70=0.5)
    with SRF08(bus, 0x70, clock=clock, retries=2) as s:
        bus.inject_io_error(0x70, count=2)
        assert s.read().range_m == 0.50
        bus.inject_io_error(0x70)
        with pytest.raises(DeviceIOError, match="srf08@0x70") as ei:
            s.read()
        assert ei.value.errno == errno.EIO


def test_a_missing_device_times_out_on_open():
    clock, _, bus = make(x70=0.5)
    s = SRF08(bus, 0x7E, clock=clock, timeout_s=0.05)
    with pytest.raises(DeviceTimeoutError, match="still busy"):
        s.open()
    assert not s.is_open


def test_the_busy_timeout_message_names_the_sonar_the_wait_and_the_likely_causes():
    """A 0.6 s timeout is 600 ms; the message says what register 0 did and what that usually means."""
    clock, _, bus = make(x70=0.5)
    s = SRF08(bus, 0x7E, clock=clock, timeout_s=0.6)
    with pytest.raises(DeviceTimeoutError) as info:
        s.open()
    assert str(info.value) == (
        "srf08@0x7E: still busy 600 ms after the ranging started (register 0 reads 0xFF or is not"
        " acknowledged): device absent, wrong address, or not finishing its ranging"
    )


@pytest.mark.parametrize("mode", [BusyMode.FF, BusyMode.NACK])
def test_a_new_ranging_waits_for_an_uncollected_one_instead_of_being_lost(mode):
    clock, scene, bus = make(busy_mode=mode, x70=0.5)
    with SRF08(bus, 0x70, clock=clock) as s:
        s.start_ranging()  # result never collected
        scene.ranges[0x70] = 0.9
        t0 = clock.now_ns()
        s.start_ranging()  # in FF mode a write now would be dropped without a word
        assert clock.now_ns() - t0 == 65_000_000
        assert bus.devices[0x70].rangings == 2
        assert s.read_range_cm() == 90


def test_a_stuck_sonar_keeps_reporting_the_same_value():
    clock, scene, bus = make(x70=0.5)
    with SRF08(bus, 0x70, clock=clock) as s:
        bus.stick(0x70, 42)
        scene.ranges[0x70] = 0.9
        assert s.read().range_m == 0.42
        bus.clear_faults(0x70)
        assert s.read().range_m == 0.90


def test_using_a_closed_driver_raises():
    clock, _, bus = make(x70=0.5)
    s = SRF08(bus, 0x70, clock=clock)
    with pytest.raises(DeviceClosedError, match="srf08@0x70"):
        s.read()


def test_addresses_outside_0x70_0x7f_are_refused():
    _, _, bus = make(x70=0.5)
    with pytest.raises(CommandError, match=r"0x70\.\.0x7F"):
        SRF08(bus, 0xE0)


def test_general_call_starts_every_sonar_at_once():
    clock, scene, bus = make(x70=0.3, x71=0.6)
    bus.write_byte_data(0x00, 0, 0x51)
    assert [a for a, _ in scene.calls] == [0x70, 0x71]
    assert bus.read_byte_data(0x70, 0) == 0xFF  # both busy
    clock.advance(0.065)
    # one acoustic space (the default): 0x71 hears 0x70's echo of the nearer object first
    assert bus.read_i2c_block_data(0x71, 2, 2) == [0, 30]
    apart = SRF08Bus(clock, scene, addresses=[0x70, 0x71], groups=[(0x70,), (0x71,)])
    apart.write_byte_data(0x00, 0, 0x51)
    clock.advance(0.065)
    assert apart.read_i2c_block_data(0x71, 2, 2) == [0, 60]


# --- address change -----------------------------------------------------------------------------------


def test_address_change_refuses_without_confirmation_and_validates():
    _, _, bus = make(x70=0.5, x71=0.5)
    with pytest.raises(CommandError, match="confirm=True"):
        change_address(bus, 0x70, 0x7A)
    with pytest.raises(CommandError, match="new=0xF0"):
        change_address(bus, 0x70, 0xF0, confirm=True)
    with pytest.raises(CommandError, match="already answers"):
        change_address(bus, 0x70, 0x71, confirm=True)
    with pytest.raises(DeviceIOError, match="old=0x7B"):
        change_address(bus, 0x7B, 0x7C, confirm=True)
    assert sorted(bus.devices) == [0x70, 0x71]


def test_address_change_sends_the_four_byte_sequence_and_moves_the_device():
    _, _, bus = make(x70=0.5)
    writes: list[tuple[int, int, int]] = []
    original = bus.write_byte_data

    def spy(addr, reg, value, force=None):
        writes.append((addr, reg, value))
        original(addr, reg, value)

    bus.write_byte_data = spy  # type: ignore[method-assign]
    change_address(bus, 0x70, 0x79, confirm=True)
    assert writes == [(0x70, 0, 0xA0), (0x70, 0, 0xAA), (0x70, 0, 0xA5), (0x70, 0, 0xF2)]
    assert scan(bus) == {0x79: 11}


def test_an_interrupted_address_sequence_changes_nothing():
    clock, _, bus = make(x70=0.5)
    for v in (0xA0, 0xAA, 0x51, 0xA5, 0xF2):  # a ranging command in the middle breaks it
        clock.advance(0.1)
        bus.write_byte_data(0x70, 0, v)
    assert list(bus.devices) == [0x70]


# --- two arrays of three ---------------------------------------------------------------------------------


def test_an_io_error_on_one_sonar_leaves_the_other_five_reading(caplog):
    ranges = {f"x{0x70 + k:02x}": 0.30 + 0.1 * k for k in range(6)}
    clock, _, bus = make(busy_mode=BusyMode.NACK, **ranges)
    arrays = [
        RangerSonarArray(
            [SRF08(bus, 0x70 + 3 * a + k, clock=clock) for k in range(3)], name=f"array{a}", clock=clock
        )
        for a in range(2)
    ]
    assert all(isinstance(arr, SonarArray) for arr in arrays)

    def cycle(arr):
        """Three reads 65 ms apart: one firing slot each, so every sonar of ``arr`` is fired once."""
        for _ in range(3):
            clock.advance(0.065)
            r = arr.read()
        return r

    for arr in arrays:
        arr.open()
    bus.inject_io_error(0x74)  # middle sonar of the second array dies
    with caplog.at_level(logging.INFO, logger="hw.sonar_array"):
        left, right = cycle(arrays[0]), cycle(arrays[1])
    assert left.ranges_m == pytest.approx((0.30, 0.40, 0.50))
    assert right.ranges_m[0] == pytest.approx(0.60) and right.ranges_m[2] == pytest.approx(0.80)
    assert math.isnan(right.ranges_m[1])
    assert arrays[1].error_counts == [0, 1, 0] and arrays[0].error_counts == [0, 0, 0]
    assert "sonar 2" in caplog.text and "0x74" in caplog.text
    for _ in range(4):
        cycle(arrays[1])
    assert arrays[1].dead == (False, True, False)
    assert "sonar 2" in caplog.records[-1].getMessage() and caplog.records[-1].levelno == logging.WARNING
    # dead: the next 9 firings rest it (no bus traffic to 0x74), the 10th tries again
    bus.clear_faults(0x74)
    before = bus.devices[0x74].rangings
    for _ in range(9):
        r = cycle(arrays[1])
        assert math.isnan(r.ranges_m[1]) and r.ranges_m[0] == pytest.approx(0.60)
    assert bus.devices[0x74].rangings == before
    assert arrays[1].skipped_counts == [0, 9, 0]
    assert isinstance(arrays[1].last_errors[1], DeviceIOError)  # the bus's EIO, kept for diagnostics
    with caplog.at_level(logging.INFO, logger="hw.sonar_array"):
        assert cycle(arrays[1]).ranges_m[1] == pytest.approx(0.70)
    back = [r for r in caplog.records if r.getMessage() == "array1: sonar 2 is back"]
    assert len(back) == 1 and back[0].levelno == logging.WARNING
    assert arrays[1].dead == (False, False, False)
    assert arrays[1].error_counts == [0, 5, 0]
    for arr in arrays:
        arr.close()


def test_the_array_needs_three_rangers_and_a_servo_to_turn():
    clock, _, bus = make(x70=0.5, x71=0.5, x72=0.5)
    with pytest.raises(CommandError, match="exactly 3"):
        RangerSonarArray([SRF08(bus, 0x70, clock=clock)])
    with RangerSonarArray([SRF08(bus, 0x70 + k, clock=clock) for k in range(3)], clock=clock) as arr:
        assert arr.read().servo_angle_deg == 90.0
        with pytest.raises(CommandError, match="no servo"):
            arr.set_servo_deg(45.0)


@pytest.mark.hardware
def test_real_srf08_on_i2c_bus_1_answers_a_ranging():
    with SRF08(1, 0x70) as s:
        r = s.read()
        assert r.range_m == math.inf or 0.03 <= r.range_m < 11.0


def test_a_scripted_obstacle_approaching_is_read_as_the_script_says():
    from hw.emulators.srf08 import ScriptedRanges

    clock = ManualClock()
    script = ScriptedRanges([(0.1, {0x70: 1.0}), (0.3, {0x70: 0.5, 0x71: 0.7}), (0.5, {})])
    bus = SRF08Bus(clock, script, addresses=[0x70, 0x71])
    with SRF08(bus, 0x70, clock=clock) as a, SRF08(bus, 0x71, clock=clock) as b:
        seen = []
        for t in (0.0, 0.2, 0.35, 0.6):
            clock.sleep_until_ns(round(t * 1e9))
            seen.append((a.read().range_m, b.read().range_m))
    assert seen[1][0] == 1.0 and seen[1][1] == math.inf  # 0x71 not named before 0.3 s
    assert seen[2] == (0.5, 0.7)
    assert seen[0][0] == math.inf and all(v == math.inf for v in seen[3])


def test_a_script_with_times_out_of_order_is_refused():
    from hw.emulators.srf08 import ScriptedRanges

    with pytest.raises(HardwareError, match=r"keyframes\[1\]"):
        ScriptedRanges([(1.0, {0x70: 1.0}), (0.5, {0x70: 0.5})])


def test_echoes_at_the_three_centimetre_minimum_are_valid_and_closer_ones_are_not():
    """SPEC table 5.1 / datasheet: the SRF08 measures from 3 cm; a result of 3 cm reads 0.03 m, 2 cm is
    inside the ring-down and reads NaN (REP-117 invalid)."""
    clock, scene, bus = make(x70=0.03)
    with SRF08(bus, 0x70, clock=clock) as s:
        assert s.read().range_m == 0.03
        scene.ranges[0x70] = 0.02
        assert math.isnan(s.read().range_m)


def test_a_reading_is_stamped_with_its_ping_and_carries_the_sensors_cone():
    """REP-117 / ``sensor_msgs/Range``: the stamp is the time of the ping (the clock when the ranging
    command was written), not of the read; the field of view is the SPEC's 60 degrees (table 5.1)."""
    clock, _, bus = make(x70=0.5)
    with SRF08(bus, 0x70, clock=clock) as s:
        clock.advance(1.0)
        ping = clock.now_ns()
        r = s.read()
        assert clock.now_ns() > ping  # the read waited out the 65 ms ranging
        assert r.stamp_ns == ping
        assert r.field_of_view_rad == pytest.approx(math.radians(60.0))


class ReadOnlyRanger:
    """A :class:`hw.interfaces.Ranger` with only ``read`` (no split start/collect), at a fixed range;
    ``start_ranging`` here is a trap: a ranger without ``collect`` must be read whole."""

    def __init__(self, clock, range_m, split_start=False):
        self.clock, self.range_m, self.reads, self.name = clock, range_m, 0, f"fixed {range_m} m"
        if split_start:
            self.start_ranging = self._trap

    def _trap(self):
        raise AssertionError("start_ranging used on a ranger that has no collect")

    def open(self):
        pass

    def close(self):
        pass

    def read(self):
        from hw.interfaces import RangeReading

        self.reads += 1
        return RangeReading(self.clock.now_ns(), self.range_m, 0.03, 6.0, math.radians(60.0))


def test_rangers_without_a_split_ranging_are_read_whole_in_their_slot():
    """Any :class:`hw.interfaces.Ranger` can sit in an array: one without ``start_ranging`` and
    ``collect`` is read inside its slot (the SRF08 firing schedule, one sonar per 65 ms slot)."""
    clock = ManualClock()
    rangers = [
        ReadOnlyRanger(clock, 1.0),
        ReadOnlyRanger(clock, 2.0, split_start=True),
        ReadOnlyRanger(clock, 3.0),
    ]
    with RangerSonarArray(rangers, clock=clock) as arr:
        assert [r.reads for r in rangers] == [1, 1, 1]  # open fired each once
        assert arr.read().ranges_m == (1.0, 2.0, 3.0)


def test_an_uncollected_ranging_delays_the_next_ping_until_the_device_is_idle_in_sleep_mode():
    """Datasheet: a ranging at the default range takes 65 ms and the SRF08 ignores the bus meanwhile.
    Pinged at t0 and again 30 ms later without collecting, the second ping goes out when the first
    ranging ends, t0 + 65 ms (5 ms polls from 30 ms: 35, ..., 65), not a whole ranging after the call."""
    clock, _, bus = make(busy_mode=BusyMode.NACK, x70=0.5)
    with SRF08(bus, 0x70, clock=clock, wait="sleep", poll_interval_s=0.005) as s:
        t0 = s.start_ranging()
        clock.advance(0.030)
        assert s.start_ranging() - t0 == 65_000_000
        assert bus.devices[0x70].rangings == 2


class CountingBus(SRF08Bus):
    """An :class:`SRF08Bus` that counts register-0 reads (busy polls), can float the echo registers,
    and fails scripted register-0 reads: ``eio`` holds one flag per read, True raising EIO."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.register0_reads = 0
        self.floating = False
        self.eio: list[bool] = []

    def read_byte_data(self, i2c_addr, register, force=None):
        if register == 0:
            self.register0_reads += 1
            if self.eio and self.eio.pop(0):
                raise OSError(errno.EIO, "Input/output error")
        return super().read_byte_data(i2c_addr, register, force)

    def read_i2c_block_data(self, i2c_addr, register, length, force=None):
        if self.floating:  # SDA floating high: nothing drives the bus
            return [0xFF] * length
        return super().read_i2c_block_data(i2c_addr, register, length, force)


def test_a_collected_ranging_lets_the_next_ping_go_out_without_polling_first():
    """Datasheet: once the echo registers have been read the ranging is over, so the next ranging
    command can be written at once; only an uncollected ranging needs register 0 polled first."""
    clock = ManualClock()
    bus = CountingBus(clock, lambda a, t: 0.5, addresses=[0x70])
    with SRF08(bus, 0x70, clock=clock) as s:
        s.read()
        before = bus.register0_reads
        s.start_ranging()
        assert bus.register0_reads == before


def test_echo_registers_reading_0xffff_are_an_io_error_not_a_range():
    """Datasheet: the echo is 16 bits, high byte first; 0xFFFF (655.35 m) is SDA floating high, no
    device driving the bus. The driver raises an EIO DeviceIOError naming the sonar and 0xFFFF."""
    clock = ManualClock()
    bus = CountingBus(clock, lambda a, t: 0.5, addresses=[0x70])
    with SRF08(bus, 0x70, clock=clock) as s:
        s.start_ranging()
        bus.floating = True
        with pytest.raises(DeviceIOError) as info:
            s.read_range_cm()
        assert info.value.errno == errno.EIO
        message = str(info.value.strerror)
        assert "srf08@0x70" in message and "0xFFFF" in message


def test_io_errors_while_polling_are_retried_in_a_row_and_a_busy_answer_resets_the_count():
    """``retries=2``: two I/O errors (EIO, not a busy NACK) in a row are retried; an answer in between
    (busy 0xFF, the 65 ms ranging is not over) starts the count again, so busy, EIO, EIO, busy, EIO,
    EIO still ends in a range."""
    clock = ManualClock()
    bus = CountingBus(clock, lambda a, t: 0.5, addresses=[0x70])
    with SRF08(bus, 0x70, clock=clock, retries=2) as s:
        s.start_ranging()
        bus.eio = [False, True, True, False, True, True]
        assert s.read_range_cm() == 50
        assert not bus.eio


def test_a_third_io_error_in_a_row_while_polling_raises_naming_the_sonar():
    """``retries=2`` allows 3 attempts: the third EIO in a row is raised as DeviceIOError(EIO)."""
    clock = ManualClock()
    bus = CountingBus(clock, lambda a, t: 0.5, addresses=[0x70])
    with SRF08(bus, 0x70, clock=clock, retries=2) as s:
        s.start_ranging()
        bus.eio = [True, True, True, False]
        with pytest.raises(DeviceIOError) as info:
            s.read_range_cm()
        assert info.value.errno == errno.EIO
        assert str(info.value.strerror).startswith("srf08@0x70: I/O error while polling register 0: ")
        assert bus.eio == [False]


@pytest.mark.parametrize(
    ("max_range_m", "register"),
    [(0.043, 0), (0.044, 1), (1.0, 23), (1.075, 24), (2.021, 46), (2.022, 47), (11.008, 255)],
)
def test_the_range_register_is_the_smallest_whose_range_covers_the_request(max_range_m, register):
    """Datasheet: range = register x 43 mm + 43 mm. By hand: 0 gives 43 mm; 44 mm needs 1 (86 mm);
    1 m needs 23 (1032 mm); 1075 mm is exactly 24; 2021 mm exactly 46, 2022 mm needs 47 (2064 mm);
    11008 mm is the largest, 255."""
    assert range_register_for(max_range_m) == register


@pytest.mark.parametrize("bad", [0.042, 11.009, 12.0, math.inf, math.nan])
def test_a_range_outside_the_registers_43_mm_to_11_008_m_is_refused(bad):
    """Datasheet: the range register spans 43 mm (0) to 11.008 m (255)."""
    with pytest.raises(CommandError) as info:
        range_register_for(bad)
    assert str(info.value) == f"max_range_m={bad!r} must be within 0.043..11.008 m"
