"""GridSpec: validation, shape, and the world <-> cell indexing of thesis equations 4.2.1-4.2.3."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.errors import GridSpecError, MappingError
from mapping.grid import GridSpec


def test_default_grid_is_twenty_metres_of_five_centimetre_cells_around_the_origin() -> None:
    g = GridSpec()
    assert g.shape == (400, 400)
    assert g.origin == (-200, -200)
    assert g.extent == pytest.approx((-10.0, 10.0, -10.0, 10.0))


def test_hand_computed_indices_and_centres() -> None:
    g = GridSpec(cell_size=0.5, size_x=4.0, size_y=2.0, centre=(1.0, 0.0))
    # nx = 8, ny = 4; centre lattice cell (2, 0) -> origin (2 - 4, 0 - 2) = (-2, -2)
    assert g.shape == (8, 4)
    assert g.origin == (-2, -2)
    i, j = g.world_to_index([-1.0, -0.01, 0.0, 2.99], [-1.0, -0.26, 0.25, 0.99])
    assert i.tolist() == [0, 1, 2, 7]
    assert j.tolist() == [0, 1, 2, 3]
    u, v = g.index_to_world([0, 7], [0, 3])
    assert u.tolist() == [-0.75, 2.75]
    assert v.tolist() == [-0.75, 0.75]


def test_thesis_equation_4_2_1_gives_the_cell_centre() -> None:
    g = GridSpec(cell_size=0.05, size_x=2.0, size_y=2.0)
    raw = np.array([0.01, 0.049, 0.051, -0.001, -0.07])
    i, j = g.world_to_index(raw, raw)
    u, _ = g.index_to_world(i, j)
    val_4_2_1 = np.floor(raw * (1 / 0.05)) * 0.05 + 0.05 / 2
    np.testing.assert_allclose(u, val_4_2_1, rtol=0, atol=1e-15)


def test_points_outside_the_grid_get_indices_outside_the_shape() -> None:
    g = GridSpec(cell_size=1.0, size_x=4.0, size_y=4.0)
    i, j = g.world_to_index([-2.01, 1.99, 2.0], [0.0, 0.0, 0.0])
    assert g.contains_index(i, j).tolist() == [False, True, False]


centres = st.floats(-1000.0, 1000.0, allow_nan=False)
cell_sizes = st.sampled_from([0.01, 0.05, 0.1, 0.25, 1.0, 0.3])


@settings(max_examples=200, deadline=None)
@given(cs=cell_sizes, nx=st.integers(1, 60), ny=st.integers(1, 60), cx=centres, cy=centres, data=st.data())
def test_world_to_index_to_world_returns_the_cell_centre_for_any_centre(
    cs: float, nx: int, ny: int, cx: float, cy: float, data: st.DataObject
) -> None:
    g = GridSpec(cell_size=cs, size_x=nx * cs, size_y=ny * cs, centre=(cx, cy))
    u0, u1, v0, v1 = g.extent
    u = data.draw(st.lists(st.floats(u0, u1, allow_nan=False), min_size=1, max_size=20))
    v = data.draw(st.lists(st.floats(v0, v1, allow_nan=False), min_size=len(u), max_size=len(u)))
    i, j = g.world_to_index(u, v)
    inside = g.contains_index(i, j)
    i, j = i[inside], j[inside]
    cu, cv = g.index_to_world(i, j)
    # the centre is in the same cell ...
    i2, j2 = g.world_to_index(cu, cv)
    np.testing.assert_array_equal(i2, i)
    np.testing.assert_array_equal(j2, j)
    # ... it is the middle of the cell that holds the point ...
    uu, vv = np.asarray(u)[inside], np.asarray(v)[inside]
    assert np.all(np.abs(uu - cu) <= cs / 2 * (1 + 1e-9) + 1e-9 * abs(cx))
    assert np.all(np.abs(vv - cv) <= cs / 2 * (1 + 1e-9) + 1e-9 * abs(cy))
    # ... and index -> world -> index -> world is a fixed point, bit for bit.
    cu2, cv2 = g.index_to_world(i2, j2)
    np.testing.assert_array_equal(cu2, cu)
    np.testing.assert_array_equal(cv2, cv)


@settings(max_examples=100, deadline=None)
@given(cs=cell_sizes, n=st.integers(1, 50), cx=centres, cy=centres)
def test_every_cell_index_round_trips_through_its_centre(cs: float, n: int, cx: float, cy: float) -> None:
    g = GridSpec(cell_size=cs, size_x=n * cs, size_y=n * cs, centre=(cx, cy))
    ii, jj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    u, v = g.index_to_world(ii, jj)
    i2, j2 = g.world_to_index(u, v)
    np.testing.assert_array_equal(i2, ii)
    np.testing.assert_array_equal(j2, jj)


@given(cx=centres, cy=centres)
def test_grid_middle_contains_the_centre(cx: float, cy: float) -> None:
    g = GridSpec(cell_size=0.05, size_x=1.0, size_y=1.0, centre=(cx, cy))
    i, j = g.world_to_index(cx, cy)
    assert (int(i), int(j)) == (10, 10)


def test_grid_frame_reorders_columns_for_each_kept_axis() -> None:
    p = np.array([1.0, 2.0, 3.0])
    assert GridSpec(axis="z").to_grid_frame(p).tolist() == [1.0, 2.0, 3.0]
    assert GridSpec(axis="x").to_grid_frame(p).tolist() == [2.0, 3.0, 1.0]
    assert GridSpec(axis="y").to_grid_frame(p).tolist() == [1.0, 3.0, 2.0]
    for axis in "xyz":
        g = GridSpec(axis=axis)  # type: ignore[arg-type]
        assert g.to_world_frame(g.to_grid_frame(p)).tolist() == p.tolist()


def test_gridspec_is_frozen() -> None:
    g = GridSpec()
    with pytest.raises(AttributeError):
        g.cell_size = 0.1  # type: ignore[misc]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cell_size": 0.0}, r"GridSpec\.cell_size=0\.0.*> 0"),
        ({"cell_size": -0.05}, r"GridSpec\.cell_size=-0\.05"),
        ({"cell_size": math.nan}, r"GridSpec\.cell_size=nan"),
        ({"cell_size": "5cm"}, r"GridSpec\.cell_size='5cm'"),
        ({"size_x": math.inf}, r"GridSpec\.size_x=inf"),
        ({"size_y": 1.03}, r"GridSpec\.size_y=1\.03.*whole number"),
        ({"size_x": 0.01}, r"GridSpec\.size_x=0\.01.*whole number"),
        ({"centre": (0.0,)}, r"GridSpec\.centre=\(0\.0,\)"),
        ({"centre": (0.0, math.nan)}, r"GridSpec\.centre=.*finite"),
        ({"axis": "w"}, r"GridSpec\.axis='w'.*'z', 'x', 'y'"),
        ({"cell_size": 1e-4, "size_x": 1000.0, "size_y": 1000.0}, r"at most"),
    ],
)
def test_invalid_gridspec_fields_are_refused_with_field_value_and_expectation(
    kwargs: dict, match: str
) -> None:
    with pytest.raises(GridSpecError, match=match) as err:
        GridSpec(**kwargs)
    assert isinstance(err.value, MappingError) and isinstance(err.value, ValueError)


def test_covering_grid_of_a_hand_computed_box() -> None:
    # box x 0..1, y 0..0.5, cells of 0.5 m: x = 1.0 lies in lattice cell 2, y = 0.5 in cell 1
    g = GridSpec.covering((0.0, 0.0), (1.0, 0.5), 0.5)
    assert g.shape == (3, 2)
    assert g.extent == (0.0, 1.5, 0.0, 1.0)
    # margins: x -0.25..1.25 spans lattice cells -1..2, y -0.05..0.45 spans cells -1..0
    g = GridSpec.covering((0.0, 0.0), (1.0, 0.4), 0.5, margin=(0.25, 0.05), axis="x")
    assert (g.shape, g.extent, g.axis) == ((4, 2), (-0.5, 1.5, -0.5, 0.5), "x")


@settings(max_examples=200, deadline=None)
@given(
    lo=st.tuples(st.floats(-50, 50), st.floats(-50, 50)),
    size=st.tuples(st.floats(0, 20), st.floats(0, 20)),
    cs=st.sampled_from([0.01, 0.05, 0.1, 0.3, 1.0]),
    margin=st.floats(0, 3),
)
def test_covering_grid_holds_every_corner_of_the_box_and_no_spare_row(
    lo: tuple[float, float], size: tuple[float, float], cs: float, margin: float
) -> None:
    hi = (lo[0] + size[0], lo[1] + size[1])
    g = GridSpec.covering(lo, hi, cs, margin)
    us = np.array([lo[0] - margin, hi[0] + margin, lo[0] - margin, hi[0] + margin])
    vs = np.array([lo[1] - margin, lo[1] - margin, hi[1] + margin, hi[1] + margin])
    i, j = g.world_to_index(us, vs)
    assert g.contains_index(i, j).all()
    nx, ny = g.shape
    # the corners sit in the first and last row and column: the grid is the smallest that covers them
    assert set(i.tolist()) == {0, nx - 1} or nx == 1
    assert set(j.tolist()) == {0, ny - 1} or ny == 1


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (((0.0, 0.0), (1.0, 1.0), 0.0), r"cell_size=0\.0: expected a number of metres > 0"),
        (((0.0, 0.0), (1.0, 1.0), 0.1, -0.5), r"margin=-0\.5: expected finite metres >= 0"),
        (((1.0, 0.0), (0.0, 1.0), 0.1), r"lo=\(1\.0, 0\.0\), hi=\(0\.0, 1\.0\): expected finite bounds"),
        (((math.nan, 0.0), (1.0, 1.0), 0.1), r"expected finite bounds with lo <= hi"),
    ],
)
def test_covering_refuses_a_bad_box_cell_or_margin(args: tuple, message: str) -> None:
    with pytest.raises(GridSpecError, match=message):
        GridSpec.covering(*args)
