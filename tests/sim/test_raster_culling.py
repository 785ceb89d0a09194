"""The culled Kinect raster (:mod:`sim._raster_kernels`) gives, bit for bit, the z-buffer of drawing
every triangle in index order against every pixel of its box (:mod:`tests.sim.raster_reference`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim._raster_kernels import CHUNK_FACES, draw
from sim.kinect import MODELS
from tests.sim.raster_reference import draw_reference

p = pytest.importorskip("pybullet")

FAR = 6.75 * 1.5  # what sim.kinect passes: 1.5 x the Kinect v2's range


def _rays():
    rays = MODELS["kinect2"].intrinsics.rays()
    return np.ascontiguousarray(rays[0, :, 1]), np.ascontiguousarray(rays[:, 0, 2])


def _same(verts, faces, geom, t, far=FAR):
    ax, by = _rays()
    rot, org = np.ascontiguousarray(t[:3, :3]), np.ascontiguousarray(t[:3, 3])
    z0, f0, _ = draw_reference(verts, faces, rot, org, ax, by, far)
    z1, f1, _ = draw(verts, faces, geom, rot, org, ax, by, far)
    assert np.array_equal(z0, z1), f"{int((z0 != z1).sum())} depths differ"
    assert np.array_equal(f0, f1), f"{int((f0 != f1).sum())} triangles differ"
    return z1, f1


def _route_poses(chair, route, n):
    """n camera poses along the route's polyline from the start, heading along it with a yaw sway."""
    t0 = chair.kinect_pose()
    pts = np.array([(0.0, 0.0), *route.waypoints])
    seg = np.diff(pts, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    out = []
    for i in range(n):
        s = cum[-1] * i / n
        k = min(int(np.searchsorted(cum, s, side="right")) - 1, len(seg) - 1)
        xy = pts[k] + seg[k] * (s - cum[k]) / (cum[k + 1] - cum[k])
        yaw = math.atan2(seg[k, 1], seg[k, 0]) + 0.25 * math.sin(i / 7.0)
        t = t0.copy()
        t[:2, 3] += xy
        c, sn = math.cos(yaw), math.sin(yaw)
        t[:3, :3] = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]]) @ t0[:3, :3]
        out.append(t)
    return out


@pytest.fixture(scope="module")
def office():
    from sim.chair import SimChair
    from sim.scene import load_scenario

    sc = load_scenario("office_corridor")
    chair = SimChair(scene=sc.scene, start=sc.start, sensor="kinect2", sonars=False, seed=0)
    chair.mirror.sync()
    yield chair, sc.route
    chair.close()


def test_the_culled_raster_is_the_index_order_raster_along_the_office_route(office):
    chair, route = office
    m = chair.mirror
    assert m.tri_faces.shape[0] > 6000  # the bookcase, the seated person and the plant: many chunks
    looked_back = chair.kinect_pose()
    looked_back[:3, :3] = np.diag([-1.0, -1.0, 1.0]) @ looked_back[:3, :3]
    looked_back[:3, 3] += (8.0, -0.5, 0.0)  # from the room back through the doorway
    for t in [*_route_poses(chair, route, 40), looked_back]:
        z, _ = _same(m.tri_vertices, m.tri_faces, m.tri_geometry, t)
        assert np.isfinite(z).mean() > 0.3


def test_a_wall_in_front_culls_what_is_behind_it_and_keeps_the_pixels_exact():
    # 400 small triangles behind a wall that covers the image; a second wall behind, coplanar
    # triangles overlapping (exact depth ties: the lower index wins) and one reaching behind the camera
    rng = np.random.default_rng(11)
    tris = [((1.0, -5.0, -5.0), (1.0, 5.0, -5.0), (1.0, 0.0, 5.0))]  # the wall at x = 1 m
    for _ in range(400):
        c = rng.uniform((2.0, -2.0, -1.5), (6.0, 2.0, 1.5))
        tris.append(tuple(tuple(c + rng.normal(0.0, 0.08, 3)) for _ in range(3)))
    tris += [((3.0, -1.0, -1.0), (3.0, 1.0, -1.0), (3.0, 0.0, 1.0))] * 2  # coplanar duplicates
    tris.append(((-1.0, 0.5, -0.2), (4.0, 0.5, -0.2), (4.0, 0.5, 0.4)))  # starts behind the camera
    verts = np.array([v for tri in tris for v in tri], dtype=np.float64)
    faces = np.arange(len(verts), dtype=np.int64).reshape(-1, 3)
    geom = np.zeros(len(faces), dtype=np.int64)
    geom[1:] = 1 + np.arange(len(faces) - 1) // 50  # several geometries, chunks of each
    eye = np.eye(4)
    z, f = _same(verts, faces, geom, eye)
    assert np.isfinite(z).all()
    assert np.all((f == 0) | (f == len(faces) - 1))  # only the wall and the near triangle show
    # without the wall: the objects behind it show, and the duplicated triangle's lower index wins
    _, f = _same(verts[3:], faces[1:] - 3, geom[1:], eye)
    dup = len(faces) - 3 - 1  # index of the first duplicate in the reduced list
    assert np.any(f == dup)
    assert not np.any(f == dup + 1)


