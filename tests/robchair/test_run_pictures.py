"""The run folder's map pictures: ``map_2d.png`` (the run's map over the scene truth with the whole
driven path) and ``map/zoom_2d.png`` (drawn only when the zoom region holds a structure)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import matplotlib.image as mpimg
import numpy as np
import pytest

from mapping.grid import GridSpec
from mapping.vhv import VHVMap
from robchair.platform.paths import SCENES
from robchair.scenario import scenario_grid, write_zoom_picture
from sim.scene import ground_truth_points, load_scenario

BAND = (0.10, 1.5)


def _run(maps: dict[str, VHVMap], paths: dict[str, np.ndarray] | None = None) -> SimpleNamespace:
    return SimpleNamespace(maps=maps, extra={}, paths=paths or {})


def _wall(x: float, y0: float, y1: float) -> np.ndarray:
    """Points of a 1 m high wall at ``x`` from ``y0`` to ``y1``, one per cm."""
    y, z = np.meshgrid(np.arange(y0, y1, 0.01), np.arange(0.0, 1.0, 0.01))
    return np.column_stack([np.full(y.size, x), y.ravel(), z.ravel()])


def test_an_empty_zoom_region_draws_no_picture_and_says_why(tmp_path: Path) -> None:
    """The region 9..11 x -1.8..0.2 m round the goal of office_corridor holds nothing: the picture
    would be white, so it is not written and metrics say which region was empty."""
    main = VHVMap(GridSpec(0.05, 16.0, 8.0, (5.0, 0.0)))
    main.insert(_wall(12.1, -3.0, 3.0))
    fine = VHVMap(GridSpec(0.01, 2.0, 2.0, (10.0, -0.8)))
    res = _run({"odometry": main, "zoom": fine})
    assert write_zoom_picture(res, BAND, tmp_path / "zoom_2d.png") is False
    assert not (tmp_path / "zoom_2d.png").exists()
    assert res.extra["zoom"]["picture"] == (
        "not drawn: the zoom region x 9.00..11.00 m, y -1.80..0.20 m (around the chair at the end of "
        "the run) holds no occupied cell in the band 0.1-1.5 m"
    )


def test_a_zoom_region_holding_a_wall_is_drawn(tmp_path: Path) -> None:
    main = VHVMap(GridSpec(0.05, 16.0, 8.0, (5.0, 0.0)))
    fine = VHVMap(GridSpec(0.01, 2.0, 2.0, (6.0, 0.0)))
    wall = _wall(6.05, 0.7, 1.0)  # a door jamb inside the region
    main.insert(wall)
    fine.insert(wall)
    res = _run({"odometry": main, "zoom": fine})
    assert write_zoom_picture(res, BAND, tmp_path / "zoom_2d.png") is True
    assert (tmp_path / "zoom_2d.png").stat().st_size > 10_000
    assert res.extra["zoom"]["picture"] == "zoom_2d.png"


def test_map_2d_draws_the_run_map_and_the_whole_driven_path(tmp_path: Path) -> None:
    """True paths from the start (0, 0) to x = 9.9 m (the far end of office_corridor's route) and to
    x = 5.3 m, drawn on the same axes: their pixel spans along x are in the ratio 9.9 / 5.3 (hand
    computation), so the whole path is drawn, not a part of it."""
    from robchair.viz.map_picture import write_map_2d

    sc = load_scenario(SCENES / "office_corridor.toml")
    m = VHVMap(scenario_grid(sc))
    m.insert(ground_truth_points(sc.scene, 0.05, np.random.default_rng(0)))
    spans = []
    for end in (9.9, 5.3):
        xs = np.linspace(0.0, end, 200)
        truth = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
        path = write_map_2d(_run({"odometry": m}, {"ground_truth": truth}), sc, BAND, tmp_path / f"{end}.png",
                            map_name="odometry")  # fmt: skip
        img = mpimg.imread(path)[..., :3]
        green = np.all(np.abs(img - np.array([0x2C, 0xA0, 0x2C]) / 255) < 0.06, axis=-1)  # tab:green
        h = green.shape[0]
        cols = np.flatnonzero(green[int(0.35 * h) : int(0.8 * h)].any(axis=0))  # below the legend
        spans.append(cols.max() - cols.min())
        assert np.all(img < 0.2, axis=-1).sum() > 2000  # the map's occupied cells are drawn
    assert spans[0] / spans[1] == pytest.approx(9.9 / 5.3, rel=0.03)
