"""The route follower's progress runs along the path: a loop whose end lies on the way in is driven whole."""

from __future__ import annotations

import math

import pytest

from robchair.platform.kinematics import DiffDrive, Pose2D, integrate_arc
from robchair.route import PurePursuit, Route
from robchair.sources import Observation

# A loop round a 2 m x 2 m room: in along y = 0 to x = 4, round, and back down x = 2 to (2, 0), a
# point the path already crossed on the way in, 2 m after the start. Length by hand: 4 + 2 + 2 + 2 = 10 m.
LOOP = Route(((0.0, 0.0), (4.0, 0.0), (4.0, 2.0), (2.0, 2.0), (2.0, 0.0)), speed=0.4, lookahead_m=0.6)
LOOP_LENGTH_M = 10.0


def _obs(pose: Pose2D) -> Observation:
    return Observation(0, pose, None, (), None)


def _drive(pp: PurePursuit, start: Pose2D, dt: float = 0.1, max_s: float = 120.0) -> tuple[float, Pose2D]:
    """Drive an ideal differential-drive chair by the follower's commands until done; (path m, pose)."""
    drive, pose, travelled = DiffDrive(), start, 0.0
    for _ in range(round(max_s / dt)):
        cmd = pp.command(_obs(pose))
        if cmd.done:
            return travelled, pose
        wl, wr = drive.wheel_speeds(cmd.v, cmd.w)
        pose = integrate_arc(pose, wl * drive.r * dt, wr * drive.r * dt, drive.b)
        travelled += abs(cmd.v) * dt
    raise AssertionError(f"not done after {max_s} s at {pose}")


def test_passing_over_the_end_of_a_loop_on_the_way_in_does_not_complete_it() -> None:
    pp = PurePursuit(LOOP, DiffDrive())
    for i in range(41):  # along the way in, 1 cm to the left of the path (a small cross-track error)
        cmd = pp.command(_obs(Pose2D(0.1 * i, 0.01, 0.0)))
        assert not cmd.done, f"done at x = {0.1 * i:.1f} m on the first pass"
        assert cmd.v > 0.1 or i > 35  # no slowing down for the goal on the way past it


def test_a_loop_whose_end_lies_on_the_way_in_is_driven_whole_before_it_is_done() -> None:
    # starting 5 cm to the left of the path, as a chair placed by hand would
    travelled, pose = _drive(PurePursuit(LOOP, DiffDrive()), Pose2D(0.0, 0.05, 0.0))
    # done at the end: within the goal tolerance of (2, 0), after about the loop's 10 m (corners cut by
    # pure pursuit and the goal tolerance make it a little less)
    assert math.hypot(pose.x - 2.0, pose.y) <= LOOP.goal_tolerance_m
    assert travelled == pytest.approx(LOOP_LENGTH_M, abs=0.8)


def test_progress_never_jumps_to_a_later_stretch_of_the_path_that_passes_nearby() -> None:
    # a hairpin: out along y = 0 and back along y = 0.3; at (1, 0.16) the way back is nearer (0.14 m)
    # than the way out (0.16 m), but only the way out is within the search window (two look-aheads)
    hairpin = Route(((0.0, 0.0), (3.0, 0.0), (3.0, 0.3), (0.0, 0.3)), lookahead_m=0.5)
    pp = PurePursuit(hairpin, DiffDrive())
    pp.command(_obs(Pose2D(1.0, 0.16, 0.0)))
    assert pp.cross_track_error(Pose2D(1.0, 0.16, 0.0)) == pytest.approx(0.16)
