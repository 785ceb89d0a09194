"""One batched cast per physics step for all the chair's sonar arrays (sim.sonar.SonarGroup)."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pybullet")
# open3d needs the libusb of `libusb-package` preloaded (mapping._deps); a bare import fails without it
from mapping._deps import import_open3d

import_open3d()


@pytest.fixture(scope="module")
def chair():
    from robchair.platform.paths import SCENES
    from sim.chair import SimChair
    from sim.scene import load_scene

    c = SimChair(scene=load_scene(SCENES / "office.toml"), sensor=None, sonars=True, raycast_threads=1)
    yield c
    c.close()


def _separate(chair, mount):
    """The exact path: this array's beams cast on their own (SonarArraySim's own first echo)."""
    arr = chair.sonars[mount]
    return arr._beam.first_echo(arr.mirror, arr.sonar_poses(chair.robot.link_transform(mount), 0.0))


def test_batched_sonar_echoes_equal_each_arrays_own_cast_bit_for_bit(chair):
    """Each ray's hit does not depend on the other rays of an Embree call, so the group's batch gives
    every array the raw echoes its own cast gives, NaN (no echo) included, over poses and servo turns."""
    from sim.chair import SONAR_MOUNTS

    rng = np.random.default_rng(4)
    seen = 0
    for _ in range(12):
        x, y = rng.uniform(-4.0, 4.0, 2)
        chair.teleport((float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
        for m in SONAR_MOUNTS:
            chair.robot.set_servo_deg(m, float(rng.uniform(-40.0, 40.0)))
        chair.step(20)  # the servos turn toward their targets
        casts = chair.sonar_group.casts
        got = {m: chair.sonar_raw(m).copy() for m in SONAR_MOUNTS}
        assert chair.sonar_group.casts == casts + 1  # one cast served both arrays
        for m in SONAR_MOUNTS:
            ref = _separate(chair, m)
            np.testing.assert_array_equal(got[m], ref)
            seen += int(np.isfinite(ref).sum())
    assert seen > 30  # the poses saw walls, not only silence


def test_a_new_physics_step_or_a_restart_casts_again(chair):
    """The kept echoes serve only the instant they were cast at: after a physics step, or a restart
    that puts the clock back at the same step count, the next read casts anew."""
    from sim.chair import SONAR_MOUNTS

    chair.teleport((0.0, 0.0, 0.0))
    chair.step(2)
    m0, m1 = SONAR_MOUNTS
    chair.sonar_raw(m0)
    casts = chair.sonar_group.casts
    chair.sonar_raw(m1)
    assert chair.sonar_group.casts == casts
    chair.step(1)
    chair.sonar_raw(m1)
    assert chair.sonar_group.casts == casts + 1
    steps = chair.world.steps
    chair.restart((1.0, -0.5, 0.3))
    chair.step(steps)  # the same step count as the kept batch, another place
    got = chair.sonar_raw(m1)
    assert chair.sonar_group.casts == casts + 2
    np.testing.assert_array_equal(got, _separate(chair, m1))


def test_an_arrays_three_readings_round_to_whole_centimetres_within_the_srf08_range():
    """SRF08 (SPEC table): 3 cm to 6 m, reported in whole cm; NaN is no echo. Hand values: 0.4449 m
    reads 44 cm, 1.005 m rounds to 100 cm (1.005 is stored just below, as 1.00499...), 6.004 m reads
    6.00 m, 6.006 m rounds to 6.01 m beyond the range (no reading), 0.02 m is under the minimum."""
    from sim.sonar import SONAR_MODELS, SonarArraySim, _Beam

    arr = SonarArraySim.__new__(SonarArraySim)  # only the beam's model and the noise matter here
    arr._beam = _Beam(SONAR_MODELS["srf08"], 5.0, 40.0)
    arr.noise_std_m, arr.rng = 0.0, np.random.default_rng(0)
    got = [arr.finish(np.array(r)) for r in ([0.4449, 1.005, 6.004], [6.006, 0.02, np.nan])]
    assert got[0] == pytest.approx((0.44, 1.00, 6.00), abs=1e-12)
    assert all(math.isnan(v) for v in got[1])


def test_the_compiled_ray_rows_are_numpys_bit_for_bit():
    """sim._sonar_kernels.fill_rays writes each sonar's origin and the directions as float32, the rows
    numpy's broadcasting assignments give (the previous fill), over random poses and directions."""
    from sim._sonar_kernels import fill_rays

    rng = np.random.default_rng(7)
    for k, n in ((1, 5), (6, 1102), (3, 17)):
        stack = np.tile(np.eye(4), (k, 1, 1))
        stack[:, :3, :] = rng.normal(0.0, 3.0, (k, 3, 4))
        dirs = rng.normal(0.0, 1.0, (k * n, 3))
        ref = np.empty((k * n, 6), dtype=np.float32)
        ref.reshape(k, n, 6)[:, :, :3] = stack[:, None, :3, 3]
        ref[:, 3:] = dirs
        got = np.full((k * n, 6), np.nan, dtype=np.float32)
        fill_rays(stack, dirs, got)
        np.testing.assert_array_equal(got.view(np.uint32), ref.view(np.uint32))
    with pytest.raises(ValueError, match="fill_rays: stack"):
        fill_rays(np.zeros((2, 4, 4)), np.zeros((5, 3)), np.zeros((5, 6), np.float32))  # 5 rays, 2 sonars
    with pytest.raises(ValueError, match="float32"):
        fill_rays(np.zeros((1, 4, 4)), np.zeros((4, 3)), np.zeros((4, 6)))


