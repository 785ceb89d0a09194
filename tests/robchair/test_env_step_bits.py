"""The light environment's episodes, bit for bit as recorded (``tests/robchair/data/env_step_digests.json``).

The reference was recorded from the code before the step's fast paths (``env_step_record``): every
observation, reward, termination and info of seeded episodes, and the runtime's result (poses, safety
stops, distances, the maps) must come out the same, digest for digest. It was recorded with the
sensors' Embree casters, so the episodes are replayed with them: the chair's default casters (the
laser's plane cut, the sonars' raster) give Embree's hits only to its float32 rounding, which moves a
millimetre-rounded reading now and then, and have their own tests against Embree. Embree's own last bit
depends on the vector instructions it picks on the machine, so the file holds one reference per machine it
was recorded on (all from the code before the fast paths), and an episode must equal one of them in full.
"""

from __future__ import annotations

import pytest

pytest.importorskip("pybullet")
pytest.importorskip("gymnasium")

from tests.robchair.env_step_record import CASES, first_difference, record_case, references


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
    got = record_case(env_id, kwargs, seed, action_seed, steps)
    misses = {ref["recorded_on"]: first_difference(got, ref["cases"][name]) for ref in references()}
    assert None in misses.values(), "matches no recorded reference: " + "; ".join(
        f"{where}: {why}" for where, why in misses.items()
    )


def test_the_references_differ_only_where_embree_rounds_a_laser_beam_the_other_way():
    """The machines' references are the same episodes: same rewards, ends, infos and results, and an
    observation differs in a handful of steps only (one laser beam a millimetre apart)."""
    refs = references()
    assert len(refs) >= 2
    for name, *_ in CASES:
        a, b = (r["cases"][name] for r in refs[:2])
        assert a["results"] == b["results"] and a["counts"] == b["counts"] and a["reset"] == b["reset"]
        assert len(a["steps"]) == len(b["steps"])
        apart = [k for k, (x, y) in enumerate(zip(a["steps"], b["steps"], strict=True)) if x != y]
        assert all(a["steps"][k][1:] == b["steps"][k][1:] for k in apart)  # observation digest only
        assert len(apart) <= 0.02 * len(a["steps"])
