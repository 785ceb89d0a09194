"""SRF08 firing schedule: 65 ms echo windows within an array, both arrays in step, no stale echoes."""

from __future__ import annotations

import itertools
import math

import pytest

from hw.clock import ManualClock
from hw.emulators.srf08 import SRF08Bus
from hw.errors import CommandError
from hw.sonar_array import ECHO_WINDOW_S, RangerSonarArray, SonarFiringGroup
from hw.srf08 import SRF08

ADDRESSES = (0x70, 0x71, 0x72, 0x73, 0x74, 0x75)


class Scene:
    """An object 3 m in front of the left array's first sonar only; every ping is recorded."""

    def __init__(self, ranges=None):
        self.ranges = ranges if ranges is not None else {0x70: 3.0}
        self.pings: list[tuple[int, int]] = []

    def __call__(self, address, stamp_ns):
        self.pings.append((address, stamp_ns))
        return self.ranges.get(address, math.nan)


def _arrays(scene, grouped=True, max_range_m=2.0, acoustic_groups=None):
    clock = ManualClock()
    bus = SRF08Bus(clock, scene, addresses=ADDRESSES, groups=acoustic_groups)
    arrays = [
        RangerSonarArray(
            [SRF08(bus, a, clock=clock, max_range_m=max_range_m) for a in ADDRESSES[3 * k : 3 * k + 3]],
            name=name,
            clock=clock,
        )
        for k, name in enumerate(("left", "right"))
    ]
    group = SonarFiringGroup(arrays, clock=clock) if grouped else None
    for arr in arrays:
        arr.open()
    return clock, bus, arrays, group


APART = [ADDRESSES[:3], ADDRESSES[3:]]  # arrays that do not hear each other


@pytest.mark.parametrize(("grouped", "acoustic_groups"), [(True, None), (False, APART)])
def test_a_far_echo_of_the_previous_ping_is_not_read_as_a_near_obstacle(grouped, acoustic_groups):
    # 2 m range setting: results are ready 11.9 ms after the ping; fired as soon as the previous result
    # was read, the middle sonar heard the left one's 3 m echo as an obstacle at about 0.4 m
    scene = Scene()
    clock, bus, arrays, _ = _arrays(scene, grouped=grouped, acoustic_groups=acoustic_groups)
    for _ in range(6):
        clock.advance(0.1)
        left, right = arrays[0].read(), arrays[1].read()
        assert left.ranges_m == (math.inf,) * 3  # 3 m is beyond the 2.021 m setting: no return
        assert right.ranges_m == (math.inf,) * 3
    assert bus.stale_echoes == 0


def test_arrays_that_hear_each_other_but_fire_on_their_own_read_stale_echoes():
    # why the two arrays share one firing group: fired 15 ms after the left array's ping, the right
    # array's sonar hears its 3 m echo as an obstacle at 3 - 343 x 0.015 / 2 = 0.43 m
    scene = Scene()
    clock, bus, arrays, _ = _arrays(scene, grouped=False)
    seen = []
    for _ in range(6):
        clock.advance(0.1)
        arrays[0].read()
        seen.append(arrays[1].read().ranges_m[0])
    assert bus.stale_echoes > 0 and min(seen) == pytest.approx(0.43)


def test_pings_of_one_array_are_65_ms_apart_and_both_arrays_fire_in_step():
    scene = Scene()
    clock, _, arrays, group = _arrays(scene)  # opening fired each sonar once (one array after the other)
    assert group.cycle_time_s == pytest.approx(0.195)
    t0, n0 = clock.now_ns(), len(scene.pings)
    for _ in range(9):  # a 10 Hz loop: one slot per cycle
        clock.advance(0.1)
        arrays[0].read()
        arrays[1].read()
    window = round(ECHO_WINDOW_S * 1e9)
    by_array = [[t for a, t in scene.pings if a in ADDRESSES[3 * k : 3 * k + 3]] for k in range(2)]
    for stamps in by_array:
        assert min(b - a for a, b in itertools.pairwise(stamps)) >= window
    loop = [[t for t in stamps if t > t0] for stamps in by_array]
    assert len(loop[0]) == 9 and loop[0] == loop[1]  # slot k fires sonar k of both arrays at once
    assert len(scene.pings) - n0 == 18
    for address in ADDRESSES:
        own = [t for a, t in scene.pings if a == address]
        assert min(b - a for a, b in itertools.pairwise(own)) >= 3 * window


