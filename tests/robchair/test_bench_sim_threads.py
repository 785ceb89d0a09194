"""The loop's ray caster casts on one Embree thread by default and in every ``bench sim`` configuration.

On the 2-vCPU AMD machine a parallel cast left TBB's workers spinning between frames, taking the CPU
from the capture and mapping threads: office_corridor, 2 simulated s, 2 CPUs, mapping threaded, took
56.6 s CPU with 2 cast threads against 5.8 s with 1 (load 25, session 8). Two frames are already in
flight on the capture threads, so one cast thread per frame keeps both cores busy without spinning.
The CPU figure lives in the benchmark (``robchair bench sim``); this pins the configuration.
"""

import inspect

from robchair.commands.bench_sim import CONFIGS
from robchair.scenario import run_scenario


def test_bench_sim_configs_cast_on_one_thread() -> None:
    assert CONFIGS, "bench sim has no configurations"
    for config in CONFIGS:
        assert config["raycast_threads"] == 1, config["name"]


def test_run_scenario_casts_on_one_thread_by_default() -> None:
    assert inspect.signature(run_scenario).parameters["raycast_threads"].default == 1
