"""Running a command again never fails on its own earlier output, and every refusal names only flags
the command has.

The rules (README "Output folders", :mod:`robchair.outdir`): without ``--out`` every command that
writes a folder writes a new ``runs/<name>-<UTC time>/``; every such command accepts ``--overwrite``;
``report`` and ``view`` replace only their own earlier file.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import pytest

from robchair.cli import build_parser, main
from robchair.outdir import MARKER, timestamped_dir

SWEEP = str(Path(__file__).resolve().parents[2] / "examples" / "sweeps" / "speed_and_seed.toml")

# each command that writes a folder, with the cheapest arguments that reach its folder check
FOLDER_COMMANDS: dict[str, list[str]] = {
    "sim": ["sim", "--duration", "0.05", "--no-progress"],
    "run": ["run", "--backend", "sim", "--duration", "0.1"],
    "map": ["map", "--sample"],
    "pid": ["pid", "--no-plots"],
    "nav-eval": ["nav-eval", "--episodes", "1"],
    "sweep": ["sweep", SWEEP],
    **{f"bench {b}": ["bench", b] for b in ("mapping", "sim", "table52", "env", "laser", "sweep", "zoom")},
}


def _subparser(words: list[str]) -> argparse.ArgumentParser:
    parser = build_parser()
    for w in words:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[w]
    return parser


def _flags(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings}


@pytest.mark.parametrize("command", sorted(FOLDER_COMMANDS))
def test_every_folder_command_accepts_overwrite_and_defaults_to_a_new_folder(command: str) -> None:
    parser = _subparser(command.split())
    assert "--overwrite" in _flags(parser)
    out = next(a for a in parser._actions if "--out" in a.option_strings)
    assert out.default is None  # no fixed folder: a new runs/<name>-<UTC time>/ per run
    if command != "run":  # `run` without --out writes no folder at all
        assert "UTC time" in (out.help or "")


@pytest.mark.parametrize("command", sorted(FOLDER_COMMANDS))
def test_a_refused_earlier_output_names_only_flags_the_command_has(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "earlier"
    out.mkdir()
    (out / "result.json").write_text("{}")
    marker = ".robchair-sweep" if command == "sweep" else MARKER
    (out / marker).write_text(json.dumps({"written_by": "robchair", "entries": ["result.json"]}))
    assert main([*FOLDER_COMMANDS[command], "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "earlier" in err, err
    named = set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", err))
    assert "--overwrite" in named
    assert named <= _flags(_subparser(command.split())), err
    assert (out / "result.json").read_text() == "{}"  # nothing touched


def test_timestamped_folders_of_two_runs_in_one_second_differ(tmp_path: Path) -> None:
    """The second run within the same UTC second gets ``-2`` (README "Output folders")."""
    first = timestamped_dir("pid", tmp_path)
    first.mkdir()
    second = timestamped_dir("pid", tmp_path)
    assert re.fullmatch(r"pid-\d{8}T\d{6}Z", first.name)
    if second.name.startswith(first.name):  # the clock did not tick over to the next second
        assert second.name == f"{first.name}-2"
    assert second != first


def test_pid_twice_then_pid_with_step_metrics_all_succeed(tmp_path: Path, monkeypatch) -> None:
    """The README's two `pid` lines, the first one twice, in one folder: three new run folders."""
    monkeypatch.chdir(tmp_path)
    for argv in (["pid", "--no-plots"], ["pid", "--no-plots"],
                 ["pid", "--no-plots", "--tr", "0.1365", "--tp", "0.3975", "--mp", "0.10"]):  # fmt: skip
        assert main(argv) == 0
    folders = sorted((tmp_path / "runs").iterdir())
    assert len(folders) == 3 and all((f / "pid.json").is_file() for f in folders)


def _run_folder(path: Path, entries: list[str]) -> Path:
    path.mkdir()
    (path / "metrics.json").write_text('{"status": "ok", "cycles": 3}')
    (path / MARKER).write_text(json.dumps({"written_by": "robchair", "entries": entries}))
    return path


def test_report_twice_replaces_its_own_page_and_keeps_a_foreign_one(tmp_path: Path, capsys) -> None:
    run = _run_folder(tmp_path / "run", ["metrics.json"])
    assert main(["report", str(run)]) == 0
    first = (run / "report.html").stat().st_mtime_ns
    assert main(["report", str(run)]) == 0  # its own page, now listed in the marker
    assert (run / "report.html").stat().st_mtime_ns >= first
    assert "report.html" in json.loads((run / MARKER).read_text())["entries"]
    other = _run_folder(tmp_path / "other", ["metrics.json"])
    (other / "report.html").write_text("mine")
    capsys.readouterr()
    assert main(["report", str(other)]) == 2
    err = capsys.readouterr().err
    assert "not written by robchair" in err and "--overwrite" in err
    assert (other / "report.html").read_text() == "mine"
    assert main(["report", str(other), "--overwrite"]) == 0
    assert (other / "report.html").read_text() != "mine"


def test_view_rebuild_keeps_a_foreign_recording(tmp_path: Path, capsys) -> None:
    run = _run_folder(tmp_path / "run", ["metrics.json"])
    (run / "recording.rrd").write_text("mine")
    assert main(["view", str(run), "--rebuild", "--no-viewer"]) == 2
    assert "not written by robchair" in capsys.readouterr().err
    assert (run / "recording.rrd").read_text() == "mine"
