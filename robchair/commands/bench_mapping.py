"""`robchair bench mapping`: time the VHV build against Open3D voxelization and OctoMap on one core.

Clouds: a 1920x1080 (2,073,600-point) organized Kinect-v2-HD-like frame of an indoor scene with ~10 %
NaN (``mapping.synthetic``), plus a scaling series of the same scene at 22k, 217k, 313k, 1M and 2.07M
points. For each cloud, in the same run and process, pinned to one CPU:

* the project's VHV build (``VHVMap.insert`` into an empty map; NaN filtering included) on the
  compiled path (numba, one thread) and on the pure-numpy path;
* Open3D ``VoxelGrid.create_from_point_cloud`` at the same cell size (its NaN filtering and the
  numpy -> Vector3dVector copy timed separately and reported beside it);
* OctoMap ``OcTree.insertPointCloud`` (``pyoctomap``) from the sensor origin — note that OctoMap
  also ray-casts the free space along every beam, so it does more work than an occupancy build.

Then the probabilistic map (:mod:`robchair.commands.bench_mapping_evidence`): occupied + free +
evidence update of the HD frame into a map holding previous frames, against OctoMap's insertion and
DUFOMap's (same work: both clear free space), and the clearing time of a walker seen at 30 Hz.

It prints medians (wall clock, and process CPU time, which a busy shared machine does not inflate),
the ratios against the baselines, the thesis's figure (~166 ms per 2.07M-point frame: about 6 frames/s
on a 4-core i7, C++), the peak extra memory of the VHV build (tracemalloc sees numpy's and numba's
allocations) against the input size, and writes everything as JSON. Every timed build runs in one
thread (numba kernels are serial; OMP/OPENBLAS/MKL/NUMBA thread counts are set to 1 before Open3D is
imported); ``--pin-cpu N`` also pins the process to one CPU.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import statistics
import time
from collections.abc import Iterator
from typing import Any

from robchair.commands.bench_output import add_out_arguments, results_dir, write_results
from robchair.commands.bench_output import verdict as bench_verdict

# NUMBA_NUM_THREADS is not among them: numba refuses a changed value once its threads run (a later
# kernel in the same process raises); numba.set_num_threads(1) below single-threads it instead.
_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

# Thesis: about 6 frames/s of 2,073,600-point clouds (C++, 4-core i7), i.e. ~166 ms per frame.
THESIS_MS_PER_HD_FRAME = 166.0
# (height, width) of the scaling series: 22k, 217k, 313k, 1M, 2.07M points (16:9 frames of the scene).
SERIES = ((112, 198), (350, 620), (420, 746), (750, 1333), (1080, 1920))
QUICK_SERIES = ((36, 64), (72, 128))
TARGET_MS = 8.0
#: The VHV build of the HD frame at least this many times faster than Open3D's voxelization, same run.
TARGET_RATIO_OPEN3D = 5.0


def register(subparsers: Any) -> None:
    """Add the ``mapping`` benchmark to ``robchair bench``."""
    p = subparsers.add_parser(
        "mapping",
        help="VHV build vs Open3D voxelization vs OctoMap insertion on Kinect-v2-HD-like clouds (one core)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--repeat", type=int, default=9, help="timed repetitions per cloud (default 9)")
    p.add_argument(
        "--octomap-repeat",
        type=int,
        default=1,
        help="repetitions of the (slow) OctoMap insertion (default 1)",
    )
    p.add_argument("--cell", type=float, default=0.05, help="cell / voxel size in metres (default 0.05)")
    p.add_argument("--tolerance", type=float, default=0.05, help="VHV tolerance in metres (default 0.05)")
    add_out_arguments(p, "mapping")
    p.add_argument("--quick", action="store_true", help="tiny clouds and 2 repetitions: a smoke run")
    p.add_argument("--no-octomap", action="store_true", help="skip the OctoMap baseline")
    p.add_argument("--no-open3d", action="store_true", help="skip the Open3D baseline")
    p.add_argument("--seed", type=int, default=0, help="seed of the synthetic scene (default 0)")
    p.add_argument(
        "--no-evidence",
        action="store_true",
        help="skip the probabilistic map (evidence insertion vs OctoMap/DUFOMap, walker clearing)",
    )
    p.add_argument(
        "--prior-frames",
        type=int,
        default=3,
        help="frames the probabilistic map holds before the timed HD frame (default 3)",
    )
    p.add_argument("--pin-cpu", type=int, default=None, metavar="N", help="pin the process to CPU N")
    p.set_defaults(func=_run)


@contextlib.contextmanager
def _one_core(pin_cpu: int | None) -> Iterator[str]:
    """Single-thread the libraries and optionally pin to one CPU (undone on exit); say what was done.

    Every timed build is single-threaded (numba kernels are serial; the thread variables stop OpenMP
    and BLAS pools). Pinning to a fixed CPU is optional because on a shared machine that CPU may be
    busy with someone else's work while the other one idles.
    """
    done = []
    saved_env = {v: os.environ.get(v) for v in _THREAD_VARS}
    saved_cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    for var in _THREAD_VARS:
        os.environ[var] = "1"
    done.append("/".join(v.split("_")[0] for v in _THREAD_VARS) + "_NUM_THREADS=1")
    if pin_cpu is not None and saved_cpus:
        os.sched_setaffinity(0, {pin_cpu})
        done.append(f"process pinned to CPU {pin_cpu} (sched_setaffinity)")
    else:
        done.append("not pinned (single-threaded builds; --pin-cpu N pins)")
    try:
        import numba

        numba.set_num_threads(1)
        done.append("numba.set_num_threads(1) (the VHV kernels are serial anyway)")
    except Exception:  # pragma: no cover - numba's thread layer may already be fixed
        pass
    try:
        yield "; ".join(done)
    finally:
        if pin_cpu is not None and saved_cpus:
            os.sched_setaffinity(0, set(saved_cpus))
        for var, value in saved_env.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value


def _time_ms(fn: Any, repeat: int) -> tuple[list[float], list[float]]:
    """Wall-clock and process-CPU milliseconds of ``repeat`` calls (CPU time is immune to waiting for
    a core on a shared machine, wall time is what a user sees)."""
    wall, cpu = [], []
    for _ in range(max(1, repeat)):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return wall, cpu


def _summary(times: tuple[list[float], list[float]]) -> dict[str, Any]:
    wall, cpu = times
    return {
        "median_ms": statistics.median(wall),
        "min_ms": min(wall),
        "cpu_median_ms": statistics.median(cpu),
        "times_ms": wall,
        "cpu_times_ms": cpu,
    }


def _peak_extra_bytes(fn: Any) -> int:
    import tracemalloc

    tracemalloc.start()
    try:
        fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return int(peak)


def _run(args: argparse.Namespace) -> int:
    from robchair.platform.errors import RobChairError

    if args.repeat < 1 or args.octomap_repeat < 1:
        raise RobChairError(f"--repeat {args.repeat} / --octomap-repeat {args.octomap_repeat}: expected >= 1")
    if args.pin_cpu is not None and hasattr(os, "sched_getaffinity"):
        if args.pin_cpu not in os.sched_getaffinity(0):
            raise RobChairError(f"--pin-cpu {args.pin_cpu}: not one of this process's CPUs")
    out = results_dir(args, "mapping")  # refused before anything is measured
    load0 = os.getloadavg()
    with _one_core(args.pin_cpu) as pinned:
        result = _bench(args, pinned)
    write_results(out, "mapping", result, load0, os.getloadavg())
    return 0


def _bench(args: argparse.Namespace, pinned: str) -> dict[str, Any]:
    import numpy as np

    from mapping.grid import GridSpec
    from mapping.synthetic import kinect_hd_like_cloud
    from mapping.vhv import VHVMap

    series = QUICK_SERIES if args.quick else SERIES
    repeat = 2 if args.quick else args.repeat
    spec = GridSpec(cell_size=args.cell, size_x=20.0, size_y=20.0)
    origin = np.array([0.0, 0.0, 1.0])  # mapping.synthetic's camera position

    o3d = None
    if not args.no_open3d:
        from mapping._deps import import_open3d

        o3d = import_open3d()
    octomap = None
    if not args.no_octomap:
        from mapping._deps import require

        octomap = require("pyoctomap", "the OctoMap baseline of `robchair bench mapping`")

    rng = np.random.default_rng(args.seed)
    # First call loads the compiled kernels (numba cache) or compiles them; time it apart.
    warm = kinect_hd_like_cloud(np.random.default_rng(args.seed), 36, 64)
    t0 = time.perf_counter()
    VHVMap(spec, args.tolerance).insert(warm)
    first_call_ms = (time.perf_counter() - t0) * 1e3
    VHVMap(spec, args.tolerance).insert(warm.astype(np.float64))

    rows = []
    print(f"one core: {pinned}")
    print(f"VHV first call (numba cache load or compile): {first_call_ms:.0f} ms")
    header = (
        f"{'points':>9} {'NaN%':>5} | {'VHV fast':>9} {'(cpu)':>7} {'VHV sort':>9} {'VHV numpy':>9} | "
        f"{'O3D voxel':>9} {'O3D+copy':>9} "
        f"{'x fast':>6} | {'OctoMap*':>9} {'x fast':>7} | {'structs':>7} {'voxels':>7} {'O3D vox':>7} | "
        f"{'peak/in':>7}"
    )
    print(header)
    print("-" * len(header))
    for h, w in series:
        cloud = kinect_hd_like_cloud(rng, h, w)
        flat = cloud.reshape(-1, 3)
        n = flat.shape[0]
        nan_frac = float(np.isnan(flat[:, 0]).mean())
        row: dict[str, Any] = {"height": h, "width": w, "points": n, "nan_fraction": nan_frac}

        def vhv(method: Any, cloud: Any = cloud) -> Any:
            m = VHVMap(spec, args.tolerance)
            stats = m.insert(cloud, sensor_origin=origin, method=method)
            return m, stats

        m, stats = vhv("auto")
        row["vhv_fast"] = _summary(_time_ms(lambda: vhv("auto"), repeat))
        row["vhv_fast"]["path"] = stats.method
        row["vhv_numpy"] = _summary(_time_ms(lambda: vhv("numpy"), max(1, repeat // 2)))
        # The thesis's pipeline (group by cell, sort each cell, cluster), compiled: shows the choice.
        row["vhv_sort"] = _summary(_time_ms(lambda: vhv("sort"), max(1, repeat // 2)))
        row["structures"] = m.n_structures
        row["voxels"] = m.n_voxels
        row["cells_occupied"] = m.n_cells_occupied
        row["points_inserted"] = stats.points_inserted
        row["points_dropped_nonfinite"] = stats.points_dropped_nonfinite
        peak = _peak_extra_bytes(lambda: vhv("auto"))
        peak_np = _peak_extra_bytes(lambda: vhv("numpy"))
        row["input_bytes"] = int(cloud.nbytes)
        row["vhv_fast"]["peak_extra_bytes"] = peak
        row["vhv_numpy"]["peak_extra_bytes"] = peak_np
        fast = row["vhv_fast"]["median_ms"]
        fast_cpu = max(row["vhv_fast"]["cpu_median_ms"], 1e-3)

        o3d_txt = f"{'-':>9} {'-':>9} {'-':>6}"
        if o3d is not None:
            finite = flat[np.isfinite(flat).all(axis=1)].astype(np.float64)
            pcd = o3d.geometry.PointCloud()
            pcd.points = o3d.utility.Vector3dVector(finite)

            def o3d_voxel(pcd: Any = pcd) -> Any:
                return o3d.geometry.VoxelGrid.create_from_point_cloud(pcd, voxel_size=args.cell)

            def o3d_with_copy(flat: Any = flat) -> Any:
                ok = flat[np.isfinite(flat).all(axis=1)].astype(np.float64)
                p = o3d.geometry.PointCloud()
                p.points = o3d.utility.Vector3dVector(ok)
                return o3d.geometry.VoxelGrid.create_from_point_cloud(p, voxel_size=args.cell)

            vg = o3d_voxel()
            row["open3d_voxels"] = len(vg.get_voxels())
            row["open3d_voxelgrid"] = _summary(_time_ms(o3d_voxel, repeat))
            row["open3d_with_nan_filter_and_copy"] = _summary(_time_ms(o3d_with_copy, max(1, repeat // 2)))
            row["ratio_open3d_over_vhv_fast"] = row["open3d_voxelgrid"]["median_ms"] / fast
            row["ratio_open3d_over_vhv_fast_cpu"] = row["open3d_voxelgrid"]["cpu_median_ms"] / fast_cpu
            o3d_txt = (
                f"{row['open3d_voxelgrid']['median_ms']:9.1f} "
                f"{row['open3d_with_nan_filter_and_copy']['median_ms']:9.1f} "
                f"{row['ratio_open3d_over_vhv_fast']:6.1f}"
            )
        oct_txt = f"{'-':>9} {'-':>7}"
        if octomap is not None:
            finite64 = np.ascontiguousarray(flat[np.isfinite(flat).all(axis=1)], dtype=np.float64)

            def octo(finite64: Any = finite64) -> Any:
                tree = octomap.OcTree(args.cell)
                tree.insertPointCloud(finite64, origin)
                return tree

            row["octomap_insert"] = _summary(_time_ms(octo, 1 if args.quick else args.octomap_repeat))
            row["octomap_insert"]["note"] = "OctoMap ray-casts free space along every beam (more work)"
            row["ratio_octomap_over_vhv_fast"] = row["octomap_insert"]["median_ms"] / fast
            row["ratio_octomap_over_vhv_fast_cpu"] = row["octomap_insert"]["cpu_median_ms"] / fast_cpu
            oct_txt = f"{row['octomap_insert']['median_ms']:9.0f} {row['ratio_octomap_over_vhv_fast']:7.0f}"
        print(
            f"{n:9d} {100 * nan_frac:5.1f} | {fast:9.1f} {row['vhv_fast']['cpu_median_ms']:7.1f} "
            f"{row['vhv_sort']['median_ms']:9.1f} "
            f"{row['vhv_numpy']['median_ms']:9.1f} | {o3d_txt} | "
            f"{oct_txt} | {row['structures']:7d} {row['voxels']:7d} {row.get('open3d_voxels', 0):7d} | "
            f"{peak / cloud.nbytes:7.2f}"
        )
        rows.append(row)
    print("-" * len(header))
    print("times: median wall-clock ms per frame on one core, (cpu) = median process CPU ms;")
    print(
        "VHV includes NaN filtering; fast = bins (numba) or its sort fallback, sort = the thesis's pipeline"
    )
    print("(counting sort by cell + sort per cell, numba), numpy = the bin algorithm in plain numpy;")
    print("'x fast' = baseline median / VHV fast median")
    print("* OctoMap also ray-casts the free space of every beam, so it does more than an occupancy build.")
    print(f"thesis (C++, 4-core i7, 2,073,600 points): ~{THESIS_MS_PER_HD_FRAME:.0f} ms/frame (~6 frames/s)")
    print("peak/in: peak extra memory of the VHV build (tracemalloc: numpy + numba allocations) / input")
    hd = next((r for r in rows if r["points"] == 1920 * 1080), None)
    verdict: dict[str, Any] = {}
    if hd is not None:
        f = hd["vhv_fast"]["median_ms"]
        fc = hd["vhv_fast"]["cpu_median_ms"]
        verdict = {
            "vhv_fast_median_ms": f,
            "vhv_fast_cpu_median_ms": hd["vhv_fast"]["cpu_median_ms"],
            "vhv_numpy_median_ms": hd["vhv_numpy"]["median_ms"],
            "vhv_sort_median_ms": hd["vhv_sort"]["median_ms"],
            "target_ms": TARGET_MS,
            "meets_time_target": f <= TARGET_MS,
            "meets_time_target_in_cpu_time": fc <= TARGET_MS,
            "thesis_ms": THESIS_MS_PER_HD_FRAME,
            "speedup_vs_thesis": THESIS_MS_PER_HD_FRAME / f,
            "ratio_open3d": hd.get("ratio_open3d_over_vhv_fast"),
            "target_ratio_open3d": TARGET_RATIO_OPEN3D,
            "meets_open3d_target": (hd.get("ratio_open3d_over_vhv_fast") or 0) >= TARGET_RATIO_OPEN3D,
            "ratio_octomap": hd.get("ratio_octomap_over_vhv_fast"),
            "meets_octomap_target_100x": (hd.get("ratio_octomap_over_vhv_fast") or 0) >= 100,
            "ratio_open3d_cpu": hd.get("ratio_open3d_over_vhv_fast_cpu"),
            "ratio_octomap_cpu": hd.get("ratio_octomap_over_vhv_fast_cpu"),
            "peak_extra_over_input": hd["vhv_fast"]["peak_extra_bytes"] / hd["input_bytes"],
            "meets_memory_target_2x": hd["vhv_fast"]["peak_extra_bytes"] <= 2 * hd["input_bytes"],
        }
        print(
            f"HD frame: VHV {f:.1f} ms wall, {fc:.1f} ms CPU (target <= {TARGET_MS:.0f} ms: wall "
            f"{bench_verdict(verdict['meets_time_target'])}, CPU "
            f"{bench_verdict(verdict['meets_time_target_in_cpu_time'])}); "
            f"{THESIS_MS_PER_HD_FRAME / fc:.1f}x faster than the thesis's figure in CPU time; "
            f"peak extra memory {verdict['peak_extra_over_input']:.2f}x input"
        )
        ro = verdict["ratio_open3d"]
        ro_txt = "-" if ro is None else f"{ro:.1f}x"
        print(f"  Open3D / VHV: {ro_txt} (target >= {TARGET_RATIO_OPEN3D:.0f}x in the same run: "
              f"{bench_verdict(verdict['meets_open3d_target'])})")  # fmt: skip
        for name in ("open3d", "octomap"):
            if verdict[f"ratio_{name}"] is not None:
                print(
                    f"  {name}: {verdict[f'ratio_{name}']:.1f}x slower in wall time, "
                    f"{verdict[f'ratio_{name}_cpu']:.1f}x in CPU time"
                )
        if f > 2 * fc:
            print("  note: wall time is more than twice the CPU time: the machine is busy, prefer CPU times")
    evidence: dict[str, Any] = {}
    if not args.no_evidence:
        from robchair.commands.bench_mapping_evidence import bench_depth_frame, bench_insert, bench_walker

        print()
        evidence["insert"] = bench_insert(
            args.cell, args.tolerance, args.seed, repeat, max(0, args.prior_frames), octomap, args.quick
        )
        evidence["depth_frame"] = bench_depth_frame(args.cell, args.tolerance, args.seed, repeat, args.quick)
        evidence["walker"] = bench_walker(args.seed, args.quick)
    result = {
        "benchmark": "mapping",
        "one_core": pinned,
        "python": platform.python_version(),
        "machine": platform.machine(),
        "processor": platform.processor(),
        "cell_size": args.cell,
        "tolerance": args.tolerance,
        "repeat": repeat,
        "quick": bool(args.quick),
        "seed": args.seed,
        "first_call_ms": first_call_ms,
        "thesis_ms_per_hd_frame": THESIS_MS_PER_HD_FRAME,
        "rows": rows,
        "hd_frame": verdict,
        "evidence": evidence,
    }
    return result
