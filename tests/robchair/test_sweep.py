"""Sweeps: file expansion, output-folder rules, and a real sweep on a local 2-CPU Ray instance."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from robchair.sweep import SweepError, load_sweep, parse_sweep, run_sweep
from robchair.sweep.executor import prepare_out
from robchair.sweep.harness import allowed_parameters
from robchair.sweep.results import flatten

ALLOWED = allowed_parameters()


def test_grid_expands_to_the_cartesian_product_plus_explicit_runs() -> None:
    spec = parse_sweep(
        {
            "sweep": {"duration": 1.0},
            "grid": {"seed": [0, 1, 2], "sensor": ["kinect1", "kinect2"]},
            "runs": [{"scenario": "office_tour", "seed": 9}],
        },
        ALLOWED,
    )
    assert len(spec.points) == 3 * 2 + 1
    assert all(p.params["duration"] == 1.0 for p in spec.points)
    assert spec.points[-1].params == {"duration": 1.0, "scenario": "office_tour", "seed": 9}
    assert set(spec.swept) == {"seed", "sensor", "scenario"}


def test_run_ids_do_not_depend_on_the_order_of_the_grid() -> None:
    a = parse_sweep({"grid": {"seed": [0, 1], "sensor": ["kinect1", "kinect2"]}}, ALLOWED)
    b = parse_sweep({"grid": {"sensor": ["kinect2", "kinect1"], "seed": [1, 0]}}, ALLOWED)
    assert {p.run_id for p in a.points} == {p.run_id for p in b.points}


def test_unknown_parameter_is_refused_naming_file_key_and_allowed_keys(tmp_path: Path) -> None:
    f = tmp_path / "s.toml"
    f.write_text("[grid]\ncell = [0.05, 0.1]\n")
    with pytest.raises(
        SweepError, match=r"s\.toml \[grid\]: unknown parameter 'cell'; allowed: scenario, seed"
    ):
        load_sweep(f, ALLOWED)


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        ({"grid": {"seed": 3}}, r"expected a non-empty list"),
        ({"grid": {"seed": []}}, r"expected a non-empty list"),
        ({}, r"has no runs"),
        ({"runs": [{"seed": 1}, {"seed": 1}]}, r"same parameters"),
        ({"sweeps": {}}, r"unknown table \[sweeps\]"),
        ({"runs": [{"seed": [1]}]}, r"expected a number, a string or a bool"),
    ],
)
def test_invalid_sweeps_are_refused_with_one_line(doc: dict, match: str) -> None:
    with pytest.raises(SweepError, match=match):
        parse_sweep(doc, ALLOWED)


def test_a_missing_or_broken_sweep_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(SweepError, match="no such sweep file"):
        load_sweep(tmp_path / "none.toml", ALLOWED)
    bad = tmp_path / "bad.toml"
    bad.write_text("[grid\n")
    with pytest.raises(SweepError, match="not a valid TOML"):
        load_sweep(bad, ALLOWED)


def test_flatten_gives_dotted_scalars_and_list_counts() -> None:
    got = flatten({"map": {"iou": 0.5, "f": {"p": 1}}, "safety": {"stops": [1, 2, 3]}, "x": None}, "m.")
    assert got == {"m.map.iou": 0.5, "m.map.f.p": 1, "m.safety.stops.count": 3, "m.x": None}


def test_a_foreign_non_empty_folder_is_refused_and_kept(tmp_path: Path) -> None:
    spec = parse_sweep({"runs": [{"seed": 1}]}, ALLOWED)
    (tmp_path / "keep.txt").write_text("keep")
    with pytest.raises(SweepError, match="non-empty folder this project did not create"):
        prepare_out(tmp_path, spec, resume=False)
    assert (tmp_path / "keep.txt").read_text() == "keep"
    with pytest.raises(SweepError, match="holds no sweep to resume"):
        prepare_out(tmp_path / "new", spec, resume=True)


def test_an_earlier_sweep_needs_resume(tmp_path: Path) -> None:
    spec = parse_sweep({"runs": [{"seed": 1}]}, ALLOWED)
    prepare_out(tmp_path / "s", spec, resume=False)
    with pytest.raises(SweepError, match="add --resume"):
        prepare_out(tmp_path / "s", spec, resume=False)
    prepare_out(tmp_path / "s", spec, resume=True)


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_sweep_of_four_tiny_runs_records_the_failure_and_resumes(ray_2cpu, tmp_path: Path) -> None:
    sweep_file = tmp_path / "tiny.toml"
    sweep_file.write_text(
        '[sweep]\nname = "tiny"\nduration = 0.1\npictures = false\nbag = false\n'
        "[grid]\nseed = [0, 1]\n"
        '[[runs]]\nseed = 2\nsensor = "kinect1"\n'
        '[[runs]]\nscenario = "no_such_scenario"\n'
    )
    spec = load_sweep(sweep_file, ALLOWED)
    out = tmp_path / "out"
    res = run_sweep(spec, out, progress=False)

    rows = _rows(out / "results.csv")
    assert [r["run_id"] for r in rows] == [p.run_id for p in spec.points]
    assert [r["status"] for r in rows] == ["ok", "ok", "ok", "failed"]
    assert [r["seed"] for r in rows[:3]] == ["0", "1", "2"]
    # every successful row carries the run's own metrics.json figures
    for r, p in zip(rows[:3], spec.points[:3], strict=True):
        metrics = json.loads((out / "runs" / p.run_id / "metrics.json").read_text())
        assert float(r["metrics.sim_time_s"]) == pytest.approx(metrics["sim_time_s"])
        assert r["metrics.sensor"] == metrics["sensor"]
    assert rows[2]["metrics.sensor"] == "kinect1"
    failed = json.loads((out / "records" / f"{spec.points[3].run_id}.json").read_text())
    assert failed["status"] == "failed"
    assert "no_such_scenario" in failed["error"] and "\n" not in failed["error"]
    assert failed["traceback"]
    summary = json.loads((out / "results.json").read_text())
    assert (summary["runs"], summary["ok"], summary["failed"]) == (4, 3, 1)
    assert len(res.failed) == 1

    stamps = {
        p.run_id: (out / "runs" / p.run_id / "metrics.json").stat().st_mtime_ns for p in spec.points[:3]
    }
    again = run_sweep(spec, out, resume=True, progress=False)
    assert sorted(again.skipped) == sorted(stamps)
    assert [r["status"] for r in again.records] == ["ok", "ok", "ok", "failed"]
    for rid, ns in stamps.items():  # complete runs were not run again
        assert (out / "runs" / rid / "metrics.json").stat().st_mtime_ns == ns


def test_safety_limits_in_a_sweep_reach_the_harness_as_safety_limits(monkeypatch, tmp_path: Path) -> None:
    import robchair.scenario
    from robchair.sweep.harness import run_harness

    seen: dict = {}

    class _Result:
        def metrics(self) -> dict:
            return {"ok": True}

    def fake_run_scenario(scenario, **kwargs):
        seen.update(kwargs, scenario=scenario)
        return _Result()

    monkeypatch.setattr(robchair.scenario, "run_scenario", fake_run_scenario)
    spec = parse_sweep({"runs": [{"seed": 3, "safety.margin_m": 0.3, "safety": True, "bag": False}]}, ALLOWED)
    assert run_harness(spec.points[0].params, tmp_path / "r") == {"ok": True}
    assert seen["scenario"] == "office_corridor" and seen["seed"] == 3 and seen["write_bag"] is False
    assert seen["safety"] is True
    assert seen["safety_limits"].margin_m == pytest.approx(0.3)
    from robchair.platform.safety import SafetyLimits
    from robchair.platform.spec import load_spec

    assert seen["safety_limits"].max_speed == SafetyLimits.from_spec(load_spec()).max_speed  # the rest: spec
    with pytest.raises(SweepError, match=r"unknown parameter 'safety\.margin'"):
        parse_sweep({"runs": [{"safety.margin": 0.3}]}, ALLOWED)


def test_the_example_sweep_files_parse() -> None:
    examples = sorted((Path(__file__).parents[2] / "examples" / "sweeps").glob("*.toml"))
    assert examples
    for f in examples:
        assert load_sweep(f, ALLOWED).points


def test_a_local_ray_sessions_workers_have_the_thread_env_without_a_runtime_env(ray_2cpu) -> None:
    """ray_session starts a local instance with THREAD_ENV in its processes' environment, not as a
    runtime_env (which made Ray start a runtime-env agent and fresh workers: ~3 s a session); the driver's
    own environment is as it was once Ray has started (ray_2cpu is started by ray_session)."""
    from robchair.sweep.harness import THREAD_ENV

    def _worker_env() -> tuple[dict[str, str | None], str]:  # a local function: pickled by value
        import os

        import ray

        return {k: os.environ.get(k) for k in THREAD_ENV}, ray.get_runtime_context().get_runtime_env_string()

    env, runtime_env = ray_2cpu.get(ray_2cpu.remote(num_cpus=1)(_worker_env).remote())
    assert env == THREAD_ENV
    assert json.loads(runtime_env) == {}


def test_the_environment_ray_starts_in_is_the_drivers_again_afterwards(monkeypatch) -> None:
    import os

    from robchair.sweep.executor import _environment

    monkeypatch.setenv("ROBCHAIR_T_KEPT", "before")
    monkeypatch.delenv("ROBCHAIR_T_NEW", raising=False)
    with _environment({"ROBCHAIR_T_KEPT": "during", "ROBCHAIR_T_NEW": "during"}):
        assert os.environ["ROBCHAIR_T_KEPT"] == os.environ["ROBCHAIR_T_NEW"] == "during"
    assert os.environ["ROBCHAIR_T_KEPT"] == "before" and "ROBCHAIR_T_NEW" not in os.environ
