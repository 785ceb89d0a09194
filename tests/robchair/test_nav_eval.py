"""Navigation metrics (SPL, BARN score, summaries) and the `robchair nav-eval` command."""

from __future__ import annotations

import json

import pytest

from robchair.navigation.metrics import barn_score, format_table, spl_term, summarize


def test_spl_follows_anderson_et_al_2018():
    assert spl_term(True, 4.0, 5.0) == pytest.approx(0.8)
    assert spl_term(True, 4.0, 3.9) == 1.0  # never above 1
    assert spl_term(False, 4.0, 4.0) == 0.0


def test_barn_score_is_optimal_time_over_clipped_actual_time():
    # OT = 2 m / 0.5 m/s = 4 s; 10 s clips up to 16 s -> 0.25, 40 s -> 0.125, 100 s clips to 32 s
    assert barn_score(True, 2.0, 0.5, 10.0) == pytest.approx(0.25)
    assert barn_score(True, 2.0, 0.5, 24.0) == pytest.approx(4 / 24)
    assert barn_score(True, 2.0, 0.5, 100.0) == pytest.approx(0.125)
    assert barn_score(False, 2.0, 0.5, 10.0) == 0.0


def _ep(success, collision, spl, t, p, l, interv=None):
    return {
        "success": success,
        "collision": collision,
        "spl": spl,
        "time_s": t,
        "path_length_m": p,
        "shortest_path_m": l,
        "barn_score": 0.2 if success else 0.0,
        "safety_interventions": interv,
    }


def test_summary_averages_over_all_episodes_and_times_over_successes_only():
    s = summarize([_ep(True, False, 0.8, 10.0, 5.0, 4.0, 1), _ep(False, True, 0.0, 3.0, 1.0, 4.0, 3)])
    assert s["success_rate"] == 0.5 and s["collision_rate"] == 0.5
    assert s["spl"] == pytest.approx(0.4)
    assert s["time_to_goal_s"] == 10.0 and s["path_length_ratio"] == pytest.approx(1.25)
    assert s["safety_interventions_per_episode"] == 2.0
    assert "n/a" in format_table([("x", summarize([_ep(False, False, 0.0, 3.0, 1.0, 4.0)]))])


def test_nav_eval_prints_its_table_and_writes_json_and_a_picture(tmp_path, capsys):
    pytest.importorskip("pybullet")
    from robchair.cli import main

    out = tmp_path / "eval"
    code = main(
        ["nav-eval", "--env", "RobChair/Navigation-v1", "--episodes", "1", "--policy", "baseline",
         "--seed", "1", "--out", str(out), "--pictures", "1"]
    )  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    assert "baseline" in text and "SPL" in text and "BARN" in text
    data = json.loads((out / "nav_eval.json").read_text())
    ep = data["policies"]["baseline"]["episodes"][0]
    assert ep["seed"] == 1 and ep["shortest_path_m"] > 0 and "trajectory" in ep
    assert (out / "episode_baseline_1.png").stat().st_size > 1000


def test_nav_eval_refuses_an_unknown_policy_or_id_in_one_line(capsys):
    from robchair.cli import main

    assert main(["nav-eval", "--env", "RobChair/Nope-v0", "--episodes", "1"]) == 2
    assert "RobChair/Nope-v0" in capsys.readouterr().err
    assert main(["nav-eval", "--policy", "no_such_module:make", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert "no_such_module" in err and err.count("\n") == 1


def test_serial_and_distributed_nav_eval_give_the_same_results_for_the_same_seeds(ray_2cpu, tmp_path):
    pytest.importorskip("pybullet")
    from robchair.cli import main

    common = ["nav-eval", "--env", "RobChair/Navigation-v1", "--episodes", "2", "--seed", "4",
              "--policy", "baseline", "--policy", "random", "--pictures", "1"]  # fmt: skip
    assert main([*common, "--out", str(tmp_path / "serial")]) == 0
    assert main([*common, "--ray", "--out", str(tmp_path / "ray")]) == 0
    workers = {n["NodeManagerAddress"] for n in ray_2cpu.nodes()}
    serial = json.loads((tmp_path / "serial" / "nav_eval.json").read_text())
    distributed = json.loads((tmp_path / "ray" / "nav_eval.json").read_text())
    assert workers
    assert [e["seed"] for e in distributed["policies"]["random"]["episodes"]] == [4, 5]
    assert distributed == serial  # every episode and every summary figure, bit for bit
    assert (tmp_path / "ray" / "episode_baseline_4.png").stat().st_size > 1000
