"""mapping.grid.voxel_filter: the first measured point of each voxel of a lattice, in input order."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapping.grid import voxel_filter


def _reference(points: np.ndarray, size: float, t: np.ndarray) -> np.ndarray:
    """The definition, one point at a time: voxel ``floor((R p + t) / size)`` per axis, the first finite
    point of each voxel kept, in input order."""
    seen: set[tuple[int, int, int]] = set()
    kept = []
    for p in points.reshape(-1, 3).astype(np.float64):
        if not np.isfinite(p).all():
            continue
        q = [p[0] * t[k, 0] + p[1] * t[k, 1] + p[2] * t[k, 2] + t[k, 3] for k in range(3)]
        key = tuple(math.floor(c * (1.0 / size)) for c in q)
        if key not in seen:
            seen.add(key)
            kept.append(p)
    return np.array(kept, dtype=np.float32).reshape(-1, 3)


def test_the_first_point_of_each_voxel_is_kept_on_the_lattice_of_the_given_frame():
    """By hand, 10 cm voxels: in the points' own frame the x voxels are 0, 0, 1, -, 0, -1 (the NaN point
    dropped): points 0, 2 and 5 stay. Shifted 4.5 cm along x into the lattice's frame they are
    0.055, 0.095, 0.165, -, 0.135, 0.035 m: voxels 0, 0, 1, -, 1, 0 (y and z in voxel 0): points 0 and 2
    stay, in their own coordinates."""
    pts = np.array([[0.01, 0.0, 0.0], [0.05, 0.02, 0.03], [0.12, 0.0, 0.0], [np.nan, 0.0, 0.0],
                    [0.09, 0.09, 0.09], [-0.01, 0.0, 0.0]])  # fmt: skip
    np.testing.assert_array_equal(voxel_filter(pts, 0.1), pts[[0, 2, 5]].astype(np.float32))
    shift = np.eye(4)
    shift[0, 3] = 0.045
    out = voxel_filter(pts, 0.1, shift)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, pts[[0, 2]].astype(np.float32))


def test_an_organised_depth_frame_with_holes_gives_the_points_of_the_definition():
    """A 60 x 80 float32 frame (a tilted plane 1-4 m away, 20 % NaN) through a rotated and shifted
    lattice at 5 cm: the kept points are those of the definition, computed point by point."""
    rng = np.random.default_rng(3)
    h, w = 60, 80
    v, u = np.mgrid[0:h, 0:w]
    depth = 1.0 + 3.0 * u / w + rng.normal(0.0, 0.01, (h, w))
    frame = np.stack([(u - w / 2) * depth / 300, (v - h / 2) * depth / 300, depth], axis=2).astype(np.float32)
    frame[rng.random((h, w)) < 0.2] = np.nan
    c, s = math.cos(0.7), math.sin(0.7)
    t = np.array([[c, 0.0, s, 0.31], [0.0, 1.0, 0.0, -0.12], [-s, 0.0, c, 1.07], [0.0, 0.0, 0.0, 1.0]])
    out = voxel_filter(frame, 0.05, t)
    expected = _reference(frame, 0.05, t)
    assert 100 < len(expected) < np.isfinite(frame).all(axis=2).sum()
    np.testing.assert_array_equal(out, expected)


@pytest.mark.parametrize("scale", [1.0, 1e6])
def test_points_near_and_very_far_from_the_origin_follow_the_same_definition(scale):
    """Random points in a box of side 2 * scale metres (1e6 m: voxel indices beyond 2**20, the kernel's
    packing, so the sorting path answers) and as integers: the definition's points either way."""
    rng = np.random.default_rng(5)
    pts = np.round(rng.uniform(-scale, scale, (3000, 3)) / 0.05) * 0.05 + 0.012
    pts[::7] = pts[::7] + 0.001  # repeats of a voxel, later in the input
    pts = np.concatenate([pts, pts[:500] + 0.002])
    np.testing.assert_array_equal(voxel_filter(pts, 0.05), _reference(pts, 0.05, np.eye(4)))
    ints = rng.integers(-50, 50, (2000, 3))
    np.testing.assert_array_equal(voxel_filter(ints, 10.0), _reference(ints.astype(float), 10.0, np.eye(4)))
