"""One command per output folder at a time, stale staging folders cleaned up, a full disk named.

Expected behaviour from the output-folder rules (robchair.outdir's module docstring, README "Output
folders"): a second command on the same target refuses at once with one line; a staging folder left
by a killed process (SIGKILL cannot be caught, so nothing of the killed process can clean up) is
removed by the next command into the same place; ENOSPC (errno 28, POSIX) names the folder written.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from robchair.cli import main
from robchair.outdir import MARKER, OutputDirError, check_output_dir, staged_output_dir

ROOT = Path(__file__).resolve().parents[2]


def _python(code: str, **kw) -> subprocess.Popen:  # type: ignore[type-arg]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], env=env, text=True, **kw)


@pytest.fixture
def holder(tmp_path: Path):
    """Another process that has checked ``tmp_path / "Z"`` (as a command does at start) and waits."""
    proc = _python(
        f"""
        import sys
        from robchair.outdir import check_output_dir
        check_output_dir({str(tmp_path / "Z")!r})
        print("ready", flush=True)
        sys.stdin.readline()
        """,
        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
    yield proc
    proc.communicate("\n", timeout=30)


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_second_command_on_a_target_being_written_refuses_at_once(
    tmp_path: Path, holder, overwrite: bool
) -> None:
    with pytest.raises(OutputDirError, match=rf"pid {holder.pid}\) is writing it"):
        check_output_dir(tmp_path / "Z", overwrite=overwrite)


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_second_robchair_sim_on_the_same_out_exits_2_with_one_line_before_simulating(
    tmp_path: Path, holder, capsys, overwrite: bool
) -> None:
    argv = ["sim", "--out", str(tmp_path / "Z"), "--duration", "0.3", "--no-progress", "--no-pictures"]
    assert main(argv + (["--overwrite"] if overwrite else [])) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is writing it" in err
    assert not (tmp_path / "Z").exists()


def test_the_lock_is_released_when_the_output_is_in_place(tmp_path: Path) -> None:
    with staged_output_dir(tmp_path / "Z") as stage:
        (stage / "a.txt").write_text("a")
    with staged_output_dir(tmp_path / "Z", overwrite=True) as stage:
        (stage / "a.txt").write_text("b")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["Z"]  # no lock file, no staging folder left


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_staging_folder_left_by_a_killed_command_is_removed_by_the_next_one(
    tmp_path: Path, caplog, overwrite: bool
) -> None:
    target = tmp_path / "Z"
    if overwrite:  # an earlier output: the killed command staged inside it
        with staged_output_dir(target) as stage:
            (stage / "a.txt").write_text("a")
    killed = _python(
        f"""
        import os, signal
        from robchair.outdir import staged_output_dir
        with staged_output_dir({str(target)!r}, overwrite={overwrite}) as stage:
            (stage / "big.bin").write_bytes(bytes(1 << 20))
            os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    assert killed.wait(timeout=60) == -9
    left = [
        p
        for p in (*tmp_path.iterdir(), *(target.iterdir() if target.is_dir() else ()))
        if ".partial-" in p.name
    ]
    assert len(left) == 1
    with caplog.at_level(logging.WARNING, logger="robchair.outdir"):
        with staged_output_dir(target, overwrite=True) as stage:
            (stage / "a.txt").write_text("new")
    assert not left[0].exists()
    assert str(left[0]) in caplog.text
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "a.txt"]


def test_a_staging_folder_of_a_live_command_is_left_alone(tmp_path: Path, holder) -> None:
    live = tmp_path / f".Y.partial-{holder.pid}-0123abcd"
    live.mkdir()
    with staged_output_dir(tmp_path / "Y") as stage:
        (stage / "a.txt").write_text("a")
    assert live.is_dir()


def test_a_full_disk_names_the_output_folder_and_leaves_nothing(tmp_path: Path) -> None:
    target = tmp_path / "new" / "Z"
    with pytest.raises(OSError, match="No space left on device") as err:
        with staged_output_dir(target) as stage:
            (stage / "a.txt").write_text("a")
            with open("/dev/full", "w") as f:  # the kernel's always-full device: ENOSPC on write
                f.write("x" * 100)
    assert str(target) in str(err.value)
    assert list(tmp_path.iterdir()) == []
