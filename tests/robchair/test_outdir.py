"""The staged output folder replaces its target only when the block succeeds."""

from pathlib import Path

import pytest

from robchair.outdir import staged_output_dir


def test_successful_block_creates_target_with_its_files(tmp_path: Path) -> None:
    target = tmp_path / "run"
    with staged_output_dir(target) as stage:
        (stage / "a.txt").write_text("hello")
        assert not target.exists()
    assert (target / "a.txt").read_text() == "hello"
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
    with pytest.raises(ValueError), staged_output_dir(target) as stage:
        (stage / "new.txt").write_text("new")
        raise ValueError("bad input")
    assert sorted(p.name for p in target.iterdir()) == ["old.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_successful_block_replaces_previous_output_whole(tmp_path: Path) -> None:
    target = tmp_path / "run"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with staged_output_dir(target) as stage:
        (stage / "new.txt").write_text("new")
    assert sorted(p.name for p in target.iterdir()) == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]
