"""`robchair bench sim`: real-time factor of the whole simulated chair driven by the runtime, 1 and 2 cores.

Workload: physics at 240 Hz with the motor plants and PIDs, the runtime at 60 Hz with the safety layer
on, a Kinect v2 (512x424) at 30 Hz, six sonars (two arrays) at 20 Hz, and every Kinect frame inserted
into the perception stage's main map (``--map``: the probabilistic VHV map by default, or the thesis's
accumulate-only one), placed by scan-to-map matching, with the zoom and the odometry map beside it, at
``robchair sim``'s rates (:data:`robchair.scenario.MATCH_EVERY`, :data:`robchair.scenario.EVALUATION_EVERY`),
while the chair drives the office corridor route (:func:`robchair.scenario.run_scenario`).

Configurations, all measured in the same run:

* ``1 core``: the process is pinned to one CPU (``os.sched_setaffinity``), Embree casts on 1 thread
  and capture and mapping run inline on the loop's thread.
* ``2 cores``: pinned to two CPUs; Embree casts on 1 thread (spinning TBB workers cost more than the
  parallel cast gained), Kinect frames are captured on two
  background threads (up to two frames in flight) and mapped on another thread. The result is bit for
  bit the serial run's (a test checks it).
* ``2 cores, pybullet camera`` (``--pybullet-camera``): as ``2 cores`` with PyBullet's CPU renderer.

Baseline: the revision this loop replaced, as a whole: its scenario runner (its own loop without the
runtime or the safety layer) on its own simulator (render, sonars, physics as they were then), i.e. the
last main-line revision that had ``sim/runner.py``, unpacked from git history and run in a child
process (:mod:`robchair.commands.bench_sim_baseline`), alternating with the new loop so both see the
same machine load. Reported: medians of ``--repeats`` runs, and new / old. Real-time factor = simulated
time / wall time of the loop (setup excluded). Both processes keep freed heap blocks (``robchair sim
--keep-freed-memory``; the old runner always did). The JSON records the load average before and after
and the baseline's revision.

On one core the new loop's time per simulated second is at least its own simulator's render + sonar +
physics stages: the bench prints the ratio over the baseline that this bound allows
(:func:`ratio_bound`; ``ratio_bound`` per row in the JSON).
"""

from __future__ import annotations

import argparse
import math
import os
from typing import Any

from robchair.commands.bench_output import add_out_arguments, results_dir, write_results
from robchair.commands.bench_sim_baseline import BaselineRunner, baseline_revision

BASELINE_WHAT = "the replaced scenario runner on its own simulator: that whole revision, in a child process"


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "sim", help="real-time factor of physics + Kinect + sonars + mapping (1 and 2 cores)"
    )
    p.add_argument("--duration", type=float, default=4.0, help="simulated seconds per run (default 4)")
    p.add_argument("--repeats", type=int, default=1, help="runs per configuration (median; default 1)")
    p.add_argument("--scenario", default="office_corridor", help="scenario (default office_corridor)")
    p.add_argument("--pybullet-camera", action="store_true", help="also measure PyBullet's renderer")
    p.add_argument("--no-baseline", action="store_true", help="do not measure the replaced scenario runner")
    p.add_argument(
        "--map",
        choices=("probabilistic", "thesis"),
        default="probabilistic",
        help="map kind of the new loop (default probabilistic; thesis: accumulate only)",
    )
    add_out_arguments(p, "sim")
    p.add_argument(
        "--live",
        action="store_true",
        help="instead: the loop's CPU time per simulated second with the live view off, on without a client "
        "and on with one (robchair.commands.bench_live; JSON in --out as bench_sim_live.json)",
    )
    p.set_defaults(func=_run)


