"""Median CPU per sonar group cast: the raster's first_echo against the Embree path's (and Embree's
cast_rays alone), same process, at 300 poses spread over a RobChair/Navigation-v1 run.

Run: ``OPENBLAS_NUM_THREADS=1 python scripts/bench_sonar_cast.py [REPS=3] [STEPS=1200]``
(a measuring script, as scripts/profile_map_build.py).
"""

from __future__ import annotations

import sys
import time
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

import sim.envs  # noqa: F401  (registers the envs)
import sim.sonar as so
from sim._sonar_kernels import fill_rays


def record(steps: int) -> tuple[Any, Any, list[list[np.ndarray]]]:
    """Every group cast's sonar poses over a seeded run of ``steps`` env steps."""
    rec: list[tuple[Any, Any, list[np.ndarray]]] = []
    orig = so._Beam.first_echo

    def spy(self: Any, mirror: Any, poses: Any, **kw: Any) -> Any:
        rec.append((self, mirror, [np.array(p) for p in poses]))
        return orig(self, mirror, poses, **kw)

    so._Beam.first_echo = spy  # type: ignore[method-assign]
    try:
        env = gym.make("RobChair/Navigation-v1")
        env.reset(seed=1)
        env.action_space.seed(1)
        for _ in range(steps):
            _, _, te, tr, _ = env.step(env.action_space.sample())
            if te or tr:
                env.reset()
    finally:
        so._Beam.first_echo = orig  # type: ignore[method-assign]
    beam, mirror, _ = rec[-1]
    every = [p for _, m, p in rec if m is mirror]
    return beam, mirror, every[:: max(1, len(every) // 300)][:300]


def main(reps: int, steps: int) -> None:
    warnings.filterwarnings("ignore")
    beam, mirror, poses = record(steps)
    rays = np.empty((len(poses[0]) * len(beam.dirs), 6), np.float32)

    def cast_only(p: list[np.ndarray]) -> int:
        st = np.asarray(p)
        d = np.matmul(beam.dirs, st[:, :3, :3].transpose(0, 2, 1)).reshape(-1, 3)
        fill_rays(st, d, rays)
        t0 = time.process_time_ns()
        mirror.cast_raw(rays)
        return time.process_time_ns() - t0

    worst = 0.0
    for p in poses:
        a, b = beam.first_echo(mirror, p), beam.first_echo(mirror, p, caster="embree")
        assert np.array_equal(np.isnan(a), np.isnan(b)), (a, b)
        if np.isfinite(a).any():
            worst = max(worst, float(np.nanmax(np.abs(a - b))))
    print(f"{len(poses)} group casts of {len(poses[0])} sonars, worst |raster - embree| {worst:.3g} m")
    res: dict[str, list[int]] = {"raster first_echo": [], "embree first_echo": [], "embree cast_rays": []}
    for _ in range(reps):
        for p in poses:
            for caster, key in (("raster", "raster first_echo"), ("embree", "embree first_echo")):
                t0 = time.process_time_ns()
                beam.first_echo(mirror, p, caster=caster)
                res[key].append(time.process_time_ns() - t0)
            res["embree cast_rays"].append(cast_only(p))
    med = {k: float(np.median(v)) / 1e3 for k, v in res.items()}
    for k, v in med.items():
        print(f"{k:18s} median {v:7.1f} us over {len(res[k])} casts")
    whole = med["embree first_echo"] / med["raster first_echo"]
    alone = med["embree cast_rays"] / med["raster first_echo"]
    print(f"speed-up: {whole:.2f}x on the whole first_echo, {alone:.2f}x against Embree's cast alone")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3, int(sys.argv[2]) if len(sys.argv) > 2 else 1200)
