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
