"""The first run after an install says that it is compiling, instead of sitting silent for half a minute."""

from __future__ import annotations

import os
import subprocess
import sys
import types
from pathlib import Path

from mapping._deps import announce_compilation

ROOT = Path(__file__).resolve().parents[2]


def test_an_empty_kernel_cache_is_announced_on_stderr_when_the_kernels_are_imported(tmp_path) -> None:
    """numba caches compiled kernels in NUMBA_CACHE_DIR; an empty one is what a fresh install has."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", "import mapping._vhv_kernels"], env=env, capture_output=True,
                         text=True, timeout=120, check=True)  # fmt: skip
    assert "compiling mapping kernels (first run only" in res.stderr


def _module_with_index(name: str, index: Path) -> types.ModuleType:
    mod = types.ModuleType(name)
    kernel = types.SimpleNamespace(_cache=types.SimpleNamespace(_cache_file=types.SimpleNamespace()))
    kernel._cache._cache_file._index_path = str(index)
    mod.kernel = kernel  # type: ignore[attr-defined]
    return mod


def test_cached_kernels_say_nothing_and_missing_ones_are_announced_once(tmp_path, capsys) -> None:
    """A module with a cached kernel (its index file exists) was compiled before: nothing is said. A module
    with none is announced, once."""
    index = tmp_path / "kernel.nbi"
    index.write_bytes(b"")
    announce_compilation(_module_with_index("cached_kernels_for_test", index), "test kernels")
    assert capsys.readouterr().err == ""
    missing = _module_with_index("uncached_kernels_for_test", tmp_path / "absent.nbi")
    announce_compilation(missing, "test kernels")
    announce_compilation(missing, "test kernels")
    assert capsys.readouterr().err.count("compiling test kernels") == 1
