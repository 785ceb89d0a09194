"""The cells of the free space, without its heights: what the 2D three-valued map uses (mapping.derived)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping import derived as D
from mapping.errors import MappingError
from mapping.grid import GridSpec
from mapping.synthetic import kinect_hd_like_cloud
from mapping.vhv import VHVMap

SPEC = GridSpec(cell_size=0.05, size_x=1.0, size_y=1.0)
coord = st.floats(-0.7, 0.7, allow_nan=False)
clouds = st.lists(st.tuples(coord, coord, st.floats(-0.5, 2.0, allow_nan=False)), min_size=1, max_size=60)


def _cells(i: np.ndarray, j: np.ndarray) -> set[tuple[int, int]]:
    return set(zip(np.asarray(i).tolist(), np.asarray(j).tolist()))


def _codes_from_free_space(
    m: VHVMap, band: tuple[float, float], origin: tuple[float, float, float]
) -> np.ndarray:
    """occupancy_codes as it was: the cells of the merged free structures marked free."""
    codes = np.full(m.spec.shape, -1, dtype=np.int8)
    s = m.structures()
    codes[s.i, s.j] = 0
    fs = D.free_space(m, origin)
    codes[np.asarray(fs.i, np.intp), np.asarray(fs.j, np.intp)] = 0
    codes[D.occupancy_2d(m, *band)] = 100
    return codes


@settings(max_examples=60)
@given(clouds, st.tuples(coord, coord, st.floats(0.0, 1.5)))
def test_free_cells_are_the_cells_of_the_free_structures(points: list, origin: tuple) -> None:
    m = VHVMap(SPEC, tolerance=0.05)
    m.insert(np.array(points, float))
    i, j = D.free_cells(m, origin)
    fs = D.free_space(m, origin)
    assert _cells(i, j) == _cells(fs.i, fs.j)
    assert _cells(i, j) == _cells(*D.free_cells(m, origin)) and len(i) == len(
        D.free_space(m, origin, merge=False)
    )
    band = (0.1, 1.6)
    assert np.array_equal(D.occupancy_codes(m, band, -1, origin), _codes_from_free_space(m, band, origin))


def test_a_kinect_like_map_gets_the_same_codes_without_the_free_structures(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """occupancy_codes marks the free cells without building the free structures (their heights, the
    sort by height and the merge: two thirds of free_space's time), with the same codes."""
    m = VHVMap(GridSpec(cell_size=0.05, size_x=12.0, size_y=12.0), 0.05)
    origin = (0.0, 0.0, 1.0)
    m.insert(kinect_hd_like_cloud(np.random.default_rng(1), 36, 64), sensor_origin=origin)
    expected = _codes_from_free_space(m, (0.1, 1.6), origin)
    assert np.count_nonzero(expected == 0) > 100

    def no_free_structures(*args: object, **kwargs: object) -> None:
        raise AssertionError("occupancy_codes built the free structures")

    monkeypatch.setattr(D, "free_space", no_free_structures)
    assert np.array_equal(D.occupancy_codes(m, (0.1, 1.6), -1, origin), expected)


def test_free_cells_need_a_sensor_origin_as_free_space_does() -> None:
    m = VHVMap(SPEC, tolerance=0.05)
    for mm in (m, VHVMap(SPEC, tolerance=0.05)):
        with pytest.raises(MappingError, match="no sensor_origin"):
            D.free_cells(mm)
    m.insert([[0.1, 0.1, 0.5]])
    with pytest.raises(MappingError, match=r"sensor_origin=\(1, 2\)"):
        D.free_cells(m, (1, 2))
    assert [len(a) for a in D.free_cells(VHVMap(SPEC, tolerance=0.05), (0.0, 0.0, 1.0))] == [0, 0]
