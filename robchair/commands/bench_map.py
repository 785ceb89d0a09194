"""`robchair bench map`: `robchair map` on a run's bag, against real time (the run's simulated seconds).

Workload: the bag of a `robchair sim` run (``--bag BAG``, or a fresh default run of ``--duration``
seconds without pictures, recorded first and not timed) mapped the way it rebuilds the run's map
(``--map-kind probabilistic``). Each repeat runs the command in a new process, as a user does, twice:
with its pictures and with ``--no-pictures``. Three figures per run, each as simulated seconds per
second of wall time (the target: at least 10x real time):

* **build**: reading the bag, placing every cloud through TF and inserting it into the map (the
  command's ``read_and_build`` seconds in summary.json): what "builds its map" means here;
* **inserts**: the map's inserts alone (summary.json ``build_ms``: the clouds and their no-return rays;
  on the command's build pipeline, the wall time of the pass that inserts the frames), and their share
  of the build and of the whole command (what is left to the rest of the command);
* **whole command**: the process from start to exit (interpreter, imports, building, every output).
* **build, CPU time**: the build's CPU seconds (summary.json ``read_and_build_cpu``), which a machine
  shared with other work inflates less than the wall time.

The named baseline is real time (the run's ``sim_time_s`` from its metrics.json, else the bag's
TF span). Medians over ``--repeats``; JSON in ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from robchair.commands.bench_output import add_out_arguments, results_dir, verdict, write_results

TARGET_X = 10.0  # the map command builds a 20 s run's map at least 10x faster than real time


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser("map", help="robchair map on a run's bag: build and whole command vs real time")
    p.add_argument("--bag", type=Path, default=None, help="a run's bag (default: record a default sim run)")
    p.add_argument(
        "--duration", type=float, default=20.0, help="simulated seconds of the recorded run (default 20)"
    )
    p.add_argument("--repeats", type=int, default=3, help="runs of each command (median; default 3)")
    add_out_arguments(p, "map")
    p.set_defaults(func=_run)


def _robchair(*argv: str) -> float:
    """Run ``robchair ARGV`` in a new process; its wall time, s."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "robchair.cli", *argv], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        from robchair.platform.errors import RobChairError

        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RobChairError(f"robchair {' '.join(argv[:2])}: exit code {proc.returncode}: {tail}")
    return wall


def sim_seconds(bag: Path) -> tuple[float, str]:
    """The run's simulated seconds: its metrics.json beside the bag, else the bag's TF time span."""
    metrics = bag.parent / "metrics.json"
    if metrics.is_file():
        return float(json.loads(metrics.read_text())["sim_time_s"]), "metrics.json sim_time_s"
    from mapping.io.bags import read_bag_tf

    span = read_bag_tf(bag).time_range_ns()
    return ((span[1] - span[0]) / 1e9 if span else 0.0), "the bag's /tf span"


def measure(bag: Path, repeats: int, work: Path) -> dict[str, Any]:
    """Map ``bag`` ``repeats`` times with and without pictures; medians of the wall times, s."""
    runs: dict[str, list[float]] = {"whole": [], "whole_no_pictures": [], "read_and_build": [], "inserts": [],
                                    "read_and_build_cpu": []}  # fmt: skip
    for k in range(repeats):
        for pictures in (True, False):
            out = work / f"map{k}{'' if pictures else '-np'}"
            extra = () if pictures else ("--no-pictures",)
            wall = _robchair("map", str(bag), "--map-kind", "probabilistic", "--out", str(out), *extra)
            runs["whole" if pictures else "whole_no_pictures"].append(wall)
            timing = json.loads((out / "summary.json").read_text())["timing_s"]
            runs["read_and_build"].append(float(timing["read_and_build"]))
            runs["inserts"].append(float(timing["build"]))
            runs["read_and_build_cpu"].append(float(timing["read_and_build_cpu"]))
    return {k: statistics.median(v) for k, v in runs.items()}


def _run(args: argparse.Namespace) -> int:
    from robchair.platform.errors import RobChairError

    if args.repeats < 1:
        raise RobChairError(f"--repeats must be >= 1, got {args.repeats}")
    if args.bag is not None and not args.bag.exists():
        raise RobChairError(f"--bag {args.bag}: no such bag")
    out = results_dir(args, "map")  # refused before anything is measured
    with tempfile.TemporaryDirectory(prefix="robchair-bench-map-") as tmp:
        work = Path(tmp)
        bag = args.bag
        if bag is None:
            print(f"recording a default `robchair sim --duration {args.duration:g}` run (not timed) ...")
            _robchair("sim", "--duration", f"{args.duration:g}", "--no-pictures", "--no-progress",
                      "--out", str(work / "run"))  # fmt: skip
            bag = work / "run" / "bag"
        sim_s, sim_source = sim_seconds(bag)
        size_mb = sum(f.stat().st_size for f in bag.rglob("*") if f.is_file()) / 1e6
        load0 = os.getloadavg()
        m = measure(bag, args.repeats, work)
        load1 = os.getloadavg()
    print(f"robchair bench map: {bag} ({size_mb:.1f} MB), {sim_s:.2f} simulated s ({sim_source}), "
          f"median of {args.repeats}, each in a new process; target >= {TARGET_X:g}x real time")  # fmt: skip
    print("build = reading the bag, placing every cloud through TF and inserting it into the map")
    print(f"{'figure':40s} {'s':>8s} {'x real time':>12s}  target")
    rows = [("build (read + place + insert)", "read_and_build"), ("inserts alone", "inserts"),
            ("build, CPU time", "read_and_build_cpu"),
            ("whole command, with pictures", "whole"),
            ("whole command, --no-pictures", "whole_no_pictures")]  # fmt: skip
    result: dict[str, Any] = {"bag": str(bag), "bag_mb": size_mb, "sim_time_s": sim_s,
                              "sim_time_source": sim_source, "repeats": args.repeats,
                              "target_x_real_time": TARGET_X, "wall_s": m, "x_real_time": {},
                              "verdict": {}}  # fmt: skip
    for label, key in rows:
        x = sim_s / max(m[key], 1e-9)
        result["x_real_time"][key] = x
        result["verdict"][key] = verdict(x >= TARGET_X)
        print(f"{label:40s} {m[key]:8.2f} {x:12.1f}  {verdict(x >= TARGET_X)}")
    share = {"of_build": m["inserts"] / max(m["read_and_build"], 1e-9),
             "of_whole_command": m["inserts"] / max(m["whole"], 1e-9)}  # fmt: skip
    result["inserts_share"] = share
    print(f"inserts' share: {100 * share['of_build']:.0f} % of the build, "
          f"{100 * share['of_whole_command']:.0f} % of the whole command with pictures")  # fmt: skip
    cores = cores_needed(m["read_and_build_cpu"], sim_s)
    result["cores_needed_at_target"] = cores
    print(f"the build's CPU: {m['read_and_build_cpu']:.2f} s; {TARGET_X:g}x real time is at most "
          f"{sim_s / TARGET_X:.2f} s of wall time, so this build needs >= {cores} cores even when every "
          f"stage overlaps perfectly (this machine: {os.cpu_count()})")  # fmt: skip
    write_results(out, "map", result, load0, load1)
    return 0


def cores_needed(build_cpu_s: float, sim_s: float) -> int:
    """Cores a build of ``build_cpu_s`` CPU seconds needs to finish in ``sim_s / TARGET_X`` seconds of
    wall time with its work spread perfectly over them (a lower bound: the store's updates are serial)."""
    budget = sim_s / TARGET_X
    return max(1, math.ceil(build_cpu_s / budget - 1e-9)) if budget > 0 else 0
