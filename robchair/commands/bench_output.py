"""What every ``robchair bench`` command writes last: the machine's load, then its JSON results."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any


def verdict(ok: bool) -> str:
    """The word printed beside a target: ``"met"`` or ``"missed"``."""
    return "met" if ok else "missed"


def median_of(runs: list[dict[str, Any]]) -> dict[str, float]:
    """Median of every numeric field over ``runs``; a field that is None or absent in a run is taken
    over the runs that have it, and left out when none has it."""
    import statistics

    keys = dict.fromkeys(k for r in runs for k in r)
    out: dict[str, float] = {}
    for k in keys:
        vals = [r[k] for r in runs if isinstance(r.get(k), int | float) and not isinstance(r.get(k), bool)]
        if vals:
            out[k] = float(statistics.median(vals))
    return out


def write_results(
    out: str | Path,
    result: dict[str, Any],
    load_before: tuple[float, float, float],
    load_after: tuple[float, float, float],
) -> Path:
    """Print the load average, then write ``result`` with the machine's state to ``out`` as JSON.

    Wall-clock figures depend on what else the machine runs, so the file records the load average
    (``os.getloadavg()``) taken before and after the measurement, the CPU count and the UTC time. The
    file appears whole or not at all (written beside it, then renamed).

    Args:
        out: the JSON file to write; its folder is created.
        result: the measured figures (JSON-serialisable).
        load_before: ``os.getloadavg()`` before the measurement.
        load_after: ``os.getloadavg()`` after it.

    Returns:
        The path written.
    """
    print(f"load average before/after: {load_before[0]:.2f} / {load_after[0]:.2f} on {os.cpu_count()} CPUs")
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {
        **result,
        "load_average_before": load_before,
        "load_average_after": load_after,
        "cpus": os.cpu_count(),
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    tmp = path.with_suffix(".json.partial")
    tmp.write_text(json.dumps(record, indent=2))
    tmp.replace(path)
    print(f"wrote {path}")
    return path
