"""Every command that writes a folder keeps existing data, refuses `--out .`, leaves no folders
behind when it fails and prints nothing on stdout before its one-line error."""

from __future__ import annotations

import pathlib
from pathlib import Path

import pytest

from robchair.cli import main

ROUTE = "waypoints = [[0, 0], [0.3, 0]]\nspeed = 0.3\n"
RUN_CONFIG = "[emulated]\nsonars = false\n[runtime]\nrate_hz = 10.0\n"
# A binary PCD whose header is fine and whose data is short: refused while its data is parsed.
TRUNCATED_PCD = (
    b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
    b"WIDTH 10\nHEIGHT 1\nPOINTS 10\nDATA binary\n" + b"\0" * 50
)


def _argv(command: str, tmp_path: Path) -> list[str]:
    """The cheapest successful invocation of each command (without --out)."""
    if command == "sim":
        return ["sim", "--duration", "0.05", "--no-progress", "--no-bag", "--no-pictures"]
    if command == "run":
        (tmp_path / "route.toml").write_text(ROUTE)
        (tmp_path / "cfg.toml").write_text(RUN_CONFIG)
        cfg, route = str(tmp_path / "cfg.toml"), str(tmp_path / "route.toml")
        return ["run", "--backend", "emulated", "--config", cfg, "--route", route, "--duration", "0.3"]
    if command == "map":
        return ["map", "--sample"]
    if command == "pid":
        return ["pid", "--no-plots"]
    assert command == "bench table52"
    return [
        "bench",
        "table52",
        "--objects",
        "chair",
        "--placements",
        "1",
        "--repeats",
        "1",
        "--skip-backends",
    ]


COMMANDS = ["sim", "run", "map", "pid", "bench table52"]


def _fail_inside_the_output_block(command: str, tmp_path: Path, monkeypatch) -> list[str]:
    """Arguments that make ``command`` fail after it started writing its output folder."""
    if command == "map":  # the case: a file refused while its data is parsed
        (tmp_path / "bad.pcd").write_bytes(TRUNCATED_PCD)
        return ["map", str(tmp_path / "bad.pcd")]
    if command == "sim":  # a simulation that fails (no need to simulate for that)
        import sim.runner
        from sim.errors import SimError

        def fail(*args, **kwargs):
            raise SimError("the simulation failed")

        monkeypatch.setattr(sim.runner, "_simulate", fail)
        return _argv(command, tmp_path)
    # The others cannot fail on bad data inside the block: make the last step, moving the finished
    # folder into place, fail as on a full disk.
    rename = pathlib.Path.rename

    def failing_rename(self, target):
        if ".partial-" in self.name:
            raise OSError(28, "No space left on device", str(target))
        return rename(self, target)

    monkeypatch.setattr(pathlib.Path, "rename", failing_rename)
    return _argv(command, tmp_path)


@pytest.mark.parametrize("command", COMMANDS)
def test_existing_file_in_the_out_folder_is_kept_and_the_command_refused(command, tmp_path, capsys):
    out = tmp_path / "x"
    out.mkdir()
    (out / "a.txt").write_text("keep")
    assert main([*_argv(command, tmp_path), "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.strip().splitlines()
    assert f"--out {out}: folder is not empty and was not written by robchair" in line
    assert "--overwrite" in line
    assert sorted(p.name for p in out.iterdir()) == ["a.txt"]
    assert (out / "a.txt").read_text() == "keep"


@pytest.mark.parametrize("command", COMMANDS)
def test_out_dot_is_refused_and_the_current_folder_untouched(command, tmp_path, capsys, monkeypatch):
    cwd = tmp_path / "work"
    cwd.mkdir()
    (cwd / "draft.txt").write_text("draft")
    argv = _argv(command, tmp_path)
    monkeypatch.chdir(cwd)
    assert main([*argv, "--out", "."]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.strip().splitlines()
    assert "--out .: is the current folder" in line
    assert sorted(p.name for p in cwd.iterdir()) == ["draft.txt"]
    assert (cwd / "draft.txt").read_text() == "draft"


@pytest.mark.parametrize("command", COMMANDS)
def test_failed_command_leaves_no_new_folder_and_no_parent_behind(command, tmp_path, capsys, monkeypatch):
    argv = _fail_inside_the_output_block(command, tmp_path, monkeypatch)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main([*argv, "--out", str(tmp_path / "new" / "deeper" / "out")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


@pytest.mark.parametrize("command", COMMANDS)
def test_failed_command_prints_nothing_on_stdout_before_its_error(command, tmp_path, capsys, monkeypatch):
    argv = _fail_inside_the_output_block(command, tmp_path, monkeypatch)
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.strip().splitlines()
    assert line.startswith(f"robchair {argv[0]}: error: ")


def test_overwrite_writes_into_a_foreign_folder_and_keeps_its_files(tmp_path, capsys):
    out = tmp_path / "x"
    out.mkdir()
    (out / "a.txt").write_text("keep")
    assert main(["pid", "--no-plots", "--out", str(out), "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [".robchair-output", "a.txt", "pid.json"]
    assert (out / "a.txt").read_text() == "keep"


def test_second_run_into_the_same_folder_needs_overwrite_and_then_replaces_only_its_output(tmp_path, capsys):
    out = tmp_path / "pid"
    assert main(["pid", "--out", str(out)]) == 0
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert main(["pid", "--no-plots", "--out", str(out)]) == 2
    assert "holds an earlier robchair output" in capsys.readouterr().err
    assert (out / "step_responses.png").is_file()
    assert main(["pid", "--no-plots", "--out", str(out), "--overwrite"]) == 0
    # the earlier pictures were outputs of the same command: replaced (gone); the notes are kept
    assert sorted(p.name for p in out.iterdir()) == [".robchair-output", "notes.txt", "pid.json"]