def test_all_sonar_mounts_in_one_query_equal_each_links_own_query(chair):
    """SimRobot.link_transforms (one getLinkStates call, used by SimChair.sonar_raw) gives every mount
    the transform link_transform gives it alone, bit for bit, with the servos turned."""
    from sim.chair import SONAR_MOUNTS
    from sim.errors import SimError

    chair.teleport((0.5, -0.3, 0.7))
    for m, deg in zip(SONAR_MOUNTS, (25.0, -35.0), strict=False):
        chair.robot.set_servo_deg(m, deg)
    chair.step(30)
    got = chair.robot.link_transforms(list(SONAR_MOUNTS))
    assert list(got) == list(SONAR_MOUNTS)
    for m in SONAR_MOUNTS:
        np.testing.assert_array_equal(got[m], chair.robot.link_transform(m))
    with pytest.raises(SimError, match="no link 'nowhere'"):
        chair.robot.link_transforms(["nowhere"])


def test_the_arrays_of_one_instant_read_the_mount_poses_once(chair, monkeypatch):
    """SimChair.sonar_raw keeps the mounts' poses of the instant's first read for the other arrays (one
    getLinkStates per physics step, not one per array); a step or a teleport reads them again, and
    the echoes are the ones a fresh query gives."""
    from sim.chair import SONAR_MOUNTS

    calls: list[str] = []
    real = chair.robot.link_transforms

    def counted(names):  # type: ignore[no-untyped-def]
        calls.append("query")
        return real(names)

    monkeypatch.setattr(chair.robot, "link_transforms", counted)
    chair.teleport((0.3, 0.2, 0.4))
    chair.step(3)
    got = [chair.sonar_raw(m).copy() for m in SONAR_MOUNTS]
    assert len(calls) == 1
    for m, g in zip(SONAR_MOUNTS, got, strict=True):
        np.testing.assert_array_equal(g, _separate(chair, m))
    chair.step(1)
    chair.sonar_raw(SONAR_MOUNTS[1])
    assert len(calls) == 2
    chair.teleport((-1.0, 0.5, 2.0))  # moved at the same physics step: read again, cast again
    casts = chair.sonar_group.casts
    got = chair.sonar_raw(SONAR_MOUNTS[0])
    assert len(calls) == 3 and chair.sonar_group.casts == casts + 1
    np.testing.assert_array_equal(got, _separate(chair, SONAR_MOUNTS[0]))


def test_a_static_scene_is_mirrored_once_per_episode_and_a_full_sync_finds_nothing_changed(chair):
    """Without walking people every scene body is static and the chair is left out of the mirror:
    the mirror's stamp is the restart count, so stepping and reading the sonars re-reads no body's
    pose (the per-step sync re-read every body), a full sync forced afterwards changes nothing (the
    scene built once is the one a per-step sync would have built), and a restart syncs once."""
    from sim.chair import SONAR_MOUNTS

    m = chair.mirror
    assert not chair.bodies.moving
    chair.sonar_raw(SONAR_MOUNTS[0])
    reads: list[int] = []
    real = m._link_poses

    def counted(body, links):  # type: ignore[no-untyped-def]
        reads.append(body)
        return real(body, links)

    m._link_poses = counted
    try:
        rebuilds = m.rebuilds
        for _ in range(4):
            chair.step(3)
            chair.sonar_raw(SONAR_MOUNTS[0])
        assert reads == []
        m._synced_stamp = None  # what the per-step sync did: re-read every body
        assert m.sync() is False and reads and m.rebuilds == rebuilds
        reads.clear()
        chair.restart((0.5, 0.5, 0.0))
        chair.step(2)
        chair.sonar_raw(SONAR_MOUNTS[0])
        chair.step(2)
        chair.sonar_raw(SONAR_MOUNTS[0])
        assert 0 < len(reads) <= len(chair.bodies.ids) + 1  # one sync after the restart, not two
        assert chair.robot.body in m.exclude_bodies
    finally:
        del m._link_poses


def test_with_walking_people_the_mirror_follows_every_physics_step():
    """Scripted people move at every physics step: there the mirror's stamp is the step count."""
    from sim.chair import SimChair
    from sim.scene import load_scenario

    sc = load_scenario("outdoor_people")
    c = SimChair(scene=sc.scene, start=sc.start, sensor=None, sonars=True, raycast_threads=1)
    try:
        assert c.bodies.moving
        s0 = c.mirror.step_counter()
        c.step(2)
        assert c.mirror.step_counter() == s0 + 2 == c.world.steps
        rebuilds = c.mirror.rebuilds
        c.sonar_raw(SONAR_MOUNTS_LEFT)
        c.step(1)
        c.sonar_raw(SONAR_MOUNTS_LEFT)
        assert c.mirror.rebuilds == rebuilds + 2  # the people moved: rebuilt at each step
    finally:
        c.close()


SONAR_MOUNTS_LEFT = "sonar_array_left"
