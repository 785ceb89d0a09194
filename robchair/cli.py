"""The `robchair` command line: one entry point, one sub-command module per capability.

Each module in COMMANDS / BENCHES exposes ``register(subparsers)`` which adds its parser and sets
``func`` (a callable taking the parsed ``argparse.Namespace`` and returning an exit code); a listed
module that cannot be imported is an error of the installation, raised as such. Modules import their
heavy dependencies inside ``func`` so ``robchair --help`` stays fast, and a command line that names one
command imports only that command's module (:func:`build_parser`).

Any error the project raises on purpose (MappingError, HardwareError, SimError, RobChairError), and
file-system errors, become one line on stderr and exit code 2.

SIGINT, SIGTERM and SIGHUP (where their action is still the default) raise
:class:`robchair.platform.errors.StopSignal` in the command: the drive loop stops the motors (zero speeds,
then the emergency stop), staging folders are removed, then one line is printed and the exit code is
``128 + signo`` (130, 143, 129). A repeated signal is ignored while that happens.

A signal that arrives while this thread compiles or loads a numba kernel (numba's compiler is Python
code driving LLVM; an exception raised in the middle of it leaves LLVM objects half-owned, which was
seen as a lost signal, a "no compiled object yet" error, or a double free at exit) first stops the
running drive loops' motors from the handler, then is raised once the compiler lock is released.

A command runs with numpy on one BLAS thread and without transparent huge pages for its arrays, unless
the environment says otherwise (``OPENBLAS_NUM_THREADS``, ``NUMPY_MADVISE_HUGEPAGE``; a process that
imported numpy before :func:`main` keeps its own, its child processes get these). On Linux numpy asks
the kernel for huge pages (``madvise``) for every array of 4 MB or more; the commands' arrays of that
size are mostly made, filled and freed once a frame (a Kinect frame and what is computed from it), and
there the kernel's huge-page faults cost more than they give back: on the 2-vCPU VM of the benchmarks
a 0.1 s `robchair sim office_tour --sensor kinect2-hd` took 5.3-7.8 s of CPU with them and 4.3-4.4 s
without (half of it system time spent faulting the pages in).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from typing import NoReturn

COMMANDS = (
    "robchair.commands.map",
    "robchair.commands.pid",
    "robchair.commands.sim",
    "robchair.commands.run",
    "robchair.commands.hw",
    "robchair.commands.sweep",
    "robchair.commands.view",
    "robchair.commands.report",
    "robchair.commands.nav_eval",
    "robchair.commands.assist_eval",
)
BENCHES = (
    "robchair.commands.bench_mapping",
    "robchair.commands.bench_sim",
    "robchair.commands.bench_table52",
    "robchair.commands.bench_env",
    "robchair.commands.bench_sweep",
    "robchair.commands.bench_zoom",
    "robchair.commands.bench_laser",
    "robchair.commands.bench_assist",
    "robchair.commands.bench_map",
    "robchair.commands.bench_table",
)


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors (a bad choice, a missing value ...) are one line, exit code 2.

    Sub-command parsers are of the same class (argparse creates them with the parent's class).
    """

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def command_name(module: str) -> str:
    """The sub-command a module of :data:`COMMANDS` / :data:`BENCHES` registers: its last name without
    ``bench_``, ``_`` as ``-`` (``robchair.commands.nav_eval`` -> ``nav-eval``)."""
    return module.rsplit(".", 1)[-1].removeprefix("bench_").replace("_", "-")