# Embree casts on 1 thread in every configuration: on 2 cores the two capture threads already keep
# two frames in flight, and TBB's workers spinning after each parallel cast took the CPU from them
# (office_corridor 2 sim s, 2 CPUs, mapping threaded, load 25: 56.6 s CPU with 2 cast threads,
# 5.8 s with 1). Two-core configurations still run first (TBB sizes its pool from the first affinity).
CONFIGS: tuple[dict[str, Any], ...] = (
    {"name": "2 cores", "cpus": 2, "raycast_threads": 1, "mapping_thread": True, "camera_backend": "raycast"},
    {
        "name": "2 cores, pybullet camera",
        "cpus": 2,
        "raycast_threads": 1,
        "mapping_thread": True,
        "camera_backend": "pybullet",
    },
    {"name": "1 core", "cpus": 1, "raycast_threads": 1, "mapping_thread": False, "camera_backend": "raycast"},
)


#: Simulated seconds of the untimed warm-up run of each loop (new and old) before the timed rows. Long
#: enough that every kernel a timed run calls has been compiled or loaded: with 0.1 s, on a cold numba
#: cache six mapping and matching kernels (the first match, the dynamic decay) compiled inside the first
#: timed row (office_corridor; :func:`compiled_during` records them).
WARMUP_S = 1.0


def compiled_during(fn: Any) -> tuple[Any, list[str]]:
    """``(fn(), names)``: the result of ``fn()`` and the numba kernels compiled while it ran
    (qualified names, in order; numba's own overloads they pulled in left out; empty when every
    kernel came from memory or the disk cache)."""
    from numba.core import event

    with event.install_recorder("numba:compile") as rec:
        out = fn()
    funcs = [e.data["dispatcher"].py_func for _, e in rec.buffer if e.is_start]
    return out, [f.__qualname__ for f in funcs if not f.__module__.startswith("numba.")]


