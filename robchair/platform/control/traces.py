"""Step-trace files: read and write the CSV a ``robchair pid --trace`` run fits."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from robchair.platform.control.identification import TraceFit, identify_from_trace
from robchair.platform.control.plant import ControlError


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


# ------------------------------------------------------------------------------------ units and checks

TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
"""Seconds per unit of the time column."""

COMMAND_UNITS = ("rpm", "power", "percent", "fraction")
"""Command column units: RPM-equivalent (the plant's input, +-max RPM), Roboteq power (+-1000),
percent of full scale (+-100), fraction of full scale (+-1)."""

SPEED_UNITS = ("rpm", "rad/s", "counts/s", "counts/sample", "counts")
"""Speed column units: motor-shaft RPM, rad/s, encoder counts per second, counts per sample (the
difference of the counter between rows), cumulative counts (the counter itself)."""

MIN_TIME_STEP_S = 1e-5
MAX_TIME_STEP_S = 0.1
"""Plausible median sample time of a motor step trace, s: a 100 kHz logger to a 10 Hz one. The
identified motors peak about 0.4 s after the step, so a coarser trace cannot show the response."""

SPEED_LIMIT_FACTOR = 1.5
"""A speed beyond this many times the motor's max RPM cannot be a motor speed in RPM."""

GAIN_RANGE = (0.5, 2.0)
"""Plausible DC gain K (speed RPM per command RPM-equivalent) when both columns are in RPM: the
command is defined as the speed it gives in steady state, so K is 1 up to load and friction."""


@dataclass(frozen=True)
class TraceUnits:
    """Declared units of a step trace's columns.

    Attributes:
        time: ``"s"``, ``"ms"`` or ``"us"``.
        command: One of :data:`COMMAND_UNITS`.
        speed: One of :data:`SPEED_UNITS`, or None for RPM *undeclared*: then the speed column is also
            checked for the signs of encoder counts (cumulative, or per sample) and refused if it
            shows them. Declaring ``"rpm"`` turns those guesses off.
    """

    time: str = "s"
    command: str = "rpm"
    speed: str | None = None

    def __post_init__(self) -> None:
        for name, value, allowed in (
            ("time unit", self.time, tuple(TIME_UNITS)),
            ("command unit", self.command, COMMAND_UNITS),
            ("speed unit", self.speed, (None, *SPEED_UNITS)),
        ):
            if value not in allowed:
                raise ControlError(f"trace {name} {value!r}: expected one of {', '.join(map(str, allowed))}")


def normalise_trace(
    t: npt.ArrayLike,
    u: npt.ArrayLike,
    y: npt.ArrayLike,
    units: TraceUnits,
    max_motor_rpm: float,
    counts_per_rev: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Convert a trace to seconds, RPM-equivalent command and motor-shaft RPM, refusing nonsense.

    Args:
        t, u, y: The trace's columns (finite samples), in ``units``.
        units: Declared column units.
        max_motor_rpm: The controller's full scale (``^MXRPM``, the spec's max motor RPM).
        counts_per_rev: Encoder counts per motor-shaft revolution (quadrature x4 PPR, divided by the
            gear ratio when the encoder sits on the wheel).

    Returns:
        (t_s, u_rpm, y_rpm), arrays of the same length (one shorter for cumulative counts, which are
        differentiated between rows).

    Raises:
        ControlError: One line naming the column and what is wrong with it: implausible time steps,
            a command beyond the controller's full scale, a speed column that rises like cumulative
            counts or goes beyond any motor speed.
    """
    t_a, u_a, y_a = (np.asarray(a, dtype=float).ravel() for a in (t, u, y))
    if t_a.size < 2:
        raise ControlError(f"trace has {t_a.size} samples: expected at least 10")
    t_s = t_a * TIME_UNITS[units.time]
    steps = np.diff(t_s)
    if np.any(steps <= 0):
        raise ControlError("trace time column is not strictly increasing")
    dt = float(np.median(steps))
    if not MIN_TIME_STEP_S <= dt <= MAX_TIME_STEP_S:
        hint = "; is it in milliseconds? pass --time-unit ms" if units.time == "s" and dt > 0.1 else ""
        raise ControlError(
            f"trace time column: median step {dt:.6g} s (time unit {units.time!r}) is implausible for a "
            f"motor step trace (expected {MIN_TIME_STEP_S:g}..{MAX_TIME_STEP_S:g} s){hint}"
        )
    full = {"rpm": max_motor_rpm, "power": 1000.0, "percent": 100.0, "fraction": 1.0}[units.command]
    u_peak = float(np.max(np.abs(u_a)))
    if u_peak > full * (1.0 + 1e-9):
        raise ControlError(
            f"trace command column reaches {u_peak:.6g} {units.command}, beyond the controller's full scale "
            f"+-{full:g} {units.command} (+-{max_motor_rpm:g} RPM-equivalent): declare its unit "
            f"(--command-unit {'|'.join(COMMAND_UNITS)})"
        )
    u_rpm = u_a * (max_motor_rpm / full)
    speed = units.speed or "rpm"
    if units.speed is None:
        _refuse_cumulative(t_s, y_a)
    if speed == "counts":
        y_rpm = np.diff(y_a) / steps / counts_per_rev * 60.0
        t_s, u_rpm = t_s[1:], u_rpm[1:]
    elif speed == "counts/sample":
        y_rpm = y_a / dt / counts_per_rev * 60.0
    elif speed == "counts/s":
        y_rpm = y_a / counts_per_rev * 60.0
    elif speed == "rad/s":
        y_rpm = y_a * 60.0 / (2.0 * math.pi)
    else:
        y_rpm = y_a.copy()
    y_peak = float(np.max(np.abs(y_rpm)))
    if y_peak > SPEED_LIMIT_FACTOR * max_motor_rpm:
        raise ControlError(
            f"trace speed column reaches {y_peak:.6g} RPM (read as {speed}), beyond "
            f"{SPEED_LIMIT_FACTOR:g} x the motor's max {max_motor_rpm:g} RPM: declare its unit "
            f"(--speed-unit {'|'.join(SPEED_UNITS)})"
        )
    return t_s, u_rpm, y_rpm


def _refuse_cumulative(t: np.ndarray, y: np.ndarray) -> None:
    """Refuse a speed column that only ever grows (or only shrinks) and is still moving at the end.

    A speed step response settles; a cumulative encoder counter under a constant command keeps rising
    at a constant rate. The test: the column never reverses (beyond 1 % of its span) and the last
    quarter of the trace still holds more than a fifth of its total change.
    """
    span = float(np.max(y) - np.min(y))
    if span <= 0:
        return
    d = np.diff(y)
    monotonic = bool(np.all(d >= -0.01 * span) or np.all(d <= 0.01 * span))
    late = t >= t[0] + 0.75 * (t[-1] - t[0])
    late_change = abs(float(y[-1] - y[np.argmax(late)]))
    if monotonic and late_change > 0.2 * span:
        raise ControlError(
            f"trace speed column is monotonic and still rising at the end ({late_change / span:.0%} of its "
            "change in the last quarter of the trace), like cumulative encoder counts, not a speed that "
            "settles: declare --speed-unit counts, or record until the speed settles"
        )


def check_trace_gain(
    gain: float, y_rpm: np.ndarray, dt: float, units: TraceUnits, counts_per_rev: float
) -> None:
    """Refuse a fitted DC gain that says the command and speed columns are in different units.

    Only applies to undeclared speed units (``units.speed is None``): a declared unit is trusted.

    Raises:
        ControlError: K outside :data:`GAIN_RANGE`, or an integer speed column whose gain is that of
            encoder counts per sample read as RPM.
    """
    if units.speed is not None:
        return
    per_sample = counts_per_rev * dt / 60.0  # counts per sample for 1 RPM
    integral = bool(np.all(np.abs(y_rpm - np.round(y_rpm)) < 1e-9))
    if integral and abs(gain - 1.0) > 0.2 and 0.8 <= gain / per_sample <= 1.25:
        raise ControlError(
            f"trace speed column looks like encoder counts per sample: integers, and read as RPM the DC "
            f"gain is {gain:.3g} where read as counts per {dt * 1e3:.3g} ms sample it is "
            f"{gain / per_sample:.3g}; declare --speed-unit counts/sample (or --speed-unit rpm)"
        )
    lo, hi = GAIN_RANGE
    if not lo <= gain <= hi:
        raise ControlError(
            f"trace fit gives a DC gain of {gain:.4g} speed RPM per command RPM (expected {lo:g}..{hi:g}): "
            "the columns are in different units (a command in percent or power? a speed in counts?); "
            "declare --command-unit and --speed-unit"
        )


def fit_step_trace(
    t: npt.ArrayLike,
    u: npt.ArrayLike,
    y: npt.ArrayLike,
    units: TraceUnits,
    max_motor_rpm: float,
    counts_per_rev: float,
    fit_delay: bool = True,
) -> tuple[TraceFit, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Normalise a trace to s / RPM, refuse nonsense, and fit the plant (:func:`identify_from_trace`).

    Returns:
        (fit, (t_s, u_rpm, y_rpm)): the fit and the normalised trace it was made on.

    Raises:
        ControlError: See :func:`normalise_trace`, :func:`identify_from_trace` and
            :func:`check_trace_gain`.
    """
    t_s, u_rpm, y_rpm = normalise_trace(t, u, y, units, max_motor_rpm, counts_per_rev)
    fit = identify_from_trace(t_s, u_rpm, y_rpm, fit_delay=fit_delay)
    check_trace_gain(fit.plant.gain, y_rpm, float(np.median(np.diff(t_s))), units, counts_per_rev)
    return fit, (t_s, u_rpm, y_rpm)
