"""Every example in README.md runs as written, and runs again: twice in a row in the same folder.

The README's ``sh`` blocks are split into commands (one a line, comments dropped) and its ``python`` blocks
are run whole, each in a fresh temporary folder with this environment's ``robchair`` on ``PATH``. Every
command that runs here runs twice in that folder and must succeed both times (README "Output folders":
a second run never fails on the first one's output). Every
command must appear in exactly one of :data:`AS_WRITTEN`, :data:`VARIANT` or :data:`EXEMPT`, so a new
README line without a check fails the first test. Heavy commands run as written under ``-m slow`` (a syntax
line, :data:`SYNTAX`, as each command it stands for) and in their smallest honest variant (the same
command with a shorter ``--duration`` or fewer ``--episodes``, the sims without the PNG pictures that the
run-folder tests draw, or ``--help`` for a syntax line) in the default run. Commands that
need real hardware or a Ray cluster are exempt, with the reason.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
BIN = Path(sys.executable).parent

MAIN_JOB = (
    "python3.11 -m venv .venv && .venv/bin/pip install -q -e '.[viz]' && "
    ".venv/bin/robchair sim --out runs/default --overwrite"
)
TEST_SUITE = "python3.11 -m venv .venv && .venv/bin/pip install -q -e '.[dev]' && .venv/bin/python -m pytest"
SWEEP = "robchair sweep examples/sweeps/speed_and_seed.toml"
NAV_EVAL = "robchair nav-eval --env RobChair/NavigationRooms-v1"
BENCHES = ("mapping", "sim", "table52", "env", "laser", "sweep", "zoom")
BENCH = "robchair bench " + " | ".join(BENCHES)
# a syntax line (its `|` is "or", not a shell pipe) -> the commands it stands for, each run as written
SYNTAX = {BENCH: [f"robchair bench {b}" for b in BENCHES]}

# run exactly as written in the default test run (fast enough)
AS_WRITTEN = {
    "robchair sim --list",
    "robchair map examples/cloud.pcd examples/scan.bag --cell 0.05 --tolerance 0.05 --band 0.1 1.6 "
    "--out runs/files --overwrite",
    "robchair map",
    "robchair pid",
    "robchair pid --tr 0.1365 --tp 0.3975 --mp 0.10",
    "robchair run --backend emulated --route examples/routes/short_turn.toml",
}

# command -> its smallest honest variant in the default run (None: slow only); as written under -m slow
VARIANT: dict[str, str | None] = {
    MAIN_JOB: "robchair sim --out runs/default --overwrite --duration 0.3 --no-pictures",
    "robchair sim office_tour --sensor kinect2-hd --duration 20 --seed 3 --out runs/tour --overwrite": (
        "robchair sim office_tour --sensor kinect2-hd --duration 0.1 --seed 3 --out runs/tour --overwrite "
        "--no-pictures"
    ),
    "robchair sim --no-safety": "robchair sim --no-safety --duration 0.3 --no-pictures",
    "robchair sim --pose odometry": "robchair sim --pose odometry --duration 0.3 --no-pictures",
    "robchair run --backend sim": "robchair run --backend sim --duration 0.5",
    BENCH: " && ".join(f"{c} --help" for c in SYNTAX[BENCH]),
    SWEEP: None,
    f"{NAV_EVAL} --episodes 100 --policy baseline --policy random": (
        f"{NAV_EVAL} --episodes 1 --policy baseline --policy random"
    ),
    f"{NAV_EVAL} --episodes 100 --policy baseline --ray --out runs/eval-rooms --overwrite": (
        f"{NAV_EVAL} --episodes 1 --policy baseline --ray --num-cpus 1 --out runs/eval-rooms --overwrite"
    ),
    "robchair assist-eval --user tremor --mode off --mode shield --mode assist --mode door --episodes 100 "
    "--seed 0 --out runs/assist --overwrite": (
        "robchair assist-eval --user tremor --mode off --mode door --episodes 1 --seed 0 "
        "--out runs/assist --overwrite"
    ),
    f"{SWEEP} --out runs/sweep-speed --overwrite": None,
    f"{SWEEP} --out runs/sweep-speed --resume": None,
    f"{SWEEP} --num-cpus 1": None,
}

# commands that read a run folder: made once (a short run without pictures) before the command runs twice
ON_A_RUN = {"robchair report runs/default", "robchair view runs/default"}
MAKE_RUN = "robchair sim --out runs/default --overwrite --duration 0.3 --no-pictures --no-progress"

# long-running emulators: started, their device path read from stdout, then stopped
EMULATORS = {"robchair hw emulate roboteq", "robchair hw emulate hokuyo"}

EXEMPT = {
    TEST_SUITE: "it is this test suite; the set-up part runs under -m slow with `pytest --collect-only`",
    "robchair run --backend real --config examples/chair.toml --route examples/routes/short_turn.toml": (
        "needs the real chair (Roboteq and sonars); test_example_chair_config_is_accepted checks its keys"
    ),
    "robchair hw check --port /dev/ttyACM0 --i2c 1": "needs a real Roboteq on /dev/ttyACM0 and an I2C bus",
    "robchair hw check --laser /dev/ttyACM1": "needs a real Hokuyo on /dev/ttyACM1",
    "robchair nav-eval --env RobChair/Navigation-v1 --policy MODULE:CALLABLE": "a placeholder policy",
    f"{SWEEP} --address auto --out /shared/runs/sweep-speed": "needs a running Ray cluster",
    f"{SWEEP} --address ray://HEAD:10001 --out /shared/runs/sweep-speed": "needs a Ray cluster's client",
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
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    env.update(OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
    return env


def _prepare(folder: Path) -> None:
    """What the examples expect to find: the shipped example files (routes, sweeps, inputs, configs)."""
    shutil.copytree(ROOT / "examples", folder / "examples")


def _twice(cmd: str, cwd: Path, timeout: float = 900) -> None:
    """Run ``cmd`` twice in a row in ``cwd``; both runs must succeed."""
    for k in range(2):
        res = subprocess.run(["bash", "-c", cmd], cwd=cwd, env=_env(), capture_output=True, text=True,
                             timeout=timeout)  # fmt: skip
        assert res.returncode == 0, f"run {k + 1} of `{cmd}` exited {res.returncode}:\n{res.stderr[-2000:]}"


def _run(cmd: str, cwd: Path, timeout: float = 900) -> subprocess.CompletedProcess[str]:
    res = subprocess.run(
        ["bash", "-c", cmd], cwd=cwd, env=_env(), capture_output=True, text=True, timeout=timeout
    )
    assert res.returncode == 0, f"`{cmd}` exited {res.returncode}:\n{res.stderr[-2000:]}"
    return res


def test_every_readme_command_is_checked_or_exempt_with_a_reason() -> None:
    cmds = shell_commands()
    assert MAIN_JOB in cmds and TEST_SUITE in cmds  # the two commands of the README's top
    known = AS_WRITTEN | set(VARIANT) | ON_A_RUN | EMULATORS | set(EXEMPT)
    assert [c for c in cmds if c not in known] == []
    assert [c for c in known if c not in cmds] == []  # no stale entries
    assert len(readme_blocks("python")) >= 1


@pytest.mark.parametrize("cmd", sorted(AS_WRITTEN))
def test_readme_command_runs_twice_as_written(cmd: str, tmp_path: Path) -> None:
    _prepare(tmp_path)
    _twice(cmd, tmp_path)


@pytest.mark.parametrize("cmd", sorted(c for c, v in VARIANT.items() if v is not None))
def test_readme_heavy_command_runs_twice_in_its_smallest_variant(cmd: str, tmp_path: Path) -> None:
    _prepare(tmp_path)
    variant = VARIANT[cmd]
    assert variant is not None
    _twice(variant, tmp_path)
    if "--out runs/default --overwrite" in variant:
        assert json.loads((tmp_path / "runs/default/metrics.json").read_text())["status"] == "ok"


@pytest.fixture(scope="module")
def made_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The folder :data:`MAKE_RUN` was run in (``runs/default`` in it), made once; read-only: each test
    copies it."""
    folder = tmp_path_factory.mktemp("made_run")
    _run(MAKE_RUN, folder)
    return folder


