"""The loop's first cycle does only a cycle's work: what is done once per run happens before its clock.

On a loaded machine a first cycle that also sets the run up overruns its 100 ms period, and the safety
layer rightly stops the chair for the missed deadline (a WARNING on stderr of ``robchair run``). So the
observers' setup (the bag opened, its static transforms) does not count against cycle 0's period, and
the bag's ``rosbags`` serialisers (tens of milliseconds a message type, made on first use) are made
when the recorder is built, not when the first cycle writes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from robchair.backends import get_backend
from robchair.loop_types import Observer
from robchair.observers.recorder import RunRecorder
from robchair.platform.spec import load_spec
from robchair.run_output import run_to_dir
from robchair.sources import PolicySource


@pytest.fixture(scope="module")
def spec():
    return load_spec()


class SlowSetup(Observer):
    """An observer whose episode start takes ``setup_s`` of the backend's (manual) clock."""

    def __init__(self, setup_s: float) -> None:
        self.setup_s = setup_s

    def episode_start(self, runtime: Any) -> None:
        runtime.backend.clock.advance(self.setup_s)


def test_the_observers_setup_does_not_count_against_the_first_cycles_period(spec) -> None:
    backend = get_backend("emulated", {"timeout_s": 0.1})
    res = run_to_dir(backend, PolicySource(lambda obs: (0.2, 0.0)), 1.0, None, spec=spec,
                     observers=[SlowSetup(0.3)])  # fmt: skip
    assert res.deadline_misses == 0, res.max_overrun_s
    assert [s for s in res.stops if s["reason"] == "deadline_missed"] == []
    assert res.cycles >= 6  # the run drove (0.7 s of its 1 s left after the setup, at 10 Hz)


class SerialisersMade(Observer):
    """Records which message types the run's bag had serialisers for before cycle 0, and at the end."""

    def __init__(self) -> None:
        self.before: set[str] | None = None
        self.after: set[str] | None = None
        self._store: Any = None

    def before_cycle(self, runtime: Any, k: int) -> None:
        if k == 0:
            recorder = next(ob for ob in runtime.observers if isinstance(ob, RunRecorder))
            self._store = recorder.bag.store
            self.before = set(self._store.cache)

    def episode_end(self, runtime: Any, result: Any) -> None:
        self.after = set(self._store.cache)


def test_the_bag_serialisers_are_made_before_the_first_cycle(spec, tmp_path: Path) -> None:
    probe = SerialisersMade()
    backend = get_backend("emulated", {"timeout_s": 0.1})
    res = run_to_dir(backend, PolicySource(lambda obs: (0.2, 0.0)), 1.5, tmp_path / "run", spec=spec,
                     observers=[probe])  # fmt: skip
    assert res.cycles >= 14 and probe.before is not None and probe.after is not None
    # the run wrote odometry, sonar ranges and diagnostics (the bag has them) ...
    written = {"nav_msgs/msg/Odometry", "sensor_msgs/msg/Range", "diagnostic_msgs/msg/DiagnosticArray"}
    assert written <= probe.after
    # ... and none of their serialisers was made while the loop ran
    assert probe.after - probe.before == set()
