"""`robchair bench table`: the README's benchmark table from hand-made bench JSON files."""

from __future__ import annotations

import json
from pathlib import Path

from robchair.cli import main
from robchair.commands.bench_table import BEGIN, END

# a bench_sim.json as robchair bench sim --out writes it, with figures chosen by hand
SIM = {
    "scenario": "office_corridor",
    "map_kind": "probabilistic",
    "duration_s": 4.0,
    "repeats": 3,
    "targets_ratio_to_replaced_runner": {"2 cores": 1.5, "1 core": 0.9},
    "rows": [
        {
            "config": {"name": "2 cores"},
            "median": {"rtf": 3.0, "sim_time_s": 4.0, "loop_wall_s": 1.2, "kinect_ms_per_sim_s": 100.0,
                       "sonar_ms_per_sim_s": 20.0, "physics_ms_per_sim_s": 50.0, "map odometry ms/s": 80.0},
            "baseline_median": {"rtf": 1.5},
            "cores_needed": {"cpu_ms_per_sim_s": 1146.0, "target_rtf": 2.25, "cores": 3},
        },
        {
            "config": {"name": "1 core"},
            "median": {"rtf": 1.0, "sim_time_s": 4.0, "loop_wall_s": 4.0, "kinect_ms_per_sim_s": 400.0,
                       "sonar_ms_per_sim_s": 50.0, "physics_ms_per_sim_s": 100.0, "map odometry ms/s": 300.0},
            "baseline_median": {"rtf": 2.0},
            "ratio_bound": {"max_ratio": 1.07},
        },
    ],
    "load_average_before": [0.5, 0.4, 0.3],
    "load_average_after": [1.25, 0.5, 0.4],
    "cpus": 2,
    "cpu_model": "Test CPU 9000",
    "time_utc": "2026-12-02T01:00:00Z",
}  # fmt: skip
LASER = {"scene": "office", "embree_ms": 1.25, "pybullet_ms": 15.0, "agreement_1cm": 0.995,
         "faster": "Embree", "ratio": 12.0, "load_average_before": [2.0], "load_average_after": [3.0],
         "cpus": 2, "time_utc": "2026-12-01T23:00:00Z"}  # fmt: skip
README = f"# Title\n\nintro line\n\n{BEGIN}\n| old | table |\n{END}\n\ntail line\n"


def _setup(tmp_path: Path) -> tuple[Path, Path]:
    d = tmp_path / "b"
    d.mkdir()
    (d / "bench_sim.json").write_text(json.dumps(SIM))
    (d / "bench_laser.json").write_text(json.dumps(LASER))
    readme = tmp_path / "README.md"
    readme.write_text(README)
    return d, readme


def test_the_table_between_the_markers_gives_ratios_stages_machine_and_load_from_the_json(tmp_path, capsys):
    """Expected cells computed by hand from the JSON above: 2 cores 3.0 / 1.5 = 2.00x (>= 1.5: met);
    1 core 1.0 / 2.0 = 0.50x (< 0.9: missed); rest = 1e3 * loop / sim s - stages: 2 cores
    300 - (100 + 20 + 50 + 80) = 50, 1 core 1000 - (400 + 50 + 100 + 300) = 150; machine from
    cpus, cpu_model, load_average_*[0] and the date of time_utc."""
    d, readme = _setup(tmp_path)
    assert main(["bench", "table", str(d), "--readme", str(readme)]) == 0
    text = readme.read_text()
    before, rest = text.split(BEGIN + "\n")
    table, after = rest.split("\n" + END)
    assert before == "# Title\n\nintro line\n\n" and after == "\n\ntail line\n"
    lines = table.split("\n")
    assert lines[0] == "| benchmark | command | result | measured |" and len(lines) == 4
    sim, laser = lines[2], lines[3]  # sim first, then laser (the documented order)
    assert "2 cores: RTF 3.00, 2.00x the replaced runner's 1.50 (target >= 1.5x: met)" in sim
    assert "1 core: RTF 1.00, 0.50x the replaced runner's 2.00 (target >= 0.9x: missed)" in sim
    assert "render 100, sonar 20, physics 50, map odometry 80, rest 50" in sim
    assert "render 400, sonar 50, physics 100, map odometry 300, rest 150" in sim
    assert "map odometry 300, rest 150; the new loop's simulator stages allow at most 1.07x" in sim
    assert "rest 50; 1146 ms of CPU per sim s, so its target needs >= 3 cores" in sim
    assert "`robchair bench sim --repeats 3`" in sim
    assert sim.endswith("| 2 x Test CPU 9000, load 0.5 before / 1.2 after (1-min average), 2026-12-02 |")
    assert "Embree mirror 1.25 ms, PyBullet `rayTestBatch` 15.00 ms (Embree 12.0x faster)" in laser
    assert "99.5 % of the beams" in laser and "load 2.0 before / 3.0 after" in laser
    assert "| old | table |" not in text
    # run again: the same file (the table replaces itself)
    assert main(["bench", "table", str(d), "--readme", str(readme)]) == 0
    assert readme.read_text() == text


