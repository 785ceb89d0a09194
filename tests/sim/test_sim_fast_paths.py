"""The simulator's fast paths give the answers of the slow ones they replace.

The raster caster against Embree, the fast acos and normal quantile against the exact functions,
the lateral-offset buckets against the rounded-normal CDF, the compiled point transform against
numpy, and the mirror's once-per-step sync against a world that moved.
"""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.kinect import (
    MODELS,
    KinectError,
    KinectSim,
    _offset_buckets,
    _rounded_normal_cdf,
    render_raycast,
)
from sim.raycast import MeshMirror, pose_matrix

p = pytest.importorskip("pybullet")


@pytest.fixture
def client():
    c = p.connect(p.DIRECT)
    yield c
    p.disconnect(physicsClientId=c)


def _body(c, geom, pos, rpy=(0.0, 0.0, 0.0), **kw):
    col = p.createCollisionShape(geom, physicsClientId=c, **kw)
    if "height" in kw:  # PyBullet's visual cylinders call it length
        kw["length"] = kw.pop("height")
    vis = p.createVisualShape(geom, physicsClientId=c, **kw)
    return p.createMultiBody(
        0.0, col, vis, basePosition=pos, baseOrientation=p.getQuaternionFromEuler(rpy), physicsClientId=c
    )


def _cluttered_scene(c):
    """Floor, a wall the camera stands next to (its triangles reach behind the camera),
    boxes, a sphere and a cylinder at different depths (some hiding others)."""
    _body(c, p.GEOM_BOX, [0.0, 0.0, -0.05], halfExtents=[40.0, 40.0, 0.05])  # floor, under the camera
    _body(c, p.GEOM_BOX, [0.0, 1.2, 1.0], halfExtents=[6.0, 0.05, 1.0])  # runs past the camera
    _body(c, p.GEOM_BOX, [2.5, -0.5, 0.6], rpy=(0.0, 0.0, 0.5), halfExtents=[0.3, 0.4, 0.6])
    _body(c, p.GEOM_BOX, [4.0, 0.0, 1.0], halfExtents=[0.1, 2.0, 1.0])
    _body(c, p.GEOM_SPHERE, [1.6, 0.3, 1.1], radius=0.25)
    _body(c, p.GEOM_CYLINDER, [3.0, 0.6, 0.5], radius=0.2, height=1.0)


def test_raster_caster_finds_the_same_first_hits_as_embree(client):
    _cluttered_scene(client)
    m = MeshMirror(client)
    m.sync()
    intr = MODELS["kinect2"].intrinsics
    rays = intr.rays()
    poses = [
        ([0.0, 0.0, 1.0], (0.0, 0.0, 0.0)),
        ([0.3, 0.5, 0.4], (0.0, 0.35, 0.3)),  # looking down at the floor, the wall to the left
        ([1.0, -0.8, 1.6], (0.2, 0.1, -0.6)),  # rolled
        ([5.0, 0.0, 1.0], (0.0, 0.0, math.pi)),  # looking back through the scene
    ]
    for xyz, rpy in poses:
        t = pose_matrix((xyz, p.getQuaternionFromEuler(rpy)))
        e = render_raycast(m, t, intr, 6.75, rays=rays, caster="embree")
        r = render_raycast(m, t, intr, 6.75, rays=rays, caster="raster")
        hit_e, hit_r = np.isfinite(e.depth), np.isfinite(r.depth)
        assert hit_e.sum() > 10_000
        assert (hit_e != hit_r).mean() < 1e-3  # only rays grazing an edge may differ
        both = hit_e & hit_r
        # Embree works in float32: a few micrometres; a wrong plane or pixel would be millimetres
        assert np.abs(e.depth[both] - r.depth[both]).max() < 2e-5
        assert (e.body[both] != r.body[both]).mean() < 1e-3
        # same triangle: normals parallel (the caster may orient them either way)
        cos = np.abs(np.sum(e.normals[both] * r.normals[both], axis=-1))
        assert np.mean(cos > 0.9999) > 0.999
        assert np.array_equal(r.body < 0, ~hit_r) and np.all(np.isnan(r.normals[~hit_r]))


def test_raster_caster_depth_of_a_wall_reaching_behind_the_camera_is_analytic(client):
    # wall plane y = 1 from x = -5 to 5: its two big triangles cross the camera's x = 0 plane
    _body(client, p.GEOM_BOX, [0.0, 1.05, 1.0], halfExtents=[5.0, 0.05, 3.0])
    m = MeshMirror(client)
    intr = MODELS["kinect2"].intrinsics
    rays = intr.rays()
    t = pose_matrix(([0.0, 0.0, 1.0], p.getQuaternionFromEuler((0.0, 0.0, 0.6))))  # turned toward it
    img = render_raycast(m, t, intr, 20.0, rays=rays, caster="raster")
    world_dirs = rays @ t[:3, :3].T
    sees = world_dirs[..., 1] > 1e-3
    expected = 1.0 / world_dirs[..., 1]  # depth d with d * dir_y = 1 (forward component is 1)
    inside = (
        sees & (expected * np.abs(world_dirs[..., 0]) < 4.9) & (np.abs(expected * world_dirs[..., 2]) < 2.9)
    )
    assert inside.sum() > 20_000
    np.testing.assert_allclose(img.depth[inside], expected[inside], rtol=1e-9)
    assert np.all(np.isnan(img.depth[world_dirs[..., 1] < -1e-3]))  # the other side: nothing


