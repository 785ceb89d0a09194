"""``robchair run``: drive the chair (simulated, emulated or real) with the runtime loop.

    robchair run --backend sim|emulated|real [--config FILE] [--route FILE] [--duration S] [--out DIR]
                 [--source auto|route|joystick] [--assist off|shield|assist|door]

The config file (TOML) may hold one table per backend (``[sim]``, ``[emulated]``, ``[real]``: the
keys of :mod:`robchair.backends`), ``[runtime]`` (:class:`robchair.runtime_config.RuntimeConfig`),
``[safety]`` (:class:`robchair.platform.safety.SafetyLimits` overrides) and ``[route]`` (a route
inline, like a route file).
The command source is the route (``--route`` wins over ``[route]``), else the route of the sim
backend's ``scenario`` (odometry then starts at the scenario's start pose, in the world frame), else
the backend's joystick (``--source`` picks one), behind the assistance stage of ``--assist``
(:mod:`robchair.assistance`). ``--backend sim`` without a route drives the ``office_corridor`` scenario.
With ``--out`` the run is written as a ROS 2 bag (``bag/``, MCAP), ``metrics.json`` and ``odometry.csv``.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from robchair.commands.live import add_arguments as add_live_arguments
from robchair.platform.config import ConfigSource, ConfigTable

if TYPE_CHECKING:
    from robchair.platform.kinematics import Pose2D
    from robchair.platform.spec import RobChairSpec
    from robchair.route import Route


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("run", help="run the control loop on the sim, emulated or real chair")
    p.add_argument("--backend", default="sim", help="which chair: sim, emulated or real (default sim)")
    p.add_argument(
        "--config", type=Path, help="TOML config: [sim]/[emulated]/[real], [runtime], [safety], [route]"
    )
    p.add_argument("--route", type=Path, help="route TOML (waypoints, speed, lookahead_m, goal_tolerance_m)")
    p.add_argument(
        "--duration", type=float, default=60.0, help="maximum run time in seconds of the backend clock"
    )
    p.add_argument("--rate", type=float, help="loop rate in Hz (overrides [runtime] rate_hz)")
    p.add_argument(
        "--source",
        default="auto",
        help="command source: auto (the route if there is one, else the joystick), route or joystick",
    )
    p.add_argument(
        "--assist",
        default="off",
        help="assistance of the joystick (robchair.assistance): off, shield, assist or door (default off)",
    )
    p.add_argument("--out", type=Path, help="output folder: bag/, metrics.json, odometry.csv")
    p.add_argument(
        "--map",
        choices=("probabilistic", "thesis"),
        help="map kind (overrides [runtime] map_kind; default probabilistic): probabilistic (free space, "
        "unknown) or thesis (accumulate only)",
    )
    p.add_argument(
        "--no-safety",
        action="store_true",
        help="pass commands through without the safety layer (recorded in metrics.json)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="write into an existing non-empty --out folder (same-named entries and an earlier "
        "robchair output there are replaced; other files are kept)",
    )
    p.add_argument(
        "--release-stop",
        action="store_true",
        help="release an emergency stop the motor controller still holds from an earlier run (!MG)",
    )
    add_live_arguments(p)
    p.set_defaults(func=_run)


SOURCES = ("auto", "route", "joystick")


def command_source(
    backend: Any,
    route: Route | None,
    spec: RobChairSpec,
    limits: Any,
    assist: str = "off",
    rate_hz: float = 20.0,
) -> Any:
    """The run's command source: the route's pure pursuit, else the backend's joystick behind the
    assistance stage (:class:`robchair.assistance.AssistedSource` in mode ``assist``).

    Raises:
        ConfigError: neither a route nor a joystick; an unknown assistance mode.
    """
    from robchair.assistance import AssistedSource
    from robchair.platform.errors import ConfigError
    from robchair.platform.kinematics import DiffDrive
    from robchair.route import PurePursuit
    from robchair.sources import JoystickSource

    if route is not None:
        return PurePursuit(route, DiffDrive(spec))
    if backend.joystick is None:
        raise ConfigError(
            "no command source: give --route FILE (or a [route] table), or use a backend with a joystick"
        )
    person = JoystickSource(backend.joystick, limits.max_speed, limits.max_yaw_rate)
    return AssistedSource(person, spec, limits.max_speed, limits.max_yaw_rate, assist, rate_hz=rate_hz)


RUN_CONFIG_TABLES = ("sim", "emulated", "real", "runtime", "safety", "route")


def load_run_config(path: Path | None) -> ConfigTable:
    """The ``--config`` file as a checked top-level table (empty without a file).

    Raises:
        ConfigError: the file is missing or not TOML, or has a table other than
            :data:`RUN_CONFIG_TABLES` (``<file>:<line>: <key>: unknown key ...; expected one of ...``).
    """
    from robchair.platform.config import load_toml

    if path is None:
        return ConfigTable({})
    data, source = load_toml(path, what="config file")
    top = ConfigTable(data, source)
    top.keys(RUN_CONFIG_TABLES)
    for name in RUN_CONFIG_TABLES:
        top.table(name, {})  # each one a table
    return top


def _scenario_route(name: str, spec: RobChairSpec) -> tuple[Route, Pose2D]:
    """The route of a sim scenario as a runtime Route starting at the scenario's start pose."""
    from robchair.platform.kinematics import Pose2D
    from robchair.route import Route
    from sim.backend import robot_radius
    from sim.scene import load_scenario

    sc = load_scenario(name, robot_radius=robot_radius(spec))
    x, y, yaw = sc.start
    route = Route(((x, y), *sc.route.waypoints), speed=sc.route.speed, lookahead_m=sc.route.lookahead)
    return route, Pose2D(x, y, yaw)


