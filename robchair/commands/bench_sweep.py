"""``robchair bench sweep``: Ray scaling on this machine — speed-up of 2 workers over 1, per-task overhead.

Three measurements in one run, each against its baseline:

1. Ray's overhead per task: round trips of empty tasks (submit, run, fetch the result) on a warm
   local instance, median of ``--empty`` tasks, against a plain Python call of the same function.
2. A sweep of ``--runs`` short scenario runs (``--duration`` simulated seconds each, no pictures or bag)
   with 1 worker and with 2 workers (a fresh local Ray instance each): wall time and the speed-up.
3. One 10-simulated-second run's wall time, so the per-task overhead is stated as a share of it.

Targets: 2 workers on 2 cores at least 1.7x faster than 1; overhead below 2 % of a 10 s run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from robchair.commands.bench_output import add_out_arguments, results_dir, write_results


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "sweep", help="Ray scaling: sweep wall time with 1 and 2 workers, per-task overhead"
    )
    p.add_argument("--runs", type=int, default=8, help="short runs in the sweep (default 8)")
    p.add_argument("--duration", type=float, default=1.0, help="simulated seconds per short run (default 1)")
    p.add_argument("--empty", type=int, default=200, help="empty tasks for the overhead (default 200)")
    p.add_argument(
        "--long", type=float, default=10.0, help="simulated seconds of the reference run (default 10)"
    )
    add_out_arguments(p, "sweep")
    p.set_defaults(func=_run)


def _noop(x: int) -> int:
    return x


def _empty_overhead(ray: Any, n: int) -> tuple[float, float]:
    task = ray.remote(num_cpus=1)(_noop)
    ray.get([task.remote(i) for i in range(4)])  # warm the workers
    lat = []
    for i in range(n):
        t0 = time.perf_counter()
        ray.get(task.remote(i))
        lat.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    for i in range(n):
        _noop(i)
    plain = (time.perf_counter() - t0) / n
    return statistics.median(lat), plain


def _sweep_wall(n_runs: int, duration: float, workers: int, tmp: Path) -> tuple[float, int]:
    from robchair.sweep import parse_sweep, run_sweep
    from robchair.sweep.executor import ray_session
    from robchair.sweep.harness import allowed_parameters

    spec = parse_sweep(
        {
            "sweep": {"duration": duration, "pictures": False, "bag": False},
            "grid": {"seed": list(range(n_runs))},
        },
        allowed_parameters(),
        source=f"bench-{workers}",
    )
    with ray_session(num_cpus=workers) as ray:
        ray.get([ray.remote(num_cpus=1)(_noop).remote(i) for i in range(workers)])  # start the workers first
        res = run_sweep(spec, tmp / f"w{workers}", progress=False)
    return res.wall_s, len(res.failed)


def _long_run_wall(duration: float, tmp: Path) -> float:
    from robchair.sweep.harness import pin_threads, run_harness

    pin_threads()
    t0 = time.perf_counter()
    run_harness({"duration": duration, "pictures": False, "bag": False}, tmp / "long")
    return time.perf_counter() - t0


def _run(args: argparse.Namespace) -> int:
    from robchair.platform.errors import RobChairError
    from robchair.sweep.executor import ray_session

    if args.runs < 2 or args.empty < 10 or args.duration <= 0 or args.long <= 0:
        raise RobChairError("--runs >= 2, --empty >= 10 and positive --duration/--long are required")
    out = results_dir(args, "sweep")  # refused before anything is measured
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as d:
        tmp = Path(d)
        with ray_session(num_cpus=2) as ray:
            overhead_s, plain_s = _empty_overhead(ray, args.empty)
        wall1, f1 = _sweep_wall(args.runs, args.duration, 1, tmp)
        wall2, f2 = _sweep_wall(args.runs, args.duration, 2, tmp)
        long_s = _long_run_wall(args.long, tmp)
    speedup = wall1 / wall2
    share = overhead_s / long_s
    rows = [
        (
            "empty task round trip (Ray, median)",
            f"{overhead_s * 1e3:.2f} ms",
            f"plain call {plain_s * 1e6:.2f} us",
        ),
        (f"sweep of {args.runs} x {args.duration:g} s runs, 1 worker", f"{wall1:.1f} s", f"{f1} failed"),
        (f"sweep of {args.runs} x {args.duration:g} s runs, 2 workers", f"{wall2:.1f} s", f"{f2} failed"),
        ("speed-up, 2 workers vs 1", f"{speedup:.2f}x", "target >= 1.7x"),
        (f"one {args.long:g} s run (in process)", f"{long_s:.1f} s", ""),
        ("Ray overhead per run vs that run", f"{share * 100:.3f} %", "target < 2 %"),
    ]
    width = max(len(r[0]) for r in rows)
    for name, value, note in rows:
        print(f"{name:<{width}}  {value:>12}  {note}")
    result = {
        "empty_task_round_trip_s": overhead_s,
        "plain_call_s": plain_s,
        "runs": args.runs,
        "run_duration_s": args.duration,
        "sweep_wall_1_worker_s": wall1,
        "sweep_wall_2_workers_s": wall2,
        "speedup_2_vs_1": speedup,
        "long_run_duration_s": args.long,
        "long_run_wall_s": long_s,
        "overhead_share_of_long_run": share,
        "failed_runs": f1 + f2,
    }
    write_results(out, "sweep", result, load0, os.getloadavg())
    return 0
