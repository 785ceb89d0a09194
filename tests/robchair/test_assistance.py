"""The assistance stage: doorway passage, the person's override, zero command, bad modes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robchair.assistance import MODES, AssistConfig, AssistedSource
from robchair.platform.errors import ConfigError
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import load_spec
from robchair.sources import Command, Observation
from sim.planar import doorway
from tests.robchair.assist_drive import Scripted, drive

DOOR_M = 0.85
# base_link 2.5 m before the wall, on the door's centre line, heading 8 degrees off it: driven straight,
# the chair's side (0.32 m from its centre line, Table 9.1 width 0.64 m) is 2.5 * tan(8 deg) + 0.32 > 0.425 m
# off the centre line when its front (0.58 m ahead of base_link) reaches the wall: it meets the post
START = (-2.5, 0.0, math.radians(8.0))
FORWARD = Command(0.4, 0.0, deadman=True)


def test_off_stops_at_the_post_of_a_085_m_door_approached_8_degrees_off() -> None:
    """Hand computation above: the straight line meets the post, so the safety layer stops before it."""
    d = drive(doorway(DOOR_M), "off", Scripted(lambda k: FORWARD), START, 300)
    x = d.poses[-1][0]
    assert "obstacle_map" in d.stops
    assert not d.contact
    assert x < 0.0  # base_link never reached the wall's plane: the chair did not pass
    assert d.applied[-1] == (0.0, 0.0)


def test_door_passes_a_085_m_door_approached_8_degrees_off_without_contact() -> None:
    """The same approach with ``door``: base_link ends beyond the wall (0.1 m thick) with no contact."""
    d = drive(doorway(DOOR_M), "door", Scripted(lambda k: FORWARD), START, 300)
    x = d.poses[-1][0]
    assert not d.contact
    assert x > 0.1 + 0.84  # the whole footprint (0.84 m deep) is through
    assert any(r["action"] == "door" for r in d.reports)
    assert d.reports[-1]["action"] != "door"  # handed back after the doorway


def test_the_persons_opposite_command_wins_within_the_stated_bound() -> None:
    """While ``door`` turns the chair right (its heading is 8 degrees left of the doorway's centre line),
    the person turns hard left on the spot: from the first such cycle, the person's command is applied
    within ceil(0.3 s x 20 Hz) = 6 cycles (the bound of :class:`AssistConfig`, override_s = 0.3 s), and
    stays. The doorway's steer-away release is switched off (door_release_rad = pi) so that only the
    override rule can hand the person control."""
    k_opp = 3
    opposite = Command(0.0, 2.0, deadman=True)  # a hard left against the assistance's right turn

    def person(k: int) -> Command:
        return FORWARD if k < k_opp else opposite

    d = drive(doorway(DOOR_M), "door", Scripted(person), START, 40, AssistConfig(door_release_rad=math.pi))
    assert d.reports[k_opp - 1]["action"] == "door"
    assert d.reports[k_opp - 1]["applied"][1] < 0.0  # the assistance turns right
    won = [k for k in range(k_opp, 40) if d.reports[k]["applied"] == (opposite.v, opposite.w)]
    assert won and won[0] - k_opp + 1 <= 6
    assert all(d.reports[k]["applied"] == (opposite.v, opposite.w) for k in range(won[0], 40))


def test_a_tremor_blip_backward_keeps_the_doorway_and_a_held_pull_back_wins_within_the_bound() -> None:
    """A pull back beyond reverse_release (0.5) of the speed cap (0.62 m/s) for 2 cycles (0.1 s, a
    tremor's half period at 5 Hz) counts as no forward speed: the passage goes on. Held, it is applied
    unchanged within ceil(0.3 s x 20 Hz) = 6 cycles (override_s = 0.3 s, :class:`AssistConfig`)."""
    pull = Command(-0.4, 0.0, deadman=True)
    blip = {5, 6}

    def person(k: int) -> Command:
        return pull if k in blip or k >= 20 else FORWARD

    d = drive(doorway(DOOR_M), "door", Scripted(person), START, 40)
    assert all(d.reports[k]["action"] == "door" for k in range(3, 20))  # the blip did not end the passage
    assert all(d.reports[k]["applied"][0] >= 0.0 for k in blip)
    won = [k for k in range(20, 40) if d.reports[k]["applied"] == (pull.v, pull.w)]
    assert won and won[0] - 20 + 1 <= 6
    assert all(d.reports[k]["applied"] == (pull.v, pull.w) for k in range(won[0], 40))


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("deadman", [True, False])
def test_a_zero_command_gives_zero_motion_in_every_mode(mode: str, deadman: bool) -> None:
    """Zero joystick or a released dead-man: the chair stays where it is (v = w = 0 every cycle)."""
    held = Command(0.0, 0.0, deadman=deadman)
    d = drive(doorway(DOOR_M), mode, Scripted(lambda k: held), START, 20)
    assert all(a == (0.0, 0.0) for a in d.applied)
    assert d.poses[-1] == START


@pytest.mark.parametrize("mode", MODES)
def test_a_released_deadman_stops_a_pushed_joystick_in_every_mode(mode: str) -> None:
    """Pushed forward with the dead-man released: zero from the stage (the safety layer's rule)."""
    d = drive(doorway(DOOR_M), mode, Scripted(lambda k: Command(0.4, 0.3, deadman=False)), START, 10)
    assert all(r["applied"] == (0.0, 0.0) for r in d.reports)


def test_shield_slows_smoothly_before_a_wall_and_stops_short_of_it() -> None:
    """Straight at a wall: the speed falls over the slow-down zone, without contact, and never jumps."""
    d = drive(doorway(0.0), "shield", Scripted(lambda k: FORWARD), (-2.5, 1.0, 0.0), 200)
    v = np.array([a[0] for a in d.applied])
    assert not d.contact
    front = d.poses[-1][0] + 0.58  # the footprint's front edge (centre_x 0.16 + depth 0.84 / 2)
    assert 0.2 <= -front <= 0.3  # settled just beyond shield_stop_m = 0.2 m from the wall at x = 0
    assert v[-1] < 0.01
    assert np.max(np.abs(np.diff(v))) <= 0.5 / 20 + 1e-9  # the safety layer's 0.5 m/s^2 at 20 Hz
    assert "obstacle_map" not in d.stops  # the shield slowed before the safety layer had to stop


def test_an_unknown_mode_is_refused_naming_the_allowed_ones() -> None:
    with pytest.raises(ConfigError, match="off, shield, assist, door"):
        AssistedSource(Scripted(lambda k: FORWARD), load_spec(), 0.6, 2.0, "autopilot")


def test_an_out_of_range_parameter_is_refused() -> None:
    with pytest.raises(ConfigError, match="override_s"):
        AssistConfig(override_s=-1.0)


def test_assist_leaves_a_command_with_open_space_unchanged() -> None:
    """Nothing near: the window search returns the person's twist exactly."""
    spec = load_spec()
    stage = AssistedSource(Scripted(lambda k: Command(0.3, 0.2, deadman=True)), spec, 0.62, 2.14, "assist",
                           obstacles=lambda obs: np.zeros((0, 2)))  # fmt: skip
    c = stage.command(Observation(0, Pose2D(0, 0, 0), None, (), None))
    assert (c.v, c.w) == (0.3, 0.2)
    assert stage.last["action"] == "pass"


# base_link 0.78 m before the wall (the front edge, 0.58 m ahead of it, 0.2 m before the wall), 0.2 m left
# of the centre line, 5 degrees askew: the chair's left side (0.2 + 0.32 = 0.52 m) is beyond the jamb
# (0.425 m), and 0.2 m is inside the stopping distance of any forward push of 0.4 m/s
# (0.15 + 0.4 x 0.3 + 0.4^2 / 1.6 = 0.37 m, SafetyLimits defaults): going forward cannot pass
TOO_CLOSE = (-0.78, 0.2, math.radians(5.0))


def test_off_cannot_move_when_too_close_to_a_085_m_door_and_off_its_line() -> None:
    """The hand computation above: the safety layer holds every forward push at the post."""
    d = drive(doorway(DOOR_M), "off", Scripted(lambda k: FORWARD), TOO_CLOSE, 200)
    assert not d.contact
    assert max(p[0] for p in d.poses) < -0.7  # never got nearer the wall


@pytest.mark.parametrize("mode", ["door", "assist"])
def test_door_and_assist_back_off_realign_and_pass_when_too_close_and_off_its_line(mode: str) -> None:
    """The start above with ``door`` or ``assist`` (the doorway passage guides both): a short reverse
    (at most PassageParams.reverse_m = 1.0 m, at most reverse_speed = 0.15 m/s), then through the
    doorway with no contact, ending on its centre line."""
    d = drive(doorway(DOOR_M), mode, Scripted(lambda k: FORWARD), TOO_CLOSE, 500)
    assert not d.contact
    phases = [r.get("door_phase") for r in d.reports]
    assert "back-off" in phases and phases.index("back-off") < phases.index("pass")
    backs = [a[0] for a, ph in zip(d.applied, phases, strict=True) if ph == "back-off"]
    assert min(backs) >= -0.15 - 1e-9
    assert -sum(backs) / 20.0 <= 1.0 + 1e-9  # reverse travel of the commands at 20 Hz, m
    x, y, _ = d.poses[-1]
    assert x > 0.1 + 0.84  # the whole footprint (0.84 m deep) is through the 0.1 m wall
    assert abs(y) < 0.425 - 0.32  # on the line: the chair's sides within the door's clear width


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_side_doorway_seen_at_an_angle_from_the_corridor_is_found_on_either_side(side: float) -> None:
    """A corridor wall 0.8 m to one side (y = side x 0.8), a 0.88 m gap in it from x = 0.32 to 1.20,
    the room's far wall 2.2 m beyond (seen through the gap): seen from the origin facing +x, the near
    jamb is 0.86 m away and the far one 1.44 m; hand values: the doorway's centre (0.76, side x 0.8),
    width 0.88 m, normal (0, side) (away from the chair)."""
    from robchair.assistance.doorway import DoorwayParams, find_doorways

    xs = np.arange(-0.5, 3.0, 0.02)
    wall = xs[(xs <= 0.32 + 1e-9) | (xs >= 1.20 - 1e-9)]
    far = np.arange(-0.5, 3.0, 0.02)
    far = far[(far * 0.8 / 3.0 > 0.32) & (far * 0.8 / 3.0 < 1.20)]  # seen through the gap only
    pts = np.vstack([np.stack([wall, np.full(len(wall), side * 0.8)], axis=1),
                     np.stack([far, np.full(len(far), side * 3.0)], axis=1)])  # fmt: skip
    pts = pts[np.abs(np.arctan2(pts[:, 1], pts[:, 0])) <= math.radians(120.0)]  # the laser's field of view
    found = find_doorways(pts, DoorwayParams())
    assert len(found) >= 1
    d = found[0]
    assert (d.cx, d.cy, d.width) == pytest.approx((0.76, side * 0.8, 0.88), abs=0.021)
    assert (d.nx, d.ny) == pytest.approx((0.0, side), abs=1e-6)


def test_first_point_per_cell_gives_the_indices_of_numpys_row_unique() -> None:
    """The packed-key thinning returns exactly ``np.unique(floor(p / cell), axis=0, return_index=True)``
    (the row-wise reference), with negative cells, repeated cells and points on cell edges; an empty
    input gives no index."""
    from robchair.assistance.window import first_per_cell

    rng = np.random.default_rng(3)
    for n in (1, 7, 400, 3000):
        p = rng.normal(0.0, 2.0, (n, 2))
        p[::5] = np.round(p[::5], 1)  # on 4 cm edges and repeated
        ref = np.unique(np.floor(p / 0.04).astype(np.int64), axis=0, return_index=True)[1]
        assert np.array_equal(first_per_cell(p, 0.04), ref)
    assert first_per_cell(np.zeros((0, 2)), 0.04).size == 0


def test_door_passes_random_floor_8_with_the_tremor_user() -> None:
    """Rebuilt from assist-eval episode 8 (random floors, tremor user, 0.821 m doorway), which stalled
    in ``door`` at the jamb: the passage's forward gap was measured on points thinned to one per 4 cm
    cell, which dropped the jamb point on the safety corridor's edge (0.370 m off the centre line) that
    the safety layer stopped for; and a tremor swing of the stick dropped the doorway mid-approach. The
    gap is now the safety layer's own corridor on every point, and a steer-away must be held for
    override_s."""
    from robchair.commands.assist_eval import episode_set

    ep = episode_set(8, (0.8, 0.9), "random", ["door"], "tremor")["door"]
    assert ep["success"] and ep["collisions"] == 0
