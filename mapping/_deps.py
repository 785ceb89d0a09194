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
