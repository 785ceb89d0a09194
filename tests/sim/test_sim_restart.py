"""``SimChair.restart``: an exact reset of the simulated chair, whatever it did before."""

from __future__ import annotations

import math

import pytest

from robchair.platform.spec import load_spec

pytest.importorskip("pybullet")

START = (0.3, -0.2, 0.4)


def _chair():
    from robchair.platform.paths import SCENES
    from sim.backend import SimChair

    return SimChair(load_spec(), SCENES / "office.toml", sensor=None, sonars=True, tyre_radius_error=0.0)


def _drive(chair, n=240):
    """A ramped, turning drive; the true planar poses of every step."""
    out = []
    for k in range(n):
        v = 300.0 * math.sin(2 * math.pi * k / n)
        chair.robot.set_motor_rpm(v + 80.0 * math.sin(0.05 * k), v - 80.0 * math.sin(0.05 * k))
        chair.step(1)
        p = chair.ground_truth_pose()
        out.append((p.x, p.y, p.theta))
    return out


def test_a_restarted_chair_drives_exactly_as_a_fresh_one_after_any_history():
    fresh, used = _chair(), _chair()
    try:
        fresh.restart(START)
        expected = _drive(fresh)
        # another history: drive forward and back to the start (wheels turned back to about where they
        # were), turn the sonar servos, carry a payload on a slippery floor
        used.restart(START)
        _drive(used)
        used.robot.set_servo_deg("sonar_array_left", 20.0)
        used.robot.set_payload_kg(90.0)
        used.set_floor_friction(0.5)
        used.robot.scale_motor_plants((1.04, 0.97), (1.02, 0.96))
        _drive(used, 100)
        used.set_floor_friction(1.0)  # the floor is the world's: set back as the fresh chair has it
        body = used.robot.body
        used.restart(START)
        assert used.world.steps == 0 and used.robot.body == body
        assert used.robot.servo_deg("sonar_array_left") == 0.0
        assert _drive(used) == expected
    finally:
        fresh.close()
        used.close()


def test_a_footprint_inside_a_wall_is_named_and_people_are_left_out():
    chair = _chair()
    try:
        chair.restart((2.25, 1.25, 0.0))  # inside the corridor's left wall
        assert "corridor_wall_left" in chair.footprint_overlaps()
        chair.restart(START)
        assert chair.footprint_overlaps() == []
    finally:
        chair.close()


def test_payload_friction_and_plant_scales_outside_their_ranges_are_refused():
    from sim.errors import SimError

    chair = _chair()
    try:
        with pytest.raises(SimError, match="payload_kg"):
            chair.robot.set_payload_kg(-1.0)
        with pytest.raises(SimError, match="friction"):
            chair.set_floor_friction(float("nan"))
        with pytest.raises(SimError, match="omega_n"):
            chair.robot.scale_motor_plants((0.0, 1.0), (1.0, 1.0))
    finally:
        chair.close()