@pytest.mark.parametrize("seed", range(4))
def test_random_triangle_soups_give_the_index_order_raster(seed):
    # overlapping triangles of every size at every depth, some behind the camera or beyond the range,
    # seen from a random pose: the cull must never drop a triangle that shows or wins a tie
    rng = np.random.default_rng(seed)
    n = 3 * CHUNK_FACES + 7
    centres = rng.uniform((-1.0, -4.0, -3.0), (12.0, 4.0, 3.0), (n, 3))
    size = rng.choice([0.02, 0.3, 2.0], n)[:, None, None]
    verts = (centres[:, None, :] + size * rng.normal(size=(n, 3, 3))).reshape(-1, 3)
    faces = np.arange(3 * n, dtype=np.int64).reshape(-1, 3)
    geom = np.repeat(np.arange(n // 40 + 1), 40)[:n].astype(np.int64)
    t = np.eye(4)
    yaw, pitch = rng.uniform(-0.3, 0.3, 2)
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    r_yaw = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    t[:3, :3] = r_yaw @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    z, _ = _same(verts, faces, geom, t)
    assert np.isfinite(z).mean() > 0.5
    _same(verts, faces, np.zeros(0, dtype=np.int64), t, far=4.0)  # no geometry labels, a shorter range


def test_triangles_poking_through_a_tilted_wall_are_never_culled_where_they_show():
    # the cull's edge case: a wall covering the image (every tile bounded) drawn first, then small
    # triangles through it, half in front: each one's nearest depth lies just in front of the wall,
    # close to the tiles' bounds (an over-eager cull or a tile bound below the true maximum drops them)
    rng = np.random.default_rng(4)
    square = [((-9.0, -9.0), (9.0, -9.0), (9.0, 9.0)), ((-9.0, -9.0), (9.0, 9.0), (-9.0, 9.0))]
    wall = [tuple((2.0 + 0.3 * y, y, z) for (y, z) in tri) for tri in square]  # the plane x = 2 + 0.3 y
    tris = list(wall)
    for _ in range(6):  # clusters of one chunk each (their boxes stay small)
        y0, z0 = rng.uniform(-1.2, 1.2), rng.uniform(-1.0, 1.0)
        for _ in range(CHUNK_FACES):
            y, z = y0 + rng.uniform(-0.15, 0.15), z0 + rng.uniform(-0.15, 0.15)
            c = np.array([2.0 + 0.3 * y, y, z])
            tris.append(tuple(tuple(c + rng.normal(0.0, 0.03, 3)) for _ in range(3)))
    verts = np.array([v for tri in tris for v in tri], dtype=np.float64)
    faces = np.arange(len(verts), dtype=np.int64).reshape(-1, 3)
    z, f = _same(verts, faces, np.zeros(len(faces), dtype=np.int64), np.eye(4))
    assert np.isfinite(z).all()
    assert (f >= 2).mean() > 0.01  # the small triangles show


@pytest.mark.parametrize("seed", range(3))
def test_pixel_sized_triangles_and_slivers_of_the_decimated_frame_give_the_index_order_raster(seed):
    # the env's 128 x 106 frame, where a mesh's triangles span a pixel or two: boxes drawn within a
    # twentieth of a pixel of the projection must give what boxes a pixel wider give, also for
    # vertices lying exactly on pixel rays (a box bound on a pixel) and for slivers
    from sim.kinect_models import Intrinsics

    intr = Intrinsics.from_fov(128, 106, 70.6, 60.0)
    rays = intr.rays()
    ax, by = np.ascontiguousarray(rays[0, :, 1]), np.ascontiguousarray(rays[:, 0, 2])
    rng = np.random.default_rng(seed)
    n = 4 * CHUNK_FACES
    depth = rng.uniform(1.0, 6.0, n)
    u = rng.integers(0, 128, (n, 3)) + rng.choice([0.0, 0.5], (n, 3)) * rng.uniform(-3.0, 3.0, (n, 3))
    v = rng.integers(0, 106, (n, 3)) + rng.choice([0.0, 0.5], (n, 3)) * rng.uniform(-3.0, 3.0, (n, 3))
    u[:, 1:] = u[:, :1] + np.round(u[:, 1:] - u[:, :1]) * rng.choice([0.0, 1.0], (n, 2))  # on pixels
    sliver = rng.random(n) < 0.3
    u[sliver, 2] = u[sliver, 1] + 1e-7 * rng.normal(size=sliver.sum())
    v[sliver, 2] = v[sliver, 1] + rng.uniform(-4.0, 4.0, sliver.sum())
    # the ray of a (fractional) pixel index by the pinhole formulas: at a whole index, bit for bit the
    # pixel's ray
    ay, bz = intr._ray_y(u), intr._ray_z(v)
    assert np.array_equal(intr._ray_y(np.arange(128)), ax)
    d = depth[:, None] * rng.choice([1.0, 1.0, 1.02], (n, 3))
    verts = np.stack([d, d * ay, d * bz], axis=-1).reshape(-1, 3)
    faces = np.arange(3 * n, dtype=np.int64).reshape(-1, 3)
    geom = np.repeat(np.arange(n // 64), 64).astype(np.int64)
    ref_z, ref_f, _ = draw_reference(verts, faces, np.eye(3), np.zeros(3), ax, by, FAR)
    z, f, _ = draw(verts, faces, geom, np.eye(3), np.zeros(3), ax, by, FAR)
    assert np.array_equal(ref_z, z), f"{int((ref_z != z).sum())} depths differ"
    assert np.array_equal(ref_f, f), f"{int((ref_f != f).sum())} triangles differ"
    assert np.isfinite(z).mean() > 0.2


def test_a_collinear_triangles_hit_beside_its_span_is_kept_when_a_wall_bounds_the_tiles_of_its_span():
    # three collinear vertices (zero area; the ray of pixel (111, 7) lies in their plane, a pixel above
    # their span, and passes the edge tests by rounding), behind a wall covering rows 8 and below: the
    # chunk's box must hold the triangle's whole-pixel box, or the wall's tiles cull the chunk there
    from sim.kinect_models import Intrinsics

    rays = Intrinsics.from_fov(128, 106, 70.6, 60.0).rays()
    ax, by = np.ascontiguousarray(rays[0, :, 1]), np.ascontiguousarray(rays[:, 0, 2])
    line = [
        ("0x1.681825acc4536p+0", "-0x1.7a752d7c89e06p-1", "-0x1.bce963ed3af21p-2"),
        ("0x1.681825acc4536p+0", "-0x1.7a752d7c89e06p-1", "-0x1.95794890d77f1p-1"),
        ("0x1.681825acc4536p+0", "-0x1.7a752d7c89e06p-1", "0x1.5cb48ef6c20eep-1"),
    ]
    b = 0.5 * (by[7] + by[8])
    wall = [(1.0, 9.0, b), (1.0, -9.0, b), (1.0, 0.0, -9.0)]
    verts = np.array(wall + [tuple(float.fromhex(c) for c in p) for p in line])
    faces = np.arange(6, dtype=np.int64).reshape(2, 3)
    ref_z, ref_f, _ = draw_reference(verts, faces, np.eye(3), np.zeros(3), ax, by, FAR)
    assert ref_f[7, 111] == 1 and (ref_f[8:] == 0).all()  # the construction: the hit, and the wall
    z, f, _ = draw(verts, faces, np.array([0, 1], dtype=np.int64), np.eye(3), np.zeros(3), ax, by, FAR)
    assert np.array_equal(ref_z, z) and np.array_equal(ref_f, f)
