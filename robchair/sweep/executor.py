"""Run a sweep's points as Ray tasks, with resume, a progress bar and the aggregated results."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from robchair.sweep.harness import THREAD_ENV, execute, read_record, write_record
from robchair.sweep.results import plot_metrics, write_tables
from robchair.sweep.spec import SweepError, SweepSpec

log = logging.getLogger(__name__)

MARKER = ".robchair-sweep"
#: Resources one harness run declares, so Ray packs runs onto cores and memory correctly.
RUN_CPUS = 1.0
RUN_MEMORY_BYTES = 2 << 30  # peak RSS of a Kinect 512x424 run with pictures is about 1.1 GiB


@dataclass
class SweepResult:
    """Outcome of :func:`run_sweep`.

    Attributes:
        out: The sweep folder.
        records: One record per run point, in the sweep's order (see :func:`robchair.sweep.harness.execute`).
        skipped: Run ids already complete and not run again (``resume``).
        wall_s: Wall time of the runs (Ray start-up excluded).
        files: Tables and figures written.
    """

    out: Path
    records: list[dict[str, Any]]
    skipped: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    files: list[Path] = field(default_factory=list)

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.records if r["status"] != "ok"]


@contextlib.contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None) -> Iterator[Any]:
    """A Ray connection: a local instance (``address=None``) or a cluster (``"auto"``, ``"ray://h:p"``).

    An already initialised Ray is reused and left running; one started here is shut down at the end.
    Every worker gets :data:`robchair.sweep.harness.THREAD_ENV` (numeric libraries on one thread): on a
    cluster as the job's ``runtime_env``; a local instance's processes inherit it from this process's
    environment, where it is set only while Ray starts (the driver's own is left as it was). A
    ``runtime_env`` would make the local instance start a runtime-env agent and new workers for it
    instead of using the ones it started beforehand: ~3 s of wall time a session.

    Raises:
        SweepError: Ray is not installed, or the cluster cannot be reached.
    """
    try:
        import ray
    except ImportError as exc:  # pragma: no cover - ray is a dependency of the install
        raise SweepError(f"sweeps need Ray ({exc}); install it with pip install 'ray>=2.9'") from None
    if ray.is_initialized():
        yield ray
        return
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
    if address is None:
        kwargs["num_cpus"] = num_cpus
    else:
        kwargs["address"] = address
        kwargs["runtime_env"] = {"env_vars": dict(THREAD_ENV)}
    try:
        with _environment(THREAD_ENV if address is None else {}):
            ray.init(**kwargs)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise SweepError(f"cannot start or join Ray at {address or 'a local instance'}: {exc}") from None
    try:
        yield ray
    finally:
        ray.shutdown()


@contextlib.contextmanager
def _environment(values: Mapping[str, str]) -> Iterator[None]:
    """``os.environ`` with ``values`` set inside the block, as it was again after it."""
    before = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def ordered_tasks(ray: Any, fn: Callable[..., Any], calls: list[tuple[Any, ...]], desc: str) -> Iterator[Any]:
    """``fn(*call)`` for every call as a Ray task (one CPU each, no retries), with a progress bar;
    the results are yielded in the order of ``calls`` once all have finished.

    ``fn`` must be importable in the workers (a module-level function)."""
    from tqdm import tqdm

    task = ray.remote(num_cpus=1, max_retries=0)(fn)
    refs = [task.remote(*call) for call in calls]
    pending = set(refs)
    with tqdm(total=len(refs), desc=f"{desc} (ray)", unit="ep") as bar:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            pending.difference_update(ready)
            bar.update(len(ready))
    yield from ray.get(refs)


#: What a sweep writes into its folder; ``overwrite`` replaces these and nothing else.
SWEEP_ENTRIES = (MARKER, "sweep.json", "runs", "records", "results.csv", "results.json", "figures")


def prepare_out(out: Path, spec: SweepSpec, resume: bool, overwrite: bool = False) -> None:
    """Create or re-open a sweep folder without ever destroying data that is not the sweep's own.

    A new or empty folder is taken; a folder holding this project's sweep marker is re-opened only with
    ``resume``; any other non-empty folder is refused. With ``overwrite`` (and no ``resume``) an earlier
    sweep's entries (:data:`SWEEP_ENTRIES`) are removed first and other files are kept.

    Raises:
        SweepError: The folder cannot be used (the message says why and what to do).
    """
    marker = out / MARKER
    if out.exists() and not out.is_dir():
        raise SweepError(f"--out {out}: exists and is not a folder")
    if overwrite and not resume and out.is_dir():
        for name in SWEEP_ENTRIES:
            entry = out / name
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            elif os.path.lexists(entry):
                entry.unlink()
    if marker.exists():
        if not resume:
            raise SweepError(
                f"--out {out}: holds an earlier sweep; add --resume to continue it, --overwrite to "
                "replace it, or choose a new --out"
            )
    elif out.exists() and any(out.iterdir()) and not overwrite:
        raise SweepError(
            f"--out {out}: is a non-empty folder this project did not create; choose a new --out, or "
            "pass --overwrite to write into it (other files are kept)"
        )
    elif resume:
        raise SweepError(f"--out {out}: holds no sweep to resume")
    out.mkdir(parents=True, exist_ok=True)
    marker.write_text(json.dumps({"name": spec.name, "source": spec.source}), encoding="utf-8")
    (out / "sweep.json").write_text(
        json.dumps(
            {
                "name": spec.name,
                "source": spec.source,
                "swept": list(spec.swept),
                "points": [{"run_id": p.run_id, "params": p.params} for p in spec.points],
            },
            indent=1,
        ),
        encoding="utf-8",
    )


def _complete(out: Path, run_id: str) -> dict[str, Any] | None:
    rec = read_record(out, run_id)
    if rec is not None and rec.get("status") == "ok" and (out / "runs" / run_id / "metrics.json").is_file():
        return rec
    return None


def run_sweep(
    spec: SweepSpec,
    out: Path | str,
    *,
    address: str | None = None,
    num_cpus: int | None = None,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    runner: Callable[[Mapping[str, Any], Path], dict[str, Any]] | None = None,
    memory_bytes: int = RUN_MEMORY_BYTES,
) -> SweepResult:
    """Run every point of a sweep as a Ray task and aggregate the results.

    Args:
        spec: The sweep (:func:`robchair.sweep.load_sweep`).
        out: The sweep folder: ``runs/<run_id>/`` (each run's folder), ``records/<run_id>.json``,
            ``results.csv``, ``results.json``, ``figures/``.
        address: Ray address (None: start a local instance; ``"auto"`` or ``"ray://host:port"``: a cluster).
        num_cpus: CPUs of the local instance (None: all). Each run takes one.
        resume: Skip the runs already complete in ``out``.
        overwrite: Replace an earlier sweep in ``out`` (see :func:`prepare_out`).
        progress: Show a progress bar (done / failed / running) on stderr.
        runner: The function performing one run (default: the scenario harness).
        memory_bytes: Memory each run declares to Ray's scheduler.

    Raises:
        SweepError: ``out`` cannot be used, or Ray cannot be started or reached. Failed runs do not raise.
    """
    out = Path(out).resolve()
    prepare_out(out, spec, resume, overwrite)
    records: dict[str, dict[str, Any]] = {}
    skipped = []
    todo = []
    for p in spec.points:
        done = _complete(out, p.run_id) if resume else None
        if done is not None:
            records[p.run_id] = done
            skipped.append(p.run_id)
        else:
            todo.append(p)
    t0 = time.perf_counter()
    if todo:
        with ray_session(address, num_cpus) as ray:
            task = ray.remote(num_cpus=RUN_CPUS, memory=memory_bytes, max_retries=0)(execute)
            pending = {task.remote(p.run_id, p.params, str(out), runner): p for p in todo}
            capacity = max(1, int(ray.cluster_resources().get("CPU", 1) // RUN_CPUS))
            bar = _progress(len(spec.points), len(skipped), progress)
            n_failed = 0
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
                for ref in ready:
                    point = pending.pop(ref)
                    try:
                        rec = ray.get(ref)
                    except Exception as exc:  # the worker died (out of memory, a crash): record it
                        rec = {
                            "run_id": point.run_id,
                            "params": point.params,
                            "status": "failed",
                            "error": f"{type(exc).__name__}: {exc}".splitlines()[0],
                            "traceback": None,
                            "metrics": {},
                            "wall_s": float("nan"),
                        }
                        write_record(out, rec)
                    records[point.run_id] = rec
                    n_failed += rec["status"] != "ok"
                    if bar is not None:
                        bar.update(1)
                if bar is not None:
                    bar.set_postfix(failed=n_failed, running=min(len(pending), capacity), refresh=True)
            if bar is not None:
                bar.close()
    wall = time.perf_counter() - t0
    ordered = [records[p.run_id] for p in spec.points]
    files = list(write_tables(out, ordered, spec.swept))
    files += plot_metrics(out, ordered, spec.swept, spec.metrics)
    return SweepResult(out=out, records=ordered, skipped=skipped, wall_s=wall, files=files)


def _progress(total: int, initial: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="run", desc="sweep", dynamic_ncols=True)