def test_a_read_fires_at_most_the_one_slot_that_is_due_and_stamps_the_oldest_ping():
    scene = Scene({0x70: 0.5, 0x75: 0.8})
    # arrays that do not hear each other (in one acoustic space, 0x73, fired with 0x70, would also
    # hear 0x70's echo of the object in front of the left array)
    clock, _, arrays, group = _arrays(scene, acoustic_groups=[ADDRESSES[:3], ADDRESSES[3:]])
    n0, last_slot = len(scene.pings), scene.pings[-1][1]
    left, right = arrays[0].read(), arrays[1].read()  # opening fired every sonar; nothing due yet
    assert len(scene.pings) == n0
    assert left.ranges_m == (0.5, math.inf, math.inf) and right.ranges_m == (math.inf, math.inf, 0.8)
    # the stamp is the oldest ping of the array's three
    assert right.stamp_ns == min(t for a, t in scene.pings if a in ADDRESSES[3:])
    clock.sleep_until_ns(last_slot + round(ECHO_WINDOW_S * 1e9))
    arrays[1].read()  # due: one slot, both arrays
    new = scene.pings[n0:]
    k = ADDRESSES.index(new[0][0]) % 3
    assert len(new) == 2 and new[0][1] == new[1][1]  # one slot: sonar k of both arrays at once
    assert {a for a, _ in new} == {ADDRESSES[k], ADDRESSES[3 + k]}
    assert arrays[0].read().ranges_m[0] == 0.5 and len(scene.pings) == n0 + 2
    assert group.slots >= 7


def test_an_echo_window_shorter_than_the_datasheet_allows_is_refused():
    scene = Scene()
    _, _, arrays, _ = _arrays(scene, grouped=False)
    with pytest.raises(CommandError, match="every 65 ms"):
        SonarFiringGroup(arrays, echo_window_s=0.012)
    with pytest.raises(CommandError, match="distinct arrays"):
        SonarFiringGroup([arrays[0], arrays[0]])


def test_the_emulated_backend_fires_its_two_arrays_in_one_group():
    from robchair.backends import get_backend

    backend = get_backend("emulated", {})
    try:
        left, right = backend.sonar_arrays
        assert isinstance(left, RangerSonarArray) and isinstance(right, RangerSonarArray)
        group = left.group
        assert group is not None and right.group is group
        assert group.cycle_time_s == pytest.approx(0.195)
    finally:
        backend.close()


def test_slots_fire_sonars_one_two_three_in_turn_and_are_counted_one_by_one():
    """Firing schedule (module docstring): slot k fires sonar k of every array, k = 0, 1, 2, 0, ...
    Opening the left array fires its three sonars (3 slots), opening the right array three more
    (6 slots, 2 cycles); then every 100 ms read fires one slot: 6 reads make 12 slots, 4 cycles."""
    scene = Scene()
    clock, _, arrays, group = _arrays(scene)
    assert (group.slots, group.cycles) == (6, 2)
    n0 = len(scene.pings)
    for _ in range(6):
        clock.advance(0.1)
        arrays[0].read()
    left = [ADDRESSES.index(a) for a, _ in scene.pings[n0:] if a in ADDRESSES[:3]]
    assert left == [0, 1, 2, 0, 1, 2]
    assert (group.slots, group.cycles) == (12, 4)


def test_arrays_opened_before_their_group_is_formed_are_primed_by_the_first_read():
    """An array joined to a group after it was opened has no ping in the group yet: the first read
    fires the group's three slots (65 ms apart, datasheet firing interval) and returns a full set."""
    scene = Scene({0x70: 0.5, 0x72: 1.0})
    clock, _, arrays, _ = _arrays(scene, grouped=False, acoustic_groups=APART)
    group = SonarFiringGroup(arrays, clock=clock)
    assert arrays[0].group is group
    reading = arrays[0].read()
    assert reading.ranges_m == (0.5, math.inf, 1.0)
    assert group.slots == 3


class OffsetClock:
    """The same time as ``base``, read 10 s later (a second time source for the firing slots)."""

    OFFSET_NS = 10_000_000_000

    def __init__(self, base):
        self.base = base

    def now_ns(self):
        return self.base.now_ns() + self.OFFSET_NS

    def sleep_until_ns(self, t_ns):
        self.base.sleep_until_ns(t_ns - self.OFFSET_NS)


def test_slots_are_timed_and_stamped_by_the_groups_clock_or_by_default_the_first_arrays():
    """``SonarFiringGroup(clock=...)`` times the slots (and so the readings' stamps); without one it
    uses the first array's clock. A group clock 10 s ahead stamps the readings 10 s later."""
    scene = Scene({0x70: 0.5})
    clock, _, arrays, _ = _arrays(scene, grouped=False, acoustic_groups=APART)
    group = SonarFiringGroup(arrays, clock=OffsetClock(clock))
    assert arrays[0].group is arrays[1].group is group
    reading = arrays[0].read()  # primes the new group: three slots of both arrays, six pings
    assert reading.stamp_ns == scene.pings[-6][1] + OffsetClock.OFFSET_NS
    solo = SonarFiringGroup([arrays[1]])  # default: the array's own clock
    stamp = arrays[1].read().stamp_ns
    assert solo.slots == 3 and stamp == scene.pings[-3][1]
