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


def test_a_module_announced_while_another_compiles_is_said_when_its_own_kernel_starts(
    tmp_path, capsys, monkeypatch
) -> None:
    """The Kinect thread compiles its kernels while the loop announces the wheel kernels (which wait for
    numba's compiler): the screen keeps the Kinect line until a wheel kernel starts, then names it."""
    from mapping import _deps

    monkeypatch.setattr(_deps, "_compiling", ["another_module_compiling"])
    monkeypatch.setattr(_deps, "_last_said", ["another_module_compiling"])
    waiting = _module_with_index("waiting_kernels_for_test", tmp_path / "absent.nbi")
    announce_compilation(waiting, "waiting kernels")
    assert capsys.readouterr().err == ""
    _deps._compile_started("another_module_compiling")  # its next kernel: still the same line
    assert capsys.readouterr().err == ""
    _deps._compile_started("waiting_kernels_for_test")
    assert capsys.readouterr().err.startswith("compiling waiting kernels (first run only")
    _deps._compile_started("waiting_kernels_for_test")
    assert capsys.readouterr().err == ""


def _cached_kernels_and_announces(path: Path) -> tuple[list[str], bool]:
    """The functions of ``path`` compiled by numba with ``cache=True``, and whether it calls
    :func:`announce_compilation`."""
    import ast

    tree = ast.parse(path.read_text(encoding="utf-8"))
    kernels = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            for dec in node.decorator_list:
                cached = isinstance(dec, ast.Call) and any(
                    k.arg == "cache" and isinstance(k.value, ast.Constant) and k.value.value is True
                    for k in dec.keywords
                )
                name = ast.unparse(dec.func) if isinstance(dec, ast.Call) else ""
                if cached and name.split(".")[-1] in ("njit", "jit"):
                    kernels.append(node.name)
    announces = any(
        isinstance(n, ast.Call) and ast.unparse(n.func).split(".")[-1] == "announce_compilation"
        for n in ast.walk(tree)
    )
    return kernels, announces


def test_every_module_with_cached_kernels_says_when_it_compiles_them() -> None:
    """A first run is silent for no kernel: each module of the packages that defines a numba kernel
    cached on disk calls :func:`announce_compilation` (at import or before the first call)."""
    silent = {}
    for package in ("mapping", "sim", "robchair", "hw"):
        for path in sorted((ROOT / package).rglob("*.py")):
            kernels, announces = _cached_kernels_and_announces(path)
            if kernels and not announces:
                silent[str(path.relative_to(ROOT))] = kernels
    assert silent == {}, f"modules that compile kernels without saying so on a first run: {silent}"


def test_the_kernel_scan_finds_the_kernels_it_checks() -> None:
    """The scan above sees the suite's kernel modules (it would pass vacuously on a scan that finds none)."""
    kernels, announces = _cached_kernels_and_announces(ROOT / "sim" / "_kinect_kernels.py")
    assert "finish" in kernels and announces
    kernels, _ = _cached_kernels_and_announces(ROOT / "mapping" / "io" / "lzf.py")
    assert kernels == ["_decompress_into", "_compress_into"]


_KERNEL_MODULE = """
import sys
import numba
from mapping._deps import announce_compilation


@numba.njit(cache=True)
def kernel(x):
    return x + {n}


announce_compilation(sys.modules[__name__], "{name} kernels")
"""


def test_a_module_is_announced_again_when_its_kernels_compile_after_another_modules(tmp_path) -> None:
    """Module a is announced at import, then b; a's kernel compiles next, so a's message comes again (the
    screen names what compiles). With the cache filled a second run says nothing."""
    for n, name in enumerate(("alpha", "beta")):
        (tmp_path / f"{name}_kernels_mod.py").write_text(_KERNEL_MODULE.format(n=n, name=name))
    code = "import alpha_kernels_mod as a, beta_kernels_mod as b\na.kernel(1)\nb.kernel(1)"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": f"{tmp_path}:{ROOT}"}
    run = [sys.executable, "-c", code]
    kw = {"env": env, "capture_output": True, "text": True, "timeout": 120, "check": True, "cwd": tmp_path}
    first = subprocess.run(run, **kw)  # type: ignore[call-overload]
    said = [line.split(" (")[0] for line in first.stderr.splitlines() if line.startswith("compiling")]
    assert said == ["compiling alpha kernels", "compiling beta kernels", "compiling alpha kernels",
                    "compiling beta kernels"]  # fmt: skip
    again = subprocess.run(run, **kw)  # type: ignore[call-overload]
    assert "compiling" not in again.stderr
