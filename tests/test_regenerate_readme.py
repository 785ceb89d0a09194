"""examples/regenerate_readme.py copies a run's pictures into the README's assets and rewrites the main
job's Performance row from the run's metrics.json, marked with the machine and its load."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_regeneration_from_existing_runs_copies_pictures_and_rewrites_the_row(tmp_path: Path) -> None:
    runs, assets, readme = tmp_path / "runs", tmp_path / "assets", tmp_path / "README.md"
    (runs / "default").mkdir(parents=True)
    (runs / "pid-readme").mkdir()
    for folder, name in (
        ("default", "scene.png"),
        ("default", "map_2d.png"),
        ("pid-readme", "step_responses.png"),
    ):
        (runs / folder / name).write_bytes(f"png of {name}".encode())
    wall = {"loop": 133.0, "setup": 14.0, "pictures": 19.0}
    metrics = {"sim_time_s": 20.2, "collisions": 0, "real_time_factor": 0.15, "route": {"goal_reached": True},
               "safety": {"stops": []}, "wall_time_s": wall}  # fmt: skip
    (runs / "default" / "metrics.json").write_text(json.dumps(metrics))
    readme.write_text(
        "# x\n\n| a | b |\n|---|---|\n| the main job: old figures | old | loaded |\n| other | row |\n"
    )
    cmd = [sys.executable, str(ROOT / "examples/regenerate_readme.py"), "--reuse", "--runs", str(runs),
           "--assets", str(assets), "--readme", str(readme)]  # fmt: skip
    res = subprocess.run(
        cmd, capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)}
    )
    assert res.returncode == 0, res.stderr
    assert (assets / "sim_office_corridor_map_2d.png").read_bytes() == b"png of map_2d.png"
    assert (assets / "sim_office_corridor_scene.png").read_bytes() == b"png of scene.png"
    assert (assets / "pid_step_responses.png").read_bytes() == b"png of step_responses.png"
    text = readme.read_text()
    row = next(line for line in text.splitlines() if line.startswith("| the main job: "))
    assert "goal reached at 20.2 s simulated, 0 collisions, 0 safety stops" in row
    assert "wall time loop 133 s, set-up 14 s, pictures 19 s, real-time factor 0.15" in row
    assert f"| {os.cpu_count()} x " in row and "load " in row and "before /" in row
    assert "old figures" not in text and "| other | row |" in text  # only that row changed
