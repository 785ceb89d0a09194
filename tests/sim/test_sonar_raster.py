"""The sonar beams cast in image space (sim._sonar_raster), bounded against Embree's cast.

The raster is exact geometry in float64 over the mirror's float32 vertices; Embree casts float32 rays.
So the raw first echoes agree up to Embree's float32 rounding (bounded here at 1e-4 m; measured
worst 7e-7 m over 400 random office poses), echo or silence alike.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pybullet")
# open3d needs the libusb of `libusb-package` preloaded (mapping._deps); a bare import fails without it
from mapping._deps import import_open3d

import_open3d()

import pybullet as p  # noqa: E402

from robchair.platform import frames  # noqa: E402
from sim.sonar import SonarArraySim, SonarSim, SonarSimError  # noqa: E402

TOL_M = 1e-4


@pytest.fixture(scope="module")
def chair():
    from robchair.platform.paths import SCENES
    from sim.chair import SimChair
    from sim.scene import load_scene

    c = SimChair(scene=load_scene(SCENES / "office.toml"), sensor=None, sonars=True, raycast_threads=1)
    yield c
    c.close()


def _agree(got, ref):
    """Same NaNs, finite values within TOL_M; returns the largest difference."""
    got, ref = np.asarray(got), np.asarray(ref)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    fin = np.isfinite(ref)
    worst = float(np.max(np.abs(got[fin] - ref[fin]))) if fin.any() else 0.0
    assert worst <= TOL_M
    return worst


def _office_stacks(arr, count, seed):
    """Sonar pose stacks of two arrays (6 sonars) at random places, headings, heights and servo turns."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        x, y = rng.uniform(-1.5, 11.5), rng.uniform(-2.8, 2.8)
        t = frames.se3_planar(x, y, rng.uniform(-math.pi, math.pi), rng.uniform(0.2, 0.8))
        other = t @ frames.se3_planar(0.1, 0.2, float(rng.uniform(-0.5, 0.5)), 0.0)
        yield arr.sonar_poses(t, float(rng.uniform(-40.0, 40.0))) + arr.sonar_poses(other, 0.0)


def test_raster_first_echoes_equal_embree_s_over_random_office_poses(chair):
    """400 random poses of two arrays in the office (2400 sonars): the same echo or silence, the same
    range within 1e-4 m (the raster's is exact; Embree's carries its float32 rounding)."""
    arr = chair.sonars["sonar_array_left"]
    beam, m = arr._beam, chair.mirror
    seen = 0
    for poses in _office_stacks(arr, 400, 3):
        got = beam.first_echo(m, poses)
        _agree(got, beam.first_echo(m, poses, caster="embree"))
        seen += int(np.isfinite(got).sum())
    assert seen > 1500  # the poses see the scene, not only silence


def test_raster_nearest_hits_of_every_ray_equal_embree_s(chair):
    """Below the echo rule: each ray's nearest hit within the range, hit or miss, at Embree's distance."""
    from sim._sonar_kernels import fill_rays
    from sim._sonar_raster import beam_hits

    arr = chair.sonars["sonar_array_left"]
    beam, m = arr._beam, chair.mirror
    m.sync()
    rays, grid, bin_start, _, _ = beam._raster_layout()
    chunks, bounds = beam._raster_mesh(m)
    hits = 0
    for poses in _office_stacks(arr, 40, 5):
        st = np.asarray(poses)
        dist, face = beam_hits(m.tri_vertices, m.tri_faces, chunks, bounds, st, rays, grid, bin_start, 6.0)
        dirs = np.matmul(rays.T, st[:, :3, :3].transpose(0, 2, 1)).reshape(-1, 3)
        rows = np.empty((len(dirs), 6), dtype=np.float32)
        fill_rays(st, dirs, rows)
        t_hit, _, _ = m.cast_raw(rows)
        ref = t_hit.astype(float).reshape(dist.shape)
        ref[~(ref <= 6.0)] = np.inf
        np.testing.assert_array_equal(np.isfinite(dist), np.isfinite(ref))
        np.testing.assert_array_equal(face >= 0, np.isfinite(dist))
        fin = np.isfinite(ref)
        assert np.max(np.abs(dist[fin] - ref[fin])) <= TOL_M
        hits += int(fin.sum())
    assert hits > 100_000


