"""Sweep files: a grid or a list of scenario-harness runs, read from TOML and expanded into run points.

A sweep file has up to four tables::

    [sweep]                      # optional: name and values shared by every run
    name = "cell-size-study"
    scenario = "office_corridor"
    duration = 5.0

    [grid]                       # the Cartesian product of these lists
    seed = [0, 1, 2]
    "mapping.cell_size" = [0.05, 0.1]

    [[runs]]                     # and/or explicit runs (each merged over [sweep])
    scenario = "office_tour"
    seed = 3

    [report]                     # optional: metrics to plot against every swept parameter
    metrics = ["real_time_factor", "odometry_drift.final_position_error_m"]

Run parameters are the harness's keys (:data:`robchair.sweep.harness.PARAMETERS`); a run with an
unknown key is refused before anything starts, with the file, the key and the allowed keys named.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from robchair.platform.errors import ConfigError

Scalar = bool | int | float | str

TABLES = ("sweep", "grid", "runs", "report")
DEFAULT_METRICS = (
    "real_time_factor",
    "odometry_drift.final_position_error_m",
    "map.odometry_map_vs_scene.precision",
    "safety.stop_count",
)


class SweepError(ConfigError):
    """A sweep file is invalid; the message names the file, the key and what was expected."""


@dataclass(frozen=True)
class RunPoint:
    """One run of a sweep.

    Attributes:
        run_id: Folder name of the run, stable for the same parameters whatever their order in the file:
            a readable slug of the swept values and the first 8 hex digits of the parameters' SHA-1.
        params: Every harness parameter of the run (shared values merged with the swept ones).
        swept: The names of the parameters that vary across the sweep.
    """

    run_id: str
    params: dict[str, Scalar]
    swept: tuple[str, ...] = ()


@dataclass(frozen=True)
class SweepSpec:
    """A parsed sweep file.

    Attributes:
        name: Sweep name (default: the file's stem).
        points: The runs, in file order (grid first, then the explicit runs).
        metrics: Dotted metric keys to plot against every swept parameter.
        source: The file it was read from.
    """

    name: str
    points: tuple[RunPoint, ...]
    metrics: tuple[str, ...] = DEFAULT_METRICS
    source: str = "<dict>"
    swept: tuple[str, ...] = field(default=())


def _check_scalar(value: Any, where: str) -> Scalar:
    if isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise SweepError(f"{where}: {value!r} is not a finite number")
        return value
    raise SweepError(f"{where}: {value!r} is a {type(value).__name__}; expected a number, a string or a bool")


def _check_keys(params: Mapping[str, Any], allowed: Sequence[str], where: str) -> None:
    for key in params:
        if key not in allowed:
            raise SweepError(f"{where}: unknown parameter {key!r}; allowed: {', '.join(allowed)}")


def run_id_of(params: Mapping[str, Scalar], swept: Sequence[str]) -> str:
    """Stable folder name of a run: slug of the swept values + 8 hex digits of the parameters' hash."""
    digest = hashlib.sha1(json.dumps(dict(params), sort_keys=True).encode()).hexdigest()[:8]
    parts = [f"{k.rsplit('.', 1)[-1]}={params[k]}" for k in sorted(swept) if k in params]
    slug = re.sub(r"[^A-Za-z0-9=._-]+", "-", "_".join(parts))[:80].strip("-_")
    return f"{slug}-{digest}" if slug else digest


def parse_sweep(data: Mapping[str, Any], allowed: Sequence[str], source: str = "<dict>") -> SweepSpec:
    """Expand a sweep mapping (the TOML's tables) into run points.

    Args:
        data: The TOML document as a mapping.
        allowed: The run parameters the harness accepts.
        source: Name of the file, for messages.

    Raises:
        SweepError: Unknown table or parameter, a non-list grid entry, an empty sweep, duplicate runs.
    """
    for key in data:
        if key not in TABLES:
            raise SweepError(f"{source}: unknown table [{key}]; allowed: {', '.join(TABLES)}")
    shared = dict(data.get("sweep", {}))
    name = str(shared.pop("name", Path(source).stem))
    _check_keys(shared, allowed, f"{source} [sweep]")
    base = {k: _check_scalar(v, f"{source} [sweep] {k}") for k, v in shared.items()}

    grid = data.get("grid", {})
    if not isinstance(grid, Mapping):
        raise SweepError(f"{source}: [grid] must be a table of lists")
    _check_keys(grid, allowed, f"{source} [grid]")
    axes: list[tuple[str, list[Scalar]]] = []
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise SweepError(f"{source} [grid] {key}: expected a non-empty list of values, got {values!r}")
        axes.append((key, [_check_scalar(v, f"{source} [grid] {key}") for v in values]))

    raw_points: list[dict[str, Scalar]] = []
    if axes:
        for combo in itertools.product(*(vals for _, vals in axes)):
            raw_points.append({**base, **dict(zip((k for k, _ in axes), combo, strict=True))})
    runs = data.get("runs", [])
    if not isinstance(runs, list):
        raise SweepError(f"{source}: [[runs]] must be an array of tables")
    for i, run in enumerate(runs):
        where = f"{source} [[runs]] #{i + 1}"
        if not isinstance(run, Mapping):
            raise SweepError(f"{where}: expected a table, got {run!r}")
        _check_keys(run, allowed, where)
        raw_points.append({**base, **{k: _check_scalar(v, f"{where} {k}") for k, v in run.items()}})
    if not raw_points:
        raise SweepError(f"{source}: the sweep has no runs; give a [grid] of lists or [[runs]] tables")

    swept = tuple(
        k for k in dict.fromkeys(k for p in raw_points for k in p) if len({p.get(k) for p in raw_points}) > 1
    )
    points = []
    seen: dict[str, int] = {}
    for i, p in enumerate(raw_points):
        rid = run_id_of(p, swept)
        if rid in seen:
            raise SweepError(f"{source}: runs #{seen[rid] + 1} and #{i + 1} have the same parameters {p}")
        seen[rid] = i
        points.append(RunPoint(rid, p, swept))

    report = data.get("report", {})
    metrics = report.get("metrics", list(DEFAULT_METRICS)) if isinstance(report, Mapping) else None
    if not isinstance(metrics, list) or not all(isinstance(m, str) for m in metrics):
        raise SweepError(
            f"{source} [report] metrics: expected a list of dotted metric names, got {metrics!r}"
        )
    return SweepSpec(name=name, points=tuple(points), metrics=tuple(metrics), source=source, swept=swept)


def load_sweep(path: Path | str, allowed: Sequence[str]) -> SweepSpec:
    """Read and expand a sweep TOML file (see the module docstring for its tables).

    Raises:
        SweepError: The file is missing, not TOML, or invalid.
    """
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SweepError(f"{p}: no such sweep file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SweepError(f"{p}: not a valid TOML file ({exc})") from None
    return parse_sweep(data, allowed, source=str(p))
