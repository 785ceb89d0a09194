"""Simulated Hokuyo URG-04LX: analytic ranges to a wall, beam layout, REP-117 values, noise, seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hw.errors import DeviceClosedError
from hw.interfaces import LaserScanner
from robchair.platform.errors import ConfigError
from robchair.platform.spec import load_spec, spec_from_dict
from sim.laser import URG_04LX, LaserSim, LaserSimError, mounted_pose

p = pytest.importorskip("pybullet")

WALL_X = 1.7


@pytest.fixture
def client():
    c = p.connect(p.DIRECT)
    yield c
    p.disconnect(physicsClientId=c)


def box(c, half, pos, yaw=0.0):
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=c)
    return p.createMultiBody(
        0, col, -1, basePosition=pos, baseOrientation=p.getQuaternionFromEuler([0, 0, yaw]), physicsClientId=c
    )


def wall_world(c, x=WALL_X):
    box(c, [20, 20, 0.01], [0, 0, -0.01])  # the floor, below the scan plane
    return box(c, [0.05, 10, 1], [x + 0.05, 0, 1.0])


def at(z=0.3):
    t = np.eye(4)
    t[2, 3] = z
    return t


def test_beam_layout_is_the_datasheet_one():
    """SCIP 2.0 ``PP`` of the URG-04LX: ARES 1024, AMIN 44, AMAX 725, AFRT 384 (Hokuyo's URG
    protocol documentation): steps 44..725 are 725 - 44 + 1 = 682 beams, -340..+341 steps about
    the front, i.e. -119.53..+119.88 deg (hand computation, 360/1024 deg a step)."""
    m = URG_04LX
    assert m.n_beams == 682
    assert math.degrees(m.angle_increment) == pytest.approx(0.3515625)
    assert math.degrees(m.angle_min) == pytest.approx(-340 * 0.3515625)
    assert math.degrees(m.angle_max) == pytest.approx(341 * 0.3515625)
    assert m.angles()[340] == 0.0  # step 384 (AFRT) looks straight ahead
    assert (m.range_min, m.range_max, m.scan_time) == (0.02, 4.0, 0.1)
    assert m.time_increment == pytest.approx(0.1 / 1024)


@pytest.mark.parametrize("caster", ["raster", "embree", "pybullet"])
def test_a_wall_gives_the_analytic_range_on_every_beam(client, caster):
    wall_world(client)
    laser = LaserSim(client, caster=caster, noise=False)
    scan = laser.scan(at())
    a = scan.angles()
    assert scan.n_beams == 682 and scan.ranges.dtype == np.float32
    expected = np.where(np.cos(a) > 0, WALL_X / np.cos(a), np.inf)
    expected[expected > 4.0] = np.inf  # beyond range_max: no return
    hit = np.isfinite(expected)
    assert hit.sum() > 200
    np.testing.assert_allclose(scan.ranges[hit], expected[hit], atol=0.0006)  # mm rounding
    assert np.isposinf(scan.ranges[~hit]).all()


def test_nothing_in_range_is_plus_infinity_and_too_close_is_minus_infinity(client):
    box(client, [0.05, 0.05, 1], [0.06, 0, 1.0])  # a post 1 cm in front of the laser
    laser = LaserSim(client, noise=False)
    scan = laser.scan(at())
    assert scan.ranges[340] == -np.inf
    assert np.isposinf(scan.ranges[:100]).all()  # behind-right: empty world


def test_laser_turns_with_its_pose(client):
    wall_world(client)
    laser = LaserSim(client, noise=False)
    t = at()
    yaw = math.radians(30.0)
    t[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    scan = laser.scan(t)
    assert scan.ranges[340] == pytest.approx(WALL_X / math.cos(yaw), abs=0.0006)
    k = 340 - round(yaw / URG_04LX.angle_increment)  # the beam turned back onto the wall's normal
    assert scan.ranges[k] == pytest.approx(
        WALL_X / math.cos(yaw - (340 - k) * URG_04LX.angle_increment), abs=6e-4
    )


@pytest.mark.parametrize("wall_x", [0.6, 2.5])
def test_noise_stays_within_the_datasheet_accuracy(client, wall_x):
    wall_world(client, wall_x)
    laser = LaserSim(client, rng=np.random.default_rng(7))
    exact = LaserSim(client, noise=False, mirror=laser.mirror).scan(at()).ranges.astype(float)
    beams = np.abs(URG_04LX.angles()) < math.radians(20)
    errs = np.concatenate([laser.scan(at()).ranges[beams] - exact[beams] for _ in range(40)])
    bound = 0.010 if wall_x <= 1.0 else 0.01 * wall_x
    assert np.mean(np.abs(errs) <= bound + 0.0005) > 0.99  # the +- bound as a 3-sigma envelope
    assert np.std(errs) == pytest.approx(bound / 3, rel=0.15)
    assert abs(np.mean(errs)) < bound / 10


def test_same_seed_same_scans_other_seed_other_scans(client):
    wall_world(client)
    a = LaserSim(client, rng=np.random.default_rng(3))
    b = LaserSim(client, rng=np.random.default_rng(3), mirror=a.mirror)
    c = LaserSim(client, rng=np.random.default_rng(4), mirror=a.mirror)
    sa, sb, sc = (x.scan(at()).ranges for x in (a, b, c))
    np.testing.assert_array_equal(sa, sb)
    assert not np.array_equal(sa, sc)


def test_it_is_a_laser_scanner_reading_at_its_pose_and_clock(client):
    wall_world(client)

    class Clock:
        def now_ns(self):
            return 123

        def sleep_until_ns(self, t):
            pass

    laser = LaserSim(client, noise=False, pose=at, clock=Clock())
    assert isinstance(laser, LaserScanner)
    with pytest.raises(DeviceClosedError):
        laser.read()
    with laser:
        scan = laser.read()
    assert scan.stamp_ns == 123 and scan.frame_id == "laser_link"
    assert scan.ranges[340] == pytest.approx(WALL_X)
    with pytest.raises(LaserSimError, match="needs pose"):
        LaserSim(client).__enter__().read()


def test_mount_comes_from_the_spec():
    spec = load_spec()
    m = spec.laser_mount
    assert m.parent == "base_link"
    assert m.xyz[0] > spec.body.centre_x + spec.body.depth / 2  # ahead of the footprint
    t = mounted_pose(np.eye(4), spec)
    np.testing.assert_allclose(t[:3, 3], m.xyz)
    import tomllib

    from robchair.platform.spec import DEFAULT_SPEC_PATH

    data = tomllib.loads(DEFAULT_SPEC_PATH.read_text())
    del data["mounts"]["laser_link"]
    with pytest.raises(ConfigError, match=r"mounts\.laser_link: missing"):
        _ = spec_from_dict(data).laser_mount


def test_bad_configuration_is_refused(client):
    with pytest.raises(LaserSimError, match="caster="):
        LaserSim(client, caster="optix")
    with pytest.raises(LaserSimError, match="accuracy_sigmas"):
        LaserSim(client, accuracy_sigmas=0.0)


@pytest.mark.slow
def test_laser_on_the_chair_reads_a_wall_from_its_mount_and_never_sees_the_chair():
    from sim.backend import SimChair

    chair = SimChair(sensor=None, sonars=False, noise=False)
    try:
        c = chair.world.client
        box(c, [0.05, 5, 1], [3.05, 0, 1.0])  # wall face at x = 3 m in front of base_link
        laser = LaserSim(
            c,
            noise=False,
            exclude_bodies=(chair.robot.body,),
            pose=lambda: chair.robot.link_transform("laser_link"),
        )
        with laser:
            scan = laser.read()
        mount_x = load_spec().laser_mount.xyz[0]
        assert scan.ranges[340] == pytest.approx(3.0 - mount_x, abs=0.002)
        np.testing.assert_allclose(
            chair.robot.link_transform("laser_link"), mounted_pose(np.eye(4)), atol=0.01
        )
        behind = np.abs(scan.angles()) > math.radians(100)  # beams sweeping back past the chair's sides
        assert np.isposinf(scan.ranges[behind]).all()
    finally:
        chair.close()


def test_simulated_scan_has_the_beams_the_driver_reads_from_the_sensor():
    """The simulated URG-04LX and a scan the driver decodes from the sensor's PP answer (the
    emulator's, hw.hokuyo.URG_04LX) have the same beam count and first/last angles."""
    from hw.hokuyo import URG_04LX as PP

    assert URG_04LX.n_beams == PP.amax - PP.amin + 1
    assert URG_04LX.angle_min == pytest.approx(float(PP.step_angle(PP.amin)), abs=1e-12)
    assert URG_04LX.angle_max == pytest.approx(float(PP.step_angle(PP.amax)), abs=1e-12)
