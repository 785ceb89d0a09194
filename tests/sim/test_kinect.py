"""Simulated Kinect: backends agree, planes come out analytic, NaN for no return, seeded noise."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sim.kinect import (
    MODELS,
    KinectError,
    KinectSim,
    fankhauser2015_axial_sigma_m,
    fankhauser2015_lateral_sigma_px,
    nguyen2012_axial_sigma_m,
    nguyen2012_lateral_sigma_px,
    quantize_depth,
)
from sim.raycast import MeshMirror, MeshMirrorError, pose_matrix

p = pytest.importorskip("pybullet")


@pytest.fixture
def client():
    c = p.connect(p.DIRECT)
    yield c
    p.disconnect(physicsClientId=c)


def box(c, half, pos, rpy=(0.0, 0.0, 0.0), mass=0.0, inertial=(0.0, 0.0, 0.0), frame=(0.0, 0.0, 0.0)):
    col = p.createCollisionShape(
        p.GEOM_BOX, halfExtents=half, collisionFramePosition=frame, physicsClientId=c
    )
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, visualFramePosition=frame, physicsClientId=c)
    return p.createMultiBody(
        mass,
        col,
        vis,
        basePosition=pos,
        baseOrientation=p.getQuaternionFromEuler(rpy),
        baseInertialFramePosition=inertial,
        physicsClientId=c,
    )


def cam_pose(xyz=(0.0, 0.0, 1.0), yaw=0.0, pitch=0.0):
    return (list(xyz), p.getQuaternionFromEuler([0.0, pitch, yaw]))


def wall_at(c, d, yaw=0.0, height=1.0):
    """A wall whose front face passes through (d, 0, height) with normal rotated by yaw towards the camera."""
    n = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    centre = np.array([d, 0.0, height]) + 0.05 * n
    box(c, [0.05, 8.0, 8.0], centre.tolist(), rpy=(0.0, 0.0, yaw))
    return n, np.array([d, 0.0, height])


def test_raycast_and_pybullet_backends_agree_within_1cm_on_a_test_scene(client):
    box(client, [5, 5, 0.01], [0, 0, -0.01])
    box(client, [0.05, 2, 1.5], [3, 0, 1.5], rpy=(0, 0, 0.3))
    box(client, [0.3, 0.3, 0.5], [1.8, 0.6, 0.5], rpy=(0, 0, 0.7))
    box(client, [0.2, 0.2, 0.2], [1.5, -0.5, 1.3], rpy=(0.3, 0.2, 0.1))
    pose = cam_pose(pitch=0.1)
    a = KinectSim(client, "kinect2", backend="raycast", noise=False).capture(pose).points
    b = KinectSim(client, "kinect2", backend="pybullet", noise=False).capture(pose).points
    va, vb = np.isfinite(a[..., 0]), np.isfinite(b[..., 0])
    assert va.sum() > 0.5 * va.size
    assert np.mean(va == vb) > 0.999  # same pixels valid (a few may flip exactly on an edge)
    both = va & vb
    assert np.max(np.abs(a[both] - b[both])) < 0.01


def test_depth_of_a_fronto_parallel_wall_is_its_distance_at_every_pixel(client):
    wall_at(client, 2.0)
    for backend in ("raycast", "pybullet"):
        k = KinectSim(client, "kinect2", backend=backend, noise=False)
        pts = k.capture(cam_pose()).points.astype(float)
        assert pts.shape == (424, 512, 3)
        assert np.all(np.isfinite(pts))
        np.testing.assert_allclose(pts[..., 0], 2.0, atol=1e-4)
        # lateral coordinates follow the pinhole: pixel (0, 0) is top-left -> +y (left), +z (up)
        intr = k.model.intrinsics
        assert pts[0, 0, 1] == pytest.approx(2.0 * (intr.cx - 0.5) / intr.fx, abs=1e-4)
        assert pts[0, 0, 2] == pytest.approx(2.0 * (intr.cy - 0.5) / intr.fy, abs=1e-4)


def test_depth_of_a_tilted_wall_matches_the_analytic_ray_plane_intersection(client):
    n, q = wall_at(client, 2.2, yaw=0.6)
    k = KinectSim(client, "kinect1", noise=False)
    pose = cam_pose(yaw=0.1, pitch=-0.05)
    t = pose_matrix(pose)
    pts = k.capture(pose).points.astype(float)
    rays_w = k.model.intrinsics.rays() @ t[:3, :3].T
    depth = (n @ (q - t[:3, 3])) / (rays_w @ n)  # ray parameter with unit forward component = depth
    expected = np.where((depth >= 0.6) & (depth <= 4.0), depth, np.nan)
    np.testing.assert_array_equal(np.isnan(pts[..., 0]), np.isnan(expected))
    np.testing.assert_allclose(pts[..., 0], expected, atol=2e-4)


def test_rays_that_hit_nothing_give_nan_never_zero_or_far(client):
    body = box(client, [0.2, 0.2, 0.2], [2.0, 0.0, 1.0])
    for backend in ("raycast", "pybullet"):
        cap = KinectSim(client, "kinect2", backend=backend, noise=False).capture_full(cam_pose())
        x = cap.frame.points[..., 0]
        hit = cap.body == body
        assert 0 < hit.sum() < 0.2 * hit.size
        assert np.all(np.isnan(cap.frame.points[~hit]))
        assert np.all(x[hit] == pytest.approx(1.8, abs=1e-3))


def test_an_empty_world_gives_an_all_nan_frame(client):
    f = KinectSim(client, "kinect2", noise=False).capture(cam_pose())
    assert np.all(np.isnan(f.points))


@pytest.mark.parametrize(
    ("model", "d", "valid"),
    [
        ("kinect2", 4.4, True),
        ("kinect2", 4.6, False),
        ("kinect2", 0.45, False),
        ("kinect2", 0.55, True),
        ("kinect1", 3.9, True),
        ("kinect1", 4.2, False),
        ("kinect1", 0.55, False),
    ],
)
def test_depth_outside_the_model_range_is_nan(client, model, d, valid):
    wall_at(client, d)
    f = KinectSim(client, model, noise=False).capture(cam_pose())
    h, w = f.points.shape[:2]
    centre = f.points[h // 2, w // 2, 0]
    assert np.isfinite(centre) == valid


def test_noise_model_functions_match_hand_computed_values():
    # Nguyen 2012 at z = 2 m facing the camera: 0.0012 + 0.0019 * 1.6^2 = 0.006064 m
    assert nguyen2012_axial_sigma_m(2.0, 0.0) == pytest.approx(0.006064)
    # angle term at 45 deg: 0.0001/sqrt(2) * (pi/4)^2 / (pi/4)^2
    assert nguyen2012_axial_sigma_m(2.0, math.pi / 4) == pytest.approx(0.006064 + 0.0001 / math.sqrt(2))
    assert nguyen2012_lateral_sigma_px(math.pi / 4) == pytest.approx(0.835)
    # Fankhauser 2015 at z = 2 m: 1.5 - 1.0 + 1.2 = 1.7 mm; at 45 deg + 0.1 * 2^1.5 mm
    assert fankhauser2015_axial_sigma_m(2.0, 0.0) == pytest.approx(0.0017)
    assert fankhauser2015_axial_sigma_m(2.0, math.pi / 4) == pytest.approx(0.0017 + 0.0001 * 2**1.5)
    assert fankhauser2015_lateral_sigma_px(0.3) == pytest.approx(1.6)


def test_quantization_of_kinect1_depth_follows_disparity_steps():
    k = 580.0 * 0.075 * 8.0
    z = np.array([1.0, 2.0, 4.0])
    q = quantize_depth(z, "disparity")
    np.testing.assert_allclose(q, k / np.round(k / z))
    step_at_2m = k / 174 - k / 175  # disparity step at ~2 m: z^2 / (f b 8) ~ 1.15 cm
    assert 0.011 < step_at_2m < 0.012
    np.testing.assert_allclose(quantize_depth(np.array([1.23456]), "mm"), [1.235])


@pytest.mark.parametrize("model_name", ["kinect1", "kinect2"])
def test_noise_std_at_2m_matches_the_model_within_10_percent(client, model_name):
    wall_at(client, 2.0)
    model = dataclasses.replace(MODELS[model_name], quantization=None)
    k = KinectSim(client, model, noise=True, rng=np.random.default_rng(7))
    pts = k.capture(cam_pose()).points.astype(float)
    h, w = pts.shape[:2]
    sl = (slice(h // 2 - 60, h // 2 + 60), slice(w // 2 - 60, w // 2 + 60))
    depth = pts[sl][..., 0]
    # the angle between the wall normal and each viewing ray enters the model
    rays = k.model.intrinsics.rays()[sl]
    theta = np.arccos(1.0 / np.linalg.norm(rays, axis=-1))
    fn = nguyen2012_axial_sigma_m if model_name == "kinect1" else fankhauser2015_axial_sigma_m
    expected = math.sqrt(float(np.mean(fn(2.0, theta) ** 2)))
    assert np.std(depth - 2.0) == pytest.approx(expected, rel=0.10)
    assert abs(np.mean(depth - 2.0)) < 0.1 * expected


def test_kinect2_noise_with_mm_quantization_still_matches_at_2m(client):
    wall_at(client, 2.0)
    k = KinectSim(client, "kinect2", noise=True, rng=np.random.default_rng(3))
    depth = k.capture(cam_pose()).points[150:270, 200:310, 0].astype(float)
    assert np.allclose(np.round(depth * 1000), depth * 1000, atol=1e-3)  # whole millimetres (float32)
    expected = math.sqrt(0.0017**2 + 0.001**2 / 12)
    assert np.std(depth) == pytest.approx(expected, rel=0.10)


def test_same_seed_gives_the_same_frame_and_another_seed_another(client):
    box(client, [0.3, 0.3, 0.5], [1.8, 0.2, 0.5], rpy=(0, 0, 0.7))
    wall_at(client, 3.0)

    def frame(seed):
        return KinectSim(client, "kinect1", noise=True, rng=seed).capture(cam_pose()).points

    a, b, c = frame(5), frame(5), frame(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(np.nan_to_num(a), np.nan_to_num(c))


@pytest.mark.parametrize(("model", "shape"), [("kinect2-hd", (1080, 1920)), ("kinect2-qhd", (540, 960))])
def test_registered_output_keeps_points_of_a_tilted_plane_on_the_plane(client, model, shape):
    n, q = wall_at(client, 2.0, yaw=0.5)
    k = KinectSim(client, model, noise=False)
    pose = cam_pose()
    f = k.capture(pose)
    assert f.points.shape == (*shape, 3)
    assert f.frame_id == "kinect_rgb"
    world = k.to_world(f.points.astype(float), pose).reshape(-1, 3)
    world = world[np.isfinite(world[:, 0])]
    # the colour camera is wider than the depth camera: its sides stay NaN, the rest is filled
    assert 0.6 * shape[0] * shape[1] < len(world) < 0.9 * shape[0] * shape[1]
    assert np.max(np.abs((world - q) @ n)) < 1e-4


def test_registered_output_is_in_the_colour_camera_frame(client):
    wall_at(client, 2.0)
    k = KinectSim(client, "kinect2-hd", noise=False)
    pts = k.capture(cam_pose()).points.astype(float)
    valid = np.isfinite(pts[..., 0])
    # the centre pixel of the colour camera looks straight ahead from 5.2 cm left of the depth camera
    assert pts[540, 960, 0] == pytest.approx(2.0, abs=1e-4)
    assert abs(pts[540, 960, 1]) < 0.003
    world = k.to_world(pts, cam_pose())
    assert np.nanmean(world[..., 1][valid]) == pytest.approx(np.nanmean(pts[..., 1][valid]) + 0.052, abs=1e-6)


def test_the_mirror_matches_pybullet_ray_tests_with_offset_inertial_and_shape_frames(client):
    box(
        client,
        [0.3, 0.2, 0.5],
        [2, 0, 0.5],
        rpy=(0.1, 0.2, 0.3),
        mass=1.0,
        inertial=(0.1, 0.05, -0.2),
        frame=(0.05, -0.1, 0.02),
    )
    box(client, [0.2, 0.4, 0.3], [1.5, -1.0, 1.0], rpy=(0.0, 0.4, -0.2), mass=2.0, inertial=(-0.1, 0.0, 0.1))
    # a two-link body: the mirror must use the link frames after a joint moved
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.1, 0.1, 0.3], physicsClientId=client)
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=[0.1, 0.1, 0.3], physicsClientId=client)
    arm = p.createMultiBody(
        1.0,
        col,
        vis,
        basePosition=[2.0, 1.0, 0.5],
        linkMasses=[1.0],
        linkCollisionShapeIndices=[col],
        linkVisualShapeIndices=[vis],
        linkPositions=[[0, 0, 0.6]],
        linkOrientations=[[0, 0, 0, 1]],
        linkInertialFramePositions=[[0, 0, 0.1]],
        linkInertialFrameOrientations=[[0, 0, 0, 1]],
        linkParentIndices=[0],
        linkJointTypes=[p.JOINT_REVOLUTE],
        linkJointAxis=[[1, 0, 0]],
        physicsClientId=client,
    )
    p.resetJointState(arm, 0, 0.8, physicsClientId=client)
    m = MeshMirror(client)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(6000, 3))
    d[:, 0] = np.abs(d[:, 0]) * 3
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.array([0.0, 0.0, 0.7])
    hits = m.cast(o, d, max_range=10.0)
    p.performCollisionDetection(physicsClientId=client)  # refresh Bullet's broadphase boxes first
    res = []
    for i in range(0, len(d), 2000):
        res += p.rayTestBatch(
            [o.tolist()] * len(d[i : i + 2000]), (o + 10 * d[i : i + 2000]).tolist(), physicsClientId=client
        )
    pb_body = np.array([r[0] for r in res])
    pb_dist = np.where(pb_body >= 0, np.array([r[2] for r in res]) * 10, np.inf)
    assert np.isfinite(pb_dist).sum() > 300
    agree = np.isfinite(pb_dist) == np.isfinite(hits.distance)
    assert agree.mean() > 0.998  # rays grazing an edge may differ in float32
    both = np.isfinite(pb_dist) & np.isfinite(hits.distance)
    err = np.abs(pb_dist[both] - hits.distance[both])
    # exact triangles (float32) vs Bullet's iterative convex ray cast, which is off by up to a few mm
    # for rays grazing a face; any frame error would shift every hit by centimetres
    assert np.percentile(err, 95) < 1e-5
    assert err.max() < 5e-3
    assert np.array_equal(m.body_of(hits.geometry)[both], pb_body[both])


def test_the_mirror_follows_a_moving_body_and_skips_excluded_ones(client):
    b = box(client, [0.1, 1.0, 1.0], [2.0, 0.0, 0.0])
    other = box(client, [0.1, 1.0, 1.0], [1.0, 0.0, 0.0])
    m = MeshMirror(client, exclude_bodies=[other])
    assert m.sync() is True
    assert m.sync() is False  # nothing moved: no rebuild
    assert m.cast([0, 0, 0], [[1.0, 0, 0]]).distance[0] == pytest.approx(1.9, abs=1e-5)
    p.resetBasePositionAndOrientation(b, [3.0, 0.0, 0.0], [0, 0, 0, 1], physicsClientId=client)
    assert m.sync() is True
    assert m.cast([0, 0, 0], [[1.0, 0, 0]]).distance[0] == pytest.approx(2.9, abs=1e-5)
    p.removeBody(b, physicsClientId=client)
    m.sync()
    assert m.cast([0, 0, 0], [[1.0, 0, 0]]).distance[0] == math.inf
    # PyBullet hands the freed id to the next body: the mirror must notice the new shape anyway
    col = p.createCollisionShape(p.GEOM_SPHERE, radius=0.5, physicsClientId=client)
    assert p.createMultiBody(0, col, -1, basePosition=[2.0, 0, 0], physicsClientId=client) == b
    assert m.sync() is True
    assert m.cast([0, 0, 0], [[1.0, 0, 0]]).distance[0] == pytest.approx(1.5, abs=2e-3)


def test_bad_inputs_are_refused_with_a_clear_message(client):
    with pytest.raises(KinectError, match="unknown Kinect model 'kinect3'"):
        KinectSim(client, "kinect3")
    with pytest.raises(KinectError, match="backend 'gl'"):
        KinectSim(client, "kinect2", backend="gl")
    k = KinectSim(client, "kinect2", noise=False)
    with pytest.raises(MeshMirrorError, match="4x4"):
        k.capture(np.eye(3))
    with pytest.raises(MeshMirrorError, match="not finite"):
        k.capture(([0, 0, np.nan], [0, 0, 0, 1]))
    with pytest.raises(MeshMirrorError, match="directions"):
        MeshMirror(client).cast([0, 0, 0], np.zeros((3, 2)))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    d=st.floats(0.8, 3.5),
    wall_yaw=st.floats(-1.0, 1.0),
    cam_yaw=st.floats(-0.3, 0.3),
    cam_pitch=st.floats(-0.3, 0.3),
)
def test_any_plane_seen_from_any_pose_comes_out_on_the_plane(client, d, wall_yaw, cam_yaw, cam_pitch):
    ids = [
        p.getBodyUniqueId(i, physicsClientId=client) for i in range(p.getNumBodies(physicsClientId=client))
    ]
    for b in ids:
        p.removeBody(b, physicsClientId=client)
    n, q = wall_at(client, d, yaw=wall_yaw)
    small = dataclasses.replace(MODELS["kinect2"], name="small", width=64, height=53)
    k = KinectSim(client, small, noise=False)
    pose = cam_pose(yaw=cam_yaw, pitch=cam_pitch)
    world = k.to_world(k.capture(pose).points.astype(float), pose).reshape(-1, 3)
    world = world[np.isfinite(world[:, 0])]
    assert len(world) > 0
    assert np.max(np.abs((world - q) @ n)) < 1e-4
    # every valid point is within the model's depth range along the optical axis
    depth = (world - pose_matrix(pose)[:3, 3]) @ pose_matrix(pose)[:3, 0]
    assert depth.min() >= 0.5 - 1e-6 and depth.max() <= 4.5 + 1e-6


def test_lateral_noise_moves_a_depth_edge_as_the_kinect2_model_says(client):
    # a wall covering exactly the left half of the image (world y >= 0): columns 0..255 see it
    box(client, [0.05, 4.0, 8.0], [2.05, 4.0, 1.0])
    tall = dataclasses.replace(MODELS["kinect2"], name="tall", height=2120)  # more rows, same noise model
    k = KinectSim(client, tall, noise=True, rng=np.random.default_rng(11))
    valid = np.isfinite(k.capture(cam_pose()).points[..., 0])
    rows = slice(100, 2020)  # away from the top and bottom, where vertical jitter clips
    assert valid[rows, :246].all() and not valid[rows, 266:].any()  # 6 sigma either side
    # pixel k columns right of the edge takes the wall's depth iff rint(k + 1.6 n) <= 0,
    # i.e. n < (0.5 - k) / 1.6 with n standard normal (Fankhauser 2015: sigma_L = 1.6 px)
    n_rows = rows.stop - rows.start
    for offset in (1, 2, 3):
        expected = 0.5 * math.erfc(-((0.5 - offset) / 1.6) / math.sqrt(2))
        # each row is an independent Bernoulli draw: allow 4 binomial standard errors (a sigma_L
        # of 1.2 or 2.0 px instead of 1.6 misses offset 2 or 3 by more than that)
        tol = 4.0 * math.sqrt(expected * (1.0 - expected) / n_rows)
        assert valid[rows, 255 + offset].mean() == pytest.approx(expected, abs=tol)


def test_excluded_links_and_bodies_are_invisible_to_both_backends(client):
    wall_at(client, 3.0)
    near = box(client, [0.1, 3.0, 3.0], [1.5, 0.0, 1.0])
    # a two-link body: base low on the left, link 0 high on the right
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.1, 0.3, 0.3], physicsClientId=client)
    two = p.createMultiBody(
        0,
        col,
        -1,
        basePosition=[1.0, 0.5, 0.7],
        linkMasses=[0],
        linkCollisionShapeIndices=[col],
        linkVisualShapeIndices=[-1],
        linkPositions=[[0, -1.0, 0.6]],
        linkOrientations=[[0, 0, 0, 1]],
        linkInertialFramePositions=[[0, 0, 0]],
        linkInertialFrameOrientations=[[0, 0, 0, 1]],
        linkParentIndices=[0],
        linkJointTypes=[p.JOINT_FIXED],
        linkJointAxis=[[0, 0, 1]],
        physicsClientId=client,
    )
    m = MeshMirror(client, exclude_bodies=[near], exclude_links=[(two, 0)])
    cap = KinectSim(client, "kinect2", noise=False, mirror=m).capture_full(cam_pose())
    assert not np.any(cap.body == near)
    assert np.any((cap.body == two) & (cap.link == -1))
    assert not np.any((cap.body == two) & (cap.link == 0))
    assert np.nanmax(cap.frame.points[..., 0]) == pytest.approx(3.0, abs=1e-4)  # the wall behind shows
    pb = KinectSim(client, "kinect2", backend="pybullet", noise=False, exclude_bodies=[near]).capture_full(
        cam_pose()
    )
    assert not np.any(pb.body == near)
    assert np.any((pb.body == two) & (pb.link == 0))


def test_compiled_kernels_and_the_camera_module_share_constants_without_importing_each_other():
    import ast
    import inspect

    import sim._kinect_kernels as kernels

    tree = ast.parse(inspect.getsource(kernels))
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert "sim.kinect" not in imported
    assert "sim.kinect_params" in imported
