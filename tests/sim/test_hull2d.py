"""sim.hull2d: the plane's convex hull without scipy, the scenario's waypoint check on it, and a scenario
load that no longer imports scipy.spatial."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import ConvexHull, QhullError

from sim.hull2d import convex_hull_2d, inside_by

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("seed", range(20))
def test_the_corners_are_qhulls_vertices_counter_clockwise(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(int(rng.integers(3, 400)), 2))
    if seed % 4 == 0:  # a grid: many collinear and repeated points
        pts = np.round(pts * 2) / 2
    hull = convex_hull_2d(pts)
    corners = sorted(map(tuple, pts[hull].tolist()))  # of repeated points either may be the corner
    assert corners == sorted(map(tuple, pts[ConvexHull(pts).vertices].tolist()))
    assert len(set(corners)) == len(corners)
    c = pts[hull]
    e = np.roll(c, -1, axis=0) - c
    turn = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
    assert (turn > 0).all()  # every corner a left turn: counter-clockwise and no collinear corner


@pytest.mark.parametrize(
    "pts",
    [np.zeros((0, 2)), np.array([[1.0, 2.0]]), np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [1.0, 1.0]])],
)
def test_points_without_area_have_under_three_corners_where_qhull_refuses(pts: np.ndarray) -> None:
    assert len(convex_hull_2d(pts)) < 3
    assert not inside_by(pts, convex_hull_2d(pts), (1.0, 1.0), margin=0.0)
    with pytest.raises((QhullError, ValueError)):
        ConvexHull(pts)


def test_inside_by_is_the_distance_from_every_edge() -> None:
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.5]])
    hull = convex_hull_2d(square)
    assert len(hull) == 4
    assert inside_by(square, hull, (0.5, 0.5), margin=0.49)
    assert not inside_by(square, hull, (0.5, 0.5), margin=0.5)
    assert not inside_by(square, hull, (0.0005, 0.5), margin=1e-3)  # within 1 mm of the edge: outside
    assert inside_by(square, hull, (0.002, 0.5), margin=1e-3)
    assert not inside_by(square, hull, (1.5, 0.5), margin=0.0)
    with pytest.raises(ValueError):
        convex_hull_2d(np.zeros((3, 3)))
    with pytest.raises(ValueError):
        convex_hull_2d(np.array([[0.0, np.nan], [1.0, 0.0], [0.0, 1.0]]))


def test_loading_every_scenario_does_not_import_scipy_spatial() -> None:
    """The waypoint check costs no scipy.spatial import (a tenth of a short `robchair sim`'s CPU)."""
    code = (
        "import sys\nfrom sim.scene import list_scenarios, load_scenario\n"
        "[load_scenario(s) for s in list_scenarios()]\n"
        "print(sorted(m for m in sys.modules if m.startswith('scipy.spatial')))"
    )
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env={"PYTHONPATH": str(ROOT), "PATH": ""})  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"
