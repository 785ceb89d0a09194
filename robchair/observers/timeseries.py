"""The run's time series: one row per cycle in ``timeseries.csv`` (the schema :mod:`robchair.report` reads).

Columns (SI units unless the name says otherwise; an empty cell means "no value this cycle"):

==================  ============================================================================
``t_s``             cycle time since the start of the run, s
``v_req``           forward speed the command source asked for, m/s
``w_req``           yaw rate the command source asked for, rad/s
``v_cmd``           forward speed written to the motors after the safety layer, m/s
``w_cmd``           yaw rate written to the motors after the safety layer, rad/s
``left_rpm_cmd``    left motor set point, motor-shaft RPM
``right_rpm_cmd``   right motor set point, motor-shaft RPM
``left_rpm_meas``   left motor speed the controller reported at the start of the cycle, RPM
``right_rpm_meas``  right motor speed the controller reported at the start of the cycle, RPM
``mapping_ms``      wall time of the depth frames mapped since the previous row, ms (summed)
``intervened``      1 when the safety layer changed the command, else 0
==================  ============================================================================

The same file is written for every backend.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import IO, Any

from robchair.loop_types import CycleResult, LoopView, Observer, RunResult

COLUMNS = (
    "t_s",
    "v_req",
    "w_req",
    "v_cmd",
    "w_cmd",
    "left_rpm_cmd",
    "right_rpm_cmd",
    "left_rpm_meas",
    "right_rpm_meas",
    "mapping_ms",
    "intervened",
)


class TimeseriesWriter(Observer):
    """Writes one :data:`COLUMNS` row per cycle to a CSV file.

    Args:
        path: the CSV file to create.
    """

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self._file: IO[str] | None = None
        self._writer: Any = None
        self._maps_seen = 0
        self.rows = 0

    def episode_start(self, runtime: LoopView) -> None:
        self._file = self.path.open("w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._file)
        self._writer.writerow(COLUMNS)
        self._maps_seen = len(runtime.perception.map_ms)

    def after_cycle(self, runtime: LoopView, cycle: CycleResult) -> None:
        if self._writer is None:
            return
        left, right = runtime.drive.motor_rpm(cycle.decision.v, cycle.decision.w)
        if cycle.fault is not None:
            left, right = 0.0, 0.0
        meas = cycle.motor_state.speed_rpm if cycle.motor_state is not None else ("", "")
        map_ms = runtime.perception.map_ms
        new = map_ms[self._maps_seen :]
        self._maps_seen = len(map_ms)
        self._writer.writerow(
            (
                f"{(cycle.stamp_ns - runtime.t0_ns) / 1e9:.4f}",
                f"{cycle.command.v:.5g}",
                f"{cycle.command.w:.5g}",
                f"{cycle.decision.v:.5g}",
                f"{cycle.decision.w:.5g}",
                f"{left:.5g}",
                f"{right:.5g}",
                *(f"{m:.5g}" if m != "" else "" for m in meas),
                f"{sum(new):.4g}" if new else "",
                int(cycle.intervened),
            )
        )
        self.rows += 1

    def episode_end(self, runtime: LoopView, result: RunResult) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
