"""``robchair sweep``: run a grid or list of scenario runs as Ray tasks, locally or on a cluster."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from robchair.outdir import OVERWRITE_HELP


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "sweep",
        help="run a sweep of scenario runs (grid or list from a TOML file) on Ray; aggregate the metrics",
        description=(
            "Each run point of SWEEP.toml is one run of the scenario harness, executed as a Ray task in its "
            "own worker process and written to OUT/runs/<run>/. Without --address a local Ray instance is "
            "started; --address auto or ray://host:port joins a cluster. A failed run is recorded and the "
            "sweep goes on. Results: OUT/results.csv, OUT/results.json, OUT/figures/*.png."
        ),
    )
    p.add_argument("sweep", type=Path, help="sweep file (TOML: [sweep], [grid], [[runs]], [report])")
    p.add_argument(
        "--out", type=Path, default=None, help="sweep folder (default a new runs/sweep-<name>-<UTC time>)"
    )
    p.add_argument(
        "--address", default=None, help="Ray cluster address (auto, ray://host:port); default local"
    )
    p.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local Ray instance (default: all)")
    p.add_argument(
        "--resume", action="store_true", help="continue the sweep in --out, skipping complete runs"
    )
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from robchair.outdir import timestamped_dir
    from robchair.sweep import SweepError, load_sweep, run_sweep
    from robchair.sweep.harness import allowed_parameters

    if args.num_cpus is not None and args.num_cpus < 1:
        raise SweepError(f"--num-cpus must be at least 1, got {args.num_cpus}")
    if args.num_cpus is not None and args.address is not None:
        raise SweepError("--num-cpus sizes a local Ray instance; a cluster (--address) brings its own CPUs")
    spec = load_sweep(args.sweep, allowed_parameters())
    if args.resume and args.overwrite:
        raise SweepError("--resume continues the sweep in --out, --overwrite replaces it: choose one")
    if args.resume and args.out is None:
        raise SweepError("--resume needs the --out folder of the sweep to continue")
    out = args.out if args.out is not None else timestamped_dir(f"sweep-{spec.name}")
    res = run_sweep(
        spec,
        out,
        address=args.address,
        num_cpus=args.num_cpus,
        resume=args.resume,
        overwrite=args.overwrite,
        progress=not args.no_progress,
    )
    ok = len(res.records) - len(res.failed)
    print(
        f"{len(res.records)} runs: {ok} ok, {len(res.failed)} failed, {len(res.skipped)} already complete; "
        f"{res.wall_s:.1f} s; results in {res.out}"
    )
    for r in res.failed:
        print(f"  failed {r['run_id']}: {r['error']}")
    return 0 if not res.failed else 1
