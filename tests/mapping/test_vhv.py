"""VHVMap: hand-computed examples, an independent slow reference, and the map's invariants."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mapping.errors import MappingError, PointsError
from mapping.grid import GridSpec
from mapping.vhv import InsertStats, Structures, VHVMap
from tests.mapping.vhv_cases import METHODS, SPEC, as_tuples, chunked_edge_clouds


def reference_structures(
    points: np.ndarray, spec: GridSpec, tol: float
) -> list[tuple[int, int, float, float]]:
    """Thesis pipeline in plain Python: index -> sort -> unique -> cluster (4.2.4). Tiny inputs only."""
    cu, cv, ch = spec.columns
    (ou, ov), (nx, ny) = spec.origin, spec.shape
    ics = 1.0 / spec.cell_size
    cells: dict[tuple[int, int], list[float]] = defaultdict(list)
    for p in np.asarray(points).reshape(-1, 3).tolist():
        if not all(math.isfinite(c) for c in p):
            continue
        fu, fv = p[cu] * ics, p[cv] * ics
        if not (math.isfinite(fu) and math.isfinite(fv)):  # |coordinate| near 1.8e308: off any grid
            continue
        i = math.floor(fu) - ou
        j = math.floor(fv) - ov
        if 0 <= i < nx and 0 <= j < ny:
            cells[(i, j)].append(p[ch])
    out = []
    for (i, j), hs in sorted(cells.items()):
        zs = sorted(set(hs))
        bottom = top = zs[0]
        for z in zs[1:]:
            if z - top <= tol:
                top = z
            else:
                out.append((i, j, bottom, top))
                bottom = top = z
        out.append((i, j, bottom, top))
    return out


# Coordinates with many exact collisions, cell edges and gaps of exactly `tolerance`.
special = st.sampled_from(
    [0.0, 0.05, 0.1, -0.05, 0.02, 0.04, 0.07, 0.15, 0.2, -0.5, 0.49, 0.5, 1e-9, 1.5e308, -1.5e308]
)
coord = st.one_of(special, st.floats(-0.6, 0.6, allow_nan=False, width=64))
height = st.one_of(special, st.floats(-1.0, 2.0, allow_nan=False))
point = st.tuples(coord, coord, height)
clouds = st.lists(point, min_size=0, max_size=60).map(
    lambda ps: np.array(ps, dtype=np.float64).reshape(-1, 3)
)
tolerances = st.sampled_from([0.05, 0.02, 0.1, 0.3])


# ---------------------------------------------------------------------- hand-computed examples
@pytest.mark.parametrize("method", METHODS)
def test_gap_larger_than_tolerance_starts_a_new_structure(method: str) -> None:
    m = VHVMap(SPEC, tolerance=0.05)
    pts = [[0.01, 0.01, z] for z in (0.0, 0.02, 0.04, 0.2)]
    stats = m.insert(pts, method=method)
    s = m.structures()
    assert stats.points_inserted == 4 and stats.frame_structures == 2
    assert s.i.tolist() == [10, 10] and s.j.tolist() == [10, 10]
    assert s.bottom.tolist() == [0.0, 0.2]
    assert s.top.tolist() == [0.04, 0.2]
    assert s.middle.tolist() == [0.02, 0.2]


@pytest.mark.parametrize("method", METHODS)
def test_gap_equal_to_tolerance_keeps_one_structure(method: str) -> None:
    m = VHVMap(GridSpec(cell_size=1.0, size_x=2.0, size_y=2.0), tolerance=0.5)
    m.insert([[0.5, 0.5, 0.0], [0.5, 0.5, 0.5], [0.5, 0.5, 1.0], [0.5, 0.5, 1.75]], method=method)
    assert as_tuples(m.structures()) == [(1, 1, 0.0, 1.0), (1, 1, 1.75, 1.75)]


@pytest.mark.parametrize("method", METHODS)
def test_duplicates_and_separate_cells_are_handled_like_the_thesis(method: str) -> None:
    m = VHVMap(SPEC, tolerance=0.05)
    pts = [
        [0.01, 0.01, 1.0],
        [0.02, 0.03, 1.0],  # same cell, duplicate height
        [0.06, 0.01, 1.0],  # next cell in x
        [-0.01, 0.01, 0.3],  # previous cell in x
        [0.01, 0.01, 1.06],  # gap 0.06 > 0.05
    ]
    m.insert(pts, method=method)
    assert as_tuples(m.structures()) == [
        (9, 10, 0.3, 0.3),
        (10, 10, 1.0, 1.0),
        (10, 10, 1.06, 1.06),
        (11, 10, 1.0, 1.0),
    ]
    assert m.n_structures == 4 and m.n_cells_occupied == 3
    assert as_tuples(m.structures_at(0.049, 0.001)) == [(10, 10, 1.0, 1.0), (10, 10, 1.06, 1.06)]
    assert as_tuples(m.structures_in_cell(11, 10)) == [(11, 10, 1.0, 1.0)]
    assert len(m.structures_at(5.0, 5.0)) == 0


def test_standard_voxel_count_of_a_hand_built_map() -> None:
    # Binary-exact values so that the gaps are exactly what they read.
    m = VHVMap(GridSpec(cell_size=0.25, size_x=1.0, size_y=1.0), tolerance=0.0625)
    # cell A: one structure 0.0 .. 0.625 -> voxels k = 0, 1, 2; cell B: 0.78125 and 0.84375 (gap 0.0625
    # joins) and 0.9375 (gap 0.09375: new structure) -> both structures in voxel k = 3, counted once.
    pts = [[0.1, 0.1, z] for z in np.arange(0.0, 0.6251, 0.0625)]
    pts += [[0.3, 0.1, z] for z in (0.78125, 0.84375, 0.9375)]
    m.insert(np.array(pts))
    assert as_tuples(m.structures()) == [(2, 2, 0.0, 0.625), (3, 2, 0.78125, 0.84375), (3, 2, 0.9375, 0.9375)]
    assert m.n_voxels == 3 + 1


def test_bbox_spans_cell_edges_and_heights() -> None:
    m = VHVMap(SPEC, tolerance=0.05)
    assert m.bbox() is None
    m.insert([[0.01, 0.01, 0.2], [-0.07, 0.12, -0.1]])
    lo, hi = m.bbox()  # type: ignore[misc]
    np.testing.assert_allclose(lo, [-0.1, 0.0, -0.1])
    np.testing.assert_allclose(hi, [0.05, 0.15, 0.2])


# ---------------------------------------------------------------------- bad and odd input
@pytest.mark.parametrize("method", METHODS)
def test_nonfinite_and_out_of_grid_points_are_dropped_and_counted(method: str) -> None:
    m = VHVMap(SPEC, tolerance=0.05)
    pts = np.array(
        [
            [0.0, 0.0, 0.0],
            [np.nan, 0.0, 0.0],
            [0.0, np.inf, 0.0],
            [0.0, 0.0, -np.inf],
            [0.6, 0.0, 0.0],  # outside (grid spans [-0.5, 0.5))
            [0.0, -0.51, 0.0],
            [0.0, 0.0, 1e300],  # finite: kept
            [1e308, 0.0, 0.0],  # finite, far outside (u * (1 / cell_size) overflows to inf)
            [0.0, 0.0, -1.7e308],  # finite: kept (h * (1 / bin width) overflows to -inf)
        ]
    )
    stats = m.insert(pts, method=method)
    assert (
        stats.points_in,
        stats.points_dropped_nonfinite,
        stats.points_outside_grid,
        stats.points_inserted,
    ) == (
        9,
        3,
        3,
        3,
    )
    assert as_tuples(m.structures()) == [
        (10, 10, -1.7e308, -1.7e308),
        (10, 10, 0.0, 0.0),
        (10, 10, 1e300, 1e300),
    ]
    assert (m.points_dropped_nonfinite, m.points_outside_grid, m.points_inserted) == (3, 3, 3)


@pytest.mark.parametrize("method", METHODS)
def test_empty_and_all_nan_clouds_give_an_empty_map(method: str) -> None:
    m = VHVMap(SPEC)
    stats = m.insert(np.empty((0, 3)), method=method)
    assert isinstance(stats, InsertStats) and stats.points_in == 0 and m.n_structures == 0
    stats = m.insert(np.full((4, 5, 3), np.nan, np.float32), method=method)
    assert stats.points_in == 20 and stats.points_dropped_nonfinite == 20 and stats.points_inserted == 0
    assert m.n_structures == 0 and m.n_cells_occupied == 0 and m.n_voxels == 0
    assert len(m.structures()) == 0


def test_empty_cloud_counts_nothing() -> None:
    m = VHVMap(SPEC)
    stats = m.insert(np.empty((0, 3)))
    assert (stats.points_in, stats.points_inserted, stats.frame_structures) == (0, 0, 0)
    assert m.n_structures == 0


@pytest.mark.parametrize(
    ("points", "match"),
    [
        (np.zeros((4, 2)), r"expected shape \(N, 3\) or \(H, W, 3\), got \(4, 2\)"),
        (np.zeros((2, 2, 2, 3)), r"got \(2, 2, 2, 3\)"),
        (np.array(["a", "b", "c"]), r"expected real numbers, got dtype <U1"),
        (np.zeros((3, 3), dtype=bool), r"dtype bool"),
        (np.zeros((3, 3), dtype=complex), r"dtype complex128"),
    ],
)
def test_malformed_point_arrays_are_refused(points: np.ndarray, match: str) -> None:
    with pytest.raises(PointsError, match=match):
        VHVMap(SPEC).insert(points)


def test_bad_tolerance_method_and_origin_are_refused() -> None:
    with pytest.raises(MappingError, match=r"tolerance=0\.0.*> 0"):
        VHVMap(SPEC, tolerance=0.0)
    with pytest.raises(MappingError, match=r"tolerance=nan"):
        VHVMap(SPEC, tolerance=math.nan)
    with pytest.raises(MappingError, match=r"expected a mapping\.grid\.GridSpec"):
        VHVMap("grid")  # type: ignore[arg-type]
    with pytest.raises(MappingError, match=r"method='fast'"):
        VHVMap(SPEC).insert([[0, 0, 0]], method="fast")  # type: ignore[arg-type]
    with pytest.raises(MappingError, match=r"sensor_origin=\(0, 0\)"):
        VHVMap(SPEC).insert([[0, 0, 0]], sensor_origin=(0, 0))


def test_integer_points_are_accepted_as_metres() -> None:
    m = VHVMap(GridSpec(cell_size=1.0, size_x=4.0, size_y=4.0))
    m.insert(np.array([[0, 0, 1], [0, 0, 3]], dtype=np.int16))
    assert as_tuples(m.structures()) == [(2, 2, 1.0, 1.0), (2, 2, 3.0, 3.0)]


def test_organized_cloud_equals_its_flattened_points() -> None:
    rng = np.random.default_rng(3)
    cloud = rng.uniform(-0.5, 0.5, (12, 16, 3)).astype(np.float32)
    cloud[rng.random((12, 16)) < 0.2] = np.nan
    a, b = VHVMap(SPEC), VHVMap(SPEC)
    sa = a.insert(cloud)
    sb = b.insert(cloud.reshape(-1, 3))
    assert a.structures().equals(b.structures())
    assert sa.points_dropped_nonfinite == sb.points_dropped_nonfinite == int(np.isnan(cloud[..., 0]).sum())


def test_float32_and_float64_copies_of_a_cloud_give_the_same_map() -> None:
    rng = np.random.default_rng(5)
    p32 = rng.uniform(-0.5, 0.5, (500, 3)).astype(np.float32)
    a, b = VHVMap(SPEC), VHVMap(SPEC)
    a.insert(p32)
    b.insert(p32.astype(np.float64))
    assert a.structures().equals(b.structures())


# ---------------------------------------------------------------------- properties
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(pts=clouds, tol=tolerances, method=st.sampled_from(METHODS))
def test_fast_paths_equal_the_slow_reference(pts: np.ndarray, tol: float, method: str) -> None:
    m = VHVMap(SPEC, tolerance=tol)
    m.insert(pts, method=method)
    assert as_tuples(m.structures()) == reference_structures(pts, SPEC, tol)


@settings(max_examples=100, deadline=None)
@given(pts=clouds, tol=tolerances)
def test_every_finite_in_grid_point_lies_in_exactly_one_structure_of_its_cell(
    pts: np.ndarray, tol: float
) -> None:
    m = VHVMap(SPEC, tolerance=tol)
    m.insert(pts)
    s = m.structures()
    i, j = SPEC.world_to_index(pts[:, 0], pts[:, 1])
    for pi, pj, z in zip(i.tolist(), j.tolist(), pts[:, 2].tolist()):
        if not SPEC.contains_index(pi, pj):
            continue
        n_containing = np.count_nonzero((s.i == pi) & (s.j == pj) & (s.bottom <= z) & (z <= s.top))
        assert n_containing == 1


@settings(max_examples=100, deadline=None)
@given(pts=clouds, tol=tolerances)
def test_structures_are_sorted_disjoint_separated_and_ordered(pts: np.ndarray, tol: float) -> None:
    m = VHVMap(SPEC, tolerance=tol)
    m.insert(pts)
    s = m.structures()
    assert np.all(s.bottom <= s.middle) and np.all(s.middle <= s.top)
    key = s.i.astype(np.int64) * SPEC.shape[1] + s.j
    assert np.all(np.diff(key) >= 0)
    same = key[1:] == key[:-1]
    assert np.all(s.bottom[1:][same] > s.top[:-1][same])
    assert np.all(s.bottom[1:][same] - s.top[:-1][same] > tol)
    assert m.n_cells_occupied == len(set(key.tolist()))


@settings(max_examples=100, deadline=None)
@given(pts=clouds, tol=tolerances, seed=st.integers(0, 2**32 - 1))
def test_result_does_not_depend_on_point_order(pts: np.ndarray, tol: float, seed: int) -> None:
    perm = np.random.default_rng(seed).permutation(pts.shape[0])
    a, b = VHVMap(SPEC, tol), VHVMap(SPEC, tol)
    a.insert(pts)
    b.insert(pts[perm])
    assert a.structures().equals(b.structures())


@settings(max_examples=150, deadline=None)
@given(pts=clouds, tol=tolerances, data=st.data(), method=st.sampled_from(METHODS))
def test_inserting_a_cloud_in_two_halves_equals_inserting_it_at_once(
    pts: np.ndarray, tol: float, data: st.DataObject, method: str
) -> None:
    cut = data.draw(st.integers(0, pts.shape[0]))
    whole, halves = VHVMap(SPEC, tol), VHVMap(SPEC, tol)
    whole.insert(pts, method=method)
    halves.insert(pts[:cut], method=method)
    halves.insert(pts[cut:], method=method)
    assert halves.structures().equals(whole.structures())
    assert halves.points_inserted == whole.points_inserted


@settings(max_examples=40, deadline=None)
@given(pts=clouds, tol=tolerances, n_parts=st.integers(2, 6))
def test_many_frames_equal_one_frame(pts: np.ndarray, tol: float, n_parts: int) -> None:
    whole, parts = VHVMap(SPEC, tol), VHVMap(SPEC, tol)
    whole.insert(pts)
    for part in np.array_split(pts, n_parts):
        parts.insert(part)
    assert parts.structures().equals(whole.structures())
    assert parts.frames == n_parts


@pytest.mark.parametrize("axis", ["x", "y"])
@settings(max_examples=40, deadline=None)
@given(pts=clouds, tol=tolerances)
def test_kept_axis_x_and_y_equal_axis_z_on_permuted_columns(axis: str, pts: np.ndarray, tol: float) -> None:
    spec_axis = GridSpec(cell_size=0.05, size_x=1.0, size_y=1.0, axis=axis)  # type: ignore[arg-type]
    a, b = VHVMap(spec_axis, tol), VHVMap(SPEC, tol)
    a.insert(pts)
    b.insert(pts[:, list(spec_axis.columns)])
    assert a.structures().equals(b.structures())


def test_a_wall_keeps_its_depth_with_kept_axis_x() -> None:
    # A wall at x in {2.00, 2.01} facing the sensor, points on a 1 cm lattice in y and z.
    y, z = np.meshgrid(np.arange(-0.2, 0.2, 0.01), np.arange(0.0, 0.4, 0.01))
    wall = np.concatenate(
        [
            np.stack([np.full(y.size, 2.0), y.ravel(), z.ravel()], 1),
            np.stack([np.full(y.size, 2.01), y.ravel(), z.ravel()], 1),
        ]
    )
    m = VHVMap(
        GridSpec(cell_size=0.05, size_x=1.0, size_y=1.0, centre=(0.0, 0.25), axis="x"), tolerance=0.005
    )
    m.insert(wall)
    s = m.structures()
    assert m.n_cells_occupied == 8 * 8
    # the gap 0.01 > tolerance: two structures per cell, exactly the two depths
    assert m.n_structures == 2 * 64
    assert set(s.bottom.tolist()) == {2.0, 2.01} and np.array_equal(s.bottom, s.top)


def test_sample_box_misses_outliers_and_the_result_stays_exact() -> None:
    # The sampled points (every 8th, hence every 32nd) sit in one cell; the others spread over the grid
    # and far up, so they overflow the guessed box: first a few thousand (overflow list), then very
    # many (exact re-selection of the points outside the box).
    rng = np.random.default_rng(11)
    for n in (4096, 40_000):
        pts = rng.uniform(-0.5, 0.5, (n, 3))
        pts[:, 2] = rng.choice([0.0, 0.3, 5.0, -7.0, 100.0], n) + rng.uniform(0, 0.01, n)
        pts[::8] = [0.01, 0.01, 0.5]
        if n == 4096:
            pts[1::2] = [0.01, 0.01, 0.5]
            pts[3::64] = [0.3, -0.2, 250.0]
            pts[5::64, 2] = np.nan  # in-grid points with a non-finite height overflow too
        m = VHVMap(SPEC, 0.05)
        stats = m.insert(pts, method="bins")
        assert as_tuples(m.structures()) == reference_structures(pts, SPEC, 0.05)
        assert stats.points_dropped_nonfinite == int(np.isnan(pts).any(axis=1).sum())


@pytest.mark.parametrize(
    ("axis", "dtype"), [("z", np.float32), ("z", np.float64), ("x", np.float32), ("y", np.float64)]
)
def test_binning_over_several_chunks_equals_the_slow_reference_on_edge_cases(axis: str, dtype: type) -> None:
    """The compiled bins path against the plain-Python thesis pipeline (index, sort, unique, cluster),
    and its counts against the hand count of non-finite rows and finite rows off the grid."""
    spec = GridSpec(cell_size=0.05, size_x=1.0, size_y=1.0, centre=(0.0, 0.0), axis=axis)
    cu, cv, _ = spec.columns
    for name, cloud in chunked_edge_clouds():
        pts = cloud.astype(dtype)
        m = VHVMap(spec, 0.05)
        stats = m.insert(pts, method="bins")
        assert stats.method == "bins", name
        assert as_tuples(m.structures()) == reference_structures(pts, spec, 0.05), name
        f = pts.astype(np.float64)
        finite = np.isfinite(f).all(axis=1)
        inside = (f[:, cu] >= -0.5) & (f[:, cu] < 0.5) & (f[:, cv] >= -0.5) & (f[:, cv] < 0.5)
        assert stats.points_dropped_nonfinite == int((~finite).sum()), name
        assert stats.points_outside_grid == int((finite & ~inside).sum()), name
        sorted_map = VHVMap(spec, 0.05)
        sorted_map.insert(pts, method="sort")
        assert m.structures().equals(sorted_map.structures()), name


def test_from_structures_rebuilds_the_same_map() -> None:
    rng = np.random.default_rng(2)
    m = VHVMap(SPEC, 0.05)
    m.insert(rng.uniform(-0.5, 0.5, (300, 3)))
    s = m.structures()
    perm = rng.permutation(len(s))
    back = VHVMap.from_structures(
        SPEC, 0.05, Structures.from_bounds(s.i[perm], s.j[perm], s.bottom[perm], s.top[perm])
    )
    assert back.structures().equals(s)
    with pytest.raises(MappingError, match="outside the grid"):
        VHVMap.from_structures(SPEC, 0.05, Structures.from_bounds([99], [0], [0.0], [1.0]))
    with pytest.raises(MappingError, match="bottom <= top"):
        VHVMap.from_structures(SPEC, 0.05, Structures.from_bounds([1], [0], [2.0], [1.0]))


def test_structures_are_read_only() -> None:
    m = VHVMap(SPEC)
    m.insert([[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="read-only"):
        m.structures().top[0] = 1.0


def test_synthetic_hd_frame_gives_the_same_map_on_every_path() -> None:
    from mapping.synthetic import kinect_hd_like_cloud

    cloud = kinect_hd_like_cloud(np.random.default_rng(0), height=108, width=192)
    spec = GridSpec(cell_size=0.05, size_x=12.0, size_y=12.0)
    maps = {}
    for method in METHODS:
        maps[method] = VHVMap(spec, 0.05)
        stats = maps[method].insert(cloud, sensor_origin=(0, 0, 1), method=method)
        assert (
            stats.points_inserted + stats.points_dropped_nonfinite + stats.points_outside_grid
            == cloud.shape[0] * cloud.shape[1]
        )
    for method in METHODS[1:]:
        assert maps[method].structures().equals(maps["auto"].structures())
    assert maps["auto"].n_structures < maps["auto"].n_voxels


@settings(max_examples=30, deadline=None)
@given(
    pts=st.lists(
        st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.one_of(special, st.floats(-1, 2))),
        min_size=2,
        max_size=40,
    ).map(lambda p: np.array(p, float)),
    method=st.sampled_from(METHODS),
)
def test_sparse_points_on_a_large_grid_take_the_sort_fallbacks_and_stay_exact(
    pts: np.ndarray, method: str
) -> None:
    # A 2000 x 2000-cell grid: the frame's box has far more cells than points (argsort fallback).
    spec = GridSpec(cell_size=0.05, size_x=100.0, size_y=100.0)
    pts = np.concatenate([pts, [[-49.9, -49.9, 0.0], [49.9, 49.9, 0.0]]])
    m = VHVMap(spec, 0.05)
    m.insert(pts, method=method)
    assert as_tuples(m.structures()) == reference_structures(pts, spec, 0.05)


@pytest.mark.slow
def test_full_hd_frame_gives_the_same_map_on_every_path_and_in_halves() -> None:
    from mapping.synthetic import kinect_hd_like_cloud

    cloud = kinect_hd_like_cloud(np.random.default_rng(4))
    spec = GridSpec(cell_size=0.05, size_x=20.0, size_y=20.0)
    ref = VHVMap(spec, 0.05)
    assert ref.insert(cloud, method="sort").method == "sort"
    for method in ("auto", "bins", "numpy"):
        m = VHVMap(spec, 0.05)
        m.insert(cloud, method=method)
        assert m.structures().equals(ref.structures()), method
    halves = VHVMap(spec, 0.05)
    halves.insert(cloud[:540])
    halves.insert(cloud[540:])
    assert halves.structures().equals(ref.structures())
