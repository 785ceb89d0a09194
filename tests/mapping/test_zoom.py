"""Zoom: a fine grid over a region of interest inside a coarse VHV map."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.errors import MappingError
from mapping.grid import GridSpec
from mapping.vhv import VHVMap
from mapping.zoom import ZoomMap

COARSE = GridSpec(cell_size=0.05, size_x=6.0, size_y=6.0, centre=(1.0, 0.0))


def _cloud(rng: np.random.Generator, n: int = 20000) -> np.ndarray:
    pts = np.column_stack([rng.uniform(-1.5, 3.5, n), rng.uniform(-2.5, 2.5, n), rng.uniform(0.0, 1.8, n)])
    # clusters with gaps around the tolerance, and points exactly on cell borders
    pts[: n // 4, 2] = rng.choice([0.0, 0.049, 0.1, 0.16, 0.7], n // 4)
    pts[n // 4 : n // 2, 0] = np.round(pts[n // 4 : n // 2, 0] / 0.01) * 0.01
    return pts


def test_coarsened_zoom_equals_the_coarse_map_over_the_region() -> None:
    rng = np.random.default_rng(1)
    z = ZoomMap(COARSE, tolerance=0.05, factor=5, region=(0.0, -1.0, 2.0, 1.0))
    for _ in range(3):
        z.insert(_cloud(rng))
    assert z.coarsened().equals(z.coarse_in_region())
    assert len(z.coarse_in_region()) > 1000


@settings(max_examples=40, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.integers(2, 10),
    st.floats(0.01, 0.2),
    st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(0.06, 3.0)),
)
def test_coarsening_is_exact_for_any_factor_tolerance_and_region(seed, factor, tol, box) -> None:
    rng = np.random.default_rng(seed)
    x0, y0, w = box
    z = ZoomMap(COARSE, tolerance=tol, factor=factor, region=(x0, y0, x0 + w, y0 + w))
    z.insert(_cloud(rng, 3000))
    z.insert(_cloud(rng, 3000))
    assert z.coarsened().equals(z.coarse_in_region())


def test_the_coarse_map_is_the_plain_vhv_map_of_the_same_points() -> None:
    rng = np.random.default_rng(2)
    pts = _cloud(rng)
    z = ZoomMap(COARSE, factor=4, region=(0.0, 0.0, 1.0, 1.0))
    z.insert(pts)
    plain = VHVMap(COARSE, 0.05)
    plain.insert(pts)
    assert z.coarse.structures().equals(plain.structures())


def test_queries_answer_fine_inside_and_coarse_outside_the_region() -> None:
    z = ZoomMap(COARSE, tolerance=0.05, factor=5, region=(0.0, 0.0, 1.0, 1.0))
    # two thin posts 2 cm apart: one coarse cell, two fine cells
    posts = [[0.512, 0.512, h] for h in np.arange(0.0, 1.0, 0.01)] + [
        [0.532, 0.512, h] for h in np.arange(0.0, 0.5, 0.01)
    ]
    far = [[2.512, 0.512, h] for h in np.arange(0.0, 0.3, 0.01)]
    z.insert(np.array(posts + far))
    assert z.cell_size_at(0.512, 0.512) == pytest.approx(0.01)
    assert z.elevation_at(0.512, 0.512) == pytest.approx(0.99)
    assert z.elevation_at(0.532, 0.512) == pytest.approx(0.49)  # the coarse cell would say 0.99
    assert z.coarse.structures_at(0.532, 0.512).top.max() == pytest.approx(0.99)
    assert math.isnan(z.elevation_at(0.552, 0.512))  # fine cell beside the posts is empty
    assert z.occupied_at(0.532, 0.512, (0.4, 1.6)) and not z.occupied_at(0.532, 0.512, (0.6, 1.6))
    # outside the region the coarse map answers
    assert z.cell_size_at(2.512, 0.512) == pytest.approx(0.05)
    assert z.elevation_at(2.53, 0.51) == pytest.approx(0.29)


def test_following_the_chair_keeps_the_overlap_and_drops_the_rest() -> None:
    z = ZoomMap(COARSE, factor=5)
    z.follow(0.0, 0.0, 1.0)
    z.insert(np.array([[0.5, 0.5, 0.2], [-0.9, -0.9, 0.3]]))
    z.follow(1.0, 1.0, 1.0)  # the region moves by 1 m: (0.5, 0.5) stays inside, (-0.9, -0.9) leaves
    assert z.region == pytest.approx((0.0, 0.0, 2.0, 2.0))
    assert z.elevation_at(0.5, 0.5) == pytest.approx(0.2) and z.cell_size_at(0.5, 0.5) == pytest.approx(0.01)
    assert len(z.fine.structures()) == 1
    assert z.elevation_at(-0.9, -0.9) == pytest.approx(0.3)  # now answered by the coarse map


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"factor": 1}, "factor=1"),
        ({"factor": 2.5}, "factor=2.5"),
        ({"region": (1.0, 0.0, 0.0, 1.0)}, "min < max"),
        ({"region": (50.0, 50.0, 51.0, 51.0)}, "outside the coarse grid"),
    ],
)
def test_bad_zoom_arguments_are_refused(kwargs, match) -> None:
    with pytest.raises(MappingError, match=match):
        ZoomMap(COARSE, **kwargs)


def test_the_fine_map_is_the_plain_vhv_map_of_the_points_inside_the_region() -> None:
    rng = np.random.default_rng(4)
    region = (0.0, -1.0, 2.0, 1.0)
    z = ZoomMap(COARSE, tolerance=0.05, factor=5, region=region)
    plain = VHVMap(z.fine.spec, 0.05)
    for _ in range(3):
        pts = np.column_stack([rng.uniform(-1.5, 3.5, 20000), rng.uniform(-2.5, 2.5, 20000),
                               rng.choice([0.0, 0.04, 0.1, 0.5, 1.2], 20000)])  # fmt: skip
        pts[::50, 2] = np.nan
        fine_stats = z.insert(pts.astype(np.float32), sensor_origin=(0.0, 0.0, 1.0))[1]
        inside = ((pts[:, 0] >= region[0]) & (pts[:, 0] < region[2]) & (pts[:, 1] >= region[1])
                  & (pts[:, 1] < region[3]) & np.isfinite(pts[:, 2]))  # fmt: skip
        plain.insert(pts[inside].astype(np.float32))
        assert fine_stats is not None and fine_stats.points_inserted == int(inside.sum())
    assert z.fine.structures().equals(plain.structures())
    assert z.fine.frames == 3 and len(z.fine.sensor_origins) == 3