def _pin(n: int) -> set[int] | None:
    """Pin this process to ``n`` CPUs; return the previous set (None where affinity is unsupported)."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    before = os.sched_getaffinity(0)
    cpus = sorted(before)[:n]
    os.sched_setaffinity(0, set(cpus))
    return before


def measure(
    config: dict[str, Any],
    scenario: str,
    duration: float,
    seed: int = 0,
    old: Any = None,
    map_kind: str = "probabilistic",
) -> dict[str, Any]:
    """One run of the workload under ``config`` (``old``: the replaced revision's
    :class:`robchair.commands.bench_sim_baseline.BaselineRunner`); RTF and components."""
    from robchair.scenario import run_scenario

    kw = dict(duration=duration, sensor="kinect2", seed=seed, progress=False, write=False,
              camera_backend=config["camera_backend"], mapping_thread=config["mapping_thread"],
              pipeline=config["mapping_thread"], sonar_hz=20.0, raycast_threads=config["raycast_threads"],
              ground_truth_map=False)  # fmt: skip
    if old is not None:  # the child process pins itself
        m: dict[str, Any] = old.run(scenario, config["cpus"], **kw)
    else:
        before = _pin(config["cpus"])
        try:
            m, compiled = compiled_during(lambda: run_scenario(scenario, map_kind=map_kind, **kw).metrics())
        finally:
            if before is not None:
                os.sched_setaffinity(0, before)
        m["compiled_in_run"] = compiled
    frames = m["frames"]["kinect_frames"] if old is not None else m["frames"]["depth_frames"]
    main = m["wall_time_s"]["components"]
    sim_s = max(m["sim_time_s"], 1e-9)
    layers = {f"map {k} ms/s": 1e3 * v / sim_s for k, v in (m.get("mapping_s_by_layer") or {}).items()}
    return {
        **layers,
        "compiled_in_run": m.get("compiled_in_run", []),
        "rtf": m["real_time_factor"],
        "sim_time_s": m["sim_time_s"],
        "loop_wall_s": m["wall_time_s"]["loop"],
        # the process's CPU over the loop, every thread (None for the replaced runner: it does not say)
        "loop_cpu_ms_per_sim_s": (
            1e3 * m["cpu_time_s"]["loop"] / sim_s if (m.get("cpu_time_s") or {}).get("loop") else None
        ),
        "kinect_frames": frames,
        "kinect_ms_per_frame": 1e3 * main["kinect_capture"] / max(frames, 1),
        "mapping_ms_per_frame": m["mapping_ms_per_frame_median"],
        "sonar_ms_per_array_reading": 1e3 * main["sonar"] / max(m["frames"]["sonar_readings"], 1),
        "physics_ms_per_sim_s": 1e3 * main["physics"] / sim_s,
        "kinect_ms_per_sim_s": 1e3 * main["kinect_capture"] / sim_s,
        "sonar_ms_per_sim_s": 1e3 * main["sonar"] / sim_s,
        "matching_ms_per_frame": ((m.get("matching") or {}).get("ms_per_frame_median")),
    }


#: Real-time factor targets per configuration.
TARGET_RTF = {"2 cores": 1.5, "1 core": 1.0}
#: The new loop's real-time factor over the replaced runner's in the same run (all layers on).
TARGET_RATIO_OLD = {"2 cores": 1.5, "1 core": 0.9}
#: Scan-to-map matching of one Kinect frame, ms (median).
TARGET_MATCH_MS = 10.0
#: Stages of the stage table: (column, measured field), in ms of wall time per simulated second.
STAGES = (
    ("render", "kinect_ms_per_sim_s"),
    ("sonar cast", "sonar_ms_per_sim_s"),
    ("physics", "physics_ms_per_sim_s"),
)


def ratio_bound(row: dict[str, Any]) -> dict[str, float] | None:
    """How fast the new loop can be against the baseline, given the new loop's simulator stages.

    On one core the stages run one after the other, so the new loop's wall time per simulated second
    is at least the sum of its Kinect render, sonar casts and physics: its RTF over the baseline's is
    at most the baseline's loop time over that sum, however cheap the rest of the loop and the maps
    become.

    Returns:
        ``{"simulator_ms_per_sim_s", "replaced_loop_ms_per_sim_s", "max_ratio"}``, or None without a
        baseline or in a configuration whose stages overlap (more than one CPU).
    """
    old, m = row.get("baseline_median"), row["median"]
    if not old or row["config"].get("cpus") != 1:
        return None
    sim = sum(m.get(f, 0.0) for _, f in STAGES)
    loop_old = 1e3 * old["loop_wall_s"] / max(old["sim_time_s"], 1e-9)
    return {"simulator_ms_per_sim_s": sim, "replaced_loop_ms_per_sim_s": loop_old,
            "max_ratio": loop_old / max(sim, 1e-9)}  # fmt: skip


def cores_needed(row: dict[str, Any]) -> dict[str, Any] | None:
    """Cores the new loop needs for its target over the replaced runner, given its CPU per simulated
    second (a lower bound: perfect overlap of every thread). None without a baseline, a target or the
    loop's CPU."""
    m, old = row["median"], row.get("baseline_median")
    goal = TARGET_RATIO_OLD.get(row["config"]["name"])
    cpu = m.get("loop_cpu_ms_per_sim_s")
    if not old or goal is None or not cpu:
        return None
    target_rtf = goal * old["rtf"]
    return {
        "cpu_ms_per_sim_s": cpu,
        "target_rtf": target_rtf,
        "cores": math.ceil(target_rtf * cpu / 1e3 - 1e-9),
    }


