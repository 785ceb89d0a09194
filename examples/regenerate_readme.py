"""Regenerate the README's pictures and the main job's figures from fresh runs, marked with the machine.

Runs the main job (``robchair sim --out runs/default --overwrite``) and ``robchair pid``, copies their
pictures into ``assets/readme/`` (``scene.png``, ``map_2d.png``, ``step_responses.png``) and rewrites the
main job's row of the README's Performance table from the run's ``metrics.json``: time to the goal,
collisions, safety stops, wall time (loop, set-up, pictures), real-time factor and the CPU time of the
whole command (``getrusage`` of the child). The row's "measured" column names the machine (CPU count,
CPU model) and its load average (``os.getloadavg``) before and after the run. Re-runnable: each run
replaces its own earlier output (``--overwrite``); ``--reuse`` takes the existing run folders instead.

    python examples/regenerate_readme.py                        # the real thing (minutes)
    python examples/regenerate_readme.py --duration 1 --assets /tmp/a --readme /tmp/README.md  # a try
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

from robchair.commands.bench_output import cpu_model

ROOT = Path(__file__).resolve().parents[1]
MAIN_ROW = re.compile(r"^\| the main job: .*$", re.M)
PICTURES = {  # run folder file -> assets/readme name
    ("default", "scene.png"): "sim_office_corridor_scene.png",
    ("default", "map_2d.png"): "sim_office_corridor_map_2d.png",
    ("pid", "step_responses.png"): "pid_step_responses.png",
}


def machine(load_before: tuple[float, ...], load_after: tuple[float, ...]) -> str:
    return (
        f"{os.cpu_count()} x {cpu_model()}, load {load_before[0]:.1f} before / {load_after[0]:.1f} after "
        f"(1-min average), {time.strftime('%Y-%m-%d', time.gmtime())}"
    )


def run(cmd: list[str], cwd: Path) -> float:
    """Run ``cmd`` (stderr shown), fail on a non-zero exit; return the CPU seconds it used."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    res = subprocess.run(cmd, cwd=cwd, stdout=subprocess.DEVNULL, check=False)
    if res.returncode != 0:
        sys.exit(f"regenerate_readme: `{' '.join(cmd)}` exited {res.returncode}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main_job_row(m: dict, cpu_s: float | None, where: str) -> str:
    """The README's Performance row of the main job from its ``metrics.json``."""
    wall = m.get("wall_time_s", {})
    goal = "goal reached" if m["route"]["goal_reached"] else "goal NOT reached"
    cpu = f"; {cpu_s:.0f} s of CPU time in all (`getrusage`)" if cpu_s is not None else ""
    return (
        "| the main job: `office_corridor` to its goal (10.2 m, Kinect v2 at 30 Hz, six sonars, safety on, "
        "bag and pictures) | `robchair sim --out runs/default --overwrite` (figures from its `metrics.json`: "
        "`sim_time_s`, `real_time_factor`, `wall_time_s`; `python examples/regenerate_readme.py` rewrites "
        f"this row) | {goal} at {m['sim_time_s']:.1f} s simulated, {m['collisions']} collisions, "
        f"{len(m['safety']['stops'])} safety stops; wall time loop {wall.get('loop', 0):.0f} s, set-up "
        f"{wall.get('setup', 0):.0f} s, pictures {wall.get('pictures', 0):.0f} s, real-time factor "
        f"{m['real_time_factor']:.2f}{cpu} | {where} |"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, default=ROOT / "runs", help="where the runs go (default runs/)")
    ap.add_argument("--assets", type=Path, default=ROOT / "assets" / "readme", help="pictures' folder")
    ap.add_argument("--readme", type=Path, default=ROOT / "README.md", help="README to rewrite")
    ap.add_argument("--duration", type=float, default=None, help="simulated s of the main job (a try)")
    ap.add_argument("--reuse", action="store_true", help="take the existing run folders, run nothing")
    args = ap.parse_args(argv)
    robchair = str(Path(sys.executable).with_name("robchair"))
    folders = {"default": args.runs / "default", "pid": args.runs / "pid-readme"}
    load0 = os.getloadavg()
    cpu_s = None
    if not args.reuse:
        sim = [robchair, "sim", "--out", str(folders["default"]), "--overwrite", "--no-progress"]
        cpu_s = run([*sim, *(["--duration", str(args.duration)] if args.duration else [])], ROOT)
        run([robchair, "pid", "--out", str(folders["pid"]), "--overwrite"], ROOT)
    load1 = os.getloadavg()
    args.assets.mkdir(parents=True, exist_ok=True)
    for (folder, name), target in PICTURES.items():
        shutil.copyfile(folders[folder] / name, args.assets / target)
        print(f"copied {folders[folder] / name} -> {args.assets / target}")
    metrics = json.loads((folders["default"] / "metrics.json").read_text())
    row = main_job_row(metrics, cpu_s, machine(load0, load1))
    text = args.readme.read_text(encoding="utf-8")
    if not MAIN_ROW.search(text):
        sys.exit(f"regenerate_readme: {args.readme}: no '| the main job: ' row to rewrite")
    args.readme.write_text(MAIN_ROW.sub(lambda _: row, text, count=1), encoding="utf-8")
    print(f"rewrote the main job's row of {args.readme}:\n{row}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
