"""Every example in README.md runs as written.

The README's ``sh`` blocks are split into commands (one a line, comments dropped) and its ``python`` blocks
are run whole, each in a fresh temporary folder with this environment's ``robchair`` on ``PATH``. Every
command must appear in exactly one of :data:`AS_WRITTEN`, :data:`VARIANT` or :data:`EXEMPT`, so a new
README line without a check fails the first test. Heavy commands run as written under ``-m slow`` and in
their smallest honest variant (the same command with a shorter ``--duration``, or ``--help`` for a
syntax line) in the default run. Commands that need real hardware or a Ray cluster are exempt, with the
reason.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
BIN = Path(sys.executable).parent

MAIN_JOB = (
    "python3.11 -m venv .venv && .venv/bin/pip install -q -e '.[viz]' && "
    ".venv/bin/robchair sim --out runs/default --overwrite"
)
TEST_SUITE = "python3.11 -m venv .venv && .venv/bin/pip install -q -e '.[dev]' && .venv/bin/python -m pytest"
SWEEP = "robchair sweep examples/sweeps/margin_and_seed.toml"
NAV_EVAL = "robchair nav-eval --env RobChair/NavigationRooms-v1"
BENCH = "robchair bench mapping | sim | table52 | env | laser | sweep | zoom"

# run exactly as written in the default test run (fast enough)
AS_WRITTEN = {
    "robchair sim --list",
    "robchair map cloud.pcd scan.bag --cell 0.05 --tolerance 0.05 --band 0.1 1.6 --out out/map",
    "robchair map",
    "robchair pid",
    "robchair pid --tr 0.1365 --tp 0.3975 --mp 0.10",
    "robchair run --backend emulated --route examples/routes/short_turn.toml",
}

# command -> its smallest honest variant in the default run (None: slow only); as written under -m slow
VARIANT: dict[str, str | None] = {
    MAIN_JOB: "robchair sim --out runs/default --overwrite --duration 0.3 --no-pictures",
    "robchair sim office_tour --sensor kinect2-hd --duration 20 --seed 3 --out runs/tour": (
        "robchair sim office_tour --sensor kinect2-hd --duration 0.2 --seed 3 --out runs/tour"
    ),
    "robchair sim --no-safety": "robchair sim --no-safety --duration 0.3 --no-pictures",
    "robchair run --backend sim": "robchair run --backend sim --duration 0.5",
    BENCH: " && ".join(
        f"robchair bench {b} --help" for b in ("mapping", "sim", "table52", "env", "laser", "sweep", "zoom")
    ),
    SWEEP: None,
    f"{NAV_EVAL} --episodes 100 --policy baseline --policy random": (
        f"{NAV_EVAL} --episodes 1 --policy baseline --policy random"
    ),
    f"{NAV_EVAL} --episodes 100 --policy baseline --ray --out runs/eval-rooms": (
        f"{NAV_EVAL} --episodes 1 --policy baseline --ray --num-cpus 1 --out runs/eval-rooms"
    ),
    "robchair assist-eval --user tremor --mode off --mode shield --mode assist --mode door --episodes 100 "
    "--seed 0 --out runs/assist": (
        "robchair assist-eval --user tremor --mode off --mode door --episodes 1 --seed 0 --out runs/assist"
    ),
    f"{SWEEP} --out runs/sweep-margin": None,
    f"{SWEEP} --out runs/sweep-margin --resume": None,
    f"{SWEEP} --num-cpus 1": None,
}

# long-running emulators: started, their device path read from stdout, then stopped
EMULATORS = {"robchair hw emulate roboteq", "robchair hw emulate hokuyo"}

EXEMPT = {
    TEST_SUITE: "it is this test suite; the set-up part runs under -m slow with `pytest --collect-only`",
    "robchair run --backend real --config chair.toml": "needs the real chair (Roboteq and sonars)",
    "robchair hw check --port /dev/ttyACM0 --i2c 1": "needs a real Roboteq on /dev/ttyACM0 and an I2C bus",
    "robchair hw check --laser /dev/ttyACM1": "needs a real Hokuyo on /dev/ttyACM1",
    "robchair nav-eval --env RobChair/Navigation-v1 --policy MODULE:CALLABLE": "a placeholder policy",
    f"{SWEEP} --address auto --out /shared/runs/sweep-margin": "needs a running Ray cluster",
    f"{SWEEP} --address ray://HEAD:10001 --out /shared/runs/sweep-margin": "needs a Ray cluster's client",
}


def readme_blocks(lang: str) -> list[str]:
    """The README's fenced code blocks of one language (a regex alternative: ``sh|bash``), in order."""
    return re.findall(rf"^```(?:{lang})\n(.*?)^```", README.read_text(), flags=re.S | re.M)


def shell_commands() -> list[str]:
    """Every command line of the README's ``sh`` blocks, without comments."""
    cmds = []
    for block in readme_blocks("sh|bash"):
        for line in block.splitlines():
            line = re.sub(r"(^|\s+)#(\s.*|$)", "", line).strip()
            if line:
                cmds.append(line)
    return cmds


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    env.update(OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
    return env


def _prepare(folder: Path) -> None:
    """What the examples expect to find: the example files and a PCD and a ROS 1 bag of clouds."""
    shutil.copytree(ROOT / "examples", folder / "examples")
    rng = np.random.default_rng(0)
    pts = rng.uniform([-2.0, -2.0, 0.0], [2.0, 2.0, 1.5], (500, 3)).astype(np.float32)
    header = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA ascii\n"
    )
    (folder / "cloud.pcd").write_text(header + "\n".join(" ".join(f"{c:.4f}" for c in p) for p in pts) + "\n")
    _write_ros1_bag(folder / "scan.bag", pts)


