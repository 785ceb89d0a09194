"""Derived maps: 2D occupancy, 2.5D elevation, standard voxels, VHV boxes, free space, probability."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping import derived as D
from mapping.errors import MappingError
from mapping.grid import GridSpec
from mapping.synthetic import kinect_hd_like_cloud, small_sample_cloud
from mapping.vhv import VHVMap

SPEC = GridSpec(cell_size=0.05, size_x=1.0, size_y=1.0)
coord = st.floats(-0.55, 0.55, allow_nan=False)
height = st.one_of(st.sampled_from([0.0, 0.1, 0.5, 1.0]), st.floats(-0.5, 2.0, allow_nan=False))
clouds = st.lists(st.tuples(coord, coord, height), max_size=50).map(
    lambda p: np.array(p, float).reshape(-1, 3)
)


def table_map() -> VHVMap:
    """A table top (0.70-0.74 m) over one cell, a floor point in another, a tall post in a third."""
    m = VHVMap(SPEC, tolerance=0.05)
    m.insert(
        [
            [0.01, 0.01, 0.70],
            [0.02, 0.02, 0.74],
            [0.11, 0.01, 0.0],
            [-0.09, -0.09, 0.0],
            [-0.09, -0.09, 0.04],
            [-0.09, -0.09, 1.90],
        ]
    )
    return m


def test_occupancy_band_sees_the_table_top_but_not_the_floor() -> None:
    m = table_map()
    occ = D.occupancy_2d(m, 0.05, 1.6)
    assert occ.shape == (20, 20) and occ.dtype == bool
    assert sorted(zip(*np.nonzero(occ))) == [(10, 10)]
    assert sorted(zip(*np.nonzero(D.occupancy_2d(m, 0.0, 2.0)))) == [(8, 8), (10, 10), (12, 10)]
    # the band touches a structure exactly at its ends
    assert D.occupancy_2d(m, 0.74, 0.8)[10, 10] and D.occupancy_2d(m, 0.6, 0.70)[10, 10]
    assert not D.occupancy_2d(m, 0.76, 1.8)[10, 10]


def test_bad_band_is_refused() -> None:
    with pytest.raises(MappingError, match=r"band \[1\.0, 0\.5\]"):
        D.occupancy_2d(table_map(), 1.0, 0.5)


def test_elevation_holds_highest_top_and_lowest_bottom() -> None:
    top, bottom = D.elevation(table_map())
    assert top[10, 10] == 0.74 and bottom[10, 10] == 0.70
    assert top[8, 8] == 1.90 and bottom[8, 8] == 0.0
    assert np.isnan(top[0, 0]) and np.isnan(bottom[0, 0])
    assert np.count_nonzero(np.isfinite(top)) == 3


def test_voxels_of_a_hand_built_map() -> None:
    v = D.voxels(table_map())
    # (8,8): 0.0-0.04 -> k=0, 1.90 -> k=38 (1.90/0.05 = 37.99.. in floating point: check by formula)
    k_post = int(np.floor(1.90 * (1 / 0.05)))
    k_table = sorted({int(np.floor(0.70 * 20)), int(np.floor(0.74 * 20))})
    expected = (
        [(8, 8, 0), (8, 8, k_post)]
        + [(10, 10, k) for k in range(k_table[0], k_table[-1] + 1)]
        + [(12, 10, 0)]
    )
    assert [tuple(r) for r in v.tolist()] == expected
    centres = D.voxel_centres(table_map())
    np.testing.assert_allclose(centres[0], [-0.075, -0.075, 0.025])


def test_vhv_boxes_have_world_corners_for_every_axis() -> None:
    m = table_map()
    boxes = D.vhv_boxes(m)
    assert boxes.shape == (m.n_structures, 2, 3)
    s = m.structures()
    k = int(np.flatnonzero((s.i == 10) & (s.j == 10))[0])
    np.testing.assert_allclose(boxes[k], [[0.0, 0.0, 0.70], [0.05, 0.05, 0.74]])
    mx = VHVMap(GridSpec(cell_size=0.05, size_x=1.0, size_y=1.0, axis="x"), 0.05)
    mx.insert([[2.0, 0.01, 0.01], [2.03, 0.01, 0.02]])
    np.testing.assert_allclose(D.vhv_boxes(mx)[0], [[2.0, 0.0, 0.0], [2.03, 0.05, 0.05]])


@settings(max_examples=60, deadline=None)
@given(pts=clouds, z0=st.floats(-0.5, 2.0), dz=st.floats(0.0, 1.0))
def test_2d_and_25d_views_agree_with_the_structures(pts: np.ndarray, z0: float, dz: float) -> None:
    m = VHVMap(SPEC, 0.05)
    m.insert(pts)
    s = m.structures()
    occ = D.occupancy_2d(m, z0, z0 + dz)
    top, bottom = D.elevation(m)
    expected_occ = np.zeros(SPEC.shape, bool)
    exp_top = np.full(SPEC.shape, -np.inf)
    exp_bot = np.full(SPEC.shape, np.inf)
    for i, j, b, t in zip(s.i, s.j, s.bottom, s.top):
        expected_occ[i, j] |= bool(t >= z0 and b <= z0 + dz)
        exp_top[i, j] = max(exp_top[i, j], t)
        exp_bot[i, j] = min(exp_bot[i, j], b)
    np.testing.assert_array_equal(occ, expected_occ)
    np.testing.assert_array_equal(top, np.where(np.isinf(exp_top), np.nan, exp_top))
    np.testing.assert_array_equal(bottom, np.where(np.isinf(exp_bot), np.nan, exp_bot))
    # elevation from the raw points, independently of the clustering
    i, j = SPEC.world_to_index(pts[:, 0], pts[:, 1])
    ok = SPEC.contains_index(i, j)
    raw_top = np.full(SPEC.shape, -np.inf)
    np.maximum.at(raw_top, (i[ok], j[ok]), pts[ok, 2])
    np.testing.assert_array_equal(top, np.where(np.isinf(raw_top), np.nan, raw_top))
    # standard voxels: count matches, and every in-grid point lies in one of them
    v = D.voxels(m)
    assert v.shape[0] == m.n_voxels == len({tuple(r) for r in v.tolist()})
    vset = {tuple(r) for r in v.tolist()}
    for a, b, z in zip(i[ok].tolist(), j[ok].tolist(), pts[ok, 2].tolist()):
        assert (a, b, int(np.floor(z * SPEC.inv_cell_size))) in vset


def test_free_space_of_one_wall_cell_seen_from_the_side() -> None:
    # Sensor at the centre of cell (10, 10) (x = y = 0.025), 1 m high; a post from 0 to 1 m in cell
    # (14, 10), whose centre is at x = 0.225. The segment crosses the lines x = 0.05, 0.10, 0.15, 0.20 at
    # s = 0.125, 0.375, 0.625, 0.875; the passages through cells 10..13 have midpoints s = 0.0625, 0.25,
    # 0.5, 0.75. The bottom line goes from 1.0 down to 0.0 (height 1 - s), the top line stays at 1.0.
    m = VHVMap(SPEC, 0.06)
    m.insert([[0.226, 0.026, 0.05 * k] for k in range(21)], sensor_origin=(0.025, 0.025, 1.0))
    assert m.n_structures == 1
    free = D.free_space(m)
    assert free.i.tolist() == [10, 11, 12, 13] and free.j.tolist() == [10] * 4
    mids = np.array([0.0625, 0.25, 0.5, 0.75])
    np.testing.assert_allclose(free.bottom, 1.0 - mids, atol=1e-12)
    np.testing.assert_allclose(free.top, 1.0, atol=1e-12)
    np.testing.assert_allclose(free.middle, (free.bottom + free.top) / 2)
    # occupancy probability: the post's cell is occupied, the crossed cells free, the rest unknown
    p = D.occupancy_probability(m)
    assert p[14, 10] == 1.0 and np.all(p[10:14, 10] == 0.0)
    assert np.count_nonzero(np.isfinite(p)) == 5
    # the same post seen diagonally: cells along the diagonal, corners skipped
    m2 = VHVMap(SPEC, 0.06)
    m2.insert([[0.226, 0.226, 0.05 * k] for k in range(21)])
    free2 = D.free_space(m2, (0.025, 0.025, 1.0))
    assert list(zip(free2.i.tolist(), free2.j.tolist())) == [(10, 10), (11, 11), (12, 12), (13, 13)]


def test_free_space_is_between_the_sensor_and_the_obstacles() -> None:
    m = VHVMap(GridSpec(cell_size=0.05, size_x=12.0, size_y=12.0), 0.05)
    origin = (0.0, 0.0, 1.0)
    m.insert(kinect_hd_like_cloud(np.random.default_rng(1), 36, 64), sensor_origin=origin)
    free = D.free_space(m)
    raw = D.free_space(m, origin, merge=False)
    assert len(free) > 0 and len(raw) >= len(free)
    assert np.all(free.bottom <= free.top)
    # merged free structures are disjoint per cell
    key = free.i.astype(np.int64) * 240 + free.j
    same = key[1:] == key[:-1]
    assert np.all(free.bottom[1:][same] > free.top[:-1][same])
    # every raw free structure is inside a merged one
    for a, b, lo, hi in list(zip(raw.i, raw.j, raw.bottom, raw.top))[::97]:
        sel = (free.i == a) & (free.j == b)
        assert np.any((free.bottom[sel] <= lo) & (hi <= free.top[sel]))
    # free cells lie between the sensor (x = 0) and the farthest obstacle, never behind the sensor
    u, _ = m.spec.index_to_world(free.i, free.j)
    u_occ, _ = m.spec.index_to_world(m.structures().i, m.structures().j)
    assert u.min() >= 0.0 and u.max() < u_occ.max()
    p = D.occupancy_probability(m, free)
    assert np.nanmin(p) >= 0 and np.nanmax(p) <= 1
    si, sj = m.structures().i, m.structures().j
    assert np.all(np.isfinite(p[si, sj]))


def test_free_space_needs_a_sensor_origin() -> None:
    m = table_map()
    with pytest.raises(MappingError, match="no sensor_origin"):
        D.free_space(m)
    with pytest.raises(MappingError, match=r"sensor_origin=\(1, 2\)"):
        D.free_space(m, (1, 2))


def test_synthetic_clouds_are_deterministic_and_shaped_like_a_kinect_frame() -> None:
    a = kinect_hd_like_cloud(np.random.default_rng(7), 54, 96)
    b = kinect_hd_like_cloud(np.random.default_rng(7), 54, 96)
    assert a.shape == (54, 96, 3) and a.dtype == np.float32
    np.testing.assert_array_equal(a, b)
    nan_rows = np.isnan(a).any(axis=2)
    assert np.array_equal(nan_rows, np.isnan(a).all(axis=2))
    assert 0.07 < nan_rows.mean() < 0.13
    finite = a[~nan_rows]
    assert finite[:, 2].min() > -0.05 and finite[:, 2].max() < 2.65  # floor to ceiling
    s = small_sample_cloud(np.random.default_rng(0))
    assert 10_000 < s.shape[0] < 100_000 and np.isfinite(s).all()
    with pytest.raises(MappingError, match="nan_fraction"):
        kinect_hd_like_cloud(np.random.default_rng(0), 4, 4, nan_fraction=1.5)


def test_voxel_count_and_voxel_list_agree_at_a_bin_edge() -> None:
    # 0.7 / 0.1 = 6.999... but 0.7 * 10 = 7.0: both counts must use the same lattice index.
    m = VHVMap(GridSpec(cell_size=0.1, size_x=1.0, size_y=1.0), 0.05)
    m.insert(np.array([[0.25, 0.05, 0.70], [0.25, 0.05, 0.72]]))
    assert m.n_voxels == len(D.voxels(m)) == 1
