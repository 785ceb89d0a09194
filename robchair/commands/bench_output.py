"""What every ``robchair bench`` command shares: its output folder, and what it writes last (the
machine's load, then its JSON results).

Each bench writes ``bench_<name>.json`` into ``--out``, a folder under the rules of
:mod:`robchair.outdir` (default a new ``runs/bench-<name>-<UTC time>/``; ``--overwrite`` to write into
an earlier one). The folder is checked before anything is measured.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

from robchair.outdir import OVERWRITE_HELP, OutputDir, check_output_dir, timestamped_dir


def add_out_arguments(parser: argparse.ArgumentParser, name: str, file: str | None = None) -> None:
    """Add ``--out`` (the results folder) and ``--overwrite`` to a bench's parser.

    Args:
        parser: the bench's parser.
        name: the bench's name (in the default folder's name).
        file: the JSON file the bench writes there (default ``bench_<name>.json``).
    """
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help=f"folder for {file or f'bench_{name}.json'} (default runs/bench-{name}-<UTC time>, a new one)",
    )
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


def results_dir(args: argparse.Namespace, name: str) -> OutputDir:
    """The bench's checked output folder (``args.out`` is set to the default when it was not given).

    Raises:
        OutputDirError: the folder may not be written (see :mod:`robchair.outdir`).
    """
    if args.out is None:
        args.out = timestamped_dir(f"bench-{name}")
    return check_output_dir(args.out, overwrite=args.overwrite)


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


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; the platform's processor string elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return " ".join(line.split(":", 1)[1].split())
    except OSError:
        pass
    return platform.processor() or platform.machine()


def write_results(
    out: OutputDir,
    name: str,
    result: dict[str, Any],
    load_before: tuple[float, float, float],
    load_after: tuple[float, float, float],
) -> Path:
    """Print the load average, then write ``result`` with the machine's state to ``bench_<name>.json``.

    Wall-clock figures depend on what else the machine runs, so the file records the load average
    (``os.getloadavg()``) taken before and after the measurement, the CPU count and model and the UTC
    time (``robchair bench table`` prints them beside each figure). The
    folder appears whole or not at all (:meth:`robchair.outdir.OutputDir.stage`).

    Args:
        out: the checked output folder (:func:`results_dir`).
        name: the bench's name.
        result: the measured figures (JSON-serialisable).
        load_before: ``os.getloadavg()`` before the measurement.
        load_after: ``os.getloadavg()`` after it.

    Returns:
        The path written.
    """
    print(f"load average before/after: {load_before[0]:.2f} / {load_after[0]:.2f} on {os.cpu_count()} CPUs")
    record = {
        **result,
        "load_average_before": load_before,
        "load_average_after": load_after,
        "cpus": os.cpu_count(),
        "cpu_model": cpu_model(),
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    with out.stage() as staging:
        (staging / f"bench_{name}.json").write_text(json.dumps(record, indent=2), encoding="utf-8")
    path = out.given / f"bench_{name}.json"
    print(f"wrote {path}")
    return path
