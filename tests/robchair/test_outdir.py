"""Output folders are written only when the block succeeds and never destroy data."""

from pathlib import Path

import pytest

from robchair.outdir import MARKER, OutputDirError, check_output_dir, staged_output_dir


def test_successful_block_creates_target_with_its_files(tmp_path: Path) -> None:
    target = tmp_path / "run"
    with staged_output_dir(target) as stage:
        (stage / "a.txt").write_text("hello")
        assert not target.exists()
    assert (target / "a.txt").read_text() == "hello"
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "a.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_failed_block_leaves_no_output_and_no_staging_folder(tmp_path: Path) -> None:
    target = tmp_path / "run"
    with pytest.raises(RuntimeError, match="boom"), staged_output_dir(target) as stage:
        (stage / "half.txt").write_text("half")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_failed_block_keeps_the_previous_output_untouched(tmp_path: Path) -> None:
    target = tmp_path / "run"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with pytest.raises(ValueError), staged_output_dir(target, overwrite=True) as stage:
        (stage / "new.txt").write_text("new")
        raise ValueError("bad input")
    assert sorted(p.name for p in target.iterdir()) == ["old.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_foreign_non_empty_folder_is_refused_before_the_block_runs(tmp_path: Path) -> None:
    target = tmp_path / "run"
    target.mkdir()
    (target / "old.txt").write_text("old")
    ran = False
    with pytest.raises(OutputDirError, match="not empty and was not written by robchair"):
        with staged_output_dir(target):
            ran = True
    assert not ran
    assert sorted(p.name for p in target.iterdir()) == ["old.txt"]


def test_overwrite_into_a_foreign_folder_replaces_same_names_only(tmp_path: Path) -> None:
    target = tmp_path / "run"
    target.mkdir()
    (target / "old.txt").write_text("old")
    (target / "new.txt").write_text("stale")
    with staged_output_dir(target, overwrite=True) as stage:
        (stage / "new.txt").write_text("new")
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "new.txt", "old.txt"]
    assert (target / "new.txt").read_text() == "new"
    assert (target / "old.txt").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_earlier_output_is_replaced_with_overwrite_and_added_files_are_kept(tmp_path: Path) -> None:
    target = tmp_path / "run"
    with staged_output_dir(target) as stage:
        (stage / "a.txt").write_text("first")
        (stage / "sub").mkdir()
        (stage / "sub" / "b.txt").write_text("first")
    (target / "notes.txt").write_text("mine")
    with pytest.raises(OutputDirError, match="holds an earlier robchair output"):
        staged_output_dir(target).__enter__()
    with staged_output_dir(target, overwrite=True) as stage:
        (stage / "a.txt").write_text("second")
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "a.txt", "notes.txt"]
    assert (target / "a.txt").read_text() == "second"


def test_a_marker_naming_paths_outside_its_folder_touches_nothing_outside(tmp_path: Path) -> None:
    target = tmp_path / "run"
    target.mkdir()
    (tmp_path / "precious.txt").write_text("keep")
    (target / MARKER).write_text('{"entries": ["../precious.txt", "..", "/etc"]}')
    with staged_output_dir(target, overwrite=True) as stage:
        (stage / "a.txt").write_text("a")
    assert (tmp_path / "precious.txt").read_text() == "keep"
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "a.txt"]


def test_empty_existing_folder_is_used_and_kept_when_the_block_fails(tmp_path: Path) -> None:
    target = tmp_path / "run"
    target.mkdir()
    with pytest.raises(ValueError), staged_output_dir(target) as stage:
        raise ValueError("bad input")
    assert target.is_dir() and not any(target.iterdir())
    with staged_output_dir(target) as stage:
        (stage / "a.txt").write_text("a")
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "a.txt"]


def test_failed_block_removes_exactly_the_parents_it_created(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    target = tmp_path / "a" / "b" / "c" / "run"
    with pytest.raises(RuntimeError), staged_output_dir(target):
        assert (tmp_path / "a" / "b" / "c").is_dir()
        raise RuntimeError("boom")
    assert [p.name for p in tmp_path.iterdir()] == ["a"]
    assert list((tmp_path / "a").iterdir()) == []


def test_current_folder_and_a_file_are_refused(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OutputDirError, match="is the current folder"):
        check_output_dir(".")
    with pytest.raises(OutputDirError, match="is the current folder"):
        check_output_dir(tmp_path.parent)
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputDirError, match="is a file"):
        check_output_dir("f", overwrite=True)


def test_output_folder_gets_the_usual_permissions(tmp_path: Path) -> None:
    import os

    umask = os.umask(0o022)
    os.umask(umask)
    with staged_output_dir(tmp_path / "run") as stage:
        (stage / "a.txt").write_text("a")
    assert (tmp_path / "run").stat().st_mode & 0o777 == 0o777 & ~umask
