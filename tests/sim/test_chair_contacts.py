"""The chair's contacts per physics step: the pair queries of the nearby bodies give the full query's
answer (:meth:`sim.chair.SimChair._contact_candidates` leaves out only bodies it cannot reach)."""

from __future__ import annotations

import math

import numpy as np
import pybullet as p
import pytest

from robchair.platform.paths import SCENES
from sim.chair import SimChair
from sim.scene import load_scene


@pytest.fixture(scope="module")
def office():
    chair = SimChair(scene=load_scene(SCENES / "office.toml"), sensor=None, sonars=False, seed=0)
    yield chair
    chair.close()


def _drive(chair: SimChair, rpm: tuple[float, float] | None, intervals: int, n: int) -> tuple[int, set[str]]:
    """Step ``intervals`` x ``n`` physics steps at ``rpm`` (None: as set), checking every step's
    contacts both ways."""
    if rpm is not None:
        chair.robot.set_motor_rpm(*rpm)
    touched = 0
    names: set[str] = set()
    for _ in range(intervals):
        near = chair._contact_candidates(n)
        for _ in range(n):
            chair.step(1)
            full, among = chair.contacts(), chair._contacts_among(near)
            assert among == full
            touched += bool(full)
            names |= full
    return touched, names


def test_the_nearby_bodies_give_every_contact_of_a_drive_into_the_walls(office) -> None:
    # facing the corridor's left wall (y = 1.2 m) from 0.8 m, straight into it at full speed, then
    # random turns pushing along it
    office.teleport((0.0, 0.4, math.pi / 2))
    touched, names = _drive(office, (3000.0, 3000.0), intervals=40, n=24)
    rng = np.random.default_rng(3)
    for _ in range(30):
        office.robot.set_motor_rpm(*rng.uniform(-3000, 3000, 2))
        t, nm = _drive(office, None, intervals=1, n=24)
        touched += t
        names |= nm
    assert touched > 50 and names  # the check saw contacts, not only empty sets


def test_a_body_out_of_reach_is_not_asked_and_the_reach_grows_with_the_interval(office) -> None:
    office.teleport((0.0, 0.0, 0.0))
    office.step(24)
    names = office._body_names
    near1 = {names[b] for b in office._contact_candidates(1)}
    near_long = {names[b] for b in office._contact_candidates(240 * 20)}  # 20 s at 5 m/s: everything
    assert near1 < near_long and len(near_long) == len(office._static_boxes)
    # the far walls are left out of a one-step interval
    c = office.world.client
    x, y = p.getBasePositionAndOrientation(office.robot.body, physicsClientId=c)[0][:2]
    for body, (lo, hi) in office._static_boxes.items():
        gap = math.hypot(max(lo[0] - x, 0, x - hi[0]), max(lo[1] - y, 0, y - hi[1]))
        if gap > 3.0:
            assert names[body] not in near1
