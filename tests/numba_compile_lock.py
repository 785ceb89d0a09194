"""One numba compilation of each cached kernel for all the test run's workers, not one per worker.

A kernel with ``cache=True`` is compiled at its first call in a process and then written to the disk
cache; a process that finds it there loads it (milliseconds) instead. The xdist workers of a run on a
cold cache (a fresh clone) start together and call the same kernels, so without this each worker
compiles each kernel: the compile time of the first run is paid twice. With it, a worker about to
compile a cached kernel first takes a lock file of that kernel (``fcntl.flock``, one per kernel's
cache index) and only then looks in the cache: the worker that came second waits until the first has
written the kernel, and loads it. The two workers do different tests, so most of the time each
compiles kernels the other is not waiting for.

The lock is taken inside numba's own compiler lock, so in one process one thread at a time holds such
locks, and a kernel compiled while another is (a kernel it calls) is locked in the same thread
(re-entrant: a kernel already locked by this process is not locked again). A wait is bounded
(:data:`WAIT_S`): after it, the worker compiles as it would without this module, so the run never
hangs on a lock, and a lock that cannot be taken at all (no ``fcntl``, unwritable folder) changes
nothing. What is compiled, and the cache's files, are numba's own.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import time
from pathlib import Path
from typing import Any

WAIT_S = 120.0  # longer than the longest single kernel compile of the suite (the mapping kernels: ~20 s)
POLL_S = 0.05
LOCKS = Path(tempfile.gettempdir()) / "robchair-numba-compile-locks"

_held: set[str] = set()  # index paths this process holds the lock of (under numba's compiler lock)


def _index_path(dispatcher: Any) -> str | None:
    path = getattr(getattr(getattr(dispatcher, "_cache", None), "_cache_file", None), "_index_path", None)
    return path if isinstance(path, str) else None


def _lock(index: str) -> int | None:
    """An open, flock-ed file descriptor for the kernel of cache index ``index``; None if none was had
    within :data:`WAIT_S` (or locks cannot be taken here)."""
    import fcntl

    try:
        LOCKS.mkdir(exist_ok=True)
        fd = os.open(LOCKS / (hashlib.sha1(index.encode()).hexdigest() + ".lock"), os.O_RDWR | os.O_CREAT)
    except OSError:
        return None
    end = time.monotonic() + WAIT_S
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fd
        except BlockingIOError:
            if time.monotonic() > end:
                break
            time.sleep(POLL_S)
        except OSError:
            break
    os.close(fd)
    return None


def install() -> None:
    """Wrap ``numba``'s ``Dispatcher.compile`` with the per-kernel lock (once per process)."""
    from numba.core.compiler_lock import global_compiler_lock
    from numba.core.dispatcher import Dispatcher

    original = Dispatcher.compile
    if getattr(original, "_robchair_locked", False):
        return

    def compile(self: Any, sig: Any) -> Any:
        index = _index_path(self)
        if index is None:
            return original(self, sig)
        with global_compiler_lock:
            if index in _held:
                return original(self, sig)
            fd = _lock(index)
            if fd is None:
                return original(self, sig)
            _held.add(index)
            try:
                return original(self, sig)  # loads from the cache what another worker wrote meanwhile
            finally:
                _held.discard(index)
                os.close(fd)  # releases the flock

    compile._robchair_locked = True  # type: ignore[attr-defined]
    Dispatcher.compile = compile