def _write_ros1_bag(path: Path, pts: np.ndarray) -> None:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    t = ts.types
    pc2 = "sensor_msgs/msg/PointCloud2"
    fields = [
        t["sensor_msgs/msg/PointField"](name=n, offset=4 * k, datatype=7, count=1)
        for k, n in enumerate("xyz")
    ]
    with Writer(path) as w:
        conn = w.add_connection("/points", pc2, typestore=ts)
        for k in range(2):
            header = t["std_msgs/msg/Header"](seq=k, stamp=t["builtin_interfaces/msg/Time"](sec=k, nanosec=0),
                                              frame_id="base_link")  # fmt: skip
            msg = t[pc2](header=header, height=1, width=len(pts), fields=fields, is_bigendian=False,
                         point_step=12, row_step=12 * len(pts), data=np.frombuffer(pts.tobytes(), np.uint8),
                         is_dense=True)  # fmt: skip
            w.write(conn, (k + 1) * 10**9, ts.serialize_ros1(msg, pc2))


def _run(cmd: str, cwd: Path, timeout: float = 900) -> subprocess.CompletedProcess[str]:
    res = subprocess.run(
        ["bash", "-c", cmd], cwd=cwd, env=_env(), capture_output=True, text=True, timeout=timeout
    )
    assert res.returncode == 0, f"`{cmd}` exited {res.returncode}:\n{res.stderr[-2000:]}"
    return res


def test_every_readme_command_is_checked_or_exempt_with_a_reason() -> None:
    cmds = shell_commands()
    assert MAIN_JOB in cmds and TEST_SUITE in cmds  # the two commands of the README's top
    known = AS_WRITTEN | set(VARIANT) | EMULATORS | set(EXEMPT)
    assert [c for c in cmds if c not in known] == []
    assert [c for c in known if c not in cmds] == []  # no stale entries
    assert len(readme_blocks("python")) >= 1


@pytest.mark.parametrize("cmd", sorted(AS_WRITTEN))
def test_readme_command_runs_as_written(cmd: str, tmp_path: Path) -> None:
    _prepare(tmp_path)
    _run(cmd, tmp_path)


@pytest.mark.parametrize("cmd", sorted(c for c, v in VARIANT.items() if v is not None))
def test_readme_heavy_command_runs_in_its_smallest_variant(cmd: str, tmp_path: Path) -> None:
    _prepare(tmp_path)
    variant = VARIANT[cmd]
    assert variant is not None
    _run(variant, tmp_path)
    if "--out runs/default --overwrite" in variant:  # a second run into the same folder works too
        _run(variant, tmp_path)
        assert json.loads((tmp_path / "runs/default/metrics.json").read_text())["status"] == "ok"


@pytest.mark.parametrize("cmd", sorted(EMULATORS))
def test_readme_emulator_prints_its_device_path(cmd: str, tmp_path: Path) -> None:
    proc = subprocess.Popen(["bash", "-c", f"exec {cmd}"], cwd=tmp_path, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().strip()
        assert re.fullmatch(r"/dev/pts/\d+", line.split()[-1] if line else ""), line
        assert Path(line.split()[-1]).exists()
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_readme_python_examples_run(tmp_path: Path) -> None:
    for block in readme_blocks("python"):
        res = subprocess.run([sys.executable, "-c", block], cwd=tmp_path, env=_env(), capture_output=True,
                             text=True, timeout=600)  # fmt: skip
        assert res.returncode == 0, res.stderr[-2000:]


@pytest.mark.slow
@pytest.mark.timeout(3600)
@pytest.mark.parametrize("cmd", sorted(c for c in VARIANT if c != MAIN_JOB))
def test_readme_heavy_command_runs_as_written(cmd: str, tmp_path: Path) -> None:
    _prepare(tmp_path)
    if cmd.startswith(f"{SWEEP} --out runs/sweep-margin --resume"):
        _run(f"{SWEEP} --out runs/sweep-margin", tmp_path, timeout=1800)
    _run(cmd, tmp_path, timeout=1800)


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_readme_two_commands_work_on_a_fresh_copy_and_on_a_second_run(tmp_path: Path) -> None:
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    clone = tmp_path / "robchair"
    for rel in files.splitlines():
        if (ROOT / rel).is_file():
            (clone / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / rel, clone / rel)
    env_free = {k: v for k, v in _env().items() if k != "VIRTUAL_ENV"}
    for _ in range(2):  # a fresh clone, then the same command again
        res = subprocess.run(["bash", "-c", MAIN_JOB], cwd=clone, env=env_free, capture_output=True,
                             text=True, timeout=3600)  # fmt: skip
        assert res.returncode == 0, res.stderr[-2000:]
        m = json.loads((clone / "runs/default/metrics.json").read_text())
        assert m["route"]["goal_reached"] is True and m["collisions"] == 0
    setup = TEST_SUITE.replace("-m pytest", "-m pytest --collect-only -q")
    res = subprocess.run(["bash", "-c", setup], cwd=clone, env=env_free, capture_output=True, text=True,
                         timeout=3600)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
