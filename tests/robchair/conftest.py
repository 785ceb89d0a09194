"""Fixtures shared by the application's test files: expensive runs made once per test session and only
read by the tests that use them (a test that writes into a run folder makes its own)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest


@pytest.fixture(scope="session")
def sim_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The run folder of ``robchair sim --duration 0.3`` on the default scenario, with every default output
    (MCAP bag, pictures, report, recording, time series); read-only for the tests that take it."""
    pytest.importorskip("pybullet")
    from robchair.cli import main

    out = tmp_path_factory.mktemp("sim") / "run"
    assert main(["sim", "--duration", "0.3", "--out", str(out), "--no-progress"]) == 0
    return out


def _map_round_trip_run(tmp_path_factory: pytest.TempPathFactory, duration: str) -> Path:
    """A default `robchair sim` run of ``duration`` seconds whose bag `robchair map` maps back (the round
    trip of issue 21). Pictures, matching and the zoom region are off: the round-trip tests read only the
    bag and the odometry map, which none of them changes."""
    pytest.importorskip("pybullet")
    from robchair.cli import main

    out = tmp_path_factory.mktemp(f"sim_{duration}s") / "run"
    argv = ["sim", "--duration", duration, "--out", str(out), "--no-progress", "--no-pictures",
            "--no-matching", "--no-zoom"]  # fmt: skip
    assert main(argv) == 0
    return out


@pytest.fixture(scope="session")
def sim_run_8s(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An 8 s default `robchair sim` run (the chair drives about 2 m and turns): long enough that the
    former one-point-per-voxel bag clouds mapped back below IoU 0.95 (0.925); read-only."""
    return _map_round_trip_run(tmp_path_factory, "8")


@pytest.fixture(scope="session")
def sim_run_20s(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 20 s default `robchair sim` run (issue 21's round trip; 0.909 with the former bag); read-only."""
    return _map_round_trip_run(tmp_path_factory, "20")


@pytest.fixture(scope="session")
def emulated_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`robchair run --backend emulated` on the example's short route to its end (about 9.4 simulated s
    of --duration 20), every sonar hearing 0.8 m (the thesis trusts readings under 1 m), the safety layer
    off so the chair drives the 1.5 m + turn route; read-only."""
    from robchair.cli import main

    root = tmp_path_factory.mktemp("emulated")
    (root / "chair.toml").write_text("[emulated]\nsonar_range_m = 0.8\n")
    route = Path(__file__).resolve().parents[2] / "examples" / "routes" / "short_turn.toml"
    argv = ["run", "--backend", "emulated", "--config", str(root / "chair.toml"), "--route", str(route),
            "--duration", "20", "--no-safety", "--out", str(root / "run")]  # fmt: skip
    assert main(argv) == 0
    return root / "run"


@pytest.fixture(scope="session")
def ray_2cpu() -> Iterator[Any]:
    """A local Ray instance of 2 CPUs (the ``ray`` module), started once for every test that runs work on
    Ray (a `--ray` command joins it: an initialised Ray is reused and left running), shut down at the end
    of the session; started as the commands start theirs (:func:`robchair.sweep.executor.ray_session`),
    so its workers run with :data:`robchair.sweep.harness.THREAD_ENV`."""
    pytest.importorskip("ray")
    from robchair.sweep.executor import ray_session

    with ray_session(num_cpus=2) as ray:
        yield ray
