"""A sweep's results: one table of every run's parameters and metrics (CSV, JSON) and metric plots."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

#: Prefix of the metric columns (parameters keep their own names).
METRIC_PREFIX = "metrics."


def flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested metrics as dotted scalar keys; lists become their length under ``<key>.count``.

    ``{"map": {"iou": 0.9}, "safety": {"stops": [a, b]}}`` -> ``{"map.iou": 0.9, "safety.stops.count": 2}``.
    """
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flatten(v, key + "."))
        elif isinstance(v, list | tuple):
            out[key + ".count"] = len(v)
        elif v is None or isinstance(v, bool | int | float | str):
            out[key] = v
    return out


def table(
    records: Sequence[Mapping[str, Any]], swept: Sequence[str]
) -> tuple[list[str], list[dict[str, Any]]]:
    """Rows of the results table and its column order (run, status, parameters, then ``metrics.*``)."""
    rows: list[dict[str, Any]] = []
    param_cols: dict[str, None] = dict.fromkeys(swept)
    metric_cols: dict[str, None] = {}
    for rec in records:
        row: dict[str, Any] = {
            "run_id": rec["run_id"],
            "status": rec["status"],
            "error": rec.get("error") or "",
        }
        row["wall_s"] = round(float(rec.get("wall_s", math.nan)), 3)
        for k, v in rec.get("params", {}).items():
            param_cols.setdefault(k, None)
            row[k] = v
        for k, v in flatten(rec.get("metrics", {}), METRIC_PREFIX).items():
            metric_cols.setdefault(k, None)
            row[k] = v
        rows.append(row)
    cols = ["run_id", "status", "error", "wall_s", *param_cols, *metric_cols]
    return cols, rows


def write_tables(out: Path, records: Sequence[Mapping[str, Any]], swept: Sequence[str]) -> tuple[Path, Path]:
    """Write ``results.csv`` and ``results.json`` into ``out``; returns their paths."""
    cols, rows = table(records, swept)
    csv_path, json_path = out / "results.csv", out / "results.json"
    with csv_path.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({c: r.get(c, "") for c in cols})
    summary = {
        "runs": len(rows),
        "ok": sum(r["status"] == "ok" for r in rows),
        "failed": sum(r["status"] == "failed" for r in rows),
        "swept": list(swept),
        "rows": rows,
    }
    json_path.write_text(json.dumps(summary, indent=1), encoding="utf-8")
    return csv_path, json_path


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or v is None or v == "":
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def plot_metrics(
    out: Path, records: Sequence[Mapping[str, Any]], swept: Sequence[str], metrics: Sequence[str]
) -> list[Path]:
    """One PNG per (metric, swept parameter): every successful run as a dot, the mean per value as a line.

    Returns the written paths (``<out>/figures/<metric>__vs__<param>.png``); metrics no run reported are
    skipped.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, rows = table([r for r in records if r["status"] == "ok"], swept)
    written: list[Path] = []
    if not rows:
        return written
    fig_dir = out / "figures"
    for metric in metrics:
        ys = [_number(r.get(METRIC_PREFIX + metric)) for r in rows]
        if all(y is None for y in ys):
            continue
        for param in swept:
            xs_raw = [r.get(param) for r in rows]
            if len({str(x) for x in xs_raw}) < 2:  # nothing varies among the successful runs
                continue
            numeric = all(_number(x) is not None for x in xs_raw)
            labels = sorted({str(x) for x in xs_raw}) if not numeric else []
            pts = [
                (_number(x) if numeric else float(labels.index(str(x))), y)
                for x, y in zip(xs_raw, ys, strict=True)
                if y is not None
            ]
            if not pts:
                continue
            fig, ax = plt.subplots(figsize=(5, 3.5), dpi=100)
            px, py = zip(*pts, strict=True)
            ax.plot(px, py, "o", alpha=0.6, label="run")
            means: dict[float, list[float]] = {}
            for x, y in pts:
                means.setdefault(float(x), []).append(y)  # type: ignore[arg-type]
            mx = sorted(means)
            ax.plot(mx, [sum(means[x]) / len(means[x]) for x in mx], "-", color="C3", label="mean")
            if not numeric:
                ax.set_xticks(range(len(labels)), labels, rotation=20)
            ax.set_xlabel(param)
            ax.set_ylabel(metric)
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8)
            fig.tight_layout()
            fig_dir.mkdir(parents=True, exist_ok=True)
            path = fig_dir / f"{metric}__vs__{param}.png"
            fig.savefig(path)
            plt.close(fig)
            written.append(path)
    return written
