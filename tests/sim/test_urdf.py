"""The generated URDF follows the spec, and the chair stands and drives on its driven wheels."""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET

import pytest

from robchair.platform.spec import load_spec
from sim.urdf import build_urdf, write_urdf

pytest.importorskip("pybullet")


@pytest.fixture(scope="module")
def spec():
    return load_spec()


def _joint(root, name):
    for j in root.iter("joint"):
        if j.get("name") == name:
            return j
    raise AssertionError(f"no joint {name}")


def test_urdf_geometry_comes_from_the_spec_not_from_hand_copied_numbers(spec):
    # a spec with other numbers must give a URDF with those numbers
    drive = dataclasses.replace(spec.drive, wheel_radius=0.2, wheel_separation=0.7)
    other = dataclasses.replace(spec, drive=drive)
    root = ET.fromstring(build_urdf(other))
    left = _joint(root, "left_wheel_joint")
    xyz = [float(v) for v in left.find("origin").get("xyz").split()]
    assert xyz == pytest.approx([drive.wheel_x, 0.35, 0.2])
    assert _joint(root, "right_wheel_joint").find("origin").get("xyz").split()[1] == "-0.35"
    assert left.get("type") == "continuous"


def test_sonar_arrays_hang_on_revolute_servo_joints_at_their_mounts(spec):
    root = ET.fromstring(build_urdf(spec))
    for mount in ("sonar_array_left", "sonar_array_right"):
        m = spec.mounts[mount]
        j = _joint(root, m.joint.name)
        assert j.get("type") == "revolute"
        assert j.find("child").get("link") == mount
        assert [float(v) for v in j.find("origin").get("xyz").split()] == pytest.approx(list(m.xyz))
        lim = j.find("limit")
        assert float(lim.get("lower")) == pytest.approx(m.joint.lower)
        assert float(lim.get("upper")) == pytest.approx(m.joint.upper)
    k = _joint(root, "kinect_link_joint")
    assert [float(v) for v in k.find("origin").get("rpy").split()] == pytest.approx(
        list(spec.mounts["kinect_link"].rpy)
    )


def test_write_urdf_reuses_the_file_while_the_spec_is_unchanged(spec, tmp_path):
    a = write_urdf(spec, tmp_path)
    b = write_urdf(spec, tmp_path)
    assert a == b and a.read_text() == build_urdf(spec)


@pytest.fixture(scope="module")
def settled():
    from sim.robot import SimRobot
    from sim.world import World

    spec = load_spec()
    world = World()
    robot = SimRobot(world, spec, closed_loop=True)
    world.step(240)
    yield world, robot, spec
    world.close()


def test_casters_do_not_steal_the_load_driven_wheels_carry_most_of_the_weight(settled):
    world, robot, spec = settled
    total: dict[str, float] = {}
    n = 120
    for _ in range(n):
        world.step(1)
        for k, v in robot.contact_normal_forces(world.plane).items():
            total[k] = total.get(k, 0.0) + v / n
    weight = spec.total_mass * 9.81
    assert sum(total.values()) == pytest.approx(weight, rel=0.02)
    wheels = total.get("left_wheel", 0.0) + total.get("right_wheel", 0.0)
    # lever rule on the spec's centre of mass: the casters carry x_com / x_caster_contact of the body
    assert wheels / weight > 0.7
    assert "base_link" not in total  # the chassis never scrapes the floor


def test_chair_drives_straight_on_equal_wheel_speeds(settled):
    # the two real motors differ (t_p 0.40 s vs 0.36 s), which alone turns the chair while it
    # accelerates; give both wheels motor 1's dynamics so only the casters could pull it off its line
    from robchair.platform.control import DiscretePlant

    world, robot, _ = settled
    robot.right.plant = DiscretePlant(robot.left.plant.plant, robot.motor_dt)
    robot.right.pid.kp, robot.right.pid.ki, robot.right.pid.kd = (
        robot.left.pid.kp,
        robot.left.pid.ki,
        robot.left.pid.kd,
    )
    start = robot.pose2d()
    rpm = robot.drive.motor_rpm(0.5, 0.0)[0]
    robot.set_motor_rpm(rpm, rpm)
    world.step(240 * 6)
    robot.set_motor_rpm(0.0, 0.0)
    world.step(240)
    end = robot.pose2d()
    dx, dy = end.x - start.x, end.y - start.y
    assert dx > 2.5  # it moved about 3 m forward (acceleration phase aside)
    assert abs(dy) < 0.01 * dx  # and stayed on its line
    assert abs(end.theta - start.theta) < math.radians(0.5)


