"""`robchair bench sim`: real-time factor of the whole simulated chair, on one core and on two.

Workload (issue 4): physics at 240 Hz with the motor plants and PIDs, a Kinect v2 (512x424) at 30 Hz,
six sonars (two arrays) at 20 Hz, and every Kinect frame inserted into a VHV map (the odometry map
only: what the real chair would compute), while the chair drives the office corridor route.

Configurations, all measured in the same run:

* ``1 core``: the process is pinned to one CPU (``os.sched_setaffinity``), Embree casts on 1 thread
  and capture and mapping run inline on the simulation thread.
* ``2 cores``: pinned to two CPUs; Embree casts on 2 threads, Kinect frames are captured on two
  background threads (up to two frames in flight) while the simulation thread steps the physics and
  reads the sonars, and the VHV mapping runs on another thread (Embree, the numba kernels and numpy
  release the GIL). The result is bit for bit the serial run's (a test checks it).
* ``2 cores, pybullet camera``: as ``2 cores`` but the depth image comes from PyBullet's CPU renderer
  (``ER_TINY_RENDERER``) instead of ray casting, one frame in flight (PyBullet is not thread-safe):
  the baseline the issue measured at RTF ~0.4.

Real-time factor = simulated time / wall time of the simulation loop (setup excluded). The median of
``--repeats`` runs is reported with the main-thread time per component. Targets: RTF >= 1.5 on two
cores, >= 1.0 on one core. Wall-clock numbers depend on the machine's load: the JSON records the load
average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

DEFAULT_OUT = "out/bench_sim.json"


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "sim", help="real-time factor of physics + Kinect + sonars + mapping (1 and 2 cores)"
    )
    p.add_argument("--duration", type=float, default=4.0, help="simulated seconds per run (default 4)")
    p.add_argument("--repeats", type=int, default=1, help="runs per configuration (median; default 1)")
    p.add_argument("--scenario", default="office_corridor", help="scenario (default office_corridor)")
    p.add_argument("--no-pybullet-camera", action="store_true", help="skip the PyBullet-renderer baseline")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"JSON results (default {DEFAULT_OUT})")
    p.set_defaults(func=_run)


# two-core configurations first: TBB (Embree's thread pool) sizes itself from the CPU affinity it
# sees the first time it runs, so pinning to one CPU first would cap the later runs at one thread
CONFIGS: tuple[dict[str, Any], ...] = (
    {"name": "2 cores", "cpus": 2, "raycast_threads": 2, "mapping_thread": True, "camera_backend": "raycast"},
    {
        "name": "2 cores, pybullet camera",
        "cpus": 2,
        "raycast_threads": 2,
        "mapping_thread": True,
        "camera_backend": "pybullet",
    },
    {"name": "1 core", "cpus": 1, "raycast_threads": 1, "mapping_thread": False, "camera_backend": "raycast"},
)


def _pin(n: int) -> set[int] | None:
    """Pin this process to ``n`` CPUs; return the previous set (None where affinity is unsupported)."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    before = os.sched_getaffinity(0)
    cpus = sorted(before)[:n]
    os.sched_setaffinity(0, set(cpus))
    return before


def measure(config: dict[str, Any], scenario: str, duration: float, seed: int = 0) -> dict[str, Any]:
    """One run of the workload under ``config``; returns RTF and the per-component times."""
    from sim.runner import run_scenario

    before = _pin(config["cpus"])
    try:
        res = run_scenario(
            scenario,
            duration=duration,
            sensor="kinect2",
            seed=seed,
            progress=False,
            write=False,
            camera_backend=config["camera_backend"],
            mapping_thread=config["mapping_thread"],
            pipeline=config["mapping_thread"],
            sonar_hz=20.0,  # the issue's workload (faster than an SRF08's 65 ms ranging allows)
            raycast_threads=config["raycast_threads"],
            ground_truth_map=False,
        )
    finally:
        if before is not None:
            os.sched_setaffinity(0, before)
    m = res.metrics
    frames = max(m["frames"]["kinect_frames"], 1)
    main = m["wall_time_s"]["components"]
    return {
        "rtf": m["real_time_factor"],
        "sim_time_s": m["sim_time_s"],
        "loop_wall_s": m["wall_time_s"]["loop"],
        "kinect_frames": m["frames"]["kinect_frames"],
        "sonar_readings": m["frames"]["sonar_readings"] * 3,
        "kinect_ms_per_frame": 1e3 * main["kinect_capture"] / frames,
        "mapping_ms_per_frame": m["mapping_ms_per_frame_median"],
        "sonar_ms_per_array_reading": 1e3 * main["sonar"] / max(m["frames"]["sonar_readings"], 1),
        "physics_ms_per_sim_s": 1e3 * main["physics"] / max(m["sim_time_s"], 1e-9),
    }


def _run(args: argparse.Namespace) -> int:
    import statistics

    from robchair.errors import RobChairError

    if args.duration <= 0 or args.repeats < 1:
        raise RobChairError(f"--duration must be > 0 and --repeats >= 1, got {args.duration}, {args.repeats}")
    ncpu = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    configs = [c for c in CONFIGS if not (args.no_pybullet_camera and c["camera_backend"] == "pybullet")]
    load0 = os.getloadavg()
    # warm-up (imports, numba kernels, Open3D): not timed
    measure(CONFIGS[0], args.scenario, 0.1)
    rows: list[dict[str, Any]] = []
    for cfg in configs:
        if cfg["cpus"] > ncpu:
            print(f"skipping {cfg['name']!r}: only {ncpu} CPU(s) available")
            continue
        runs = [measure(cfg, args.scenario, args.duration, seed=k) for k in range(args.repeats)]
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        rows.append({"config": cfg, "median": med, "runs": runs})
    load1 = os.getloadavg()
    cols = ("RTF", "kinect ms/fr", "map ms/fr", "sonar ms/arr", "physics ms/s")
    head = f"{'configuration':28s} " + " ".join(f"{c:>{max(6, len(c))}s}" for c in cols)
    print(f"robchair bench sim: {args.scenario}, {args.duration:g} sim s per run, median of {args.repeats}")
    print(head)
    print("-" * len(head))
    for r in rows:
        m = r["median"]
        print(
            f"{r['config']['name']:28s} {m['rtf']:6.2f} {m['kinect_ms_per_frame']:12.1f} "
            f"{m['mapping_ms_per_frame']:9.1f} {m['sonar_ms_per_array_reading']:12.1f} "
            f"{m['physics_ms_per_sim_s']:12.1f}"
        )
    by = {r["config"]["name"]: r["median"]["rtf"] for r in rows}
    targets = {"2 cores": 1.5, "1 core": 1.0}
    for name, target in targets.items():
        if name in by:
            verdict = "meets" if by[name] >= target else "misses"
            print(f"{name}: RTF {by[name]:.2f} {verdict} the target {target}")
    if "2 cores" in by and "2 cores, pybullet camera" in by:
        print(
            "ray casting vs PyBullet renderer (2 cores): "
            f"{by['2 cores'] / by['2 cores, pybullet camera']:.2f}x"
        )
    print(f"load average before/after: {load0[0]:.2f} / {load1[0]:.2f} on {os.cpu_count()} CPUs")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    result = {
        "scenario": args.scenario,
        "duration_s": args.duration,
        "repeats": args.repeats,
        "targets": targets,
        "rows": rows,
        "load_average_before": load0,
        "load_average_after": load1,
        "cpus": os.cpu_count(),
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    tmp = out.with_suffix(".json.partial")
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(out)
    print(f"wrote {out}")
    return 0
