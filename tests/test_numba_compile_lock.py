"""A worker that needs a cached kernel another worker is compiling waits and loads it from the cache."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from tests import numba_compile_lock

ROOT = Path(__file__).resolve().parents[1]
KERNEL = """
import numba


@numba.njit(cache=True)
def kernel(x):
    s = 0.0
    for i in range(x.shape[0]):
        s += x[i] * x[i]
    return s
"""
CHILD = """
import sys, numpy as np
sys.path[:0] = [{root!r}, {folder!r}]
if {lock}:
    from tests.numba_compile_lock import install
    install()
import kern
print("calling", flush=True)
kern.kernel(np.arange(3.0))
print(sum(kern.kernel.stats.cache_hits.values()), sum(kern.kernel.stats.cache_misses.values()), flush=True)
"""


def _hits_misses_of_a_second_worker(tmp_path: Path, lock: bool) -> tuple[int, int]:
    """This process holds the kernel's lock while a child calls the kernel; 0.5 s after the child
    called, this process compiles the kernel (writing the cache) and lets go. The child's cache hits
    and misses."""
    import importlib

    folder = tmp_path / f"k{int(lock)}"
    folder.mkdir()
    (folder / "kern.py").write_text(KERNEL, encoding="utf-8")
    sys.path.insert(0, str(folder))
    try:
        kern = importlib.import_module("kern")
        index = numba_compile_lock._index_path(kern.kernel)
        assert index is not None
        fd = numba_compile_lock._lock(index)
        assert fd is not None
        numba_compile_lock._held.add(index)  # (this process's own compile below does not wait on it)
        child = subprocess.Popen(
            [sys.executable, "-c", CHILD.format(root=str(ROOT), folder=str(folder), lock=lock)],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert child.stdout is not None and child.stdout.readline() == "calling\n"
            time.sleep(0.5)
            import numpy as np

            kern.kernel(np.arange(3.0))  # compiled here and written to the cache
        finally:
            import os

            numba_compile_lock._held.discard(index)
            os.close(fd)
        out, _ = child.communicate(timeout=120)
    finally:
        sys.path.remove(str(folder))
        sys.modules.pop("kern", None)
    hits, misses = (int(v) for v in out.split())
    return hits, misses


def test_the_second_worker_loads_the_kernel_the_first_compiled(tmp_path: Path) -> None:
    assert _hits_misses_of_a_second_worker(tmp_path, lock=True) == (1, 0)

