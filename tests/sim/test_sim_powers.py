"""Powers only the simulated chair has: ground truth, contacts with scene bodies, teleport, watchdog."""

from __future__ import annotations

import math

import pytest

from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import load_spec

pytest.importorskip("pybullet")


@pytest.fixture()
def chair(tmp_path):
    from sim.backend import SimChair

    scene = tmp_path / "wall.toml"
    scene.write_text(
        '[scene]\nname = "wall"\ndescription = "a wall"\n'
        '[[object]]\nname = "wall"\nshape = "box"\nsize = [0.1, 3.0, 2.0]\nxyz = [2.0, 0.0, 1.0]\n'
    )
    c = SimChair(load_spec(), scene, sensor=None, sonars=False)
    yield c
    c.close()


def test_teleport_places_the_chair_at_rest_where_asked_and_contacts_name_the_body_touched(chair) -> None:
    spec = load_spec()
    front = spec.body.centre_x + spec.body.depth / 2
    chair.step(24)
    assert chair.contacts() == set()
    chair.teleport(Pose2D(1.95 - front + 0.02, 0.0, 0.0))  # the front edge 2 cm into the wall
    chair.step(2)
    assert chair.contacts() == {"wall"}
    chair.teleport((-1.0, 0.5, math.pi / 2))
    chair.step(24)
    gt = chair.ground_truth_pose()
    assert (gt.x, gt.y) == pytest.approx((-1.0, 0.5), abs=0.01) and gt.theta == pytest.approx(
        math.pi / 2, abs=0.01
    )
    assert chair.contacts() == set()
    assert chair.ground_truth_transform()[:2, 3] == pytest.approx([gt.x, gt.y])


def test_the_simulated_motor_watchdog_stops_the_motors_when_commands_stop(chair) -> None:
    from sim.backend import backend_from_chair

    backend = backend_from_chair(chair, watchdog_ms=100)
    backend.open()
    backend.motors.set_speeds_rpm(500.0, 500.0)
    backend.clock.sleep_until_ns(50_000_000)
    assert backend.motors.watchdog_trips == 0 and chair.robot.left.setpoint_rpm == 500.0
    backend.clock.sleep_until_ns(300_000_000)
    assert backend.motors.watchdog_trips == 1 and chair.robot.left.setpoint_rpm == 0.0
