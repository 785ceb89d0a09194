"""Scenario sweeps on Ray: each run of the scenario harness is one Ray task in its own worker process.

Without an address a local Ray instance is started (``ray.init()``); with ``address="auto"`` or
``"ray://host:port"`` the same code joins a cluster. A failed run is recorded with its error and does not
stop the sweep; ``resume`` skips the runs already complete. Results: ``results.csv`` / ``results.json``
(every run's parameters and flattened ``metrics.json``) and ``figures/`` (metrics vs swept parameters).
"""

from robchair.sweep.executor import SweepResult, run_sweep
from robchair.sweep.spec import RunPoint, SweepError, SweepSpec, load_sweep, parse_sweep

__all__ = ["RunPoint", "SweepError", "SweepResult", "SweepSpec", "load_sweep", "parse_sweep", "run_sweep"]
