"""Smoke test of `robchair bench mapping --quick` (no timing asserted: speed lives in the benchmark)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from mapping.grid import GridSpec
from mapping.synthetic import kinect_hd_like_cloud
from mapping.vhv import VHVMap
from robchair.cli import main


def run_quick_bench(tmp_path: Path, *extra: str) -> dict:
    out = tmp_path / "bench"
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    assert main(["bench", "mapping", "--quick", "--out", str(out), "--seed", "3", *extra]) == 0
    if affinity is not None:  # the benchmark pins itself to one CPU only while it runs
        assert os.sched_getaffinity(0) == affinity
    result = json.loads((out / "bench_mapping.json").read_text())
    assert result["quick"] is True and len(result["rows"]) == 2
    return result


def test_quick_bench_writes_json_whose_counts_match_an_independent_build(tmp_path: Path) -> None:
    result = run_quick_bench(tmp_path, "--no-open3d", "--no-octomap")
    rng = np.random.default_rng(3)
    spec = GridSpec(cell_size=0.05, size_x=20.0, size_y=20.0)
    for row in result["rows"]:
        cloud = kinect_hd_like_cloud(rng, row["height"], row["width"])
        m = VHVMap(spec, 0.05)
        stats = m.insert(cloud, method="sort")
        assert row["points"] == cloud.shape[0] * cloud.shape[1]
        assert row["structures"] == m.n_structures and row["voxels"] == m.n_voxels
        assert row["points_dropped_nonfinite"] == stats.points_dropped_nonfinite
        assert len(row["vhv_fast"]["times_ms"]) == 2 and len(row["vhv_numpy"]["times_ms"]) >= 1
        for key in ("vhv_fast", "vhv_numpy", "vhv_sort"):
            assert row[key]["median_ms"] > 0 and row[key]["cpu_median_ms"] >= 0
        assert row["vhv_fast"]["peak_extra_bytes"] > 0
        assert "open3d_voxelgrid" not in row and "octomap_insert" not in row
    ev = result["evidence"]
    prob = ev["insert"]["probabilistic"]
    assert prob["median_ms"] > 0 and prob["free_intervals"] > 0 and prob["fan_passages"] > 0
    assert "octomap" not in ev["insert"] and "dufomap" in ev["insert"]  # run, or skipped with a reason
    assert ev["walker"]["cells"] > 0 and ev["walker"]["rate_hz"] == 30.0
    depth = ev["depth_frame"]
    assert depth["points"] == 36 * 64 and depth["max_range_m"] == 6.0  # the quick run's depth frame
    assert depth["probabilistic"]["cpu_median_ms"] >= 0 and depth["probabilistic"]["fan_passages"] > 0


@pytest.mark.slow
def test_quick_bench_with_open3d_and_octomap_baselines(tmp_path: Path) -> None:
    result = run_quick_bench(tmp_path)
    for row in result["rows"]:
        assert row["open3d_voxels"] > 0 and row["open3d_voxelgrid"]["median_ms"] > 0
        assert row["octomap_insert"]["median_ms"] > 0 and "ray-casts" in row["octomap_insert"]["note"]
        assert row["ratio_open3d_over_vhv_fast"] > 0


def test_bench_refuses_a_zero_repeat(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "mapping", "--repeat", "0", "--out", str(tmp_path / "b")]) == 2
    assert "--repeat 0" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()
