"""VHV builds frame after frame: chunked binning against a numpy reference, frames of any size in a row
on one thread, and a build stopped midway (split from tests/mapping/test_vhv.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mapping.grid import GridSpec
from mapping.vhv import VHVMap
from tests.mapping.vhv_cases import METHODS, SPEC, as_tuples, chunked_edge_clouds


def numpy_reference_structures(
    points: np.ndarray, spec: GridSpec, tol: float
) -> list[tuple[int, int, float, float]]:
    """Independent vectorised reference: per cell, sort the distinct heights and split at gaps > tol."""
    p = np.asarray(points).reshape(-1, 3).astype(np.float64)
    cu, cv, ch = spec.columns
    (ou, ov), (nx, ny) = spec.origin, spec.shape
    ics = 1.0 / spec.cell_size
    with np.errstate(invalid="ignore", over="ignore"):
        fu, fv = np.floor(p[:, cu] * ics), np.floor(p[:, cv] * ics)
        keep = np.isfinite(p).all(axis=1) & np.isfinite(fu) & np.isfinite(fv)
        keep &= (fu - ou >= 0) & (fu - ou < nx) & (fv - ov >= 0) & (fv - ov < ny)
    i = (fu[keep] - ou).astype(np.int64)
    j = (fv[keep] - ov).astype(np.int64)
    h = p[keep, ch]
    key = i * ny + j
    order = np.lexsort((h, key))
    key, h = key[order], h[order]
    distinct = np.ones(key.shape[0], bool)
    distinct[1:] = (key[1:] != key[:-1]) | (h[1:] != h[:-1])
    key, h = key[distinct], h[distinct]
    start = np.ones(key.shape[0], bool)
    start[1:] = (key[1:] != key[:-1]) | (h[1:] - h[:-1] > tol)
    first = np.flatnonzero(start)
    last = np.append(first[1:], key.shape[0]).astype(np.int64)[: first.shape[0]] - 1
    return list(
        zip((key[first] // ny).tolist(), (key[first] % ny).tolist(), h[first].tolist(), h[last].tolist())
    )


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.one_of(st.integers(0, 9), st.integers(4090, 4100), st.integers(8189, 8200), st.integers(0, 13000)),
    seed=st.integers(0, 2**32 - 1),
    bad=st.floats(0.0, 0.5),
    dtype=st.sampled_from([np.float32, np.float64]),
    tol=st.sampled_from([0.05, 0.02, 0.1, 0.3]),  # the tolerances of test_vhv.py
    method=st.sampled_from(METHODS),
)
def test_binning_over_chunks_and_streams_equals_a_numpy_reference(
    n: int, seed: int, bad: float, dtype: type, tol: float, method: str
) -> None:
    """Chunk and scatter-stream tails (sizes near multiples of 4096 and 4), NaN/inf coordinates,
    off-grid points and heights far from the bulk (the overflow path), in float32 and float64."""
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(-0.55, 0.55, n), rng.uniform(-0.55, 0.55, n), rng.normal(0.5, 0.3, n)])
    pts[:, 2] = np.round(pts[:, 2] / 0.01) * 0.01  # gaps of exactly the tolerance and repeated heights
    hit = rng.random((n, 3)) < bad / 3
    pts[hit] = rng.choice(np.array([np.nan, np.inf, -np.inf, 50.0, -40.0, 0.5, -0.5]), int(hit.sum()))
    pts = pts.astype(dtype)
    m = VHVMap(SPEC, tolerance=tol)
    m.insert(pts, method=method)
    assert as_tuples(m.structures()) == numpy_reference_structures(pts, SPEC, tol)


def test_frames_of_any_size_in_a_row_on_one_thread_equal_fresh_builds_and_leave_the_table_empty() -> None:
    """The bins path keeps its (min, max) table between frames of a thread and relies on the
    extraction emptying it: a sequence of frames of growing and shrinking boxes, with NaN, off-grid and
    overflow points, gives on every frame the map a fresh numpy build gives, and the kept table is all
    (+inf, -inf) afterwards."""
    from mapping import _vhv_build
    from mapping.synthetic import kinect_hd_like_cloud

    rng = np.random.default_rng(5)
    spec = GridSpec(cell_size=0.05, size_x=20.0, size_y=20.0)
    frames = [kinect_hd_like_cloud(rng, h, w) for h, w in ((240, 320), (60, 80), (300, 400), (120, 160))]
    frames += [c.astype(np.float32) for _, c in chunked_edge_clouds()]
    for k, cloud in enumerate(frames + frames[::-1]):
        m, ref = VHVMap(spec, 0.05), VHVMap(spec, 0.05)
        stats = m.insert(cloud, method="bins")
        ref_stats = ref.insert(cloud, method="numpy")
        assert m.structures().equals(ref.structures()), k
        assert (stats.points_dropped_nonfinite, stats.points_outside_grid) == (
            ref_stats.points_dropped_nonfinite,
            ref_stats.points_outside_grid,
        ), k
        table, clean = _vhv_build._tables.f
        assert clean and bool(np.all(table[0::2] == np.inf)) and bool(np.all(table[1::2] == -np.inf)), k


def test_a_build_that_stopped_midway_leaves_no_trace_in_the_next_frame(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A build that raises after binning (its table still full) must not leak into the next frame."""
    from mapping import _vhv_kernels
    from mapping.synthetic import kinect_hd_like_cloud

    rng = np.random.default_rng(6)
    spec = GridSpec(cell_size=0.05, size_x=20.0, size_y=20.0)
    first, second = kinect_hd_like_cloud(rng, 240, 320), kinect_hd_like_cloud(rng, 200, 300)

    def stop(*args: object) -> int:
        raise KeyboardInterrupt

    with monkeypatch.context() as mp:
        mp.setattr(_vhv_kernels, "extract_bins", stop)
        with pytest.raises(KeyboardInterrupt):
            VHVMap(spec, 0.05).insert(first, method="bins")
    m, ref = VHVMap(spec, 0.05), VHVMap(spec, 0.05)
    m.insert(second, method="bins")
    ref.insert(second, method="numpy")
    assert m.structures().equals(ref.structures())