def _first_word(words: Sequence[str]) -> tuple[str | None, Sequence[str]]:
    """The first of ``words`` that is not an option, and the words after it; None before a help option
    or when every word is an option."""
    for i, word in enumerate(words):
        if word in ("-h", "--help"):
            break
        if not word.startswith("-"):
            return word, words[i + 1 :]
    return None, ()


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``robchair`` parser with every listed command, or, given the command line ``argv`` it will
    parse, with the one command that line names (``sim ...``; ``bench map ...``: the bench with that one
    benchmark): each command's module costs its import (all of them ~0.3 s of CPU, what every command
    paid before its work). A line naming no listed command (``--help``, a typo) gets every command, so
    help and errors list them all; one command's own parser and its help are the same either way.

    Raises:
        ModuleNotFoundError: A listed module that is imported cannot be found (an installation error).
    """
    commands: Sequence[str] = COMMANDS
    benches: Sequence[str] | None = BENCHES
    if argv is not None:
        first, rest = _first_word(argv)
        if first == "bench":
            commands = ()
            benches = [m for m in BENCHES if command_name(m) == _first_word(rest)[0]] or BENCHES
        elif chosen := [m for m in COMMANDS if command_name(m) == first]:
            commands, benches = chosen, None
    parser = OneLineParser(
        prog="robchair",
        description="RobChair digital twin: mapping, simulation, hardware and motor control.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in commands:
        importlib.import_module(name).register(sub)
    if benches is None:
        return parser
    bench = sub.add_parser("bench", help="benchmarks against named baselines (prints a table, writes JSON)")
    bench_sub = bench.add_subparsers(dest="bench", metavar="BENCH")
    for name in benches:
        importlib.import_module(name).register(bench_sub)

    def _bench_help(_args: argparse.Namespace) -> int:
        bench.print_help()
        return 2

    bench.set_defaults(func=_bench_help)
    return parser


def _project_errors() -> tuple[type[BaseException], ...]:
    from hw.errors import HardwareError
    from mapping.errors import MappingError
    from robchair.platform.errors import RobChairError
    from sim.errors import SimError

    return (MappingError, HardwareError, SimError, RobChairError, OSError)


STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


@contextlib.contextmanager
def stop_signals_raise() -> Iterator[None]:
    """Turn :data:`STOP_SIGNALS` into :class:`robchair.platform.errors.StopSignal` inside the block.

    A signal the parent set to be ignored (``nohup``) stays ignored; outside the main thread nothing
    is installed. The first signal raises; later ones are ignored so the stop and clean-up can finish.
    """
    from robchair.platform.errors import StopSignal

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    numbers = [getattr(signal, n) for n in STOP_SIGNALS if hasattr(signal, n)]
    deferred: list[int] = []

    def handler(signo: int, _frame: object) -> None:
        if _compiling_here():
            if not deferred:
                deferred.append(signo)
                _halt_running_loops(StopSignal(signo))
                _raise_after_compiling(deferred)
            return
        for s in numbers:
            signal.signal(s, signal.SIG_IGN)
        raise StopSignal(signo)

    previous = {}
    for s in numbers:
        if signal.getsignal(s) in (signal.SIG_DFL, signal.default_int_handler):
            previous[s] = signal.signal(s, handler)
    try:
        yield
    finally:
        for s, old in previous.items():
            signal.signal(s, old)


def _compiling_here() -> bool:
    """True while this thread holds numba's compiler lock (compiling or loading a cached kernel)."""
    lock_module = sys.modules.get("numba.core.compiler_lock")
    return bool(lock_module is not None and lock_module.global_compiler_lock.is_locked())


def _halt_running_loops(cause: BaseException) -> None:
    """Zero speeds and the emergency stop on the process's running drive loops (if any were made)."""
    runtime = sys.modules.get("robchair.runtime")
    if runtime is not None:
        runtime.halt_running_loops(cause)


def _raise_after_compiling(deferred: list[int]) -> None:
    """Deliver ``deferred[0]`` again once this thread has released numba's compiler lock."""
    from numba.core import event

    main = threading.current_thread()

    class _Released(event.Listener):  # type: ignore[misc]
        def on_start(self, _event: object) -> None:
            pass

        def on_end(self, _event: object) -> None:
            if threading.current_thread() is main and not _compiling_here():
                event.unregister("numba:compiler_lock", self)
                signo = deferred.pop()
                signal.raise_signal(signo)

    event.register("numba:compiler_lock", _Released())


def main(argv: Sequence[str] | None = None) -> int:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")  # read by numpy's import (module docstring)
    words = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(words)
    args = parser.parse_args(words)
    logging.basicConfig(
        level=(logging.WARNING, logging.INFO, logging.DEBUG)[min(args.verbose, 2)],
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with stop_signals_raise():
            return int(args.func(args) or 0)
    except _project_errors() as exc:
        print(f"robchair {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        signo = int(getattr(exc, "signo", signal.SIGINT))
        stopped = "; motors stopped" if getattr(exc, "motors_stopped", False) else ""
        print(f"robchair {args.command}: stopped by {signal.Signals(signo).name}{stopped}", file=sys.stderr)
        return 128 + signo


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
