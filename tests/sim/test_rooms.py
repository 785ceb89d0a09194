"""Random floors: seeded, within the accessible-door and table ranges, feasible for the chair."""

from __future__ import annotations

import dataclasses

import pytest

from sim.rooms import (
    DOOR_WIDTH,
    EVAL_SEEDS,
    TRAIN_SEEDS,
    FloorConfig,
    RoomsError,
    floor_is_feasible,
    generate_floor,
)
from sim.scene import SceneObject


def test_a_seed_always_gives_the_same_floor_and_other_seeds_other_floors():
    a, b, c = generate_floor(7), generate_floor(7), generate_floor(8)
    assert a.scene.objects == b.scene.objects
    assert a.scene.objects != c.scene.objects


def test_doorways_are_as_wide_as_accessible_doors_and_tables_too_low_to_drive_under():
    spec_height = FloorConfig().chair_height
    tables = 0
    for seed in range(6):
        floor = generate_floor(seed)
        assert len(floor.rooms) >= 2
        for _, _, w in floor.doors:
            assert DOOR_WIDTH[0] <= w <= DOOR_WIDTH[1]
        for obj in floor.scene.objects:
            if obj.name.endswith("_top"):
                tables += 1
                top = obj.xyz[2] + obj.size[2] / 2
                assert 0.10 < top < spec_height  # in the chair's obstacle band: it cannot pass under
    assert tables > 0


def test_every_generated_floor_joins_corridor_and_rooms_for_the_chair():
    for seed in (0, 1, 2):
        floor = generate_floor(seed)
        assert floor_is_feasible(floor, FloorConfig())


def test_a_floor_with_a_blocked_doorway_is_not_feasible():
    floor = generate_floor(0)
    x, y, w = floor.doors[0]
    plug = SceneObject(name="plug", shape="box", xyz=(x, y, 0.5), size=(w + 0.2, 0.6, 1.0))
    blocked = dataclasses.replace(
        floor, scene=dataclasses.replace(floor.scene, objects=(*floor.scene.objects, plug))
    )
    assert not floor_is_feasible(blocked, FloorConfig())


def test_walkers_walk_in_the_dynamic_configuration_only():
    assert not any(o.motion for o in generate_floor(3).scene.objects)
    walkers = [o for o in generate_floor(3, FloorConfig(walkers=2)).scene.objects if o.motion]
    assert len(walkers) == 2 and all(0.6 <= o.motion.speed <= 1.2 for o in walkers)


def test_training_and_evaluation_seed_ranges_never_overlap():
    assert TRAIN_SEEDS.stop <= EVAL_SEEDS.start or EVAL_SEEDS.stop <= TRAIN_SEEDS.start


def test_bad_seeds_and_ranges_are_refused():
    with pytest.raises(RoomsError, match="seed"):
        generate_floor(-1)
    with pytest.raises(RoomsError, match="corridor"):
        FloorConfig(corridor=(2.0, 1.0))
    with pytest.raises(RoomsError, match="walkers"):
        FloorConfig(walkers=-1)
