"""`robchair bench laser` runs both casters on the same poses and reports them side by side."""

from __future__ import annotations

import json

import pytest

from robchair.cli import main


@pytest.mark.slow
def test_bench_laser_times_both_casters_and_they_see_the_same_world(tmp_path, capsys) -> None:
    out = tmp_path / "bench"
    assert main(["bench", "laser", "--scans", "4", "--out", str(out)]) == 0
    res = json.loads((out / "bench_laser.json").read_text())
    assert res["embree_ms"] > 0 and res["pybullet_ms"] > 0 and res["raster_ms"] > 0
    assert res["raster_vs_embree_max_m"] < 2e-5
    assert res["beams_with_return"] > 0.5  # the office walls are within 4 m of the start
    assert res["agreement_1cm"] == 1.0
    assert "faster" in capsys.readouterr().out


def test_bench_laser_refuses_zero_scans(capsys) -> None:
    assert main(["bench", "laser", "--scans", "0"]) == 2
    assert "--scans must be >= 1" in capsys.readouterr().err
