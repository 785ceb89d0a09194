"""scene.png: the overview picture frames the scene, the chair, the route and the driven path."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")

import itertools

from robchair.platform.spec import load_spec
from sim.backend import robot_radius
from sim.render import CHAIR_HEIGHT_M, overview_camera, project, render_scene
from sim.scene import load_scenario

W, H = 480, 300
PATH_RGB = np.array([0xE8, 0x59, 0x0C])  # the driven path's colour in render_scene


def _driven(scenario) -> np.ndarray:
    """A driven path along the scenario's route (start -> last waypoint), x, y, yaw."""
    pts = np.array([scenario.start[:2], *scenario.route.waypoints], dtype=float)
    xy = np.concatenate(
        [np.linspace(a, b, 20, endpoint=False) for a, b in itertools.pairwise(pts)] + [pts[-1:]]
    )
    yaw = np.arctan2(*np.diff(xy, axis=0)[:, ::-1].T)
    return np.c_[xy, np.r_[yaw, yaw[-1]]]


@pytest.mark.parametrize("name", ["outdoor_people", "thesis_objects_drive"])
def test_the_picture_frames_the_chair_at_start_and_end_and_the_whole_route(name) -> None:
    spec = load_spec()
    sc = load_scenario(name, robot_radius=robot_radius(spec))
    path = _driven(sc)
    route = np.array([sc.start[:2], *sc.route.waypoints])
    x0, y0, x1, y1 = sc.scene.bounds_xy()
    r = 0.5 * max(spec.body.width, spec.body.depth)
    chair_boxes = [(x + dx, y + dy) for x, y, _ in (path[0], path[-1]) for dx in (-r, r) for dy in (-r, r)]
    xy = [*route, (x0, y0), (x1, y1), *chair_boxes]
    pts = np.array([(x, y, z) for x, y in xy for z in (0.0, CHAIR_HEIGHT_M)])
    pv = overview_camera(sc, spec, path, W / H)[2]
    uv = project(pts, pv, W, H)
    assert (uv >= 0).all() and (uv[:, 0] <= W).all() and (uv[:, 1] <= H).all()

    img = render_scene(sc, spec, path=path, width=W, height=H)
    assert img.shape == (H, W, 3) and img.dtype == np.uint8
    # the driven path is drawn: its colour is in the picture near both of its ends
    drawn = np.all(np.abs(img.astype(int) - PATH_RGB) < 30, axis=-1)
    for end in (path[0], path[-1]):
        ((u, v),) = project(np.array([[end[0], end[1], 0.03]]), pv, W, H)
        assert 0 <= u < W and 0 <= v < H
        win = drawn[max(0, int(v) - 12) : int(v) + 12, max(0, int(u) - 12) : int(u) + 12]
        assert win.any(), f"no driven path drawn near ({u:.0f}, {v:.0f})"


def test_without_a_path_the_picture_shows_the_route_and_no_driven_path() -> None:
    spec = load_spec()
    sc = load_scenario("office_corridor", robot_radius=robot_radius(spec))
    img = render_scene(sc, spec, width=W, height=H)
    drawn = np.all(np.abs(img.astype(int) - PATH_RGB) < 30, axis=-1)
    assert drawn.sum() < 20  # only the scene's own colours (no orange path)
    route_rgb = np.array([0x1F, 0x5F, 0xD6])
    assert np.all(np.abs(img.astype(int) - route_rgb) < 30, axis=-1).sum() > 50
