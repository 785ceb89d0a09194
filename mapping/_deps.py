"""Optional heavy imports with clear messages (open3d needs libusb preloaded)."""

from __future__ import annotations

import ctypes
import importlib
from types import ModuleType
from typing import Any

from mapping.errors import MappingError

_open3d: ModuleType | None = None


def _preload_libusb() -> None:
    """Load the libusb-1.0 shipped by the `libusb-package` wheel before open3d.

    open3d's wheel links against ``libusb-1.0.so.0`` but pip does not provide it; loading the copy
    from `libusb-package` with RTLD_GLOBAL satisfies the dynamic linker without a system package.
    """
    try:
        ctypes.CDLL("libusb-1.0.so.0", mode=ctypes.RTLD_GLOBAL)
        return
    except OSError:
        pass
    try:
        import libusb_package
    except ImportError as exc:  # pragma: no cover - dependency of the distribution
        raise MappingError("open3d needs libusb-1.0: pip install libusb-package") from exc
    path = libusb_package.get_library_path()
    if path is None:  # pragma: no cover
        raise MappingError("libusb-package did not ship a libusb-1.0 library for this platform")
    ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)


def import_open3d() -> Any:
    """Import open3d (once), preloading libusb; raise a clear MappingError if unavailable."""
    global _open3d
    if _open3d is None:
        _preload_libusb()
        try:
            _open3d = importlib.import_module("open3d")
        except ImportError as exc:
            raise MappingError(f"open3d is required here but could not be imported: {exc}") from exc
    return _open3d


def require(module: str, purpose: str) -> Any:
    """Import an optional module or raise a MappingError naming the package and why it is needed."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MappingError(f"{purpose} needs the Python package '{module}' ({exc})") from exc


_announced: set[str] = set()


def announce_compilation(module: ModuleType, what: str) -> None:
    """Say on stderr, once per process and module, that ``module``'s numba kernels are being compiled.

    numba compiles a kernel at its first call and caches it on disk (``cache=True``), so only the first
    run after an install pays (tens of seconds for the mapping kernels). A kernel has been cached when
    its index file exists; a module none of whose kernels has one is compiled for the first time (a run
    that finds some indexes compiles only the kernels it had not used before, and says nothing).
    """
    name = module.__name__
    if name in _announced:
        return
    _announced.add(name)
    import os
    import sys

    indexes = []
    for obj in vars(module).values():
        index = getattr(getattr(getattr(obj, "_cache", None), "_cache_file", None), "_index_path", None)
        if isinstance(index, str):
            indexes.append(os.path.exists(index))
    if indexes and not any(indexes):
        print(f"compiling {what} (first run only, cached afterwards)...", file=sys.stderr, flush=True)
