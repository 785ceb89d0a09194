"""Digests of seeded light-environment episodes: every observation, reward, termination and info, and
the runtime's result (poses, safety stops, distances, the maps), for bit-for-bit comparisons.

``python -m tests.robchair.env_step_record`` writes :data:`DIGESTS` (the reference of
``test_env_step_bits.py``); regenerate it only for a change that is meant to alter an episode.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

DIGESTS = Path(__file__).parent / "data" / "env_step_digests.json"

#: (name, env id, make kwargs, reset seed, action seed, steps)
CASES: tuple[tuple[str, str, dict[str, Any], int, int, int], ...] = (
    ("v1", "RobChair/Navigation-v1", {}, 3, 5, 300),
    ("v1-odometry-frame", "RobChair/Navigation-v1", {"pose_source": "odometry", "map_memory": "frame"},
     8, 9, 90),
    ("v2", "RobChair/Navigation-v2", {}, 4, 6, 60),
)  # fmt: skip


def _h(*parts: Any) -> str:
    """sha256 of arrays (dtype, shape and bytes) and other values (their repr)."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(repr(p).encode())
    return h.hexdigest()[:20]


def _obs(obs: dict[str, np.ndarray]) -> str:
    return _h(*[x for k in sorted(obs) for x in (k, obs[k])])


def _result(res: Any) -> dict[str, str]:
    """The runtime result's deterministic parts (wall and CPU times left out)."""
    maps = {}
    for name, m in sorted(res.maps.items()):
        if hasattr(m, "cell_keys"):
            s = m.structures()
            maps[name] = _h(np.asarray(m.cell_keys), np.asarray(s.bottom), np.asarray(s.top))
        else:
            maps[name] = _h(type(m).__name__, getattr(m, "n_structures", None))
    return {
        "scalars": _h(res.cycles, res.sim_time_s, res.final_pose, res.distance_m, res.limited_cycles,
                      res.min_sonar_distance_m, res.min_map_distance_m, res.map_frames,
                      res.watchdog_trips, res.deadline_misses, res.driver_fault, res.error),
        "stops": _h(res.stops),
        "poses": _h(np.asarray(res.poses, dtype=np.float64)),
        "frames": _h(sorted(res.extra.get("frames", {}).items())),
        "maps": _h(sorted(maps.items())),
    }  # fmt: skip


def record_case(
    env_id: str, kwargs: dict[str, Any], seed: int, action_seed: int, steps: int
) -> dict[str, Any]:
    """Run the case; per step ``[obs digest, reward, terminated, truncated, info digest]``, the
    results of the episodes (one per reset) and counts of what happened (safety, ends)."""
    import gymnasium

    import sim.envs  # noqa: F401  (registers the ids)

    env = gymnasium.make(env_id, **kwargs)
    rng = np.random.default_rng(action_seed)
    out: dict[str, Any] = {"steps": [], "results": [], "counts": {}}
    counts: dict[str, int] = {}
    try:
        obs, info = env.reset(seed=seed)
        out["reset"] = [_obs(obs), _h(sorted(info.items()))]
        u: Any = env.unwrapped
        action = np.zeros(2, np.float32)
        for k in range(steps):
            if k % 4 == 0:  # hold each random command a few steps: the chair gets somewhere
                action = np.array([rng.uniform(-0.4, 1.0), rng.uniform(-1.0, 1.0)], np.float32)
            obs, reward, terminated, truncated, info = env.step(action)
            out["steps"].append([_obs(obs), repr(reward), terminated, truncated, _h(sorted(info.items()))])
            why = str(info["safety"]["reason"]).split(":")[0]
            counts[why] = counts.get(why, 0) + 1
            if terminated or truncated:
                counts["ends"] = counts.get("ends", 0) + 1
                res = u.runtime.result
                obs, info = env.reset()
                out["results"].append(_result(res))
                out["steps"].append(["reset", _obs(obs), _h(sorted(info.items()))])
        res = u.runtime.result
        u.runtime.stop()
        out["results"].append(_result(res))
    finally:
        env.close()
    out["counts"] = counts
    return out


def record() -> dict[str, Any]:
    """Every case of :data:`CASES`, by name, with the sensors' Embree casters (as the digests were
    recorded; test_env_step_bits replays them so)."""
    import sim.laser
    import sim.sonar

    sim.laser.DEFAULT_CASTER = sim.sonar.DEFAULT_CASTER = "embree"
    return {name: record_case(env_id, kw, seed, a_seed, n) for name, env_id, kw, seed, a_seed, n in CASES}


if __name__ == "__main__":
    doc = record()
    DIGESTS.write_text(json.dumps(doc, indent=0) + "\n")
    for name, case in doc.items():
        print(name, len(case["steps"]), "steps", case["counts"], file=sys.stderr)
