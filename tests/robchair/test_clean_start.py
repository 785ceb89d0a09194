"""A clean emulated run raises no false alarm: start-up is neither a watchdog trip nor a missed deadline.

Independent expectation: nothing stalls in a run on an open floor with no fault injected, so the
controller's watchdog (Roboteq manual: it stops the motors when no command came for ``^RWD`` ms) has
nothing to stop before cycle 0 (the motors were commanded zero when the controller was activated), and
no cycle may overrun its period. Each run is a fresh interpreter, as a user's is: the compiled mapping
kernels load cold, as on a fresh boot. A stall in the middle of a run is still a trip
(tests/robchair/test_runtime.py::test_runtime_stall_lets_the_emulated_controller_watchdog_stop_the_motors).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from robchair.backends import get_backend
from robchair.perception import Perception
from robchair.platform.kinematics import DiffDrive
from robchair.platform.spec import load_spec
from robchair.route import PurePursuit, Route
from robchair.run_output import run_to_dir

ROOT = Path(__file__).resolve().parents[2]


def test_a_clean_emulated_run_has_no_watchdog_trip_and_no_deadline_stop(tmp_path: Path) -> None:
    cfg = tmp_path / "emulated.toml"
    cfg.write_text("[emulated]\nrealtime = false\n", encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "robchair.cli", "run", "--backend", "emulated", "--config", str(cfg),
         "--route", str(ROOT / "examples/routes/short_turn.toml"), "--duration", "4"],
        capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    m = json.loads(proc.stdout)
    assert m["controller"]["watchdog_trips"] == 0
    assert m["deadline_misses"] == 0
    assert m["safety"]["stops"] == []
    assert proc.stderr == ""


class ColdKernels(Perception):
    """A perception stage whose first map insertion costs 0.5 s of the backend's clock, as loading the
    compiled kernels costs seconds of a real-time clock on a cold start (measured: 3-6 s in cycle 0)."""

    def __init__(self, spec, clock) -> None:  # type: ignore[no-untyped-def]
        super().__init__(spec)
        self.clock, self.loaded = clock, False

    def _load(self) -> None:
        if not self.loaded:
            self.clock.advance(0.5)
            self.loaded = True

    def warm_up(self) -> None:
        self._load()
        super().warm_up()

    def add_sonar(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        self._load()
        return super().add_sonar(*args, **kwargs)


def test_setup_work_of_the_perception_stage_is_done_before_the_first_cycle_s_clock_starts() -> None:
    # the 10 Hz loop's cycle 0 may end 125 ms after it began (period + 25 % slack): 0.5 s of loading
    # inside it would be a missed deadline and a deadline_missed stop
    spec = load_spec()
    backend = get_backend("emulated", {}, loop_rate_hz=10.0)
    route = Route.load(ROOT / "examples/routes/short_turn.toml")
    perception = ColdKernels(spec, backend.clock)
    res = run_to_dir(
        backend, PurePursuit(route, DiffDrive(spec)), 1.0, None, spec=spec, perception=perception
    )
    assert perception.loaded
    assert res.deadline_misses == 0
    assert res.stops == []
    assert res.watchdog_trips == 0
