"""The laser's plane-cut caster (:mod:`sim._laser_raster`) against Embree on the office scene's triangles.

Embree (an independent caster, in float32) and the plane cut (float64) must see the same world: every
beam hits or misses alike, and the ranges agree to Embree's float32 rounding (about 2.4e-7 relative,
1e-6 m at the 4 m range). Poses are random over the office floor, many inside furniture or facing walls
edge-on, with the chair's pitch and roll of a bump so the scan plane is not horizontal.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from robchair.platform.frames import se3_rpy
from robchair.platform.paths import SCENES
from sim._laser_raster import planar_first_hits
from sim.chair import SimChair
from sim.laser import LaserSim
from sim.scene import load_scene

pytest.importorskip("pybullet")


@pytest.fixture(scope="module")
def office():
    chair = SimChair(scene=load_scene(SCENES / "office.toml"), sensor=None, sonars=False, seed=0)
    yield chair
    chair.close()


def _pose(rng: np.random.Generator) -> np.ndarray:
    x, y, yaw = rng.uniform(-4, 4), rng.uniform(-4, 4), rng.uniform(-math.pi, math.pi)
    roll, pitch = rng.normal(0, 0.03, 2)
    return se3_rpy((x, y, rng.uniform(0.1, 1.2)), (roll, pitch, yaw))


def test_the_plane_cut_sees_what_embree_sees_on_the_office_floor(office) -> None:
    raster = LaserSim(office.world.client, mirror=office.mirror, caster="raster", noise=False)
    embree = LaserSim(office.world.client, mirror=office.mirror, caster="embree", noise=False)
    rng = np.random.default_rng(7)
    hits = 0
    for _ in range(150):
        t = _pose(rng)
        a, b = embree.true_ranges(t), raster.true_ranges(t)
        fa, fb = np.isfinite(a), np.isfinite(b)
        assert np.array_equal(fa, fb)
        np.testing.assert_allclose(b[fb], a[fa], rtol=0, atol=2e-5)
        hits += int(fa.sum())
    assert hits > 150 * 682 // 4  # the poses see walls and furniture, not an empty floor


def test_a_triangle_across_the_plane_is_hit_on_the_beams_its_cut_covers() -> None:
    """One vertical triangle 2 m ahead spanning y in [-1, 1] at the scan height: hand computation."""
    verts = np.array([[2.0, -1.0, -1.0], [2.0, 1.0, -1.0], [2.0, 0.0, 3.0]])
    faces = np.array([[0, 1, 2]], dtype=np.int64)
    a = np.radians(np.arange(-90.0, 90.5, 0.5))
    r = planar_first_hits(
        verts, faces, np.eye(3), np.zeros(3), a[0], math.radians(0.5), np.cos(a), np.sin(a), 4.0
    )
    # at z = 0 the triangle spans y in [-0.75, 0.75] at x = 2
    inside = np.abs(np.tan(a)) * 2.0 <= 0.75 - 1e-9
    np.testing.assert_allclose(r[inside], 2.0 / np.cos(a[inside]), rtol=1e-12)
    outside = np.abs(np.tan(a)) * 2.0 > 0.75 + 1e-9
    assert np.isinf(r[outside]).all()
    # beyond the range: nothing
    far = planar_first_hits(
        verts * 3, faces, np.eye(3), np.zeros(3), a[0], math.radians(0.5), np.cos(a), np.sin(a), 4.0
    )
    assert np.isinf(far).all()
    # beams all around from 0 rad: the cut's arc [-20.6, 20.6] deg wraps past the first beam
    b = np.radians(np.arange(0.0, 360.0, 0.5))
    ahead = planar_first_hits(
        verts, faces, np.eye(3), np.zeros(3), 0.0, math.radians(0.5), np.cos(b), np.sin(b), 4.0
    )
    seen = (np.abs(np.tan(b)) * 2.0 <= 0.75 - 1e-9) & (np.cos(b) > 0)
    assert seen[0] and seen[-1]  # both ends of the fan see it
    np.testing.assert_allclose(ahead[seen], 2.0 / np.cos(b[seen]), rtol=1e-12)
    assert np.isinf(ahead[np.cos(b) < 0.9]).all()


def test_a_vertex_on_the_scan_plane_cuts_the_triangle_from_that_vertex() -> None:
    """The triangle's second vertex lies in the plane; the cut runs from it to the crossing of the
    opposite edge: y in [-1, 1] at x = 2 (hand computation)."""
    verts = np.array([[2.0, 1.0, -1.0], [2.0, -1.0, 0.0], [2.0, 1.0, 1.0]])
    faces = np.array([[0, 1, 2]], dtype=np.int64)
    a = np.radians(np.arange(-60.0, 60.5, 0.5))
    r = planar_first_hits(
        verts, faces, np.eye(3), np.zeros(3), a[0], math.radians(0.5), np.cos(a), np.sin(a), 4.0
    )
    inside = np.abs(np.tan(a)) * 2.0 <= 1.0 - 1e-9
    np.testing.assert_allclose(r[inside], 2.0 / np.cos(a[inside]), rtol=1e-12)
    assert np.isinf(r[np.abs(np.tan(a)) * 2.0 > 1.0 + 1e-9]).all()


def test_a_laser_scan_needs_no_open3d() -> None:
    """The mirror makes its Embree scene only for an Embree query: a chair with only the laser (the
    plane cut) never imports Open3D, which costs each process about a second."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from robchair.platform.paths import SCENES\n"
        "from sim.chair import SimChair\n"
        "c = SimChair(scene=SCENES / 'office.toml', sensor=None, sonars=False, laser=True)\n"
        "c.laser.open()\n"
        "scan = c.laser.read()\n"
        "assert (scan.ranges > 0).sum() > 100, scan.ranges\n"
        "print('open3d' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "False"


def test_skipping_chunks_off_the_plane_or_out_of_range_changes_no_beam(office) -> None:
    """The chunked cut (the chair's) against cutting every triangle: bit for bit over office poses."""
    from sim._laser_raster import planar_first_hits_chunked
    from sim._sonar_raster import mesh_chunks

    mirror = LaserSim(office.world.client, noise=False).mirror  # the office's triangles, the chair left out
    mirror.sync()
    chunks, bounds = mesh_chunks(mirror.tri_vertices, mirror.tri_faces, mirror.tri_geometry)
    a = np.radians(np.arange(-120.0, 120.0, 0.35))
    rng = np.random.default_rng(11)
    culled = 0
    for _ in range(100):
        t = _pose(rng)
        rot, o = np.ascontiguousarray(t[:3, :3]), np.ascontiguousarray(t[:3, 3])
        args = (a[0], math.radians(0.35), np.cos(a), np.sin(a), 4.0)
        flat = planar_first_hits(mirror.tri_vertices, mirror.tri_faces, rot, o, *args)
        fast = planar_first_hits_chunked(mirror.tri_vertices, mirror.tri_faces, chunks, bounds, rot, o, *args)
        assert np.array_equal(flat, fast)
        culled += int(np.isfinite(flat).sum())
    assert culled > 100 * len(a) // 4  # the poses see things
