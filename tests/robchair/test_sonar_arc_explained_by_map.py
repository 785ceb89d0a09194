"""The perception stage clips a fused sonar arc to the zoom map's cells that explain its echo.

The moment of the default scenario's stop before the fix (``robchair sim``, office_corridor, seed 0,
10.87 s): the chair's front edge at the 1.4 m doorway, 8 cm right of its centre line and turned 1.8 deg
right (odometry drift); the right array, its servo at 23.4 deg (the array faces 66.6 deg right), hears
the right door post at 0.33 / 0.31 / 0.31 m. The three agree at 31 cm, where zone 3 is empty, so the
fused arc is the hull of the three beams (120 deg); its left end lies 0.28 m ahead of the front edge,
3 mm outside the chair's side, inside the corridor's lateral margin, and stopped the chair. The post is
0.28 m beside the chair's side, and the zoom map holds it (the camera saw it on the way in).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from hw.interfaces import DepthFrame, SonarArrayReading
from robchair.perception import SNAPSHOT_LAG, Perception
from robchair.platform.frames import se3_planar, transform_points
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import load_spec

# the moment: the reading, the odometry pose, and the chair's true pose (the scene's frame)
READING = SonarArrayReading(10_870_833_333, (0.33, 0.31, 0.31), 23.404450483154747)
ODOMETRY = Pose2D(5.412221356486377, 3.08e-06, -1.61e-05)
TRUE_POSE = (5.413, -0.083, -0.031)
FRAMES = {"cam": np.eye(4)}  # the clouds below are given in base_link directly


@pytest.fixture(scope="module")
def spec():
    return load_spec()


def _surface(corners: list[tuple[float, float]], z=(0.15, 1.2), step=0.01) -> np.ndarray:
    """Points (N, 3) on the vertical faces along the polyline ``corners`` (scene x, y) from ``z`` m."""
    out = []
    for (x0, y0), (x1, y1) in itertools.pairwise(corners):
        n = max(2, int(math.hypot(x1 - x0, y1 - y0) / step) + 1)
        for t in np.linspace(0.0, 1.0, n):
            for zz in np.arange(z[0], z[1], 0.05):
                out.append((x0 + t * (x1 - x0), y0 + t * (y1 - y0), zz))
    return np.asarray(out)


def _in_base(points_scene: np.ndarray) -> np.ndarray:
    return transform_points(np.linalg.inv(se3_planar(*TRUE_POSE)), points_scene)


# the right door post: the room's west wall (x 6.0 .. 6.1, y <= -0.7), its corridor face and the jamb
RIGHT_POST = _surface([(6.0, -1.2), (6.0, -0.7), (6.1, -0.7)])


class _Camera:
    def __init__(self, cloud: np.ndarray) -> None:
        self.cloud = np.asarray(cloud, np.float32)

    def read(self) -> DepthFrame:
        return DepthFrame(0, "cam", self.cloud)


def _perception(spec, mapped: np.ndarray | None, zoom: bool = True) -> Perception:
    """A perception stage whose camera saw ``mapped`` (scene points (N, 3)) from the moment's pose."""
    p = Perception(spec, frames=FRAMES, sonar_map=None, zoom_half_width=1.0 if zoom else None)
    if mapped is not None:
        cam = _Camera(_in_base(mapped))
        for _ in range(SNAPSHOT_LAG + 1):  # the loop sees the zoom as it was SNAPSHOT_LAG frames back
            p.take_depth(cam, ODOMETRY)
    return p


def test_the_doorway_moments_echo_reaches_into_the_corridor_ahead_without_a_map(spec):
    """The stop as it was: nothing locates the echo, the whole 120 deg arc counts."""
    post = _in_base(RIGHT_POST)
    assert np.abs(post[:, 1]).min() == pytest.approx(0.60, abs=0.01)  # 0.28 m beside the chair's side
    for p in (_perception(spec, None), _perception(spec, RIGHT_POST, zoom=False)):
        p.add_sonar("sonar_array_right", READING, ODOMETRY)
        assert p.sonar_distance_m() == pytest.approx(0.278, abs=0.002)


def test_an_echo_from_the_door_post_the_zoom_map_holds_does_not_stop_the_chair(spec):
    p = _perception(spec, RIGHT_POST)
    p.add_sonar("sonar_array_right", READING, ODOMETRY)
    assert p.sonar_distance_m() is None
    # the same once the chair has moved on 4 cm by odometry since the frame (the cells follow the pose)
    p.add_sonar("sonar_array_right", READING, Pose2D(ODOMETRY.x + 0.04, ODOMETRY.y, ODOMETRY.theta))
    assert p.sonar_distance_m() is None


def test_a_mapped_obstacle_in_the_corridor_at_the_echos_range_keeps_the_stop(spec):
    """The map explains the echo with what it holds: a box ahead at the arc's range is an obstacle ahead."""
    mount = np.asarray(spec.mounts["sonar_array_right"].xyz[:2])
    ahead = mount + 0.31 * np.array([math.cos(math.radians(-10)), math.sin(math.radians(-10))])
    assert abs(ahead[1]) < 0.37 and ahead[0] > 0.58  # in the corridor ahead of the front edge
    box = _surface([(ahead[0], ahead[1] - 0.03), (ahead[0], ahead[1] + 0.03)])
    base_to_scene = se3_planar(*TRUE_POSE)
    p = _perception(spec, np.concatenate([RIGHT_POST, transform_points(base_to_scene, box)]))
    p.add_sonar("sonar_array_right", READING, ODOMETRY)
    d = p.sonar_distance_m()
    assert d is not None and d == pytest.approx(ahead[0] - 0.58, abs=0.02)
