"""The light environment's episodes, bit for bit as recorded (``tests/robchair/data/env_step_digests.json``).

The reference was recorded from the code before the step's fast paths (``env_step_record``): every
observation, reward, termination and info of seeded episodes, and the runtime's result (poses, safety
stops, distances, the maps) must come out the same, digest for digest. It was recorded with the
sensors' Embree casters, so the episodes are replayed with them: the chair's default casters (the
laser's plane cut, the sonars' raster) give Embree's hits only to its float32 rounding, which moves a
millimetre-rounded reading now and then, and have their own tests against Embree.
"""

from __future__ import annotations

import json

import pytest

pytest.importorskip("pybullet")
pytest.importorskip("gymnasium")

from tests.robchair.env_step_record import CASES, DIGESTS, record_case


@pytest.fixture
def embree_casters(monkeypatch):
    """The sensors cast through Embree, as when the digests were recorded."""
    import sim.laser
    import sim.sonar

    monkeypatch.setattr(sim.laser, "DEFAULT_CASTER", "embree")
    monkeypatch.setattr(sim.sonar, "DEFAULT_CASTER", "embree")


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_a_seeded_light_episode_is_the_recorded_one_bit_for_bit(case, embree_casters):
    name, env_id, kwargs, seed, action_seed, steps = case
    want = json.loads(DIGESTS.read_text())[name]
    got = record_case(env_id, kwargs, seed, action_seed, steps)
    assert got["reset"] == want["reset"], "the first observation or info differs"
    for k, (a, b) in enumerate(zip(got["steps"], want["steps"], strict=True)):
        assert a == b, f"step {k} differs: {a} != {b}"
    assert got["results"] == want["results"]
    assert got["counts"] == want["counts"]
