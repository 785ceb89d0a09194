"""What every benchmark prints and keeps: medians over repeated runs and the verdict beside a target."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from robchair.commands.bench_output import median_of, verdict
from robchair.commands.bench_sim import TARGET_RATIO_OLD, print_stage_table, ratio_bound


def test_medians_of_repeated_runs_skip_fields_a_run_could_not_measure() -> None:
    """``bench sim --repeats 3`` took the median of the replaced runner's rows, whose matching time is
    None (it had no matching): a TypeError. Hand values: median(1, 3, 2) = 2, median(10, 30) = 20."""
    runs = [
        {"rtf": 1.0, "matching_ms_per_frame": None, "map odometry ms/s": 10.0},
        {"rtf": 3.0, "matching_ms_per_frame": None},
        {"rtf": 2.0, "matching_ms_per_frame": None, "map odometry ms/s": 30.0},
    ]
    assert median_of(runs) == {"rtf": 2.0, "map odometry ms/s": 20.0}


def test_a_target_is_met_or_missed_and_the_loop_target_is_the_documented_one() -> None:
    """The loop must reach 1.5x the replaced runner on two cores in the same run (performance target)."""
    assert (verdict(True), verdict(False)) == ("met", "missed")
    assert TARGET_RATIO_OLD["2 cores"] == 1.5


def test_the_stage_table_gives_each_stage_and_the_rest_in_ms_per_simulated_second(capsys) -> None:
    """2 sim s in a 3 s loop = 1500 ms per sim s; render 400 + sonar 100 + physics 200 + map 300 = 1000,
    so the rest is 500 (hand sum)."""
    row = {"config": {"name": "1 core"}, "median": {
        "kinect_ms_per_sim_s": 400.0, "sonar_ms_per_sim_s": 100.0, "physics_ms_per_sim_s": 200.0,
        "map odometry ms/s": 300.0, "loop_wall_s": 3.0, "sim_time_s": 2.0}}  # fmt: skip
    print_stage_table([row])
    out = capsys.readouterr().out.splitlines()
    assert out[1].split()[-8:] == ["render", "sonar", "cast", "physics", "map", "odometry", "rest", "loop"]
    assert out[2].split()[-6:] == ["400.0", "100.0", "200.0", "300.0", "500.0", "1500.0"]


def test_stages_that_overlap_on_threads_show_no_negative_rest_and_say_their_excess(capsys) -> None:
    """2 sim s in a 0.5 s loop = 250 ms per sim s against stages of 400 + 100 + 200 + 300 = 1000 (hand
    sum): the rest column says '-' and a line gives the excess of 750."""
    row = {"config": {"name": "2 cores"}, "median": {
        "kinect_ms_per_sim_s": 400.0, "sonar_ms_per_sim_s": 100.0, "physics_ms_per_sim_s": 200.0,
        "map odometry ms/s": 300.0, "loop_wall_s": 0.5, "sim_time_s": 2.0}}  # fmt: skip
    print_stage_table([row])
    out = capsys.readouterr().out.splitlines()
    assert out[2].split()[-6:] == ["400.0", "100.0", "200.0", "300.0", "-", "250.0"]
    assert (
        out[3] == "2 cores: the stages overlap on threads; their sum exceeds the loop by 750.0 ms per sim s"
    )


def test_the_ratio_bound_is_the_baseline_s_loop_time_over_the_new_loop_s_simulator_stages() -> None:
    """One core: render 400 + sonar 100 + physics 200 = 700 ms per sim s of simulator; the replaced runner's
    2.8 s loop over 4 sim s = 700 ms per sim s, so the new loop can reach at most 700 / 700 = 1.0x (hand
    computation). Two cores overlap the stages, and without a baseline there is nothing to bound."""
    med = {"kinect_ms_per_sim_s": 400.0, "sonar_ms_per_sim_s": 100.0, "physics_ms_per_sim_s": 200.0,
           "loop_wall_s": 3.0, "sim_time_s": 2.0}  # fmt: skip
    row = {"config": {"name": "1 core", "cpus": 1}, "median": med,
           "baseline_median": {"loop_wall_s": 2.8, "sim_time_s": 4.0}}  # fmt: skip
    b = ratio_bound(row)
    assert b is not None
    assert b["simulator_ms_per_sim_s"] == 700.0 and abs(b["replaced_loop_ms_per_sim_s"] - 700.0) < 1e-9
    assert abs(b["max_ratio"] - 1.0) < 1e-12
    assert ratio_bound({**row, "config": {"name": "2 cores", "cpus": 2}}) is None
    assert ratio_bound({**row, "baseline_median": None}) is None


def test_the_sim_baseline_is_the_main_line_revision_just_before_the_merge_that_removed_the_runner() -> None:
    """``git log --first-parent``: the merge of the one loop (ce4fea0, "Merge branch 'loop'") removed
    sim/runner.py from the main line; its first parent 6fea3e8 is the main line that still had it (read
    off the history by hand). The loop branch's own parent of the removal (ad71dbf) is not it."""
    from robchair.commands.bench_sim_baseline import ROOT, baseline_revision

    git = shutil.which("git")
    if git is None or subprocess.run([git, "-C", str(ROOT), "cat-file", "-e", "ce4fea0^{commit}"]).returncode:
        pytest.skip("no git history with the one loop's merge here")
    rev = baseline_revision()
    assert rev is not None and rev.sha.startswith("6fea3e8770")
    assert rev.describe().startswith("6fea3e8770 (")


def test_the_cores_the_loop_needs_are_its_target_rtf_times_its_cpu_per_simulated_second() -> None:
    """Two cores, replaced runner at RTF 1.6, target 1.5x = RTF 2.4; the loop used 1300 ms of CPU per
    sim s, so 2.4 sim s per wall s need 2.4 * 1.3 = 3.12 -> 4 cores (hand computation). 1000 ms at RTF
    2.0 is exactly 2 cores. Without the loop's CPU or a baseline: None."""
    from robchair.commands.bench_sim import cores_needed

    row = {"config": {"name": "2 cores", "cpus": 2}, "median": {"loop_cpu_ms_per_sim_s": 1300.0},
           "baseline_median": {"rtf": 1.6}}  # fmt: skip
    c = cores_needed(row)
    assert c is not None and c["cores"] == 4 and abs(c["target_rtf"] - 2.4) < 1e-12
    exact = {**row, "median": {"loop_cpu_ms_per_sim_s": 1000.0}, "baseline_median": {"rtf": 2.0 / 1.5}}
    assert cores_needed(exact)["cores"] == 2  # type: ignore[index]
    assert cores_needed({**row, "median": {}}) is None
    assert cores_needed({**row, "baseline_median": None}) is None


def test_the_loop_reports_the_process_cpu_over_the_loop_in_its_metrics() -> None:
    """metrics.json cpu_time_s.loop: the process's CPU seconds between the loop's start and stop, every
    thread (a short run: positive, and within the process's CPU over the whole call)."""
    import time

    from robchair.scenario import run_scenario

    c0 = time.process_time()
    m = run_scenario("office_corridor", duration=0.3, progress=False, write=False).metrics()
    total = time.process_time() - c0
    cpu = m["cpu_time_s"]["loop"]
    assert 0 < cpu < total and m["wall_time_s"]["loop"] > 0
