"""The perception stage clips a fused sonar arc to the laser returns that explain its echo."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hw.interfaces import SonarArrayReading
from robchair.perception import Perception
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import load_spec


@pytest.fixture(scope="module")
def spec():
    return load_spec()


def _post_in_laser_frame(spec, xy_base):
    """A door post (a few returns 1 cm apart) at ``xy_base`` in base_link, as laser-frame points."""
    lx, ly, _ = spec.mounts["laser_link"].xyz
    pts = [
        (xy_base[0] - lx + dx, xy_base[1] - ly + dy, 0.0) for dx in (-0.01, 0.0, 0.01) for dy in (-0.01, 0.0)
    ]
    return np.asarray(pts)


def test_an_echo_from_a_door_post_beside_the_path_does_not_stop_the_chair(spec):
    mount = spec.mounts["sonar_array_left"]
    d = 0.25
    post = (mount.xyz[0] + d * math.cos(math.radians(40)), mount.xyz[1] + d * math.sin(math.radians(40)))
    assert post[1] > 0.37  # outside the corridor the chair sweeps
    # all three sonars hear the post: the fused arc (about 110 deg wide) spans the corridor ahead
    reading = SonarArrayReading(0, (d, d, d + 0.01), 90.0)
    pose = Pose2D(0.0, 0.0, 0.0)

    blind = Perception(spec)
    blind.add_sonar("sonar_array_left", reading, pose)
    assert blind.sonar_distance_m() is not None and blind.sonar_distance_m() < d  # a stop, unexplained

    seeing = Perception(spec)
    seeing.add_scan("laser_link", _post_in_laser_frame(spec, post), pose)
    seeing.add_sonar("sonar_array_left", reading, pose)
    assert seeing.sonar_distance_m() is None


def test_an_echo_the_laser_does_not_explain_keeps_the_whole_arc(spec):
    """A table top above the scan plane: the laser sees only a wall further away."""
    d = 0.25
    reading = SonarArrayReading(0, (d, d, d + 0.01), 90.0)
    pose = Pose2D(1.0, 2.0, math.radians(30))
    blind = Perception(spec)
    blind.add_sonar("sonar_array_left", reading, pose)
    p = Perception(spec)
    p.add_scan("laser_link", _post_in_laser_frame(spec, (3.0, 0.0)), pose)
    p.add_sonar("sonar_array_left", reading, pose)
    assert p.sonar_distance_m() is not None
    assert p.sonar_distance_m() == pytest.approx(blind.sonar_distance_m())
