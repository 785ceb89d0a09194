"""The tests that share a fixture wider than one test run in one xdist worker (tests/conftest.py).

Expected groups read by hand from the two files' test signatures: in tests/robchair/test_mcap_bag.py three
tests take the session's ``sim_run`` (tests/robchair/conftest.py) and one takes only ``tmp_path``; in
tests/robchair/test_perception_matching.py one test takes ``sim_run`` and another the file's
module-scoped ``spec``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PLUGIN = """
import pytest

@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(items):
    for item in items:
        mark = item.get_closest_marker("xdist_group")
        print("GROUP", item.nodeid, mark.args[0] if mark else None)
"""


def _groups(tmp_path: Path, *files: str) -> dict[str, str | None]:
    """``nodeid -> xdist group`` of the tests of ``files`` as the suite's conftest marks them."""
    (tmp_path / "print_groups.py").write_text(PLUGIN, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}", "OPENBLAS_NUM_THREADS": "1"}
    res = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-n", "0", "-p",
                          "no:cacheprovider", "-p", "print_groups", *files], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    rows = [line.split(" ", 2) for line in res.stdout.splitlines() if line.startswith("GROUP ")]
    return {nodeid: None if group == "None" else group for _, nodeid, group in rows}


def test_the_users_of_a_session_fixture_share_one_group_across_files_and_a_module_fixture_has_its_own(
    tmp_path: Path,
) -> None:
    bag, perception = "tests/robchair/test_mcap_bag.py", "tests/robchair/test_perception_matching.py"
    groups = _groups(tmp_path, bag, perception)
    sim_run = {
        groups[f"{bag}::test_sim_run_bag_is_read_by_the_mcap_reader"],
        groups[f"{bag}::test_report_and_recording_of_a_sim_run"],
        groups[f"{bag}::test_a_sim_run_writes_its_report_recording_and_time_series"],
        groups[f"{perception}::test_the_bag_of_a_run_has_map_odom_base_link"],
    }
    assert len(sim_run) == 1 and None not in sim_run
    spec = groups[f"{perception}::test_unknown_pose_source_and_ground_truth_without_a_source_are_refused"]
    assert spec is not None and spec not in sim_run
    assert groups[f"{bag}::test_synthetic_run_bag_is_read_by_the_mcap_reader"] is None


SUITE_FILES = {
    "pytest.ini": "[pytest]\n",
    "test_a.py": """
import os
from pathlib import Path

import pytest

LOG = Path(__file__).parent / "log.txt"


def _note(what):
    with LOG.open("a") as f:
        f.write(f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')} {what}\\n")


@pytest.fixture(scope="session")
def built():
    _note("built")
    return 1


@pytest.mark.parametrize("k", range(4))
def test_user(built, k):
    _note(f"test_user[{k}]")


@pytest.mark.parametrize("k", range(4))
def test_plain(k):
    _note(f"test_plain[{k}]")
""",
    "test_b.py": """
from test_a import _note


def test_heavy():
    _note("test_heavy")
""",
    "durations.json": '{"test_b.py::test_heavy": 100.0}\n',
}


def test_a_two_worker_run_builds_a_shared_fixture_once_and_starts_the_recorded_heaviest_test_first(
    tmp_path: Path,
) -> None:
    """A small suite under this suite's conftest, run with ``-n 2 --dist loadgroup``: four tests share a
    session fixture (it must be built once, in one worker), and the last collected test is recorded as
    the heaviest (it must be the first test its worker runs)."""
    suite = tmp_path / "suite"
    suite.mkdir()
    (suite / "conftest.py").write_text((ROOT / "tests" / "conftest.py").read_text(encoding="utf-8"))
    for name, text in SUITE_FILES.items():
        (suite / name).write_text(text, encoding="utf-8")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    env.pop("PYTEST_XDIST_WORKER", None)
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2",
                          "--dist", "loadgroup"], cwd=suite, env=env, capture_output=True, text=True,
                         timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    rows = [line.split(" ", 1) for line in (suite / "log.txt").read_text().splitlines()]
    assert [what for _, what in rows].count("built") == 1, rows
    users = {worker for worker, what in rows if what.startswith("test_user")}
    assert len(users) == 1, rows
    heavy_worker = next(worker for worker, what in rows if what == "test_heavy")
    assert next(what for worker, what in rows if worker == heavy_worker) == "test_heavy", rows