def _run(args: argparse.Namespace) -> int:
    from robchair.backends import BACKENDS
    from robchair.commands.live import live_observers
    from robchair.outdir import check_output_dir
    from robchair.runtime_config import check_duration_s

    if args.backend not in BACKENDS:
        raise ConfigSource().invalid("--backend", args.backend, f"one of {', '.join(BACKENDS)}")
    check_duration_s(args.duration, "--duration")  # the duration and the rate before opening the chair
    if args.rate is not None and not (math.isfinite(args.rate) and args.rate > 0):
        raise ConfigSource().invalid("--rate", args.rate, "a finite loop rate in Hz > 0")
    if args.source not in SOURCES:
        raise ConfigSource().invalid("--source", args.source, f"one of {', '.join(SOURCES)}")
    from robchair.assistance import MODES

    if args.assist not in MODES:
        raise ConfigSource().invalid("--assist", args.assist, f"one of {', '.join(MODES)}")
    if args.out is not None:
        check_output_dir(args.out, overwrite=args.overwrite)  # refuse before opening the chair
    with live_observers(args) as live:  # a port in use is refused before the chair is opened too
        return _drive(args, live)


def _drive(args: argparse.Namespace, live: list[Any]) -> int:
    from robchair.backends import get_backend
    from robchair.outdir import overwrite_allowed
    from robchair.platform.errors import ConfigError
    from robchair.platform.safety import Footprint, SafetyLayer, SafetyLimits
    from robchair.platform.spec import load_spec
    from robchair.route import Route
    from robchair.run_output import run_to_dir
    from robchair.runtime_config import RuntimeConfig

    cfg = load_run_config(args.config)
    backend_table = cfg.table(args.backend, {})
    backend_cfg = dict(backend_table.data)
    if isinstance(backend_cfg.get("sensor"), str) and backend_cfg["sensor"].lower() == "none":
        backend_cfg["sensor"] = None  # TOML has no null: sensor = "none" means no depth camera
    spec_path = backend_table.string("spec", None)
    spec = load_spec(spec_path) if spec_path else load_spec()
    overrides: dict[str, Any] = {} if args.rate is None else {"rate_hz": args.rate}
    if args.map is not None:
        overrides["map_kind"] = args.map
    runtime_config = RuntimeConfig.from_dict(cfg.table("runtime", {}), **overrides)
    safety = SafetyLayer(
        SafetyLimits.from_spec(spec, cfg.table("safety", {})),
        spec.wheel_separation,
        Footprint.from_spec(spec),
    )
    route = None
    if args.route is not None:
        route = Route.load(args.route)
    elif "route" in cfg:
        route = Route.from_dict(cfg.table("route"))
    start_pose = None
    if args.source == "joystick":
        route = None
    if route is None and args.backend == "sim" and args.source != "joystick":
        if not backend_cfg.get("scene"):
            backend_cfg.setdefault("scenario", "office_corridor")
        if backend_cfg.get("scenario"):
            route, start_pose = _scenario_route(str(backend_cfg["scenario"]), spec)
    if args.release_stop and args.backend != "sim":
        backend_cfg["release_stop"] = True
    backend = get_backend(
        args.backend,
        ConfigTable(backend_cfg, backend_table.source, backend_table.where),
        loop_rate_hz=runtime_config.rate_hz,
    )
    try:  # the backend is built (an emulator may already run): close it however what follows ends
        if args.source == "route" and route is None:
            raise ConfigError("--source route: no route; give --route FILE or a [route] table")
        source = command_source(backend, route, spec, safety.limits, args.assist, runtime_config.rate_hz)
        observers = []
        chair = getattr(backend, "chair", None)
        if chair is not None:  # the simulated chair: evaluate against the physics and the scene
            from robchair.observers.evaluation import GroundTruthEvaluation

            observers.append(GroundTruthEvaluation(chair, chair.scene, ground_truth_map=False))
        with overwrite_allowed(args.overwrite):
            result = run_to_dir(
                backend,
                source,
                args.duration,
                args.out,
                spec=spec,
                config=runtime_config,
                safety=safety,
                start_pose=start_pose,
                safety_enabled=not args.no_safety,
                observers=observers + live,
            )
    except BaseException:
        backend.close()
        raise
    print(json.dumps(result.metrics(), indent=2, default=str))
    return 0 if result.driver_fault is None else 1