@pytest.mark.parametrize("cmd", sorted(ON_A_RUN))
def test_readme_command_on_a_run_folder_runs_twice(cmd: str, made_run: Path, tmp_path: Path) -> None:
    shutil.copytree(made_run / "runs", tmp_path / "runs")
    _twice(cmd, tmp_path)


def test_readme_pid_lines_run_one_after_the_other(tmp_path: Path) -> None:
    """`robchair pid`, then the README's next line `pid --tr ...`, in one folder."""
    _twice("robchair pid --no-plots", tmp_path)
    _run("robchair pid --tr 0.1365 --tp 0.3975 --mp 0.10", tmp_path)


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


def test_readme_python_examples_run_without_an_out_of_date_warning(tmp_path: Path) -> None:
    """gymnasium warns "is out of date" when a newer version of the made id is registered: the
    README's example uses the current one (shown with ``-W default``, which prints that warning)."""
    for block in readme_blocks("python"):
        res = subprocess.run([sys.executable, "-W", "default", "-c", block], cwd=tmp_path, env=_env(),
                             capture_output=True, text=True, timeout=600)  # fmt: skip
        assert res.returncode == 0, res.stderr[-2000:]
        assert "out of date" not in res.stderr, res.stderr[-2000:]


def test_sb3_example_help_works_without_stable_baselines3() -> None:
    res = subprocess.run([sys.executable, str(ROOT / "examples/sb3_light.py"), "--help"], env=_env(),
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert res.returncode == 0 and "--steps" in res.stdout, res.stderr
    import importlib.util

    if importlib.util.find_spec("stable_baselines3") is None:  # a real run says what is missing
        res = subprocess.run([sys.executable, str(ROOT / "examples/sb3_light.py"), "--steps", "1"],
                             env=_env(), capture_output=True, text=True, timeout=120)  # fmt: skip
        assert res.returncode == 2
        assert (
            res.stderr
            == "sb3_light: stable-baselines3 is not installed; pip install 'stable-baselines3>=2.3'\n"
        )


def test_shipped_example_inputs_are_small_and_what_their_generator_writes(tmp_path: Path) -> None:
    """examples/cloud.pcd and examples/scan.bag: under 1 MB each, byte for byte what
    examples/make_example_inputs.py writes (so they can be made again), and read as clouds."""
    from mapping.io import open_clouds

    script = str(ROOT / "examples/make_example_inputs.py")
    res = subprocess.run([sys.executable, script, "--out", str(tmp_path)], env=_env(), capture_output=True,
                         text=True, timeout=300)  # fmt: skip
    assert res.returncode == 0, res.stderr
    for name in ("cloud.pcd", "scan.bag"):
        shipped = ROOT / "examples" / name
        assert shipped.stat().st_size < 1_000_000
        assert shipped.read_bytes() == (tmp_path / name).read_bytes()
    assert open_clouds(ROOT / "examples/scan.bag").n_frames == 3


def test_example_chair_config_is_accepted_by_the_real_backend() -> None:
    """Every key of examples/chair.toml is one the real backend, the runtime and the safety layer take."""
    from robchair.backends import _REAL_KEYS
    from robchair.commands.run import load_run_config
    from robchair.platform.safety import SafetyLimits
    from robchair.platform.spec import load_spec
    from robchair.runtime_config import RuntimeConfig

    cfg = load_run_config(ROOT / "examples/chair.toml")
    real = cfg.table("real")
    real.keys(_REAL_KEYS)
    assert real.string("port") == "/dev/ttyACM0"
    assert RuntimeConfig.from_dict(cfg.table("runtime", {})).rate_hz == 10.0
    assert SafetyLimits.from_spec(load_spec(), cfg.table("safety", {})).max_speed == 0.5


@pytest.mark.slow
@pytest.mark.timeout(3600)
@pytest.mark.parametrize("cmd", sorted(a for c in VARIANT if c != MAIN_JOB for a in SYNTAX.get(c, [c])))
def test_readme_heavy_command_runs_as_written(cmd: str, tmp_path: Path) -> None:
    _prepare(tmp_path)
    if cmd.startswith(f"{SWEEP} --out runs/sweep-speed --resume"):
        _run(f"{SWEEP} --out runs/sweep-speed --overwrite", tmp_path, timeout=1800)
    _twice(cmd, tmp_path, timeout=1800)


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_readme_sweep_example_reaches_the_goal_and_its_parameter_moves_a_metric(tmp_path: Path) -> None:
    """The example sweep's runs drive office_corridor to its goal (10.2 m of route) and the speed cap
    changes the time to the goal: at 0.4 m/s the route cannot take less than 10.2 / 0.4 = 25.5 s, at
    the route's own 0.55 m/s it can take 18.5 s (hand computation from the scenario's route)."""
    _prepare(tmp_path)
    _run(f"{SWEEP} --num-cpus 1 --out runs/s --no-progress", tmp_path, timeout=3000)
    rows = json.loads((tmp_path / "runs/s/results.json").read_text())
    rows = rows["rows"] if isinstance(rows, dict) else rows
    assert rows and all(r["metrics.route.goal_reached"] is True for r in rows)
    by_speed: dict[float, list[float]] = {}
    for r in rows:
        by_speed.setdefault(r["safety.max_speed"], []).append(r["metrics.sim_time_s"])
    assert min(by_speed[0.4]) >= 25.5 > max(by_speed[0.55])


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