def print_stage_table(rows: list[dict[str, Any]]) -> None:
    """Where a simulated second goes, per configuration: render, sonar, physics, each map, the rest (ms).

    Mapping runs on its own thread in the two-core configurations, so there the stages overlap: when
    their sum exceeds the loop's wall time the rest column says ``-`` and a line below gives the excess.
    """
    layers = sorted({k for r in rows for k in r["median"] if k.startswith("map ")})
    cols = [c for c, _ in STAGES] + [k[:-5] for k in layers] + ["rest", "loop"]
    widths = [max(9, len(c)) for c in cols]
    print("stage table: ms of wall time per simulated second (median; 'map X': the inserts into map X)")
    print(f"{'configuration':28s} " + " ".join(f"{c:>{w}s}" for c, w in zip(cols, widths, strict=True)))
    overlaps = []
    for r in rows:
        m = r["median"]
        vals = [m.get(f, 0.0) for _, f in STAGES] + [m.get(k, 0.0) for k in layers]
        loop = 1e3 * m["loop_wall_s"] / max(m["sim_time_s"], 1e-9)
        rest = loop - sum(vals)
        cells = [f"{v:{w}.1f}" for v, w in zip(vals, widths, strict=False)]
        cells += [
            f"{rest:{widths[-2]}.1f}" if rest >= 0.0 else f"{'-':>{widths[-2]}s}",
            f"{loop:{widths[-1]}.1f}",
        ]
        print(f"{r['config']['name']:28s} " + " ".join(cells))
        if rest < 0.0:
            overlaps.append(
                f"{r['config']['name']}: the stages overlap on threads; their sum exceeds the loop by "
                f"{-rest:.1f} ms per sim s"
            )
    for line in overlaps:
        print(line)


def _run(args: argparse.Namespace) -> int:
    if getattr(args, "live", False):
        from robchair.commands.bench_live import run_live_bench

        return run_live_bench(args)

    from robchair.commands.sim import retain_freed_memory
    from robchair.platform.errors import RobChairError

    if args.duration <= 0 or args.repeats < 1:
        raise RobChairError(f"--duration must be > 0 and --repeats >= 1, got {args.duration}, {args.repeats}")
    out = results_dir(args, "sim")  # refused before anything is measured
    retain_freed_memory()
    ncpu = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    configs = [c for c in CONFIGS if args.pybullet_camera or c["camera_backend"] != "pybullet"]
    rev = None if args.no_baseline else baseline_revision()
    old = None
    if rev is None and not args.no_baseline:
        print("baseline: no git history with the replaced runner here; measuring the new loop only")
    elif rev is not None:
        print(f"baseline: the replaced runner on its own simulator, revision {rev.describe()} as a whole "
              f"(the last main-line revision before the one loop), in a child process")  # fmt: skip
        old = BaselineRunner(rev)
    try:
        return _measure_all(args, configs, ncpu, old, out)
    finally:
        if old is not None:
            old.close()


def _baseline_json(old: Any) -> dict[str, str] | None:
    if old is None:
        return None
    return {"revision": old.rev.sha, "date": old.rev.date, "subject": old.rev.subject, "what": BASELINE_WHAT}