def test_a_readme_without_markers_or_a_folder_without_bench_json_is_refused_in_one_line(tmp_path, capsys):
    d, readme = _setup(tmp_path)
    readme.write_text("# no markers\n")
    assert main(["bench", "table", str(d), "--readme", str(readme)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no line" in err[0] and str(readme) in err[0]
    assert readme.read_text() == "# no markers\n"
    empty = tmp_path / "empty"
    empty.mkdir()
    readme.write_text(README)
    assert main(["bench", "table", str(empty), "--readme", str(readme)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no bench_<name>.json" in err[0] and str(empty) in err[0]
    (d / "bench_laser.json").write_text("{not json")
    assert main(["bench", "table", str(d), "--readme", str(readme)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bench_laser.json" in err[0]
    assert readme.read_text() == README


def test_assist_and_map_rows_give_their_figures_and_verdicts_not_their_parameters(tmp_path, capsys):
    d = tmp_path / "b"
    d.mkdir()
    machine = {
        "load_average_before": [0.5],
        "load_average_after": [0.6],
        "cpus": 2,
        "time_utc": "2026-12-02T01:00:00Z",
    }
    assist = {
        "cycles": 200,
        "target_ms": 2.0,
        "met": {"door": True, "assist": False},
        "ms": {"door": {"median": 0.481, "p99": 0.697}, "assist": {"median": 2.5, "p99": 3.25}},
        **machine,
    }
    bag_map = {"sim_time_s": 20.0, "bag_mb": 209.6, "repeats": 3, "target_x_real_time": 10.0,
               "x_real_time": {"read_and_build": 2.67, "inserts": 3.29},
               "verdict": {"read_and_build": "missed", "inserts": "missed"},
               "inserts_share": {"of_build": 0.81}, "cores_needed_at_target": 4, **machine}  # fmt: skip
    (d / "bench_assist.json").write_text(json.dumps(assist))
    (d / "bench_map.json").write_text(json.dumps(bag_map))
    readme = tmp_path / "README.md"
    readme.write_text(README)
    assert main(["bench", "table", str(d), "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert (
        "door 0.481 ms median, p99 0.697 (met)" in text
        and "assist 2.500 ms median, p99 3.250 (missed)" in text
    )
    assert "target <= 2 ms" in text and "cycles 200" not in text
    assert "`robchair map` on a 20 s run's bag (210 MB); target >= 10x real time" in text
    assert "build 2.7x real time (missed)" in text and "inserts alone 3.3x real time (missed)" in text
    assert "the inserts are 81 % of the build" in text and "bag_mb" not in text
    assert "; with its CPU the build needs >= 4 cores for the target" in text


def test_the_env_row_gives_the_stand_in_envs_async_speedups(tmp_path):
    d = tmp_path / "b"
    d.mkdir()
    env = {"agent_hz": 10, "repeats": 3, "rows": [{"config": "physics only", "median_steps_per_s": 400.0}],
           "standin": {"speedup": 1.8, "speedup_with_info": 1.666}, "load_average_before": [0.5],
           "load_average_after": [0.6], "cpus": 2, "time_utc": "2026-12-02T01:00:00Z"}  # fmt: skip
    (d / "bench_env.json").write_text(json.dumps(env))
    readme = tmp_path / "README.md"
    readme.write_text(README)
    assert main(["bench", "table", str(d), "--readme", str(readme)]) == 0
    assert (
        "a stand-in env doing the light env's CPU per step without RobChair: 2 Async workers 1.80x one, "
        "1.67x with the light env's info"
    ) in readme.read_text()


def test_stages_that_overlap_on_threads_give_their_excess_not_a_negative_rest(tmp_path):
    """Mapping on its own thread: 2 sim s in a 0.5 s loop is 250 ms per sim s, while the stages add
    up to 100 + 20 + 50 + 180 = 350 (hand sum): no "rest" cell, and the overlap of 100 is said."""
    d, readme = _setup(tmp_path)
    sim = json.loads(json.dumps(SIM))
    sim["rows"][0]["median"].update(sim_time_s=2.0, loop_wall_s=0.5, **{"map odometry ms/s": 180.0})
    (d / "bench_sim.json").write_text(json.dumps(sim))
    assert main(["bench", "table", str(d), "--readme", str(readme)]) == 0
    row = next(line for line in readme.read_text().splitlines() if "bench sim" in line)
    two_cores = row.split("1 core:")[0]
    assert "rest -" not in row
    assert "map odometry 180 (they overlap on threads: their sum exceeds the loop's 250 by 100)" in two_cores
    assert "map odometry 300, rest 150" in row  # the 1-core row keeps its rest
