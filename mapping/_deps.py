"""Optional heavy imports with clear messages (open3d needs libusb preloaded)."""

from __future__ import annotations

import ctypes
import importlib
import sys
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


class _DashName:
    """One name of ``dash`` (``html``, ``dcc``, ``Dash`` ...) as open3d took it, looked up in the real
    ``dash`` (imported then, once) when it is first used: an attribute read or a call."""

    def __init__(self, name: str) -> None:
        self._name = name

    def _target(self) -> Any:
        return getattr(importlib.import_module("dash"), self._name)

    def __getattr__(self, attr: str) -> Any:
        return getattr(self._target(), attr)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self._target()(*args, **kwargs)


def _deferred_dash() -> ModuleType:
    """A stand-in ``dash`` module whose every name is a :class:`_DashName`."""
    stand_in = ModuleType("dash", "dash, imported at the first use of one of its names")
    stand_in.__getattr__ = _DashName  # type: ignore[method-assign]  # module __getattr__ (PEP 562)
    return stand_in


def import_open3d() -> Any:
    """Import open3d (once), preloading libusb; raise a clear MappingError if unavailable.

    open3d's ``visualization`` imports ``dash`` (a web framework, about 0.4 s of CPU at start-up with
    what it imports: plotly's app server, requests, IPython ...) only for ``draw_plotly_server``, which
    nothing here calls. While open3d is imported, ``dash`` (if not imported yet) is a stand-in whose names
    import the real ``dash`` when first used, so ``draw_plotly_server`` works as before; afterwards
    ``import dash`` imports the real one."""
    global _open3d
    if _open3d is None:
        _preload_libusb()
        stand_in = None if "dash" in sys.modules else _deferred_dash()
        if stand_in is not None:
            sys.modules["dash"] = stand_in
        try:
            _open3d = importlib.import_module("open3d")
        except ImportError as exc:
            raise MappingError(f"open3d is required here but could not be imported: {exc}") from exc
        finally:
            if stand_in is not None and sys.modules.get("dash") is stand_in:
                del sys.modules["dash"]
    return _open3d


def require(module: str, purpose: str) -> Any:
    """Import an optional module or raise a MappingError naming the package and why it is needed."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MappingError(f"{purpose} needs the Python package '{module}' ({exc})") from exc


_announced: set[str] = set()
# modules announced as compiled for the first time -> their message; the module of the last message said
_first_compiles: dict[str, str] = {}
_last_said: list[str] = [""]


def announce_compilation(module: ModuleType, what: str) -> None:
    """Say on stderr, once per process and module, that ``module``'s numba kernels are being compiled.

    numba compiles a kernel at its first call and caches it on disk (``cache=True``), so only the first
    run after an install pays (tens of seconds for the mapping kernels). A kernel has been cached when
    its index file exists; a module none of whose kernels has one is compiled for the first time (a run
    that finds some indexes compiles only the kernels it had not used before, and says nothing).

    A module is often announced (at import) long before some of its kernels compile (at their first
    call, e.g. when the first frame is mapped): once a module has been announced, the message is said
    again when the compilation of one of its kernels starts and the last message was another module's,
    so that the line on screen names what is compiling (a numba compile-event listener, see
    :func:`_say_again_when_compiling`). For the same reason a module announced while another module's
    kernel is compiling is said when its own first kernel starts, not at once.
    """
    name = module.__name__
    if name in _announced:
        return
    _announced.add(name)
    import os

    indexes = []
    for obj in vars(module).values():
        index = getattr(getattr(getattr(obj, "_cache", None), "_cache_file", None), "_index_path", None)
        if isinstance(index, str):
            indexes.append(os.path.exists(index))
    if indexes and not any(indexes):
        message = f"compiling {what} (first run only, cached afterwards)..."
        _first_compiles[name] = message
        _say_again_when_compiling()
        if _compiling[0] in (None, name):
            _last_said[0] = name
            print(message, file=sys.stderr, flush=True)
        # else another module's kernel is compiling (on another thread; numba compiles one kernel at a
        # time): the line on screen is right until this module's first kernel starts and is announced


_listening: list[bool] = [False]


def _say_again_when_compiling() -> None:
    """Register (once per process) a listener of numba's ``numba:compile`` events that repeats a
    first-compiled module's message when one of its kernels starts compiling after another module's
    message. numba fires the event only for a real compilation (not for a kernel loaded from the
    cache), so a run with a filled cache says nothing; nested compilations (the kernels and numba
    internals a kernel calls) are ignored."""
    if _listening[0]:
        return
    _listening[0] = True
    import threading

    from numba.core import event

    depth = threading.local()

    class _SayAgain(event.Listener):  # type: ignore[misc]
        def on_start(self, ev: Any) -> None:
            depth.n = getattr(depth, "n", 0) + 1
            if depth.n == 1:
                py_func = getattr(ev.data.get("dispatcher"), "py_func", None)
                _compile_started(str(getattr(py_func, "__module__", "")))

        def on_end(self, ev: Any) -> None:
            depth.n = getattr(depth, "n", 1) - 1
            if depth.n == 0:
                _compiling[0] = None

    event.register("numba:compile", _SayAgain())


# the module whose kernel is compiling (outermost compilation; numba compiles one at a time), or None
_compiling: list[str | None] = [None]


def _compile_started(name: str) -> None:
    """A kernel of module ``name`` starts compiling: say its module's message if the last one was another
    module's (and the module was announced as compiled for the first time)."""
    _compiling[0] = name
    if name in _first_compiles and name != _last_said[0]:
        _last_said[0] = name
        print(_first_compiles[name], file=sys.stderr, flush=True)