def _measure_all(
    args: argparse.Namespace, configs: list[dict[str, Any]], ncpu: int, old: Any, out: Any
) -> int:
    import statistics

    from robchair.commands.bench_output import median_of, verdict
    from robchair.scenario import EVALUATION_EVERY, MATCH_EVERY

    load0 = os.getloadavg()
    # warm-up (imports, numba kernels, Open3D): not timed
    measure(CONFIGS[0], args.scenario, WARMUP_S)
    if old is not None:
        try:
            measure(CONFIGS[0], args.scenario, WARMUP_S, old=old)
        except RuntimeError as exc:
            print(f"baseline: revision {old.rev.sha[:10]} did not run ({exc}); measuring the new loop only")
            old = None
    rows: list[dict[str, Any]] = []
    for cfg in configs:
        if cfg["cpus"] > ncpu:
            print(f"skipping {cfg['name']!r}: only {ncpu} CPU(s) available")
            continue
        runs, old_runs = [], []
        for k in range(args.repeats):  # alternate new and old: the same machine load for both
            runs.append(measure(cfg, args.scenario, args.duration, seed=k, map_kind=args.map))
            if old is not None:
                old_runs.append(measure(cfg, args.scenario, args.duration, seed=k, old=old))
        med = median_of(runs)
        old_med = median_of(old_runs) if old_runs else None
        rows.append({"config": cfg, "median": med, "runs": runs, "baseline_median": old_med,
                     "baseline_runs": old_runs})  # fmt: skip
    load1 = os.getloadavg()
    for r in rows:
        late = sorted({k for x in r["runs"] for k in x.get("compiled_in_run", [])})
        if late:
            print(f"warning: {r['config']['name']}: {len(late)} numba kernel(s) compiled inside a timed run "
                  f"(its RTF includes the compile time): {', '.join(late)}")  # fmt: skip
    cols = ("RTF", "old RTF", "new/old", "kinect ms/fr", "map ms/fr", "sonar ms/arr", "physics ms/s")
    head = f"{'configuration':28s} " + " ".join(f"{c:>{max(7, len(c))}s}" for c in cols)
    print(
        f"robchair bench sim: {args.scenario}, {args.map} map, {args.duration:g} sim s per run, "
        f"median of {args.repeats}; matching every {MATCH_EVERY} Kinect frames, the ground-truth pose map "
        f"every {EVALUATION_EVERY} (robchair sim's defaults)"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        m, o = r["median"], r["baseline_median"]
        old_rtf = f"{o['rtf']:7.2f}" if o else f"{'-':>7s}"
        ratio = f"{m['rtf'] / o['rtf']:7.2f}" if o else f"{'-':>7s}"
        print(
            f"{r['config']['name']:28s} {m['rtf']:7.2f} {old_rtf} {ratio} {m['kinect_ms_per_frame']:12.1f} "
            f"{m['mapping_ms_per_frame']:9.1f} {m['sonar_ms_per_array_reading']:12.1f} "
            f"{m['physics_ms_per_sim_s']:12.1f}"
        )
    for r in rows:  # scan-to-map matching of each Kinect frame (mapping.matching), inside "map ms/fr"
        ms = [x["matching_ms_per_frame"] for x in r["runs"] if x.get("matching_ms_per_frame") is not None]
        if ms:
            med = statistics.median(ms)
            ok = verdict(med <= TARGET_MATCH_MS)
            print(f"{r['config']['name']}: scan-to-map matching {med:.1f} ms per frame "
                  f"(median; target <= {TARGET_MATCH_MS:g} ms: {ok})")  # fmt: skip
    print_stage_table(rows)
    by = {r["config"]["name"]: r for r in rows}
    targets = TARGET_RTF
    for name, target in targets.items():
        if name in by:
            rtf = by[name]["median"]["rtf"]
            line = f"{name}: RTF {rtf:.2f} (target >= {target}: {verdict(rtf >= target)})"
            if by[name]["baseline_median"]:
                ratio = rtf / by[name]["baseline_median"]["rtf"]
                goal = TARGET_RATIO_OLD.get(name, 0.9)
                line += f"; {ratio:.2f}x the replaced runner (target >= {goal}x: {verdict(ratio >= goal)})"
            print(line)
    for r in rows:
        c = r["cores_needed"] = cores_needed(r)
        if c is not None:
            name = r["config"]["name"]
            print(f"{name}: the loop used {c['cpu_ms_per_sim_s']:.0f} ms of CPU per simulated second (every "
                  f"thread); RTF {c['target_rtf']:.2f} ({TARGET_RATIO_OLD.get(name)}x the replaced runner) "
                  f"needs >= {c['cores']} cores with that CPU, however well it overlaps (this row: "
                  f"{r['config']['cpus']})")  # fmt: skip
    for r in rows:
        b = r["ratio_bound"] = ratio_bound(r)
        if b is not None:
            print(
                f"{r['config']['name']}: the new loop's simulator (render + sonar + physics) takes "
                f"{b['simulator_ms_per_sim_s']:.0f} ms per sim s against the baseline's whole loop's "
                f"{b['replaced_loop_ms_per_sim_s']:.0f}, so new/old is at most "
                f"{b['max_ratio']:.2f}x with a loop and maps that cost nothing"
            )
    result = {
        "scenario": args.scenario,
        "map_kind": args.map,
        "duration_s": args.duration,
        "repeats": args.repeats,
        "targets": targets,
        "targets_ratio_to_replaced_runner": TARGET_RATIO_OLD,
        "baseline": _baseline_json(old),
        "rows": rows,
    }
    write_results(out, "sim", result, load0, load1)
    return 0
