"""The evaluation maps at a lower frame rate and the matching every k-th frame: what they skip, and how far
the run's maps and matched pose stay from the every-frame path."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from hw.interfaces import DepthFrame
from mapping.synthetic import render_scene
from robchair.perception import Perception
from robchair.platform.errors import ConfigError
from robchair.platform.frames import se3_planar
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import load_spec


class _Camera:
    def __init__(self, clouds: list[np.ndarray]) -> None:
        self.clouds = list(clouds)

    def read(self) -> DepthFrame:
        return DepthFrame(0, "cam", np.asarray(self.clouds.pop(0), np.float32))


class _Counting:
    """A map that counts its inserts."""

    def __init__(self) -> None:
        self.inserts = 0

    def insert(self, points, sensor_origin=None, **kw) -> None:
        self.inserts += 1


def test_evaluation_maps_take_every_kth_frame_and_the_matcher_registers_every_kth() -> None:
    """Six frames (seq 0..5): every 3rd is 0 and 3, so a layer takes 2 inserts, while the main map and the
    odometry map (what a recorded bag of the run maps back to) take all 6; matching every 2nd frame
    registers 0, 2, 4: 3 matches (hand count)."""
    from mapping.grid import GridSpec

    rng = np.random.default_rng(3)
    clouds = [render_scene(rng, 106, 128, nan_fraction=0.05, pitch_deg=5.0) for _ in range(6)]
    grid = GridSpec(cell_size=0.05, size_x=16.0, size_y=16.0, centre=(3.0, 0.0))
    p = Perception(load_spec(), grid=grid, frames={"cam": np.eye(4)}, sonar_map=None, pose="matched",
                   evaluation_every=3, match_every=2)  # fmt: skip
    odo, layer = _Counting(), _Counting()
    p.pose_maps["odometry"] = odo
    p.add_layer("ground_truth", layer, lambda: se3_planar(0.0, 0.0, 0.0))
    cam = _Camera(clouds)
    for k in range(6):
        p.take_depth(cam, Pose2D(0.01 * k, 0.0, 0.0))
    p.flush()
    assert (odo.inserts, layer.inserts, p.stats["depth_frames"]) == (6, 2, 6)
    assert len(p.matcher.results) == 3


@pytest.mark.parametrize("kw", [{"evaluation_every": 0}, {"match_every": 0}])
def test_a_rate_below_one_frame_is_refused(kw) -> None:
    with pytest.raises(ConfigError, match="expected an integer >= 1"):
        Perception(load_spec(), **kw)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = int((a | b).sum())
    return float((a & b).sum() / union) if union else 1.0


@pytest.fixture(scope="module")
def runs():
    """The default scenario's first 3 s, every frame into every map vs the scenario defaults' rates."""
    pytest.importorskip("pybullet")
    from robchair.scenario import EVALUATION_EVERY, MATCH_EVERY, run_scenario

    kw: dict[str, Any] = dict(duration=3.0, sensor="kinect2", seed=0, progress=False, write=False,
                              mapping_thread=False, pipeline=False, sonar_hz=20.0)  # fmt: skip
    exact = run_scenario("office_corridor", evaluation_every=1, match_every=1, **kw)
    fast = run_scenario("office_corridor", evaluation_every=EVALUATION_EVERY, match_every=MATCH_EVERY, **kw)
    return exact, fast


def test_evaluation_maps_at_the_default_rate_keep_the_every_frame_maps_2d_occupancy(runs) -> None:
    """The ground-truth map built from every EVALUATION_EVERY-th frame, the odometry map, and the matched map
    (matching every MATCH_EVERY-th frame), against every frame, as 2D maps of the chair's height band:
    occupied cells IoU >= 0.80 and free cells IoU >= 0.85 (bounds chosen for maps that are compared with
    each other and the scene at 5 cm cells; measured 0.85-0.95 occupied, 0.92-0.99 free)."""
    from mapping.derived import occupancy_codes

    exact, fast = runs
    band = (0.10, 1.0)
    for name in ("odometry", "ground_truth", "matched"):
        a, b = occupancy_codes(exact.maps[name], band), occupancy_codes(fast.maps[name], band)
        assert _iou(a == 100, b == 100) >= 0.80, name
        assert _iou(a == 0, b == 0) >= 0.85, name


def test_matching_every_kth_frame_keeps_the_matched_pose_within_a_map_cell_of_every_frame(runs) -> None:
    """The matched path with matching every MATCH_EVERY-th frame (odometry between) against matching every
    frame: within 0.05 m (one map cell, so a point moves by at most one cell) and 1 deg over the run."""
    exact, fast = runs
    a, b = np.asarray(exact.paths["matched"]), np.asarray(fast.paths["matched"])
    n = min(len(a), len(b))
    assert n > 100
    d = np.hypot(a[:n, 0] - b[:n, 0], a[:n, 1] - b[:n, 1])
    dyaw = np.abs(np.angle(np.exp(1j * (a[:n, 2] - b[:n, 2]))))
    assert d.max() <= 0.05 and dyaw.max() <= math.radians(1.0)
