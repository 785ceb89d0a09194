"""One sweep run: the scenario harness called with a run point's parameters, its outcome as a record.

This is the only place that knows how a sweep parameter reaches the harness, so the sweep file's keys
(:data:`PARAMETERS`) are checked before a single run starts.
"""

from __future__ import annotations

import json
import os
import time
import traceback
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

#: Sweep parameter -> keyword of :func:`robchair.scenario.run_scenario`.
PARAMETERS: dict[str, str] = {
    "scenario": "scenario",
    "seed": "seed",
    "sensor": "sensor",
    "duration": "duration",
    "camera_backend": "camera_backend",
    "sonar_hz": "sonar_hz",
    "pictures": "pictures",
    "bag": "write_bag",
    "bag_storage": "bag_storage",
    "safety": "safety",
}

#: Limits of the safety layer a sweep may set as ``"safety.<field>"``
#: (:class:`robchair.platform.safety.SafetyLimits`).
SAFETY_FIELDS: tuple[str, ...] = (
    "max_speed",
    "max_yaw_rate",
    "max_accel",
    "max_yaw_accel",
    "max_wheel_accel",
    "brake_decel",
    "reaction_time_s",
    "margin_m",
    "stale_after_s",
)


def allowed_parameters() -> tuple[str, ...]:
    """Every key a sweep file may set: the harness keywords and the ``safety.<field>`` limits."""
    return (*PARAMETERS, *(f"safety.{f}" for f in SAFETY_FIELDS))


#: Environment of every worker: numeric libraries on one thread each, so N runs fit N cores.
THREAD_ENV: dict[str, str] = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
    "MPLBACKEND": "Agg",
}


def pin_threads() -> None:
    """Pin this process's numeric libraries to one thread (call before they are imported)."""
    for k, v in THREAD_ENV.items():
        os.environ[k] = v


def run_harness(params: Mapping[str, Any], run_dir: Path) -> dict[str, Any]:
    """Run the scenario harness once; returns its ``metrics.json`` contents.

    Args:
        params: Sweep parameters (keys of :data:`PARAMETERS`).
        run_dir: The run folder to create.

    Raises:
        Whatever the harness raises for this run (recorded by :func:`execute`).
    """
    from robchair.scenario import run_scenario

    kwargs = {PARAMETERS[k]: v for k, v in params.items() if k in PARAMETERS}
    limits = {k.split(".", 1)[1]: float(v) for k, v in params.items() if k.startswith("safety.")}
    if limits:
        from robchair.platform.safety import SafetyLimits
        from robchair.platform.spec import load_spec

        kwargs["safety_limits"] = SafetyLimits.from_spec(load_spec(), **limits)
    scenario = kwargs.pop("scenario", "office_corridor")
    res = run_scenario(scenario, out_dir=run_dir, progress=False, raycast_threads=1, **kwargs)
    return res.metrics()


def execute(
    run_id: str,
    params: Mapping[str, Any],
    out: Path | str,
    runner: Callable[[Mapping[str, Any], Path], dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Run one point and write its record; never raises for a failed run.

    The record (also written to ``<out>/records/<run_id>.json``) has ``run_id``, ``status``
    (``"ok"`` or ``"failed"``), ``error`` (one line, or None), ``traceback``, ``wall_s``, ``params``,
    ``metrics`` (the run's ``metrics.json``, empty on failure), ``host`` and ``pid``.

    Args:
        run_id: The run's folder name.
        params: Its parameters.
        out: The sweep folder (the run goes to ``<out>/runs/<run_id>``).
        runner: The function that performs the run (default :func:`run_harness`).
    """
    pin_threads()
    out = Path(out)
    run_dir = out / "runs" / run_id
    if run_dir.exists():  # a failed earlier attempt left a partial folder: keep it aside, never delete
        n = 1
        while (aside := run_dir.with_name(f"{run_id}.attempt-{n}")).exists():
            n += 1
        run_dir.rename(aside)
    t0 = time.perf_counter()
    record: dict[str, Any] = {
        "run_id": run_id,
        "params": dict(params),
        "host": os.uname().nodename,
        "pid": os.getpid(),
    }
    try:
        metrics = (runner or run_harness)(params, run_dir)
        record.update(status="ok", error=None, traceback=None, metrics=metrics)
    except Exception as exc:  # a failed run is data, not a reason to stop the sweep
        line = f"{type(exc).__name__}: {exc}".splitlines()[0]
        record.update(status="failed", error=line, traceback=traceback.format_exc(), metrics={})
    record["wall_s"] = time.perf_counter() - t0
    write_record(out, record)
    return record


def write_record(out: Path, record: Mapping[str, Any]) -> None:
    """Write a run record atomically to ``<out>/records/<run_id>.json``."""
    rec_dir = out / "records"
    rec_dir.mkdir(parents=True, exist_ok=True)
    tmp = rec_dir / f".{record['run_id']}.json.tmp"
    tmp.write_text(json.dumps(record, indent=1, default=_json_default), encoding="utf-8")
    tmp.replace(rec_dir / f"{record['run_id']}.json")


def read_record(out: Path, run_id: str) -> dict[str, Any] | None:
    """The record of a run, or None if it has none (or an unreadable one)."""
    try:
        data = json.loads((out / "records" / f"{run_id}.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _json_default(o: Any) -> Any:
    if hasattr(o, "tolist"):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)
