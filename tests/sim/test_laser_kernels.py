"""The simulated laser's compiled beam passes against the numpy path they replace, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robchair.platform.frames import se3_from_quat
from sim import _laser_kernels
from sim.laser import URG_04LX, LaserSim

p = pytest.importorskip("pybullet")


@pytest.fixture
def client():
    c = p.connect(p.DIRECT)
    yield c
    p.disconnect(physicsClientId=c)


def _room(c, rng):
    """A floor, walls at 0.5 - 3.5 m and small boxes very close (below range_min of some poses)."""

    def box(half, pos, yaw):
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=c)
        q = p.getQuaternionFromEuler([0, 0, yaw])
        p.createMultiBody(0, col, -1, basePosition=pos, baseOrientation=q, physicsClientId=c)

    box([20, 20, 0.01], [0, 0, -0.01], 0.0)
    for _ in range(12):
        r, a = rng.uniform(0.5, 3.5), rng.uniform(-math.pi, math.pi)
        box(
            [0.05, rng.uniform(0.2, 1.5), 1.0],
            [r * math.cos(a), r * math.sin(a), 1.0],
            rng.uniform(0, math.pi),
        )
    box([0.005, 0.05, 1.0], [0.015, 0.0, 1.0], 0.0)  # closer than range_min from the origin


def _poses(rng, n):
    out = []
    for _ in range(n):
        q = p.getQuaternionFromEuler(
            [rng.normal(0, 0.05), rng.normal(0, 0.05), rng.uniform(-math.pi, math.pi)]
        )
        out.append(se3_from_quat((rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(0.1, 0.5)), q))
    out.append(se3_from_quat((0.0, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0)))  # the close box in front
    return out


@pytest.mark.parametrize("noise", [True, False])
def test_the_compiled_laser_readings_are_the_numpy_ones_bit_for_bit(client, noise):
    rng = np.random.default_rng(4)
    _room(client, rng)
    laser = LaserSim(client, noise=noise, accuracy_sigmas=2.5)
    seen = {"inf": 0, "-inf": 0, "finite": 0}
    for t in _poses(rng, 60):
        a = laser.ranges(t, rng=np.random.default_rng(7))
        b = laser.ranges_reference(t, rng=np.random.default_rng(7))
        assert a.dtype == b.dtype == np.float32
        np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))
        # and as many draws: the generators stand at the same place afterwards
        g1, g2 = np.random.default_rng(7), np.random.default_rng(7)
        laser.ranges(t, rng=g1)
        laser.ranges_reference(t, rng=g2)
        assert g1.standard_normal() == g2.standard_normal()
        seen["inf"] += int(np.isposinf(a).sum())
        seen["-inf"] += int(np.isneginf(a).sum())
        seen["finite"] += int(np.isfinite(a).sum())
    assert min(seen.values()) > 0  # every kind of reading was compared


def test_the_compiled_ranges_of_hits_keep_misses_and_far_hits_out():
    rng = np.random.default_rng(2)
    t_hit = rng.uniform(0.0, 6.0, 500).astype(np.float32)
    t_hit[::7] = np.inf
    t_hit[1:5] = (4.0, np.nextafter(np.float32(4.0), np.float32(5.0)), np.float32(0.0), 0.02)  # the limits
    gid = rng.integers(0, 3, 500).astype(np.uint32)
    invalid = 2**32 - 1
    gid[::5] = invalid
    ref = t_hit.astype(np.float64)
    ref[(gid == invalid) | ~(ref <= 4.0)] = np.inf
    got, n = _laser_kernels.hit_ranges(t_hit, gid, invalid, 0.02, 4.0)
    np.testing.assert_array_equal(got, ref)
    assert (
        n == _laser_kernels.count_measured(ref, 0.02, 4.0) == int((ref >= 0.02).sum() - np.isinf(ref).sum())
    )


def test_a_pose_that_is_not_finite_is_refused_as_before(client):
    from sim.raycast import MeshMirrorError

    laser = LaserSim(client, noise=False)
    t = np.eye(4)
    t[0, 3] = np.nan
    with pytest.raises(MeshMirrorError, match="not finite"):
        laser.ranges(t)
    with pytest.raises(MeshMirrorError, match="not finite"):
        laser.ranges(((0.0, 0.0, np.inf), (0.0, 0.0, 0.0, 1.0)))


def test_the_laser_model_is_the_urg_04lx_the_kernels_read():
    r = np.array([np.inf, 0.01, 0.02, 0.5, 1.0, 1.0000001, 3.9999, 4.0])
    assert _laser_kernels.count_measured(r, URG_04LX.range_min, URG_04LX.range_max) == 6
    out = _laser_kernels.readings(r, None, URG_04LX, 3.0)
    np.testing.assert_array_equal(out, np.array([np.inf, -np.inf, 0.02, 0.5, 1.0, 1.0, 4.0, 4.0], np.float32))
