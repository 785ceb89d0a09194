"""``robchair bench sim`` times no compilation: a warm-up long enough, and a record of late compiles.

On a cold numba cache (the first bench after an install) the old 0.1 s warm-up left six mapping and
matching kernels (the first match, the dynamic decay) to compile inside the first timed row, so the
2-core row ran at RTF 0.58 against the 1-core row's 0.83 (session 9, quiet AMD machine).
"""

import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pytest

from robchair.commands import bench_sim
from robchair.commands.bench_sim import WARMUP_S, compiled_during

ROOT = Path(__file__).resolve().parents[2]


def test_compiled_during_names_a_kernel_compiled_inside_and_not_one_compiled_before() -> None:
    @numba.njit
    def twice(x):  # type: ignore[no-untyped-def]
        return 2 * x

    out, names = compiled_during(lambda: twice(np.arange(3)))
    assert out.tolist() == [0, 2, 4]
    assert [n.rsplit(".", 1)[-1] for n in names] == ["twice"]
    out, names = compiled_during(lambda: twice(np.arange(4)))  # same signature: no compile
    assert names == []


def test_a_timed_run_that_compiled_gets_a_warning_naming_the_kernels(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    calls: list[float] = []

    def fake_measure(config: dict[str, Any], scenario: str, duration: float, **kw: Any) -> dict[str, Any]:
        calls.append(duration)
        late = ["scan", "decay_listed"] if config["name"] == "2 cores" and len(calls) == 2 else []
        return {"compiled_in_run": late, "rtf": 1.0, "sim_time_s": duration, "loop_wall_s": duration,
                "kinect_frames": 1, "kinect_ms_per_frame": 1.0, "mapping_ms_per_frame": 1.0,
                "sonar_ms_per_array_reading": 1.0, "physics_ms_per_sim_s": 1.0, "kinect_ms_per_sim_s": 1.0,
                "sonar_ms_per_sim_s": 1.0, "matching_ms_per_frame": None}  # fmt: skip

    monkeypatch.setattr(bench_sim, "measure", fake_measure)
    args = bench_sim.argparse.Namespace(
        scenario="office_corridor", duration=2.0, repeats=1, map="probabilistic"
    )
    monkeypatch.setattr(bench_sim, "write_results", lambda *a, **k: None)
    configs = [c for c in bench_sim.CONFIGS if c["camera_backend"] == "raycast"]
    assert bench_sim._measure_all(args, configs, 2, None, tmp_path) == 0
    assert calls[0] == WARMUP_S  # the untimed warm-up comes first, at its full length
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("warning:")]
    assert lines == [
        "warning: 2 cores: 2 numba kernel(s) compiled inside a timed run "
        "(its RTF includes the compile time): decay_listed, scan"
    ]


@pytest.mark.slow
def test_after_the_warm_up_a_timed_run_compiles_nothing_on_a_cold_cache(tmp_path: Path) -> None:
    code = textwrap.dedent(
        """
        from robchair.commands.bench_sim import CONFIGS, WARMUP_S, measure
        measure(CONFIGS[0], "office_corridor", WARMUP_S)
        m = measure(CONFIGS[0], "office_corridor", 1.0)
        print("LATE", m["compiled_in_run"])
        """
    )
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"), "OPENBLAS_NUM_THREADS": "1"}
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=1200)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert "compiling" in res.stderr  # the cache was cold: kernels compiled (in the warm-up)
    assert [x for x in res.stdout.splitlines() if x.startswith("LATE")] == ["LATE []"]
