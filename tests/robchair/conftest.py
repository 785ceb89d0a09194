"""Fixtures shared by the application's test files: expensive runs made once per test session and only
read by the tests that use them (a test that writes into a run folder makes its own)."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def sim_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The run folder of ``robchair sim --duration 0.3`` on the default scenario, with every default output
    (MCAP bag, pictures, report, recording, time series); read-only for the tests that take it."""
    pytest.importorskip("pybullet")
    from robchair.cli import main

    out = tmp_path_factory.mktemp("sim") / "run"
    assert main(["sim", "--duration", "0.3", "--out", str(out), "--no-progress"]) == 0
    return out