def test_wheels_do_not_slip_so_odometry_matches_the_driven_arc(settled):
    from robchair.platform.kinematics import Odometry

    world, robot, spec = settled
    odo = Odometry(spec)
    odo.update(*robot.encoder_counts())
    start = robot.pose2d()
    robot.set_motor_rpm(*robot.drive.motor_rpm(0.4, 0.4))
    for _ in range(5 * 60):
        world.step(4)
        odo.update(*robot.encoder_counts())
    end = robot.pose2d()
    turned = math.remainder(end.theta - start.theta, 2 * math.pi)
    assert abs(turned) > 1.0  # it really turned (about 2 rad)
    assert odo.pose.theta == pytest.approx(turned, abs=0.03)  # casters would make the chair under-turn


def _touches(client, robot_body, wall, xyz):
    import pybullet as p

    p.resetBasePositionAndOrientation(wall, xyz, (0, 0, 0, 1), physicsClientId=client)
    p.performCollisionDetection(physicsClientId=client)
    # Bullet also reports points within its contact threshold: only penetration (distance <= 0) counts
    pts = p.getContactPoints(bodyA=robot_body, bodyB=wall, physicsClientId=client)
    return any(c[8] <= 0.0 for c in pts)


def _first_contact(client, robot_body, wall, axis, sign, far=1.5):
    """Bisect the wall's face position along ``axis`` (0 = x, 1 = y) from outside toward the chair."""
    half = 0.05  # the wall is 0.1 m thick
    out, inside = far, 0.0  # distances of the wall's near face from base_link along sign * axis
    for _ in range(30):
        mid = (out + inside) / 2
        xyz = [0.16, 0.0, 0.5]  # the footprint's centre, half-way up
        xyz[axis] = sign * (mid + half)
        if _touches(client, robot_body, wall, tuple(xyz)):
            inside = mid
        else:
            out = mid
    return (out + inside) / 2


def test_collision_footprint_measured_against_a_movable_wall_is_the_spec_s_0_64_by_0_84_m():
    import pybullet as p

    from sim.robot import SimRobot
    from sim.world import World

    spec = load_spec()
    with World() as world:
        robot = SimRobot(world, spec)
        world.step(60)
        c = world.client
        # a wall taller than the chair, 4 m long, 0.1 m thick, static like every scene body
        walls = {}
        for axis in (0, 1):
            ext = [2.0, 2.0, 1.0]
            ext[axis] = 0.05
            col = p.createCollisionShape(p.GEOM_BOX, halfExtents=ext, physicsClientId=c)
            walls[axis] = p.createMultiBody(0.0, col, basePosition=(10, 10, 10), physicsClientId=c)
        p.setCollisionFilterPair(walls[0], world.plane, -1, -1, 0, physicsClientId=c)
        left = _first_contact(c, robot.body, walls[1], 1, +1)
        right = _first_contact(c, robot.body, walls[1], 1, -1)
        p.resetBasePositionAndOrientation(walls[1], (10, 10, 10), (0, 0, 0, 1), physicsClientId=c)
        front = _first_contact(c, robot.body, walls[0], 0, +1)
        back = _first_contact(c, robot.body, walls[0], 0, -1)
    assert left + right == pytest.approx(spec.body.width, abs=0.02)
    assert left == pytest.approx(right, abs=0.005)
    assert front + back == pytest.approx(spec.body.depth, abs=0.02)
    assert front == pytest.approx(spec.body.centre_x + spec.body.depth / 2, abs=0.015)
