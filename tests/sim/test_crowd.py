"""Scripted people keep clear of the chair (social force model, Helbing & Molnár 1995) and otherwise
walk their scripts exactly.

The park scene (assets/scenes/outdoor.toml): ``walker_crossing`` walks x = 5 m from y = -3 to 3 m and
back at 1 m/s. A chair standing at (4.3, 0) facing +x has its footprint's front edge at
4.3 + 0.16 + 0.84 / 2 = 4.88 m (assets/robchair.toml: centre_x 0.16, depth 0.84), and the walker's
body is 0.31 m to each side of its walking line (assets/meshes/person_standing_2.obj), so a walker on
its script overlaps the chair by 0.19 m twice every 12 s. A pedestrian steps round a standing
obstacle instead; the model's border force (U0 = 10 m^2/s^2, R = 0.2 m) holds a person whose driving
force is at most (1.3 v0 + v0) / tau = 4.6 m/s^2 at r >= 0.2 ln(50 / 4.6) = 0.48 m from the footprint,
more than the body's 0.31 m.
"""

from __future__ import annotations

import numpy as np

from robchair.platform.paths import SCENES
from robchair.platform.spec import load_spec
from sim.chair import SimChair
from sim.crowd import Footprint, SocialForce
from sim.scene import Motion

STEPS_PER_S = 240  # the physics' rate (sim.world)


def _footprint() -> Footprint:
    b = load_spec().body
    return Footprint(b.centre_x - b.depth / 2, b.centre_x + b.depth / 2, b.width / 2)


def test_a_person_whose_script_runs_through_a_standing_chair_keeps_half_a_metre_from_it() -> None:
    walk = Motion(((5.0, -3.0), (5.0, 3.0)), speed=1.0)
    person, fp, dt = SocialForce(speed=1.0), _footprint(), 1.0 / STEPS_PER_S
    chair = (fp, (4.3, 0.0, 0.0))
    closest = np.inf
    for k in range(24 * STEPS_PER_S):  # two round trips, four passes of the chair
        x, y, _ = walk.pose_at(k * dt)
        xn, yn, _ = walk.pose_at((k + 1) * dt)
        p = person.step(np.array([x, y]), np.array([xn - x, yn - y]) / dt, dt, chair)
        closest = min(closest, fp.nearest(chair[1], p)[0])
    assert closest >= 0.48  # the hand bound of the module docstring
    assert closest < 1.0  # it passes the chair, it is not pushed away from the whole walk


def test_a_person_far_from_the_chair_walks_its_script_exactly() -> None:
    chair = SimChair(scene=SCENES / "outdoor.toml", start=(0.0, -8.0, 0.0), sensor=None, sonars=False)
    try:
        for _ in range(3):
            chair.step(STEPS_PER_S)
            t = chair.world.time - 1.0 / STEPS_PER_S  # the people were placed before the last step
            for _, obj in chair.bodies.moving:
                assert chair.bodies.poses[obj.name] == obj.motion.pose_at(t), obj.name
    finally:
        chair.close()


def test_the_crossing_walker_steps_round_a_stopped_chair_instead_of_through_it() -> None:
    chair = SimChair(scene=SCENES / "outdoor.toml", start=(4.3, 0.0, 0.0), sensor=None, sonars=False)
    try:
        touched: set[str] = set()
        x_max = -np.inf
        for _ in range(13 * STEPS_PER_S // 8):  # past both passes, at t = 3 s and t = 9 s
            chair.step(8)
            touched |= chair.contacts()
            x_max = max(x_max, chair.bodies.poses["walker_crossing"][0])
    finally:
        chair.close()
    assert "walker_crossing" not in touched
    assert x_max > 4.88 + 0.31  # it went round the front of the chair
