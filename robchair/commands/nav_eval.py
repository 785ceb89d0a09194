"""`robchair nav-eval`: evaluate navigation policies on a RobChair Gymnasium environment.

Runs ``--episodes`` episodes (seeds ``--seed`` .. ``--seed + N - 1``) per ``--policy``, prints one
table row per policy (success rate, SPL, collision rate, safety interventions per episode, time to
goal, path length ratio, BARN score; see :mod:`robchair.navigation.metrics`), and writes
``DIR/nav_eval.json`` (the summary and every episode) and ``DIR/episode_<policy>_<seed>.png`` for
the first ``--pictures`` episodes (ground truth, the chair's own map, the planned routes and the
driven path). Random-floor ids evaluate on the evaluation floors (``room_seeds="eval"``), never on
the training ones, unless ``--split train``. Each episode is one call of the pure function
:func:`robchair.navigation.evaluation.evaluate_episode`.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Any

from robchair.outdir import OVERWRITE_HELP

DEFAULT_OUT = "runs/nav-eval-<UTC time>"  # a new folder per run


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "nav-eval", help="evaluate navigation policies (success, SPL, collisions, BARN)"
    )
    p.add_argument(
        "--env", default="RobChair/Navigation-v1", help="Gymnasium id (default RobChair/Navigation-v1)"
    )
    p.add_argument("--episodes", type=int, default=20, help="episodes per policy (default 20)")
    p.add_argument(
        "--policy",
        action="append",
        help="baseline | random | MODULE:CALLABLE (CALLABLE(env) returns policy(obs, info) -> action); "
        "repeat for several (default baseline)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    p.add_argument("--out", default=None, help=f"output folder (default {DEFAULT_OUT})")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.add_argument("--pictures", type=int, default=3, help="pictures of the first N episodes (default 3)")
    p.add_argument("--split", choices=("eval", "train"), default="eval", help="floors of random-floor ids")
    p.add_argument(
        "--ray",
        action="store_true",
        help="distribute the episodes over Ray workers (a local instance unless --address); same results",
    )
    p.add_argument(
        "--address", default=None, help="Ray cluster address (auto, ray://host:port); implies --ray"
    )
    p.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local Ray instance (default: all)")
    p.set_defaults(func=_run)


def _serial(env_id: str, seeds: list[int], spec: str, kwargs: dict[str, Any], pictures: int) -> Any:
    from tqdm import tqdm

    from robchair.navigation.evaluation import evaluate_episode

    for k, seed in enumerate(tqdm(seeds, desc=f"{spec} on {env_id}", unit="ep")):
        yield evaluate_episode(env_id, seed, spec, kwargs, keep_trajectory=k < pictures)


def _episode_task(env_id: str, seed: int, spec: str, kwargs: dict[str, Any], keep: bool) -> dict[str, Any]:
    """One episode in a Ray worker (the worker keeps its environments between episodes)."""
    import sim.envs  # noqa: F401  (registers the ids in the worker)
    from robchair.navigation.evaluation import evaluate_episode

    return evaluate_episode(env_id, seed, spec, kwargs, keep_trajectory=keep)


def _distributed(
    ray: Any, env_id: str, seeds: list[int], spec: str, kwargs: dict[str, Any], pictures: int
) -> Any:
    """The same episodes as :func:`_serial`, as Ray tasks; yielded in seed order."""
    from robchair.sweep.executor import ordered_tasks

    calls = [(env_id, seed, spec, kwargs, k < pictures) for k, seed in enumerate(seeds)]
    yield from ordered_tasks(ray, _episode_task, calls, f"{spec} on {env_id}")


def _picture(ep: dict[str, Any], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    grid = ep["_grid"]
    x0, x1, y0, y1 = grid.extent
    img = np.full((*grid.shape, 3), 1.0)
    img[ep["_truth"]] = (0.8, 0.8, 0.8)
    img[ep["_own"]] = (0.1, 0.1, 0.1)
    fig, ax = plt.subplots(figsize=(8, 8 * (y1 - y0) / max(x1 - x0, 1e-6) + 0.6))
    ax.imshow(np.transpose(img, (1, 0, 2)), origin="lower", extent=(x0, x1, y0, y1))
    for k, r in enumerate(ep.get("routes", [])):
        r = np.asarray(r)
        last = k == len(ep["routes"]) - 1
        ax.plot(
            r[:, 0],
            r[:, 1],
            "--",
            color="tab:orange",
            alpha=1.0 if last else 0.25,
            lw=1.2,
            label="planned" if last else None,
        )
    t = np.asarray(ep["trajectory"])
    ax.plot(t[:, 0], t[:, 1], "-", color="tab:blue", lw=2, label="driven")
    ax.plot(*ep["start"], "o", color="tab:blue", label="start")
    ax.plot(*ep["goal"], "*", color="tab:green", ms=14, label="goal")
    outcome = (
        "success"
        if ep["success"]
        else ("collision " + ",".join(ep["contacts"]) if ep["collision"] else "timeout")
    )
    ax.set_title(
        f"{title} seed {ep['seed']} ({ep['scene']}): {outcome}\n"
        "grey: ground truth, black: the chair's own map"
    )
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _run(args: argparse.Namespace) -> int:
    import contextlib

    import sim.envs
    from robchair.navigation.evaluation import EvaluationError, close_envs, policy_factory
    from robchair.navigation.metrics import format_table, summarize
    from robchair.outdir import check_output_dir, timestamped_dir

    if getattr(args, "verbose", 0) == 0:  # one line per safety stop would bury the progress bar
        logging.getLogger("robchair.platform.safety").setLevel(logging.ERROR)
    if args.episodes < 1:
        raise EvaluationError(f"--episodes {args.episodes}: expected at least 1")
    if args.env not in sim.envs.ENV_IDS:
        raise EvaluationError(f"--env {args.env!r}: expected one of {', '.join(sim.envs.ENV_IDS)}")
    if args.out is None:
        args.out = timestamped_dir("nav-eval")
    out_dir = check_output_dir(args.out, overwrite=args.overwrite)  # refuse before any episode
    policies = args.policy or ["baseline"]
    for spec in policies:
        policy_factory(spec)  # a bad spec fails here, before any episode runs
    kwargs: dict[str, Any] = {}
    import gymnasium

    if gymnasium.spec(args.env).kwargs.get("scene") == "rooms":
        kwargs["room_seeds"] = args.split
    results: dict[str, Any] = {"env": args.env, "env_kwargs": kwargs, "seed": args.seed, "policies": {}}
    rows = []
    if args.num_cpus is not None and args.num_cpus < 1:
        raise EvaluationError(f"--num-cpus {args.num_cpus}: expected at least 1")
    distributed = args.ray or args.address is not None
    seeds = [args.seed + k for k in range(args.episodes)]
    with contextlib.ExitStack() as stack:
        ray = None
        if distributed:
            from robchair.sweep.executor import ray_session

            ray = stack.enter_context(ray_session(args.address, args.num_cpus))
        stack.callback(close_envs)
        with out_dir.stage() as out:
            for spec in policies:
                eps = []
                run = (
                    _distributed(ray, args.env, seeds, spec, kwargs, args.pictures)
                    if ray is not None
                    else _serial(args.env, seeds, spec, kwargs, args.pictures)
                )
                for k, ep in enumerate(run):
                    if k < args.pictures:
                        safe = spec.replace(":", "_").replace("/", "_")
                        _picture(ep, out / f"episode_{safe}_{ep['seed']}.png", spec)
                        for key in [key for key in ep if key.startswith("_")]:
                            del ep[key]
                    eps.append(ep)
                summary = summarize(eps)
                results["policies"][spec] = {"summary": summary, "episodes": eps}
                rows.append((spec, summary))
            (out / "nav_eval.json").write_text(json.dumps(results, indent=2) + "\n")
    print(
        f"{args.env}, {args.episodes} episodes per policy, seeds {args.seed}..{args.seed + args.episodes - 1}"
    )
    print(format_table(rows))
    print(f"wrote {Path(args.out) / 'nav_eval.json'}")
    return 0
