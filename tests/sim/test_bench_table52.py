"""`robchair bench table52` on a subset: table printed, JSON written, counts consistent."""

from __future__ import annotations

import json

import pytest

from robchair.cli import main

pytest.importorskip("pybullet")


def test_table52_bench_on_the_chair_prints_the_row_and_writes_consistent_json(tmp_path, capsys):
    out = tmp_path / "t52"
    args = ["--objects", "chair", "--placements", "1", "--repeats", "1", "--skip-backends", "--out", str(out)]
    code = main(["bench", "table52", *args])
    assert code == 0
    text = capsys.readouterr().out
    assert "chair" in text and "36896" in text  # our row next to the thesis's point count
    data = json.loads((out / "table52.json").read_text())
    (row,) = data["rows"]
    assert row["object"] == "chair" and row["thesis_vhv"] == 97 and row["thesis_voxels"] == 210
    assert 1.5 <= row["distance_m"] <= 2.5
    assert row["points"] > 10_000
    # every structure is at least one voxel tall, so voxels can never be fewer than structures
    assert row["standard_voxels"] >= row["vhv_structures"] > 0
    assert row["ratio"] == pytest.approx(row["standard_voxels"] / row["vhv_structures"])


def test_table52_bench_refuses_an_unknown_object(tmp_path, capsys):
    code = main(["bench", "table52", "--objects", "sofa", "--out", str(tmp_path / "x")])
    assert code == 2
    assert "unknown ['sofa']" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