def test_kinect_refuses_an_unknown_caster(client):
    with pytest.raises(KinectError, match="caster 'optix'"):
        KinectSim(client, "kinect2", caster="optix")


def test_both_casters_give_the_same_noisy_frame_up_to_the_mm_quantisation(client):
    _cluttered_scene(client)
    pose = ([0.0, 0.0, 1.0], p.getQuaternionFromEuler((0.0, 0.1, 0.0)))
    a = KinectSim(client, "kinect2", rng=3, caster="raster").capture(pose).points
    b = KinectSim(client, "kinect2", rng=3, caster="embree").capture(pose).points
    same = np.isfinite(a[..., 0]) == np.isfinite(b[..., 0])
    assert same.mean() > 0.999
    both = np.isfinite(a[..., 0]) & np.isfinite(b[..., 0])
    # the same random draws: a pixel differs only when micrometres move it across a mm step
    assert np.mean(np.abs(a[both][:, 0] - b[both][:, 0]) < 1e-6) > 0.99
    assert np.abs(a[both][:, 0] - b[both][:, 0]).max() <= 1.001e-3


def test_fast_acos_is_within_3e_8_rad_of_libm():
    from sim._kinect_kernels import _acos01

    x = np.linspace(0.0, 1.0, 20_001)
    err = max(abs(_acos01(v) - math.acos(v)) for v in x)
    assert err < 3e-8


@given(st.floats(min_value=1e-12, max_value=1.0 - 1e-12))
@settings(max_examples=300, deadline=None)
def test_normal_quantile_matches_the_exact_inverse_cdf(prob):
    from sim._kinect_kernels import _normal_quantile

    exact = statistics.NormalDist().inv_cdf(prob)
    assert _normal_quantile(prob) == pytest.approx(exact, rel=2e-9, abs=1e-12)


def test_lateral_offset_buckets_give_the_offset_of_the_rounded_normal():
    from sim._kinect_kernels import _table_offset, _uniform32

    table = _rounded_normal_cdf("fankhauser2015")
    buckets = _offset_buckets(table)
    assert len(_rounded_normal_cdf("nguyen2012")) == 0  # per-pixel sigma: no table
    rng = np.random.default_rng(0)
    ks = rng.integers(0, 2**32, size=20_000, dtype=np.uint64)
    # plus the CDF steps themselves and their neighbours, where a bucket straddles a step
    steps = np.floor(table * 2.0**32).astype(np.uint64)
    ks = np.concatenate([ks, steps[steps < 2**32 - 1], steps[steps > 0] - 1])
    for k in ks:
        u = _uniform32(k)
        o = int(buckets[int(k) >> 16])
        got = _table_offset(u, table) if o == 127 else o
        # the definition: round(sigma * Phi^-1(u)) with sigma = 1.6
        direct = round(1.6 * statistics.NormalDist().inv_cdf(u))
        assert got == direct


def test_mirror_with_a_step_counter_syncs_once_per_step_and_follows_moves_after_a_step(client):
    b = _body(client, p.GEOM_BOX, [2.0, 0.0, 0.0], halfExtents=[0.1, 1.0, 1.0])
    steps = [0]
    m = MeshMirror(client)
    m.step_counter = lambda: steps[0]
    m.bodies_fixed = True
    assert m.sync() is True
    assert m.cast([0, 0, 0], [[1.0, 0, 0]]).distance[0] == pytest.approx(1.9, abs=1e-5)
    p.resetBasePositionAndOrientation(b, [3.0, 0.0, 0.0], [0, 0, 0, 1], physicsClientId=client)
    assert m.sync() is False  # same step: the world is taken as unchanged (the owner's promise)
    steps[0] += 1
    assert m.sync() is True
    assert m.cast([0, 0, 0], [[1.0, 0, 0]]).distance[0] == pytest.approx(2.9, abs=1e-5)
    steps[0] += 1
    assert m.sync() is False  # stepped, but nothing moved: no rebuild


