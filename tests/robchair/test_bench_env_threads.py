"""`robchair bench env`'s view of a vector env's workers: their threads (oversubscription check)."""

from __future__ import annotations

import sys

import pytest


def test_bench_env_counts_the_threads_of_a_process_from_proc() -> None:
    """The async rows' threads per worker come from /proc/<pid>/task: a thread started here is counted,
    and a missing pid gives None, not a number."""
    import os
    import threading

    from robchair.commands import bench_env

    if not sys.platform.startswith("linux"):
        pytest.skip("/proc is Linux's")
    (before,) = bench_env._threads_of([os.getpid()]) or [None]
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        (during,) = bench_env._threads_of([os.getpid()]) or [None]
    finally:
        stop.set()
        t.join()
    assert before is not None and during == before + 1
    assert bench_env._threads_of([]) is None
    assert bench_env._threads_of([2**22 + 12345]) is None


def test_the_independent_processes_row_runs_its_envs_at_the_same_time_and_reports_each() -> None:
    """The machine's ceiling for two workers: two forked processes each step their own env, started
    together at a barrier; each reports its wall and CPU seconds (no vector env between them)."""
    import time

    from robchair.commands import bench_env

    (cfg,) = [c for c in bench_env.CONFIGS if c.get("processes") and c["id"] == "RobChair/Navigation-v1"]
    assert cfg["processes"] == 2
    t0 = time.perf_counter()
    runs = bench_env._independent_runs(cfg, 4, 0)
    assert len(runs) == 2
    for wall, cpu in runs:
        assert 0 < wall < time.perf_counter() - t0 and cpu > 0
    row = bench_env.measure(cfg, 4, 1, 0)
    assert row["median_steps_per_s"] > 0 and len(row["process_cpu_ms_per_step"]) == 2


def test_the_idle_row_sleeps_before_every_step_and_is_no_one_env_baseline(monkeypatch) -> None:
    """An Async worker sleeps in its pipe between steps; the "idle per step" row steps the same env
    with a sleep before each step (CPU time without the sleep), and is not the one-env baseline of
    the "vs one env" column or of the CPU ratios."""
    from robchair.commands import bench_env

    (cfg,) = [c for c in bench_env.CONFIGS if c.get("idle_s")]
    assert cfg["idle_s"] == 1e-3 and cfg["id"] == "RobChair/Navigation-v1"
    assert not bench_env._one_env(cfg)
    assert [c["name"] for c in bench_env.CONFIGS if bench_env._one_env(c) and c["id"] == cfg["id"]] == [
        "light (Navigation-v1)"
    ]
    events: list[object] = []

    class Env:
        action_space = __import__("gymnasium").spaces.Box(-1.0, 1.0, (2,))

        def reset(self, seed=None):
            events.append("reset")

        def step(self, action):
            events.append("step")
            return None, 0.0, False, False, {}

    monkeypatch.setattr(bench_env.time, "sleep", lambda s: events.append(s))
    bench_env._env_run(Env(), 3, 0, 1e-3)
    assert events == ["reset", 1e-3, "step", 1e-3, "step", 1e-3, "step"]
    events.clear()
    bench_env._env_run(Env(), 2, 0)
    assert events == ["reset", "step", "step"]


def test_the_stand_in_s_calibration_gives_the_iterations_of_the_cpu_asked(monkeypatch) -> None:
    """With a clock on which one iteration of the work takes 2 us of CPU (hand-made, so the figure does
    not depend on the machine's phase: two real calibrations a second apart differed by 1.6x on the
    loaded VM), 1 ms asks 500 iterations and 4 ms 2000."""
    from robchair.commands import bench_env_standin as S

    clock = [0.0]

    def work(n: int) -> float:
        clock[0] += 2e-6 * n
        return 0.0

    monkeypatch.setattr(S, "_work", work)
    monkeypatch.setattr(S.time, "thread_time", lambda: clock[0])
    assert (S.iterations_for(1.0), S.iterations_for(4.0)) == (500, 2000)


def test_the_stand_in_env_does_the_asked_work_and_returns_the_light_envs_info() -> None:
    """The Async ceiling row's stand-in: its work per step is about the CPU asked (calibrated here),
    it has the light env's spaces, and it returns the info it was given at every step; two Async
    workers of it step and the speedups are steps/s over one in-process."""
    import time

    import gymnasium

    import sim.envs  # noqa: F401
    from robchair.commands import bench_env_standin as S

    n4 = S.iterations_for(4.0)
    obs, act, info = S.light_template("RobChair/Navigation-v1", 0)
    assert "safety" in info
    env = S.StandInEnv(obs, act, n4, info)
    o, _ = env.reset(seed=0)
    assert obs.contains(o)
    c = time.thread_time()
    for _ in range(5):
        _, _, term, trunc, got = env.step(act.sample())
    per = (time.thread_time() - c) / 5
    assert got is info and not term and not trunc and 1e-3 < per < 0.05
    res = S.measure_standin("RobChair/Navigation-v1", 1.0, 10, 1, 0)
    assert res["iterations"] > 0 and res["one_steps_per_s"] > 0
    assert res["speedup"] == res["async2_steps_per_s"] / res["one_steps_per_s"]
    assert res["speedup_with_info"] == res["async2_with_info_steps_per_s"] / res["one_steps_per_s"]
    assert isinstance(gymnasium.vector.AsyncVectorEnv, type)


def test_the_rows_are_measured_in_rounds_and_their_runs_merged_with_medians_over_them(monkeypatch) -> None:
    """Round k runs every configuration once with seed + k (a drifting machine slows all rows alike);
    a row's runs are those of the rounds, medians recomputed over them, safety stops summed."""
    from robchair.commands import bench_env

    calls = []

    def fake(config, steps, repeats, seed):  # type: ignore[no-untyped-def]
        calls.append((config["name"], repeats, seed))
        k = seed - 10
        out = {"steps_per_s": [100.0 * (k + 1)], "median_steps_per_s": 0.0, "safety_stop_steps": k}
        if config["name"] == "vec":
            out |= {"worker_cpu_ms_per_step": [[1.0 + k, 2.0 + k]], "median_worker_cpu_ms_per_step": 0.0,
                    "worker_threads": [k, k]}  # fmt: skip
        return out

    monkeypatch.setattr(bench_env, "measure", fake)
    rows = bench_env.measure_rounds(({"name": "a"}, {"name": "vec"}), 50, 3, 10)
    assert calls == [("a", 1, 10), ("vec", 1, 10), ("a", 1, 11), ("vec", 1, 11), ("a", 1, 12), ("vec", 1, 12)]
    a, vec = rows
    assert a["steps_per_s"] == [100.0, 200.0, 300.0] and a["median_steps_per_s"] == 200.0
    assert a["safety_stop_steps"] == 0 + 1 + 2
    assert vec["worker_cpu_ms_per_step"] == [[1.0, 2.0], [2.0, 3.0], [3.0, 4.0]]
    assert vec["median_worker_cpu_ms_per_step"] == 2.5
    assert vec["worker_threads"] == [2, 2]
