"""Step-trace files: read and write the CSV a ``robchair pid --trace`` run fits."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

from robchair.control.plant import ControlError


def read_step_trace(path: Path | str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Read a step trace CSV with a header naming time, command and speed columns.

    Accepted header names (case-insensitive): time: ``time``, ``t``, ``time_s``; command: ``command``,
    ``u``, ``command_rpm``, ``setpoint``; speed: ``speed``, ``y``, ``speed_rpm``, ``rpm``. Rows with a
    non-numeric or non-finite value are dropped and counted.

    Returns:
        (t, u, y, n_dropped).

    Raises:
        ControlError: The file has no usable header.
        OSError: The file cannot be read.
    """
    aliases = {
        "t": ("time", "t", "time_s"),
        "u": ("command", "u", "command_rpm", "setpoint", "setpoint_rpm"),
        "y": ("speed", "y", "speed_rpm", "rpm"),
    }
    p = Path(path)
    with p.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ControlError(f"trace file {str(p)!r} is empty: expected a header time,command,speed")
    header = [h.strip().lower() for h in rows[0]]
    cols = {}
    for key, names in aliases.items():
        hits = [i for i, h in enumerate(header) if h in names]
        if not hits:
            raise ControlError(
                f"trace file {str(p)!r}: header {rows[0]!r} has no {names[0]!r} column (accepted: {names})"
            )
        cols[key] = hits[0]
    out: dict[str, list[float]] = {"t": [], "u": [], "y": []}
    dropped = 0
    for row in rows[1:]:
        if not row or all(not c.strip() for c in row):
            continue
        try:
            vals = {k: float(row[i]) for k, i in cols.items()}
        except (ValueError, IndexError):
            dropped += 1
            continue
        if not all(math.isfinite(v) for v in vals.values()):
            dropped += 1
            continue
        for k, v in vals.items():
            out[k].append(v)
    return np.array(out["t"]), np.array(out["u"]), np.array(out["y"]), dropped


def write_step_trace(path: Path | str, t: npt.ArrayLike, u: npt.ArrayLike, y: npt.ArrayLike) -> None:
    """Write a step trace CSV (header ``time,command,speed``) that :func:`read_step_trace` reads back."""
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time", "command", "speed"])
        for row in zip(np.asarray(t, float), np.asarray(u, float), np.asarray(y, float)):
            w.writerow([repr(float(v)) for v in row])
