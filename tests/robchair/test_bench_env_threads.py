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
