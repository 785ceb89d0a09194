"""`robchair sim`: run a simulation scenario headlessly through the runtime and write its run folder."""

from __future__ import annotations

import argparse

from robchair.commands.live import add_arguments as add_live_arguments

SENSORS = ("kinect2", "kinect2-hd", "kinect2-qhd", "kinect1", "none")


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "sim",
        help="run a simulation scenario headlessly (default: office_corridor) and write a run folder",
        description=(
            "Drive the simulated RobChair along a scenario's route through the runtime (safety layer on), "
            "map every sensor frame with the VHV mapping core (odometry and ground-truth poses) and write "
            "maps, pictures, a ROS 2 bag and metrics.json into the run folder "
            "(default runs/<scenario>-<UTC time>)."
        ),
    )
    p.add_argument(
        "scenario",
        nargs="?",
        default="office_corridor",
        help="scenario name in assets/scenes/ or a scenario TOML file (default: office_corridor)",
    )
    p.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scenario's)")
    p.add_argument(
        "--sensor", choices=SENSORS, default=None, help="Kinect model, or none (default: the scenario's)"
    )
    p.add_argument("--out", default=None, help="run folder (default runs/<scenario>-<UTC timestamp>)")
    p.add_argument(
        "--seed", type=int, default=None, help="seed of every noise generator (default: the scenario's)"
    )
    p.add_argument(
        "--camera-backend",
        choices=("raycast", "pybullet"),
        default="raycast",
        help="depth camera backend: Open3D ray casting (default) or PyBullet's renderer",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="write into an existing non-empty --out folder (same-named entries and an earlier "
        "robchair output there are replaced; other files are kept)",
    )
    p.add_argument("--no-bag", action="store_true", help="do not record the ROS 2 bag")
    p.add_argument(
        "--bag-storage", choices=("mcap", "sqlite3"), default="mcap", help="bag storage (default mcap)"
    )
    p.add_argument(
        "--bag-clouds",
        choices=("voxel", "decimated", "full"),
        default="voxel",
        help="depth clouds in the bag: voxel (every frame the map is built from, thinned to the points "
        "that build the same VHV structures in the odometry map, with the no-return rays on "
        "/kinect/points/no_return: `robchair map --map-kind probabilistic` on it rebuilds the run's map; "
        "default), decimated (every 3rd frame, every 4th pixel each way) or full (every frame whole, "
        "about 70 MB per simulated second)",
    )
    p.add_argument(
        "--no-safety",
        action="store_true",
        help="drive without the safety layer (ground-truth studies; recorded in metrics.json)",
    )
    p.add_argument(
        "--keep-freed-memory",
        action="store_true",
        help="ask glibc to keep freed heap blocks for reuse (faster per-frame allocations; process-wide)",
    )
    p.add_argument(
        "--pose",
        choices=("odometry", "matched", "ground-truth"),
        default=None,
        help="pose the run's map is built with (default: matched, robchair.scenario.POSE_DEFAULT); the "
        "odometry and matched maps are built beside it either way",
    )
    p.add_argument(
        "--no-matching", action="store_true", help="no scan-to-map matching (unless --pose matched)"
    )
    p.add_argument("--no-zoom", action="store_true", help="no 1 cm zoom region around the chair")
    p.add_argument(
        "--map",
        choices=("probabilistic", "thesis"),
        default="probabilistic",
        help="map kind: probabilistic (free space, unknown, moving people cleared; default) or thesis "
        "(the thesis's accumulate-only VHV map)",
    )
    p.add_argument("--no-pictures", action="store_true", help="do not draw the PNG pictures")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--list", action="store_true", help="list the scenarios and exit")
    add_live_arguments(p)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import json

    from sim.scene import list_scenarios, load_scenario

    if args.list:
        for path in list_scenarios():
            sc = load_scenario(path)
            print(
                f"{sc.name:24s} {sc.duration:6.1f} s  {sc.sensor:10s} "
                f"scene {sc.scene.name:16s} {sc.description}"
            )
        return 0
    from robchair.commands.live import live_observers
    from robchair.outdir import check_output_dir, overwrite_allowed
    from robchair.runtime_config import check_duration_s
    from robchair.scenario import run_scenario

    if args.duration is not None:
        check_duration_s(args.duration, "--duration")
    if args.out is not None:
        check_output_dir(args.out, overwrite=args.overwrite)  # refuse before simulating
    if args.keep_freed_memory:
        retain_freed_memory()
    with overwrite_allowed(args.overwrite), live_observers(args) as live:
        res = run_scenario(
            args.scenario,
            out_dir=args.out,
            duration=args.duration,
            sensor=args.sensor,
            seed=args.seed,
            progress=not args.no_progress,
            write_bag=not args.no_bag,
            pictures=not args.no_pictures,
            camera_backend=args.camera_backend,
            safety=not args.no_safety,
            bag_storage=args.bag_storage,
            bag_clouds=args.bag_clouds,
            **({"pose": args.pose} if args.pose else {}),
            matching=not args.no_matching,
            zoom=not args.no_zoom,
            map_kind=args.map,
            observers=live,
        )
    m = res.metrics()
    summary = {
        "out": str(res.out_dir),
        "frames": m["frames"]["depth_frames"],
        "sonar_readings": m["frames"]["sonar_readings"],
        "mapping_ms_per_frame_median": m["mapping_ms_per_frame_median"],
        "real_time_factor": round(m["real_time_factor"], 3) if m["real_time_factor"] else None,
        "goal_reached": m["route"]["goal_reached"],
        "safety": {"enabled": m["safety"]["enabled"], "stops": len(m["safety"]["stops"])},
        "collisions": m["collisions"],
        "odometry_final_error_m": round(m["odometry_drift"]["final_position_error_m"], 4),
        "iou_odometry_vs_ground_truth_pose": m["map"]["iou_odometry_vs_ground_truth_pose"],
        "map_kind": m["map"]["kind"],
    }
    matched = (m["odometry_drift"] or {}).get("matched")
    if matched:
        summary["matched_final_error_m"] = round(matched["final_position_error_m"], 4)
        summary["matching_ms_per_frame_median"] = matched["matching_ms_per_frame_median"]
        summary["iou_matched_vs_ground_truth_pose"] = m["map"].get("iou_matched_vs_ground_truth_pose")
    print(json.dumps(summary, indent=2))
    return 0


def retain_freed_memory(limit_bytes: int = 1 << 30) -> bool:
    """Ask glibc's allocator to keep freed blocks up to ``limit_bytes`` for reuse; True if it agreed.

    Every sensor frame allocates a few multi-megabyte arrays and frees them a frame later. By
    default glibc serves such blocks with fresh ``mmap`` pages and returns them on ``free``, so
    each frame pays a page fault per 4 KiB it touches: measured here, a Kinect v2 capture took
    49 ms that way and 28 ms with the blocks kept. Raising the mmap and trim thresholds keeps them
    in the heap. Process-wide and harmless (memory use is bounded by the peak); a no-op where the
    C library is not glibc.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    limit = min(int(limit_bytes), 2**31 - 1)
    # older glibc caps the mmap threshold at 32 MiB (64-bit): fall back to that
    ok = bool(mallopt(m_mmap_threshold, ctypes.c_int(limit))) or bool(
        mallopt(m_mmap_threshold, ctypes.c_int(min(limit, 32 << 20)))
    )
    return ok and bool(mallopt(m_trim_threshold, ctypes.c_int(limit)))
