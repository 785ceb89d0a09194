"""The `robchair` command line: one entry point, one sub-command module per capability.

Each module in COMMANDS / BENCHES exposes ``register(subparsers)`` which adds its parser and sets
``func`` (a callable taking the parsed ``argparse.Namespace`` and returning an exit code); a listed
module that cannot be imported is an error of the installation, raised as such. Modules import their
heavy dependencies inside ``func`` so ``robchair --help`` stays fast.

Any error the project raises on purpose (MappingError, HardwareError, SimError, RobChairError), and
file-system errors, become one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence

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
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="robchair",
        description="RobChair digital twin: mapping, simulation, hardware and motor control.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(name).register(sub)
    bench = sub.add_parser("bench", help="benchmarks against named baselines (prints a table, writes JSON)")
    bench_sub = bench.add_subparsers(dest="bench", metavar="BENCH")
    for name in BENCHES:
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


def main(argv: Sequence[str] | None = None) -> int:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=(logging.WARNING, logging.INFO, logging.DEBUG)[min(args.verbose, 2)],
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except _project_errors() as exc:
        print(f"robchair {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"robchair {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
