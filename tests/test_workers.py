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
