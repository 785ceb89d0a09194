"""``robchair assist-eval``: bad input, the JSON record per mode and the picture; floors' door widths."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from robchair.cli import main
from sim.rooms import EVAL_SEEDS, FloorConfig, generate_floor


@pytest.mark.parametrize(
    ("args", "names"),
    [
        (["--mode", "autopilot"], "off, shield, assist, door"),
        (["--user", "nervous"], "typical, tremor, switch"),
        (["--door-width", "0.5", "0.9"], "0.74 <= LO <= HI <= 1.5"),
        (["--episodes", "0"], ">= 1"),
    ],
)
def test_bad_input_is_one_line_naming_the_allowed_values_and_exit_2(
    args: list[str], names: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["assist-eval", "--out", str(tmp_path / "o"), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and names in err[0]
    assert not (tmp_path / "o").exists()  # nothing half-written


def test_one_episode_writes_a_record_per_mode_and_the_paths_picture(tmp_path: Path) -> None:
    out = tmp_path / "ae"
    assert main(["assist-eval", "--user", "typical", "--mode", "off", "--mode", "shield", "--episodes", "1",
                 "--out", str(out)]) == 0  # fmt: skip
    doc = json.loads((out / "assist_eval.json").read_text())
    assert [r["mode"] for r in doc["modes"]] == ["off", "shield"]
    for r in doc["modes"]:
        assert {"success_rate", "collisions", "agreement", "peak_lon_accel"} <= set(r)
        assert 0.0 <= r["success_rate"] <= 1.0
    assert (out / "paths.png").stat().st_size > 0


def test_floors_keep_their_doorways_within_the_asked_width_range() -> None:
    """FloorConfig.door_width = (0.80, 0.90) m: every doorway's clear width lies in it."""
    for i in range(3):
        floor = generate_floor(EVAL_SEEDS[i], FloorConfig(door_width=(0.8, 0.9)))
        assert all(0.8 <= w <= 0.9 for _, _, w in floor.doors)


def test_serial_and_ray_assist_eval_give_the_same_json_and_the_report_page_shows_table_and_paths(
    ray_2cpu: Any, tmp_path: Path
) -> None:
    common = ["assist-eval", "--env", "office", "--user", "tremor", "--mode", "off", "--mode", "door",
              "--episodes", "2", "--seed", "3", "--pictures", "2"]  # fmt: skip
    assert main([*common, "--out", str(tmp_path / "serial")]) == 0
    assert main([*common, "--ray", "--out", str(tmp_path / "ray")]) == 0
    serial = json.loads((tmp_path / "serial" / "assist_eval.json").read_text())
    assert json.loads((tmp_path / "ray" / "assist_eval.json").read_text()) == serial  # bit for bit
    page = (tmp_path / "ray" / "report.md").read_text()
    assert "| mode | success |" in page and "| door |" in page and "| off |" in page
    assert "![paths.png](paths.png)" in page and "![paths_1.png](paths_1.png)" in page
    assert (tmp_path / "ray" / "paths_1.png").stat().st_size > 1000
