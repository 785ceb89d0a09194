"""Digests of seeded light-environment episodes: every observation, reward, termination and info, and
the runtime's result (poses, safety stops, distances, the maps), for bit-for-bit comparisons.

The episodes go through Embree's float32 ray casts, whose last bit depends on the instruction set Embree
picks on the machine (AVX2 or AVX-512: one laser beam in a few hundred steps lands on the other side of a
millimetre's rounding), so :data:`DIGESTS` holds one reference per machine it was recorded on, each
``{"recorded_on", "code", "cases"}``, all of them recorded from the code before the step's fast paths
(``code``: the commit). A run matches when it equals one reference's case in full.

``python -m tests.robchair.env_step_record`` writes :data:`DIGESTS` anew with this machine's recording
only (regenerate it only for a change that is meant to alter an episode); ``--add`` keeps the other
machines' references and adds, or replaces, this machine's (run it from a checkout of the reference code).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
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


def references() -> list[dict[str, Any]]:
    """The recorded references of :data:`DIGESTS`, each ``{"recorded_on", "code", "cases"}``."""
    return list(json.loads(DIGESTS.read_text())["references"])


def first_difference(got: dict[str, Any], want: dict[str, Any]) -> str | None:
    """Where the recorded case ``got`` first departs from ``want`` (None when they are equal)."""
    if got["reset"] != want["reset"]:
        return "the first observation or info differs"
    if len(got["steps"]) != len(want["steps"]):
        return f"{len(got['steps'])} steps against {len(want['steps'])}"
    for k, (a, b) in enumerate(zip(got["steps"], want["steps"], strict=True)):
        if a != b:
            return f"step {k} differs: {a} != {b}"
    if got["results"] != want["results"]:
        return f"the runtime results differ: {got['results']} != {want['results']}"
    if got["counts"] != want["counts"]:
        return f"the counts differ: {got['counts']} != {want['counts']}"
    return None


def this_machine() -> str:
    """The label of this machine's reference: CPU model, core count and Embree's widest vector set."""
    from robchair.commands.bench_output import cpu_model

    try:
        flags = set(Path("/proc/cpuinfo").read_text().split())
    except OSError:
        flags = set()
    isa = "AVX2" if "avx2" in flags else "SSE"
    if {"avx512f", "avx512vl", "avx512bw", "avx512dq"} <= flags:
        isa = "AVX-512"
    return f"{cpu_model()} ({os.cpu_count()} cores, {isa})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.robchair.env_step_record", description=__doc__)
    parser.add_argument("--add", action="store_true", help="keep the other machines' references")
    parser.add_argument("--code", default="HEAD", help="the commit whose code is recorded (a label)")
    args = parser.parse_args(argv)
    mine = {"recorded_on": this_machine(), "code": args.code, "cases": record()}
    others = [r for r in references() if r["recorded_on"] != mine["recorded_on"]] if args.add else []
    DIGESTS.write_text(json.dumps({"references": [*others, mine]}, indent=0) + "\n")
    for name, case in mine["cases"].items():
        print(name, len(case["steps"]), "steps", case["counts"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