def test_the_chairs_own_run_reads_what_embree_reads(chair):
    """The chair's batched group cast (SimChair.sonar_raw, both arrays in one raster call) as it
    drives and turns its servos, against each array's beams cast through Embree."""
    from sim.chair import SONAR_MOUNTS

    rng = np.random.default_rng(11)
    worst, seen = 0.0, 0
    for _ in range(25):
        x, y = rng.uniform(-1.0, 11.0), rng.uniform(-2.0, 2.0)
        chair.teleport((float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
        for mount in SONAR_MOUNTS:
            chair.robot.set_servo_deg(mount, float(rng.uniform(-40.0, 40.0)))
        chair.step(15)
        for mount in SONAR_MOUNTS:
            got = chair.sonar_raw(mount)
            a = chair.sonars[mount]
            poses = a.sonar_poses(chair.robot.link_transform(mount), 0.0)
            worst = max(worst, _agree(got, a._beam.first_echo(a.mirror, poses, caster="embree")))
            seen += int(np.isfinite(got).sum())
    assert seen > 60


def test_a_moved_body_is_seen_where_it_now_is():
    """A mirror rebuild (a body moved: MeshMirror.sync returns True) gives new flat arrays, and the
    raster's chunks follow them: a box beyond the range (no echo), then moved in front of the sonar,
    farther and back, reads each time what Embree reads, at the box's face."""
    c = p.connect(p.DIRECT)
    try:
        floor = p.createCollisionShape(p.GEOM_BOX, halfExtents=[20.0, 20.0, 0.01], physicsClientId=c)
        p.createMultiBody(0, floor, -1, basePosition=[0.0, 0.0, -0.01], physicsClientId=c)
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.05, 0.4, 0.4], physicsClientId=c)
        body = p.createMultiBody(0, col, -1, basePosition=[0.6, 0.0, 0.5], physicsClientId=c)
        s = SonarSim(c)
        beam, m = s._beam, s.mirror
        pose = frames.se3_planar(0.0, 0.0, 0.0, 0.5)
        for x in (8.0, 0.6, 1.3, 0.9):
            p.resetBasePositionAndOrientation(body, [x, 0.0, 0.5], [0, 0, 0, 1], physicsClientId=c)
            before = m.rebuilds
            got = beam.first_echo(m, [pose])
            assert m.rebuilds == before + 1  # the move rebuilt the mirror
            _agree(got, beam.first_echo(m, [pose], caster="embree"))
            if x < 6.0:
                assert got[0] == pytest.approx(x - 0.05, abs=1e-6)  # float32 vertices
            else:
                assert math.isnan(got[0])
    finally:
        p.disconnect(physicsClientId=c)


def test_the_raster_reads_a_square_wall_and_refuses_unknown_casters():
    """The axis ray meets a wall square to the sonar at its distance (up to the mirror's float32
    vertices), the SRF08 reading rounds it to the centimetre; a caster that does not exist is refused."""
    c = p.connect(p.DIRECT)
    try:
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.05, 4.0, 2.0], physicsClientId=c)
        p.createMultiBody(0, col, -1, basePosition=[1.3 + 0.05, 0.0, 1.0], physicsClientId=c)
        s = SonarSim(c)
        pose = frames.se3_planar(0.0, 0.0, 0.0, 0.4)
        raw = s._beam.first_echo(s.mirror, [pose])
        assert raw[0] == pytest.approx(1.3, abs=1e-7)
        assert s.measure(pose) == pytest.approx(1.3, abs=1e-12)
        with pytest.raises(SonarSimError, match="caster='optix'"):
            s._beam.first_echo(s.mirror, [pose], caster="optix")
        arr = SonarArraySim(c, mirror=s.mirror)
        assert np.isfinite(arr.measure(pose)[1])
    finally:
        p.disconnect(physicsClientId=c)


def test_beam_layout_bins_every_ray_once_and_refuses_rays_off_to_the_side():
    from sim._sonar_raster import beam_layout
    from sim.sonar import beam_rays

    dirs = beam_rays(2.0)[0]
    order, rays, grid, bin_start = beam_layout(dirs, 7, 5)
    assert sorted(order.tolist()) == list(range(len(dirs)))
    np.testing.assert_array_equal(rays.T, dirs[order])
    a0, da, c0, dc = grid[:4]
    assert bin_start[0] == 0 and bin_start[-1] == len(dirs) and np.all(np.diff(bin_start) >= 0)
    for b in range(35):
        for j in range(bin_start[b], bin_start[b + 1]):
            x, y, z = rays[:, j]
            assert int((y / x - a0) // da) == b % 7 and int((z / x - c0) // dc) == b // 7
    with pytest.raises(ValueError, match=r"x >= 0\.2"):
        beam_layout(np.array([[0.1, 0.995, 0.0]]))
    with pytest.raises(ValueError, match="grid"):
        beam_layout(dirs, 0, 3)
