"""`robchair run`: the emulated and simulated backends from the command line, its outputs and its one-line
errors (split from tests/robchair/test_runtime.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from robchair.cli import main

# Tolerance of "the same odometry" between the emulated and the simulated chair on the route
# (0, 0) -> (1.5, 0) -> (2.5, 1) at 0.3 m/s: the
# emulator's motors are the identified plant + PID alone, the simulator adds PyBullet's wheel-floor
# contact and its 240 Hz physics; measured 3.1 cm / 0.045 rad at worst along the route.
SAME_ODOMETRY_M = 0.05
SAME_HEADING_RAD = 0.06


def test_robchair_run_emulated_and_sim_give_the_same_odometry_on_the_same_route(
    tmp_path: Path, capsys
) -> None:
    route = tmp_path / "route.toml"
    route.write_text("waypoints = [[0, 0], [1.5, 0], [2.5, 1]]\nspeed = 0.3\n")
    cfg = tmp_path / "cfg.toml"
    cfg.write_text('[sim]\nsensor = "none"\nsonars = false\n[emulated]\nsonars = false\n')
    odo = {}
    for backend in ("emulated", "sim"):
        out = tmp_path / backend
        args = ["run", "--backend", backend, "--config", str(cfg), "--route", str(route), "--duration", "20"]
        assert main([*args, "--out", str(out)]) == 0
        assert json.loads((out / "metrics.json").read_text())["route"]["goal_reached"] is True
        odo[backend] = np.loadtxt(out / "odometry.csv", delimiter=",", skiprows=1)
    a, b = odo["emulated"], odo["sim"]
    n = min(len(a), len(b))
    assert abs(len(a) - len(b)) <= 2
    np.testing.assert_allclose(a[:n, 0], b[:n, 0])  # the same cycle times on both clocks
    assert np.max(np.hypot(a[:n, 1] - b[:n, 1], a[:n, 2] - b[:n, 2])) < SAME_ODOMETRY_M
    assert np.max(np.abs(a[:n, 3] - b[:n, 3])) < SAME_HEADING_RAD
    assert np.hypot(a[-1, 1] - 2.5, a[-1, 2] - 1.0) < 0.15  # and both did drive the route


def test_robchair_run_emulated_writes_bag_metrics_and_odometry(tmp_path: Path, capsys) -> None:
    route = tmp_path / "route.toml"
    route.write_text("waypoints = [[0, 0], [1, 0]]\nspeed = 0.3\n")
    cfg = tmp_path / "cfg.toml"
    cfg.write_text("[emulated]\nsonars = false\n[runtime]\nrate_hz = 10.0\n")
    out = tmp_path / "out"
    rc = main(
        [
            "run",
            "--backend",
            "emulated",
            "--config",
            str(cfg),
            "--route",
            str(route),
            "--duration",
            "10",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["route"]["goal_reached"] is True
    assert {p.name for p in out.iterdir()} == {
        "bag",
        "maps.npz",
        "metrics.json",
        "odometry.csv",
        "timeseries.csv",
        ".robchair-output",
    }
    odo = np.loadtxt(out / "odometry.csv", delimiter=",", skiprows=1)
    assert odo[-1, 1] == pytest.approx(1.0, abs=0.1)


def test_robchair_run_without_a_command_source_fails_with_one_line(tmp_path: Path, capsys) -> None:
    rc = main(["run", "--backend", "emulated", "--duration", "1"])
    assert rc == 2
    assert "no command source" in capsys.readouterr().err


@pytest.mark.slow
def test_robchair_run_sim_follows_a_scenario_route_in_the_world_frame(tmp_path: Path, capsys) -> None:
    cfg = tmp_path / "cfg.toml"
    cfg.write_text('[sim]\nscenario = "office_corridor"\nsensor = "none"\nsonars = false\n')
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--duration", "40"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["route"]["goal_reached"] is True
    # the scenario's last waypoint is (10.0, -0.8) in the world frame; odometry starts at the start pose
    assert math.hypot(m["final_pose"][0] - 10.0, m["final_pose"][1] + 0.8) < 0.15


def test_unknown_backend_or_runtime_key_is_one_line_naming_the_allowed_values(tmp_path: Path, capsys) -> None:
    assert main(["run", "--backend", "warp", "--duration", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'warp'" in err and "sim, emulated, real" in err
    cfg = tmp_path / "cfg.toml"
    cfg.write_text("[runtime]\nrate = 5.0\n")
    route = tmp_path / "route.toml"
    route.write_text("waypoints = [[0, 0], [1, 0]]\n")
    args = ["run", "--backend", "emulated", "--config", str(cfg), "--route", str(route), "--duration", "1"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert f"{cfg}:2: runtime.rate: unknown key (value 5.0); expected one of camera_every," in err
    assert "rate_hz" in err
    cfg.write_text("[emulated]\nrealtime = false\nretries = 1.5\n")
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{cfg}:3: emulated.retries = 1.5: expected an integer >= 0" in err
    cfg.write_text("[safety]\nmargin_m = -0.1\n")
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert (
        len(err.splitlines()) == 1 and f"{cfg}:2: safety.margin_m = -0.1: expected a finite number > 0" in err
    )
    cfg.write_text("[sim]\nscenario = 'nowhere'\n")
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--duration", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "scenario = 'nowhere': expected one of office_corridor" in err
    cfg.write_text("[runtimes]\nrate_hz = 5.0\n")
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert (
        len(err.splitlines()) == 1 and f"{cfg}:1: runtimes: unknown key" in err and "runtime, safety" in err
    )


def test_robchair_run_sim_without_a_route_drives_the_default_scenario(tmp_path: Path, capsys) -> None:
    cfg = tmp_path / "cfg.toml"
    cfg.write_text('[sim]\nsensor = "none"\nsonars = false\n')
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--duration", "1"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["backend"] == "sim" and m["safety"]["enabled"] is True and m["collisions"] == 0
    assert m["final_pose"][0] > 0.05  # it drove along the corridor scenario's first leg
