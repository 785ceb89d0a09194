"""`robchair bench map` on a run's bag: each figure against 10x real time with met/missed, and the inserts'
share of the build and of the whole command, from the summary.json of real `robchair map` processes."""

from __future__ import annotations

import json
import re

import pytest

from robchair.cli import main


@pytest.mark.timeout(1200)
def test_bench_map_prints_each_figure_against_10x_and_the_inserts_share(sim_run, tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "map", "--bag", str(sim_run / "bag"), "--repeats", "1", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "target >= 10x real time" in text
    for label in ("build (read + place + insert)", "inserts alone", "whole command, with pictures"):
        (row,) = [ln for ln in text.splitlines() if ln.startswith(label)]
        assert re.search(r"\s(met|missed)$", row), row
    result = json.loads((out / "bench_map.json").read_text())
    sim_s, wall = result["sim_time_s"], result["wall_s"]
    assert sim_s == json.loads((sim_run / "metrics.json").read_text())["sim_time_s"]
    x = result["x_real_time"]["read_and_build"]
    assert x == pytest.approx(sim_s / wall["read_and_build"])
    assert result["verdict"]["read_and_build"] == ("met" if x >= 10 else "missed")
    share = result["inserts_share"]
    assert 0 < share["of_build"] <= 1 and share["of_whole_command"] < share["of_build"]
    assert f"{100 * share['of_build']:.0f} % of the build" in text
    cpu = wall["read_and_build_cpu"]
    cores = result["cores_needed_at_target"]
    assert cores * sim_s / 10 >= cpu > (cores - 1) * sim_s / 10
    assert f"needs >= {cores} cores" in text


def test_the_cores_a_build_needs_at_10x_are_its_cpu_over_a_tenth_of_real_time() -> None:
    from robchair.commands.bench_map import cores_needed

    assert cores_needed(4.0, 20.0) == 2 and cores_needed(4.01, 20.0) == 3 and cores_needed(0.5, 20.0) == 1
    assert cores_needed(7.0, 20.0) == 4 and cores_needed(1.0, 0.0) == 0
