"""Bad input to `robchair sim` / `robchair run`: one line on stderr, exit code 2, nothing opened.

The rule (README "Errors"): bad input gives one clear line naming the input and what was wrong, exit
code 2, no traceback, and the motor controller is not touched before the input is known to be good.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hw.clock import ManualClock
from hw.roboteq.emulator import RoboteqEmulator
from robchair.cli import main
from robchair.platform.paths import SCENES
from sim.errors import ScenarioError
from sim.scene import load_scenario

ROOT = Path(__file__).resolve().parents[2]
BAD_DURATIONS = ["1e300", "inf", "nan", "-1", "0"]


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("duration", BAD_DURATIONS)
def test_a_bad_sim_duration_is_one_line_and_exit_2(tmp_path: Path, capsys, duration: str) -> None:
    assert main(["sim", "--duration", duration, "--out", str(tmp_path / "Z"), "--no-progress"]) == 2
    assert "--duration" in _one_line(capsys)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "flag", [["--duration", d] for d in BAD_DURATIONS] + [["--rate", "nan"], ["--rate", "0"]]
)
def test_a_bad_run_duration_or_rate_is_refused_before_the_controller_hears_anything(
    tmp_path: Path, capsys, flag: list[str]
) -> None:
    with RoboteqEmulator(clock=ManualClock()) as emu:
        cfg = tmp_path / "real.toml"
        cfg.write_text(f'[real]\nport = "{emu.device_path}"\n', encoding="utf-8")
        route = str(ROOT / "examples/routes/short_turn.toml")
        assert main(["run", "--backend", "real", "--config", str(cfg), "--route", route, *flag]) == 2
        received = list(emu.received)
    assert flag[0] in _one_line(capsys)
    assert received == []  # not opened, not configured


def test_a_bad_choice_is_one_line_naming_the_allowed_values(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["sim", "--sensor", "kinect3"])
    assert exc.value.code == 2
    err = _one_line(capsys)
    assert "kinect3" in err and "kinect2-hd" in err and "none" in err


def test_a_bad_choice_of_a_bench_is_one_line_too(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["bench", "no-such-bench"])
    assert exc.value.code == 2
    assert "no-such-bench" in _one_line(capsys)


def test_a_waypoint_inside_a_wall_is_refused_like_a_start_inside_one(tmp_path: Path) -> None:
    # office.toml: corridor_wall_left is the box x 2.25 +- 3.75, y 1.25 +- 0.05 (0.1 m thick)
    path = tmp_path / "bad.toml"
    path.write_text(
        f'[scenario]\nscene = "{SCENES / "office.toml"}"\nstart = [0.0, 0.0, 0.0]\n'
        "[route]\nwaypoints = [[1.0, 0.0], [2.0, 1.25], [3.0, 0.0]]\n",
        encoding="utf-8",
    )
    with pytest.raises(
        ScenarioError, match=r"waypoint 1 \(2\.0, 1\.25\) lies inside object 'corridor_wall_left'"
    ):
        load_scenario(path)
    path.write_text(path.read_text().replace("[2.0, 1.25]", "[2.0, 1.1]"), encoding="utf-8")
    assert load_scenario(path).route.waypoints[1] == (2.0, 1.1)  # 5 cm from the wall: allowed
