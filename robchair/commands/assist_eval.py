"""`robchair assist-eval`: shared control with a simulated user, per assistance mode.

    robchair assist-eval [--env random] --user PRESET --mode MODE [--mode MODE ...] --episodes N
                         --seed S --out DIR [--door-width LO HI] [--pictures K] [--ray [--num-cpus C]]

Each episode is a random floor of the evaluation seeds (:data:`sim.rooms.EVAL_SEEDS`, from index
``--seed``) with doorways ``--door-width`` m wide (default 0.80-0.90 m: real office doors, SPEC
section 7): the chair starts in the corridor 1.5-3 m beside a room's doorway, facing along the
corridor, and the simulated user (:mod:`sim.user`, preset ``--user``) drives into the room through
it. Every mode drives the same episodes (:func:`robchair.assistance.evaluation.run_episode`, a
kinematic planar chair with the real assistance stage and safety layer). Prints one table row per
mode; writes ``DIR/assist_eval.json`` (one record per mode with its means, and every episode),
``DIR/paths.png`` and ``DIR/paths_<k>.png`` (the first ``--pictures`` episodes' floor plans with each
mode's path) and ``DIR/report.md`` (the command, the table and the pictures). ``--ray`` runs the
episodes as Ray tasks (:func:`robchair.sweep.executor.ordered_tasks`, as ``nav-eval --ray``), with the
same results.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from pathlib import Path
from typing import Any

from robchair.outdir import OVERWRITE_HELP

DEFAULT_OUT = "runs/assist-eval-<UTC time>"  # a new folder per run
ENVS = ("random", "office")
MEANS = ("agreement", "overridden_share", "time_s", "min_clearance_m", "joystick_path", "reversals",
         "peak_lon_accel", "rms_lon_accel", "peak_lat_accel", "rms_lat_accel", "peak_jerk",
         "safety_stops")  # fmt: skip


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser("assist-eval", help="shared control with a simulated user, per assistance mode")
    p.add_argument("--env", default="random",
                   help="scenario set: random (floors with doorways; default) or office")  # fmt: skip
    p.add_argument("--user", default="tremor", help="simulated user preset: typical, tremor or switch")
    p.add_argument("--mode", action="append", help="assistance mode (repeat): off, shield, assist, door")
    p.add_argument("--episodes", type=int, default=20, help="episodes per mode (default 20)")
    p.add_argument("--seed", type=int, default=0, help="index of the first evaluation floor (default 0)")
    p.add_argument("--door-width", type=float, nargs=2, default=(0.8, 0.9), metavar=("LO", "HI"),
                   help="doorway clear width range, m (default 0.80 0.90)")  # fmt: skip
    p.add_argument(
        "--pictures",
        type=int,
        default=3,
        help="paths pictures of the first K episodes (default 3, at least 1)",
    )
    p.add_argument("--ray", action="store_true", help="run the episodes as Ray tasks (a local instance)")
    p.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local Ray instance (default: all)")
    p.add_argument("--out", default=None, help=f"output folder (default {DEFAULT_OUT})")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.set_defaults(func=_run)


def office_scenario(index: int, door_width: tuple[float, float]) -> dict[str, Any]:
    """The office floor (``assets/scenes/office.toml``) with its 1.4 m doorway narrowed to a width
    drawn from ``door_width``: the chair starts 0-1.5 m along the corridor, up to 0.4 m off its centre
    line and 0.3 rad askew, and the user drives along it and through the doorway to 1.3 m inside."""
    import dataclasses

    import numpy as np

    from robchair.platform.paths import ASSETS
    from sim.planar import from_scene
    from sim.rooms import EVAL_SEEDS
    from sim.scene import load_scene

    seed = EVAL_SEEDS[index]
    rng = np.random.default_rng(seed)
    width = float(rng.uniform(*door_width))
    scene = load_scene(ASSETS / "scenes" / "office.toml")
    objs = []
    for o in scene.objects:
        if o.name in ("room_wall_west_left", "room_wall_west_right"):  # the wall pieces y = +-0.7..+-3.0
            sign = 1.0 if o.name.endswith("left") else -1.0
            half = 0.5 * width
            assert o.size is not None
            o = dataclasses.replace(o, size=(o.size[0], 3.0 - half, o.size[2]),
                                    xyz=(o.xyz[0], sign * 0.5 * (3.0 + half), o.xyz[2]))  # fmt: skip
        objs.append(o)
    scene = dataclasses.replace(scene, objects=tuple(objs))
    start = (float(rng.uniform(0.0, 1.5)), float(rng.uniform(-0.4, 0.4)), float(rng.uniform(-0.3, 0.3)))
    route = [(5.0, 0.0), (7.4, 0.0)]  # the wall's near face at x = 6.0, 0.1 m thick
    return {"seed": seed, "floor": None, "world": from_scene(scene), "start": start, "route": route,
            "door_width": width}  # fmt: skip


def scenario(index: int, door_width: tuple[float, float], env: str = "random") -> dict[str, Any]:
    """Floor, start pose and route of evaluation episode ``index`` of scenario set ``env``."""
    if env == "office":
        return office_scenario(index, door_width)
    import numpy as np

    from sim.planar import from_scene
    from sim.rooms import EVAL_SEEDS, FloorConfig, generate_floor

    seed = EVAL_SEEDS[index]
    floor = generate_floor(seed, FloorConfig(door_width=door_width, max_clutter=0))
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = floor.corridor
    corridor_doors = [d for d in floor.doors if abs(d[1] - (y1 + 0.05)) < 1e-6]
    dx, dy, width = corridor_doors[int(rng.integers(len(corridor_doors)))]
    # side +1: start west of the doorway facing east; -1: east of it facing west (where there is room)
    west, east = dx - x0 - 0.7, x1 - dx - 0.7
    side = float(rng.choice([-1.0, 1.0])) if min(west, east) >= 1.5 else (1.0 if west > east else -1.0)
    sx = dx - side * min(float(rng.uniform(1.5, 3.0)), west if side > 0 else east)
    start = (sx, 0.5 * (y0 + y1), (0.0 if side > 0 else math.pi) + float(rng.uniform(-0.15, 0.15)))
    route = [(dx, 0.5 * (y0 + y1)), (dx, dy + 1.3)]
    return {"seed": seed, "floor": floor, "world": from_scene(floor.scene), "start": start, "route": route,
            "door_width": width}  # fmt: skip


def _check(args: argparse.Namespace) -> list[str]:
    from robchair.assistance import MODES
    from robchair.platform.errors import ConfigError
    from sim.user import PRESETS

    modes = args.mode or ["off", "door"]
    for m in modes:
        if m not in MODES:
            raise ConfigError(f"--mode {m!r}: expected one of {', '.join(MODES)}")
    if args.user not in PRESETS:
        raise ConfigError(f"--user {args.user!r}: expected one of {', '.join(PRESETS)}")
    if args.env not in ENVS:
        raise ConfigError(f"--env {args.env!r}: expected one of {', '.join(ENVS)}")
    if args.episodes < 1:
        raise ConfigError(f"--episodes {args.episodes}: expected an integer >= 1")
    if args.pictures < 0:
        raise ConfigError(f"--pictures {args.pictures}: expected an integer >= 0")
    if args.num_cpus is not None and args.num_cpus < 1:
        raise ConfigError(f"--num-cpus {args.num_cpus}: expected an integer >= 1")
    if not 0 <= args.seed < 10_000 - args.episodes:
        raise ConfigError(f"--seed {args.seed}: expected 0 <= seed < {10_000 - args.episodes}")
    lo, hi = args.door_width
    if not 0.74 <= lo <= hi <= 1.5:
        raise ConfigError(f"--door-width {lo} {hi}: expected 0.74 <= LO <= HI <= 1.5 m")
    return modes


def episode_set(index: int, door_width: tuple[float, float], env: str, modes: list[str],
                user: str) -> dict[str, dict[str, Any]]:  # fmt: skip
    """Every mode on evaluation episode ``index`` (one Ray task with ``--ray``): ``{mode: metrics}``."""
    from robchair.assistance.evaluation import run_episode
    from robchair.platform.spec import load_spec
    from sim.user import preset

    sc = scenario(index, door_width, env)
    spec, params = load_spec(), preset(user)
    out = {}
    for m in modes:
        ep = run_episode(sc["world"], spec, sc["start"], sc["route"], m, params, seed=index)
        ep.update(floor_seed=sc["seed"], door_width_m=sc["door_width"])
        out[m] = ep
    return out


def _run(args: argparse.Namespace) -> int:
    import contextlib
    import shlex
    import sys

    from tqdm import tqdm

    from robchair.commands.assist_eval_report import picture, print_table, report_page
    from robchair.outdir import check_output_dir, timestamped_dir

    modes = _check(args)
    if getattr(args, "verbose", 0) == 0:  # one line per safety stop would bury the progress bar
        logging.getLogger("robchair.platform.safety").setLevel(logging.ERROR)
    if args.out is None:
        args.out = timestamped_dir("assist-eval")
    out_dir = check_output_dir(args.out, overwrite=args.overwrite)  # refuse before any episode
    door = (float(args.door_width[0]), float(args.door_width[1]))
    calls = [(i, door, args.env, modes, args.user) for i in range(args.seed, args.seed + args.episodes)]
    desc = f"{args.user} on {args.env}"
    with contextlib.ExitStack() as stack:
        if args.ray:
            from robchair.sweep.executor import ordered_tasks, ray_session

            ray = stack.enter_context(ray_session(None, args.num_cpus))
            sets = list(ordered_tasks(ray, episode_set, calls, desc))
        else:
            sets = [episode_set(*c) for c in tqdm(calls, desc=desc, unit="ep")]
    episodes = {m: [s[m] for s in sets] for m in modes}
    records = [_summary(m, eps, args) for m, eps in episodes.items()]
    print_table(records)
    doc = {"env": args.env, "user": args.user, "episodes": args.episodes, "seed": args.seed,
           "door_width_m": list(args.door_width), "modes": records,
           "episodes_by_mode": {m: [{k: v for k, v in e.items() if k != "path"} for e in eps]
                                for m, eps in episodes.items()}}  # fmt: skip
    command = (
        "robchair " + shlex.join(sys.argv[1:]) if sys.argv[1:2] == ["assist-eval"] else "robchair assist-eval"
    )
    with out_dir.stage() as out:
        (out / "assist_eval.json").write_text(json.dumps(doc, indent=2) + "\n")
        names = []
        for k, s in enumerate(sets[: max(1, args.pictures)]):
            names.append("paths.png" if k == 0 else f"paths_{k}.png")
            picture(scenario(args.seed + k, door, args.env), s, out / names[-1], args.user)
        (out / "report.md").write_text(report_page(doc, names, command))
    where = Path(args.out)
    print(f"wrote {where / 'assist_eval.json'}, {where / 'report.md'} and {len(names)} pictures")
    return 0


def _summary(mode: str, eps: list[dict[str, Any]], args: argparse.Namespace) -> dict[str, Any]:
    import numpy as np

    rec: dict[str, Any] = {"mode": mode, "user": args.user, "episodes": len(eps),
                           "success_rate": float(np.mean([e["success"] for e in eps])),
                           "collisions": int(sum(e["collisions"] for e in eps))}  # fmt: skip
    for k in MEANS:
        rec[k] = float(np.mean([e[k] for e in eps]))
    keys = sorted({k for e in eps for k in e.get("agreement_loss", {})})
    # 1 - agreement split by what the stage did (episode means: the values add up to 1 - agreement)
    rec["agreement_loss"] = {k: float(np.mean([e.get("agreement_loss", {}).get(k, 0.0) for e in eps]))
                             for k in keys}  # fmt: skip
    rec["peak_lon_accel_max"] = float(max(e["peak_lon_accel"] for e in eps))
    ok = [e["time_s"] for e in eps if e["success"]]
    rec["time_to_goal_s"] = float(np.mean(ok)) if ok else None
    return rec
