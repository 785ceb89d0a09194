"""The structure-keeping thinning (mapping.thinning): the kept points build the very same VHV structures as
the whole cloud, on any grid of the same lattice, placed by a pose; the probabilistic map built from them
is the same map; a voxel filter of the same size does not keep the structures."""

from __future__ import annotations

import numpy as np
import pytest

from mapping.derived import occupancy_codes
from mapping.grid import GridSpec, voxel_filter
from mapping.probabilistic import make_map
from mapping.synthetic import small_sample_cloud
from mapping.thinning import structure_keeping_indices, structure_keeping_indices_numpy
from mapping.vhv import VHVMap


def _structures(spec: GridSpec, points: np.ndarray, tolerance: float = 0.05) -> tuple[np.ndarray, ...]:
    m = VHVMap(spec, tolerance)
    m.insert(points)
    s = m.structures()
    return tuple(np.asarray(getattr(s, f)) for f in ("i", "j", "bottom", "top"))


def _same(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> bool:
    return all(x.shape == y.shape and np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def _pose(x: float, y: float, yaw: float, z: float = 0.0) -> np.ndarray:
    t = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:3, 3] = (x, y, z)
    return t


def _cloud(seed: int) -> np.ndarray:
    """Walls, a low box and scattered points, with NaN pixels (float32, sensor frame)."""
    rng = np.random.default_rng(seed)
    p = np.concatenate(
        [
            rng.uniform([-2, -2, 0], [2, 2, 2], (40_000, 3)),
            rng.uniform([-1, -1, 0], [1, 1, 0.3], (40_000, 3)),
            np.column_stack([np.full(30_000, 1.5), rng.uniform(-2, 2, 30_000), rng.uniform(0, 2.2, 30_000)]),
        ]
    ).astype(np.float32)
    p[::50] = np.nan
    return p


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kept_points_build_the_same_structures_on_grids_of_the_lattice(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    p = _cloud(seed)
    t = _pose(*rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi), 0.4)
    idx = structure_keeping_indices(p, t, 0.05, 0.05)
    assert len(idx) < 0.6 * len(p) and np.all(np.diff(idx) > 0)
    world = (p.astype(np.float64) @ t[:3, :3].T + t[:3, 3]).astype(np.float32)
    # grids of other extents and centres on the same 5 cm lattice; a larger tolerance too
    for spec, tol in ((GridSpec(0.05, 8.0, 8.0), 0.05), (GridSpec(0.05, 6.0, 7.0, (0.35, -1.2)), 0.05),
                      (GridSpec(0.05, 8.0, 8.0), 0.08)):  # fmt: skip
        assert _same(_structures(spec, world, tol), _structures(spec, world[idx], tol))
    # one point per 5 cm voxel (the bag's former thinning) changes the structures
    vox = voxel_filter(p, 0.05, t)
    vox_world = (vox.astype(np.float64) @ t[:3, :3].T + t[:3, 3]).astype(np.float32)
    assert not _same(
        _structures(GridSpec(0.05, 8.0, 8.0), world), _structures(GridSpec(0.05, 8.0, 8.0), vox_world)
    )


def test_the_probabilistic_map_of_the_kept_points_is_the_map_of_the_whole_frame() -> None:
    """Occupied and free evidence come from the structures and the sensor origin only: two frames of the
    synthetic indoor sample, whole and thinned, give the same 2D map and the same stored intervals."""
    spec = GridSpec(0.05, 10.0, 10.0)
    whole, thin = (make_map(spec, 0.05, "probabilistic") for _ in range(2))
    for k, yaw in enumerate((0.0, 0.4)):
        p = small_sample_cloud(np.random.default_rng(7 + k)).astype(np.float32)
        t = _pose(0.2 * k, -0.1 * k, yaw)
        idx = structure_keeping_indices(p, t, 0.05, 0.05)
        assert len(idx) < len(p)
        w = (p.astype(np.float64) @ t[:3, :3].T + t[:3, 3]).astype(np.float32)
        origin = t[:3, :3] @ np.array([0.0, 0.0, 1.0]) + t[:3, 3]
        whole.insert(w, sensor_origin=origin, stamp=0.1 * k)
        thin.insert(w[idx], sensor_origin=origin, stamp=0.1 * k)
    a, b = occupancy_codes(whole, (0.1, 1.5)), occupancy_codes(thin, (0.1, 1.5))
    assert (a == 100).sum() > 100 and (a == 0).sum() > 100 and np.array_equal(a, b)
    ia, ib = whole.intervals(), thin.intervals()
    for f in ("i", "j", "bottom", "top", "log_odds"):
        assert np.array_equal(np.asarray(getattr(ia, f)), np.asarray(getattr(ib, f))), f


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_kernel_keeps_the_indices_of_the_sorting_reference(dtype: type) -> None:
    p = _cloud(3).astype(dtype)
    t = _pose(0.3, -0.7, 1.1, 0.2)
    got = structure_keeping_indices(p, t, 0.05, 0.05)
    assert np.array_equal(got, structure_keeping_indices_numpy(p, t, 0.05, 0.05))
    # an organized frame is taken row by row; the x kept axis bins y-z cells
    org = p[: 300 * 200].reshape(300, 200, 3)
    assert np.array_equal(
        structure_keeping_indices(org, t, 0.05, 0.05),
        structure_keeping_indices(p[: 300 * 200], t, 0.05, 0.05),
    )
    assert np.array_equal(
        structure_keeping_indices(p, t, 0.1, 0.05, "x"), structure_keeping_indices_numpy(p, t, 0.1, 0.05, "x")
    )


def test_points_beyond_the_key_packing_take_the_sorting_path() -> None:
    p = _cloud(4)
    p[7] = (6.0e4, 0.0, 1.0)  # 60 km: cell index beyond 2**20
    got = structure_keeping_indices(p, None, 0.05, 0.05)
    assert 7 in got and np.array_equal(got, structure_keeping_indices_numpy(p, None, 0.05, 0.05))


def test_empty_and_all_nan_frames_keep_nothing() -> None:
    assert structure_keeping_indices(np.zeros((0, 3), np.float32), None, 0.05, 0.05).shape == (0,)
    assert structure_keeping_indices(np.full((4, 3), np.nan, np.float32), None, 0.05, 0.05).shape == (0,)
    assert structure_keeping_indices_numpy(np.full((4, 3), np.nan), None, 0.05, 0.05).shape == (0,)


def test_bad_input_is_refused_naming_it() -> None:
    with pytest.raises(ValueError, match="points"):
        structure_keeping_indices(np.zeros((3, 2)), None, 0.05, 0.05)
    with pytest.raises(ValueError, match="tolerance"):
        structure_keeping_indices(np.zeros((3, 3)), None, 0.05, 0.0)
    with pytest.raises(ValueError, match="cell_size"):
        structure_keeping_indices(np.zeros((3, 3)), None, float("nan"), 0.05)
    with pytest.raises(ValueError, match="t_map_points"):
        structure_keeping_indices(np.zeros((3, 3)), np.eye(3), 0.05, 0.05)
    with pytest.raises(ValueError, match="axis"):
        structure_keeping_indices(np.zeros((3, 3)), None, 0.05, 0.05, "w")
