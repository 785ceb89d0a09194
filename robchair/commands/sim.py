"""`robchair sim`: run a simulation scenario headlessly and write its run folder."""

from __future__ import annotations

import argparse

SENSORS = ("kinect2", "kinect2-hd", "kinect2-qhd", "kinect1")


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "sim",
        help="run a simulation scenario headlessly (default: office_corridor) and write a run folder",
        description=(
            "Drive the simulated RobChair along a scenario's route, map every sensor frame with the VHV "
            "mapping core (odometry and ground-truth poses) and write maps, pictures, a ROS 2 bag and "
            "metrics.json into the run folder (default runs/<scenario>-<UTC time>)."
        ),
    )
    p.add_argument(
        "scenario",
        nargs="?",
        default="office_corridor",
        help="scenario name in assets/scenes/ or a scenario TOML file (default: office_corridor)",
    )
    p.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scenario's)")
    p.add_argument("--sensor", choices=SENSORS, default=None, help="Kinect model (default: the scenario's)")
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
    p.add_argument("--no-pictures", action="store_true", help="do not draw the PNG pictures")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--list", action="store_true", help="list the scenarios and exit")
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
    from robchair.outdir import check_output_dir, overwrite_allowed
    from sim.runner import run_scenario

    if args.out is not None:
        check_output_dir(args.out, overwrite=args.overwrite)  # refuse before simulating
    with overwrite_allowed(args.overwrite):
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
        )
    m = res.metrics
    summary = {
        "out": str(res.out_dir),
        "frames": m["frames"]["kinect_frames"],
        "sonar_readings": m["frames"]["sonar_readings"],
        "mapping_ms_per_frame_median": round(m["mapping_ms_per_frame_median"], 2),
        "real_time_factor": round(m["real_time_factor"], 3) if m["real_time_factor"] else None,
        "odometry_final_error_m": round(m["odometry_drift"]["final_position_error_m"], 4),
        "iou_odometry_vs_ground_truth_pose": m["map"]["iou_odometry_vs_ground_truth_pose"],
    }
    print(json.dumps(summary, indent=2))
    return 0
