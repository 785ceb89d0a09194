"""`robchair bench env`: agent steps per second of the Gymnasium navigation environments.

Configurations, all measured in the same run with the same seed and the same random actions:

* ``physics only``: the baseline every configuration stands on - one agent period of the chair's
  physics and motor plants + PIDs (240 Hz / ``agent_hz`` steps) in the same scene, no sensor, no map;
* ``light (Navigation-v1)``: six sonars mapped every step, the light observation;
* ``Kinect (NavigationKinect-v1)``: the light observation plus a Kinect v2 decimated 4x (128x106 rays);
* ``dynamic (NavigationDynamic-v1)``: the light observation on random floors with two walkers (a new
  floor, and so a new PyBullet scene, at every reset);
* ``Navigation-v0``: the earlier default (decimated Kinect only, nominal chair);
* ``light, 2 Async workers`` and ``Kinect, 2 Async workers``: the same ids in a
  :class:`gymnasium.vector.AsyncVectorEnv` of two worker processes; steps/s counts the agent steps of
  both workers, and the last column gives the speed-up over one env of the same id.
* ``light, 2 spinning Async workers`` and ``Kinect, ...``: the same, with workers that poll their pipe
  for up to 2 ms before they block (:mod:`robchair.envs.vector`), so their vCPU does not idle between
  steps (no target of their own: the targets are Gymnasium's default worker's).
* ``light, 2 independent processes`` and ``Kinect, ...``: two forked processes, each stepping its own
  env, started together: the machine's ceiling for two workers (no vector env between them);
* ``light, 1 ms idle per step``: the light env with a 1 ms sleep before each step (the sleep is in the
  wall time, not the CPU time). An Async worker sleeps in its pipe between steps; on a VM an env step
  after a sleep can cost more CPU than one back to back (caches, a vCPU given away), and this row's
  CPU over the light row's says how much of an Async worker's extra CPU that is.

Each row gives the median agent steps per second over ``--repeats`` runs of ``--steps`` steps, run in
rounds (each round runs every configuration once: a drifting machine slows all rows alike; setup, one
warm-up episode and the drawing of the seeded random actions excluded; episodes that end are reset inside
the timed loop, as a training loop would), its real-time factor (steps/s divided by the agent rate) and
its ratio to the physics-only baseline. Every step of an environment is one cycle of the chair's runtime
(sensors, perception, safety layer, motors). Wall-clock numbers depend on the machine's load (the JSON
records the load average), so the single-process rows also give the median CPU time per agent step (the
process's user + system time, every thread counted) and ``1-core steps/s`` = 1000 / CPU ms: the rate on
one dedicated core, which a loaded machine's wall clock cannot show.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
import warnings
from collections.abc import Iterator
from typing import Any

from robchair.commands.bench_output import add_out_arguments, results_dir, write_results

CONFIGS: tuple[dict[str, Any], ...] = (
    {"name": "physics only", "physics_only": True},
    {"name": "light (Navigation-v1)", "id": "RobChair/Navigation-v1", "kwargs": {}},
    {"name": "Kinect (NavigationKinect-v1)", "id": "RobChair/NavigationKinect-v1", "kwargs": {}},
    {"name": "dynamic (NavigationDynamic-v1)", "id": "RobChair/NavigationDynamic-v1", "kwargs": {}},
    {"name": "Navigation-v0", "id": "RobChair/Navigation-v0", "kwargs": {}},
    {"name": "light, 2 Async workers", "id": "RobChair/Navigation-v1", "kwargs": {}, "workers": 2},
    {"name": "Kinect, 2 Async workers", "id": "RobChair/NavigationKinect-v1", "kwargs": {}, "workers": 2},
    # the same with workers that spin on their pipe before blocking (robchair.envs.vector)
    {
        "name": "light, 2 spinning Async workers",
        "id": "RobChair/Navigation-v1",
        "kwargs": {},
        "workers": 2,
        "spin": True,
    },
    {
        "name": "Kinect, 2 spinning Async workers",
        "id": "RobChair/NavigationKinect-v1",
        "kwargs": {},
        "workers": 2,
        "spin": True,
    },
    # the machine's ceiling for two workers: two processes each stepping its own env, nothing between them
    {"name": "light, 2 independent processes", "id": "RobChair/Navigation-v1", "kwargs": {}, "processes": 2},
    {
        "name": "Kinect, 2 independent processes",
        "id": "RobChair/NavigationKinect-v1",
        "kwargs": {},
        "processes": 2,
    },
    # an Async worker sleeps in its pipe between steps: the same env with a short sleep before each step
    {"name": "light, 1 ms idle per step", "id": "RobChair/Navigation-v1", "kwargs": {}, "idle_s": 1e-3},
)


#: Steps/s of a configuration over the physics-only baseline, same run (median).
TARGET_RATIO_PHYSICS = {"light (Navigation-v1)": 0.70, "Kinect (NavigationKinect-v1)": 0.35}
#: Steps/s of two Async workers over one env of the same id, same run (median).
TARGET_SPEEDUP = {"light, 2 Async workers": 1.7, "Kinect, 2 Async workers": 1.7}


def print_targets(rows: list[dict[str, Any]]) -> None:
    """One line per target: the measured ratio, the target and "met" or "missed"."""
    from robchair.commands.bench_output import verdict

    by = {r["config"]: r for r in rows}
    for targets, key, what in ((TARGET_RATIO_PHYSICS, "ratio_to_physics_only", "of physics only"),
                               (TARGET_SPEEDUP, "speedup_vs_one_env", "one env")):  # fmt: skip
        for name, goal in targets.items():
            got = by.get(name, {}).get(key)
            if got is None:
                print(f"{name}: not measured (target >= {goal}x {what}: missed)")
            else:
                print(f"{name}: {got:.2f}x {what} (target >= {goal}x: {verdict(got >= goal)})")


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser("env", help="agent steps per second of the Gymnasium navigation environments")
    p.add_argument("--steps", type=int, default=200, help="agent steps per run (default 200)")
    p.add_argument("--repeats", type=int, default=3, help="runs per configuration (median; default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the episodes and actions (default 0)")
    add_out_arguments(p, "env")
    p.set_defaults(func=_run)


def _physics_only(steps: int, seed: int) -> tuple[float, float]:
    """Wall and CPU seconds for ``steps`` agent periods of physics + motors with random twists, no sensors."""
    import numpy as np

    from robchair.envs.navigation import AGENT_HZ
    from sim.backend import SimChair
    from sim.world import PHYSICS_HZ

    chair = SimChair(scene=_office(), sensor=None, sonars=False, seed=seed)
    try:
        drive = chair.robot.drive
        # the random twists are drawn before the timed loop, as the environments' actions are
        twists = np.random.default_rng(seed).uniform(-1, 1, (steps, 2)).tolist()
        t0, c0 = time.perf_counter(), time.process_time()
        for v, w in twists:
            chair.robot.set_motor_rpm(
                *drive.motor_rpm(*drive.limit(v * drive.max_speed, w * drive.max_yaw_rate))
            )
            chair.step(PHYSICS_HZ // AGENT_HZ)
        return time.perf_counter() - t0, time.process_time() - c0
    finally:
        chair.close()


def _office() -> Any:
    from robchair.platform.paths import SCENES
    from sim.scene import load_scene

    return load_scene(SCENES / "office.toml")


def _env_run(env: Any, steps: int, seed: int, idle_s: float = 0.0) -> tuple[float, float, int]:
    """Wall and CPU seconds for ``steps`` agent steps of ``env`` with seeded random actions, and the
    number of steps in which the safety layer stopped the chair (``info["safety"]``). ``idle_s`` > 0:
    sleep that many seconds before each step (in the wall time, not in the CPU time)."""
    env.reset(seed=seed)
    actions = _actions(env.action_space, steps, seed)
    stops = 0
    t0, c0 = time.perf_counter(), time.process_time()
    for action in actions:
        if idle_s > 0.0:
            time.sleep(idle_s)
        _, _, terminated, truncated, info = env.step(action)
        reason = (info.get("safety") or {}).get("reason")
        stops += bool(reason) and not str(reason).startswith("limited")
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - t0, time.process_time() - c0, stops


def _own_env(env_id: str, kwargs: dict[str, Any], steps: int, seed: int, start: Any, out: Any) -> None:
    """One independent process of :func:`_independent_runs`: make the env, warm it up, wait at
    ``start`` (a barrier shared with the other processes), run, put ``(wall s, CPU s)`` on ``out``."""
    import gymnasium

    import sim.envs  # noqa: F401  (registers the ids)

    with _v1_ids():
        env = gymnasium.make(env_id, **kwargs)
    try:
        _env_run(env, 5, seed)
        start.wait()
        wall, cpu, _ = _env_run(env, steps, seed)
        out.put((wall, cpu))
    finally:
        env.close()


def _independent_runs(config: dict[str, Any], steps: int, seed: int) -> list[tuple[float, float]]:
    """``(wall s, CPU s)`` of each of ``config["processes"]`` processes that step their own env at the
    same time (forked, as Gymnasium's Async workers are; started together at a barrier)."""
    import multiprocessing as mp

    n = int(config["processes"])
    ctx = mp.get_context("fork")
    start, out = ctx.Barrier(n), ctx.Queue()
    procs = [ctx.Process(target=_own_env, args=(config["id"], config["kwargs"], steps, seed + k, start, out))
             for k in range(n)]  # fmt: skip
    for p in procs:
        p.start()
    try:
        res = [out.get(timeout=600) for _ in procs]
    finally:
        for p in procs:
            p.join(timeout=60)
            if p.is_alive():
                p.kill()
    return res


def _vec_run(envs: Any, steps: int, seed: int) -> tuple[float, float, list[float] | None, list[int] | None]:
    """``steps`` vector steps (every worker one agent step each; finished ones autoreset): wall seconds,
    the parent's CPU seconds, each worker's CPU seconds and its thread count at the end (None where
    ``/proc`` cannot tell)."""
    envs.reset(seed=seed)
    actions = _actions(envs.action_space, steps, seed)
    pids = [proc.pid for proc in getattr(envs, "processes", ())]
    w0 = _cpu_of(pids)
    t0, c0 = time.perf_counter(), time.process_time()
    for action in actions:
        envs.step(action)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    w1 = _cpu_of(pids)
    workers = [b - a for a, b in zip(w0, w1, strict=True)] if w0 is not None and w1 is not None else None
    return wall, cpu, workers, _threads_of(pids)


def _threads_of(pids: list[int]) -> list[int] | None:
    """Threads of each process (Linux ``/proc/<pid>/task``); None without ``/proc`` or a pid. An env
    worker that runs more than one thread (numba, OpenBLAS, Embree/TBB or capture pools) competes
    with the other workers for the cores."""
    if not pids:
        return None
    try:
        return [len(os.listdir(f"/proc/{pid}/task")) for pid in pids]
    except OSError:
        return None


def _cpu_of(pids: list[int]) -> list[float] | None:
    """User + system CPU seconds of each process (Linux ``/proc/<pid>/stat``, clock-tick resolution);
    None without ``/proc`` or a pid."""
    if not pids:
        return None
    try:
        tick = os.sysconf("SC_CLK_TCK")
        out = []
        for pid in pids:
            with open(f"/proc/{pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            out.append((int(fields[11]) + int(fields[12])) / tick)  # utime, stime (fields 14, 15)
        return out
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def _actions(space: Any, steps: int, seed: int) -> list[Any]:
    """``steps`` seeded samples of ``space``, drawn before a timed loop: Gymnasium's ``Box.sample``
    costs about 0.1 ms a call (3 % of a light env step), which is the sampler's time, not the
    environment's; the physics-only baseline draws its twists before its loop too."""
    space.seed(seed)
    return [space.sample() for _ in range(steps)]


@contextlib.contextmanager
def _v1_ids() -> Iterator[None]:
    """Make the ids the targets name without Gymnasium's "is out of date, upgrade to v2" warning
    (forked workers inherit the filter)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*is out of date", category=DeprecationWarning)
        yield


def measure(config: dict[str, Any], steps: int, repeats: int, seed: int) -> dict[str, Any]:
    """Steps per second of one configuration: every run and the median."""
    import statistics

    workers = int(config.get("workers", 1))
    cpu: list[float] | None = None
    vec_cpu: dict[str, Any] | None = None
    safety_stops: int | None = None
    if config.get("processes"):
        ind = [_independent_runs(config, steps, seed + k) for k in range(repeats)]
        # steps/s of all processes together: every process's steps over the slowest one's wall time
        secs = [max(w for w, _ in run) / len(run) for run in ind]
        per = [1e3 * c / steps for run in ind for _, c in run]
        out0: dict[str, Any] = {
            "process_cpu_ms_per_step": per,
            "median_process_cpu_ms_per_step": statistics.median(per),
        }
        rates = [steps / s for s in secs]
        return {"steps_per_s": rates, "median_steps_per_s": statistics.median(rates), **out0}
    if config.get("physics_only"):
        _physics_only(5, seed)  # warm-up
        runs = [_physics_only(steps, seed + k) for k in range(repeats)]
        secs, cpu = [r[0] for r in runs], [r[1] for r in runs]
    elif workers > 1:
        import gymnasium

        import sim.envs

        with _v1_ids():
            if config.get("spin"):
                from robchair.envs.vector import make_spinning_async

                envs = make_spinning_async(config["id"], workers, **config["kwargs"])
            else:
                envs = gymnasium.make_vec(
                    config["id"], num_envs=workers, vectorization_mode="async", **config["kwargs"]
                )
        try:
            _vec_run(envs, 5, seed)  # warm-up in every worker
            vec_runs = [_vec_run(envs, steps, seed + k) for k in range(repeats)]
        finally:
            envs.close()
        secs = [r[0] / workers for r in vec_runs]  # seconds per agent step of all workers together
        # where a vector step's time goes: the parent's serial work (actions out, results in, infos
        # merged) and each worker's CPU per agent step (its env step plus pickling and the pipe)
        vec_cpu = {
            "wall_ms_per_vector_step": [1e3 * r[0] / steps for r in vec_runs],
            "parent_cpu_ms_per_vector_step": [1e3 * r[1] / steps for r in vec_runs],
            "worker_cpu_ms_per_step": [None if r[2] is None else [1e3 * c / steps for c in r[2]]
                                       for r in vec_runs],
            "worker_threads": vec_runs[-1][3],
        }  # fmt: skip
    else:
        import gymnasium

        import sim.envs  # noqa: F401  (registers the ids)

        with _v1_ids():
            env = gymnasium.make(config["id"], **config["kwargs"])
        try:
            _env_run(env, 5, seed)  # warm-up: numba kernels, Embree scene
            idle = float(config.get("idle_s", 0.0))
            env_runs = [_env_run(env, steps, seed + k, idle) for k in range(repeats)]
        finally:
            env.close()
        secs, cpu = [r[0] for r in env_runs], [r[1] for r in env_runs]
        safety_stops = sum(r[2] for r in env_runs)
    rates = [steps / s for s in secs]
    out: dict[str, Any] = {"steps_per_s": rates, "median_steps_per_s": statistics.median(rates)}
    if cpu is not None:
        ms = [1e3 * c / steps for c in cpu]
        out["cpu_ms_per_step"] = ms
        out["median_cpu_ms_per_step"] = statistics.median(ms)
    if safety_stops is not None:
        out["safety_stop_steps"] = safety_stops
    if vec_cpu is not None:
        out.update(vec_cpu)
        out["median_parent_cpu_ms_per_vector_step"] = statistics.median(
            vec_cpu["parent_cpu_ms_per_vector_step"]
        )
        per_worker = [c for run in vec_cpu["worker_cpu_ms_per_step"] if run is not None for c in run]
        out["median_worker_cpu_ms_per_step"] = statistics.median(per_worker) if per_worker else None
    return out


def _one_env(config: dict[str, Any]) -> bool:
    """True for a configuration that steps one env back to back (the baseline of the "vs one env"
    column and of the CPU ratios); not for workers, processes or idle-before-each-step rows."""
    return "id" in config and not any(k in config for k in ("workers", "processes", "idle_s"))


def _standin_row(rows: list[dict[str, Any]], args: argparse.Namespace) -> dict[str, Any] | None:
    """Gymnasium's Async ceiling here (:mod:`robchair.commands.bench_env_standin`): a stand-in doing the
    light env's CPU per step of work, one in-process against two Async workers; printed, and returned
    for the JSON (None when the light row has no CPU figure)."""
    from robchair.commands.bench_env_standin import measure_standin

    (light,) = [r for r in rows if r["config"] == "light (Navigation-v1)"]
    cpu_ms = light.get("median_cpu_ms_per_step")
    if not cpu_ms:
        return None
    with _v1_ids():
        res = measure_standin("RobChair/Navigation-v1", float(cpu_ms), args.steps, args.repeats, args.seed)
    print(f"stand-in env (no RobChair: {cpu_ms:.2f} ms of work per step, the light env's spaces): "
          f"2 Async workers {res['speedup']:.2f}x one in-process, {res['speedup_with_info']:.2f}x with the "
          "light env's info; Gymnasium's Async vector env allows that much here")  # fmt: skip
    return res


def measure_rounds(
    configs: tuple[dict[str, Any], ...], steps: int, repeats: int, seed: int
) -> list[dict[str, Any]]:
    """:func:`measure` of every configuration, in ``repeats`` rounds: round ``k`` runs each configuration
    once (seed ``seed + k``, its own set-up and warm-up), so that a machine whose speed drifts over
    a minute (a shared VM does) slows every row alike instead of the rows measured in its slow spell;
    the runs of the rounds are then one row's runs, with the medians over them."""
    import statistics

    rounds = [[measure(cfg, steps, 1, seed + k) for cfg in configs] for k in range(repeats)]
    merged = []
    for i in range(len(configs)):
        runs = [r[i] for r in rounds]
        row: dict[str, Any] = {}
        for key, first in runs[0].items():
            if key.startswith("median_"):
                continue
            if isinstance(first, list) and key != "worker_threads":
                row[key] = [x for run in runs for x in run[key]]
            elif key == "safety_stop_steps":
                row[key] = sum(run[key] for run in runs)
            else:
                row[key] = runs[-1][key]
        for key in runs[0]:
            if not key.startswith("median_"):
                continue
            base = key.removeprefix("median_")
            if base == "worker_cpu_ms_per_step":
                each = [c for run in row[base] if run is not None for c in run]
                row[key] = statistics.median(each) if each else None
            elif base in row:
                row[key] = statistics.median(row[base])
            else:  # a median of per-run figures the row does not keep: the median of the rounds'
                vals = [run[key] for run in runs if run[key] is not None]
                row[key] = statistics.median(vals) if vals else None
        merged.append(row)
    return merged


def _run(args: argparse.Namespace) -> int:
    import statistics

    from robchair.envs.navigation import AGENT_HZ
    from robchair.platform.errors import RobChairError

    if args.steps < 1 or args.repeats < 1:
        raise RobChairError(f"--steps and --repeats must be >= 1, got {args.steps}, {args.repeats}")
    out = results_dir(args, "env")  # refused before anything is measured
    load0 = os.getloadavg()
    rows = [{"config": cfg["name"], **res} for cfg, res in zip(CONFIGS, measure_rounds(CONFIGS, args.steps,
            args.repeats, args.seed), strict=True)]  # fmt: skip
    load1 = os.getloadavg()
    base = rows[0]["median_steps_per_s"]
    print(f"robchair bench env: {args.steps} agent steps at {AGENT_HZ} Hz per run, median of {args.repeats}")
    head = (
        f"{'configuration':32s} {'steps/s':>9s} {'RTF':>6s} {'vs physics only':>16s} {'vs one env':>12s}"
        f" {'CPU ms/step':>12s} {'1-core steps/s':>15s}"
    )
    print(head)
    print("-" * len(head))
    single = {c["id"]: r["median_steps_per_s"] for c, r in zip(CONFIGS, rows, strict=True) if _one_env(c)}
    for c, r in zip(CONFIGS, rows, strict=True):
        m = r["median_steps_per_s"]
        r["real_time_factor"] = m / AGENT_HZ
        r["ratio_to_physics_only"] = m / base
        line = f"{r['config']:32s} {m:9.1f} {m / AGENT_HZ:6.2f} {m / base:16.3f}"
        if ("workers" in c or "processes" in c) and c["id"] in single:
            r["speedup_vs_one_env"] = m / single[c["id"]]
            line += f" {r['speedup_vs_one_env']:12.2f}"
        else:
            line += f" {'':12s}"
        if "median_cpu_ms_per_step" in r:
            cms = r["median_cpu_ms_per_step"]
            r["one_core_steps_per_s"] = 1e3 / cms if cms > 0 else None
            line += f" {cms:12.2f} {1e3 / cms if cms > 0 else float('nan'):15.1f}"
        print(line)
    one_cpu = {
        c["id"]: r.get("median_cpu_ms_per_step") for c, r in zip(CONFIGS, rows, strict=True) if _one_env(c)
    }
    for c, r in zip(CONFIGS, rows, strict=True):
        if "median_process_cpu_ms_per_step" in r and one_cpu.get(c["id"]):
            f = r["median_process_cpu_ms_per_step"] / one_cpu[c["id"]]
            r["process_cpu_vs_one_env"] = f
            print(f"{r['config']}: each process {r['median_process_cpu_ms_per_step']:.2f} ms CPU per step, "
                  f"{f:.2f}x one env's alone (the same work slowed by the other process: here 2 workers "
                  f"can give at most {2 / f:.2f}x one env, however cheap the vector env)")  # fmt: skip
        if c.get("idle_s") and r.get("median_cpu_ms_per_step") and one_cpu.get(c["id"]):
            f = r["median_cpu_ms_per_step"] / one_cpu[c["id"]]
            r["idle_cpu_vs_one_env"] = f
            print(f"{r['config']}: {r['median_cpu_ms_per_step']:.2f} ms CPU per step, {f:.2f}x back to back "
                  "(an Async worker sleeps in its pipe between steps and pays this too)")  # fmt: skip
        if "median_parent_cpu_ms_per_vector_step" in r:
            wk = r.get("median_worker_cpu_ms_per_step")
            wall = statistics.median(r["wall_ms_per_vector_step"])
            each = f"{wk:.2f} ms CPU per agent step" if wk is not None else "(CPU not measured)"
            base_cpu = one_cpu.get(c["id"])
            if wk is not None and base_cpu:
                # > 1: a worker burns more CPU per step than the env alone (spinning or competing threads)
                r["worker_cpu_vs_one_env"] = wk / base_cpu
                each += f" ({wk / base_cpu:.2f}x one env's)"
            if r.get("worker_threads"):
                each += f", threads per worker {r['worker_threads']}"
            print(f"{r['config']}: per vector step {wall:.2f} ms wall, parent "
                  f"{r['median_parent_cpu_ms_per_vector_step']:.2f} ms CPU, each worker {each}")  # fmt: skip
    standin = _standin_row(rows, args)
    print_targets(rows)
    stops = {r["config"]: r["safety_stop_steps"] for r in rows if r.get("safety_stop_steps")}
    if stops:
        print("safety stops (steps the safety layer stopped the chair; logged at INFO, in info['safety']): "
              + ", ".join(f"{k} {v}" for k, v in stops.items()))  # fmt: skip
    result = {
        "agent_hz": AGENT_HZ,
        "targets": {"ratio_to_physics_only": TARGET_RATIO_PHYSICS, "speedup_vs_one_env": TARGET_SPEEDUP},
        "steps": args.steps,
        "repeats": args.repeats,
        "seed": args.seed,
        "rows": rows,
        "standin": standin,
    }
    write_results(out, "env", result, load0, load1)
    return 0