def test_compiled_sonar_echo_rule_gives_the_numpy_rule_s_ranges(client):
    from sim.sonar import SonarArraySim

    _cluttered_scene(client)
    arr = SonarArraySim(client, "srf08")
    rng = np.random.default_rng(4)
    seen = 0
    for _ in range(40):
        xyz = [rng.uniform(-1.0, 3.5), rng.uniform(-1.0, 1.0), rng.uniform(0.2, 1.5)]
        poses = arr.sonar_poses((xyz, p.getQuaternionFromEuler((0.0, 0.0, rng.uniform(-3.1, 3.1)))), 0.0)
        # the compiled rule over Embree's hits (the default caster, the raster, is bounded against
        # Embree in test_sonar_raster.py)
        fast = arr._beam.first_echo(arr.mirror, poses, caster="embree")
        slow = arr._beam.first_echo(arr.mirror, poses, compiled=False)
        np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)  # NaN where NaN
        seen += int(np.isfinite(fast).sum())
    assert seen > 30  # most sonars see something in this scene


@pytest.mark.parametrize("model", ["kinect2", "kinect1", "kinect2-qhd"])
def test_a_plain_capture_is_the_labelled_capture_s_frame(client, model):
    # capture() skips the depth and label images; the points must not change
    _cluttered_scene(client)
    pose = ([0.0, 0.2, 1.0], p.getQuaternionFromEuler((0.0, 0.1, -0.2)))
    plain = KinectSim(client, model, rng=9).capture(pose).points
    full = KinectSim(client, model, rng=9).capture_full(pose)
    assert np.isfinite(plain).sum() > 10_000
    assert np.array_equal(plain, full.frame.points, equal_nan=True)
    assert np.array_equal(np.isfinite(full.frame.points[..., 0]), full.body >= 0)


def _office_poses(chair):
    """Camera poses along the office corridor route (the bench's scene): down the corridor, through
    the doorway, turned toward the table, and looking back."""
    t0 = chair.kinect_pose()
    out = []
    for dx, yaw in [(0.0, 0.0), (2.0, 0.3), (5.5, -0.4), (7.0, -0.8), (3.0, 2.5)]:
        t = t0.copy()
        t[0, 3] += dx
        c, s = math.cos(yaw), math.sin(yaw)
        t[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ t0[:3, :3]
        out.append(t)
    return out


@pytest.fixture(scope="module")
def office_chair():
    from sim.chair import SimChair
    from sim.scene import load_scenario

    sc = load_scenario("office_corridor")
    chair = SimChair(scene=sc.scene, start=sc.start, sensor="kinect2", sonars=False, seed=0)
    yield chair
    chair.close()


@pytest.mark.parametrize("noise", [True, False])
def test_the_fused_raster_frame_is_render_plus_finish_bit_for_bit_in_the_office(office_chair, noise):
    # capture() runs sim._kinect_kernels.raster_capture (no images between raster and noise);
    # capture_full() renders the images and runs finish: the points must be identical
    c = office_chair.world.client
    for t in _office_poses(office_chair):
        plain = KinectSim(c, "kinect2", rng=5, noise=noise, mirror=office_chair.mirror).capture(t).points
        full = KinectSim(c, "kinect2", rng=5, noise=noise, mirror=office_chair.mirror).capture_full(t)
        assert np.isfinite(plain[..., 0]).mean() > 0.3
        assert np.array_equal(plain, full.frame.points, equal_nan=True)


def test_raster_caster_matches_embree_on_the_office_scene(office_chair):
    # the raster caster tests every pixel's own ray against the triangles (no approximation):
    # against Embree on the real scene, depth agrees to float32 rounding and only rays grazing an
    # edge flip between hit and miss. Measured on these five poses: 99.9995-100 % of the common pixels
    # within 1 mm (one pixel of 206k on a silhouette hits the triangle behind), 99.9th percentile
    # ~1e-6 m, no hit/miss flip.
    m = office_chair.mirror
    m.sync()
    intr = MODELS["kinect2"].intrinsics
    rays = intr.rays()
    for t in _office_poses(office_chair):
        e = render_raycast(m, t, intr, 6.75, rays=rays, caster="embree")
        r = render_raycast(m, t, intr, 6.75, rays=rays, caster="raster")
        hit_e, hit_r = np.isfinite(e.depth), np.isfinite(r.depth)
        both = hit_e & hit_r
        assert both.sum() > 50_000
        assert (hit_e != hit_r).mean() < 1e-4
        d = np.abs(e.depth[both] - r.depth[both])
        assert np.mean(d < 1e-3) > 0.9999
        assert np.quantile(d, 0.999) < 1e-5


@pytest.mark.parametrize("bitgen", [np.random.PCG64, np.random.MT19937])
def test_noise_bits_are_the_generator_s_full_range_integers(client, bitgen):
    # the PCG64 path reads the raw 64-bit outputs; the frames of a seed must stay what integers() gave
    cam = KinectSim(client, "kinect2", rng=0)
    a, b = np.random.Generator(bitgen(21)), np.random.Generator(bitgen(21))
    bits = cam.noise_bits(a)
    ref = b.integers(0, np.iinfo(np.uint64).max, size=(2, 424, 512), dtype=np.uint64, endpoint=True)
    assert bits is not None and bits.dtype == np.uint64
    assert np.array_equal(bits, ref)
    assert a.integers(0, 2**62) == b.integers(0, 2**62)  # the generators are left in the same state
