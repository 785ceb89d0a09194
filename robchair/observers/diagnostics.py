"""Motor-controller diagnostics at a low rate: into ``metrics.json`` and the bag as ``/diagnostics``.

A controller that offers ``read_diagnostics()`` (the Roboteq driver: retries, discarded lines, watchdog
trips, battery and internal volts, motor amps, temperatures, fault and status flags; five serial
transactions) is polled every ``period_s`` of the run's clock, not every cycle, so it does not starve
the control loop. Each sample is written to the run's bag as ``diagnostic_msgs/DiagnosticArray`` (one
``DiagnosticStatus`` named ``motor_controller``: OK, WARN when a status flag is set, ERROR when a fault
flag is set or the driver is in its error state) and the last one goes into ``metrics.json`` under
``controller.diagnostics``. A controller without diagnostics (the simulated one) gives
``controller.diagnostics = null``; its bag still gets ``/diagnostics`` at the same rate (an OK status
saying so, with the watchdog trips it counts), so every backend's bag has the same topics. A failing
diagnostics read raises, as any sensor does, and the runtime stops the chair.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from robchair.loop_types import CycleResult, LoopView, Observer, RunResult

if TYPE_CHECKING:
    from robchair.observers.bag_writer import RosMessages
    from robchair.observers.recorder import RunRecorder

TOPIC = "/diagnostics"
OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels


class DiagnosticsObserver(Observer):
    """Polls ``backend.motors.read_diagnostics()`` every ``period_s`` and records the samples.

    Args:
        period_s: time between samples on the run's clock, s (1 Hz by default).
        recorder: the run's recorder, whose bag gets ``/diagnostics`` (None: metrics only).
    """

    def __init__(self, period_s: float = 1.0, recorder: RunRecorder | None = None) -> None:
        self.period_ns = round(float(period_s) * 1e9)
        self.recorder = recorder
        if recorder is not None:  # its serialiser made now, before the loop's clock starts
            recorder.bag.precompile(["diagnostic_msgs/msg/DiagnosticArray"])
        self.samples = 0
        self.last: Any = None
        self._next_ns: int | None = None
        self._read: Any = None
        #: (stamp ns, sample or None, watchdog trips) of the last record (what the bag got)
        self.last_record: tuple[int, Any, int] | None = None

    def episode_start(self, runtime: LoopView) -> None:
        self._read = getattr(runtime.backend.motors, "read_diagnostics", None)
        self._next_ns = runtime.t0_ns

    def after_cycle(self, runtime: LoopView, cycle: CycleResult) -> None:
        if self._next_ns is None or cycle.stamp_ns < self._next_ns:
            return
        if cycle.fault is not None:  # the driver already failed and stopped: the fault is the report
            return
        self._next_ns = cycle.stamp_ns + self.period_ns
        sample = None
        if self._read is not None:
            sample = self._read()
            self.last = sample
            self.samples += 1
        trips = 0 if sample is not None else int(getattr(runtime.backend.motors, "watchdog_trips", 0) or 0)
        self.last_record = (cycle.stamp_ns, sample, trips)
        if self.recorder is not None:
            write_diagnostics(self.recorder.bag, cycle.stamp_ns, sample, trips)

    def episode_end(self, runtime: LoopView, result: RunResult) -> None:
        diag = None
        if self.last is not None:
            diag = {**asdict(self.last), "samples": self.samples}
        result.extra["controller"] = {**result.extra.get("controller", {}), "diagnostics": diag}


def write_diagnostics(out: RosMessages, stamp_ns: int, sample: Any, watchdog_trips: int = 0) -> None:
    """``/diagnostics``: one ``motor_controller`` status of a diagnostics sample, or (``sample`` None) the
    OK status of a controller without diagnostics, with the watchdog trips it counts."""
    t = out.t
    if sample is None:
        status = t["diagnostic_msgs/msg/DiagnosticStatus"](
            level=OK,
            name="motor_controller",
            message="no hardware diagnostics (simulated controller)",
            hardware_id="simulated",
            values=[t["diagnostic_msgs/msg/KeyValue"](key="watchdog_trips", value=str(watchdog_trips))],
        )
    else:
        level = ERROR if (sample.faults or sample.state == "error") else WARN if sample.status else OK
        message = ", ".join(sample.faults) or ", ".join(sample.status) or "ok"
        pairs = sample.as_key_values().items()
        status = t["diagnostic_msgs/msg/DiagnosticStatus"](
            level=level,
            name="motor_controller",
            message=message,
            hardware_id=f"roboteq {sample.firmware}".strip(),
            values=[t["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in pairs],
        )
    msg = t["diagnostic_msgs/msg/DiagnosticArray"](header=out.header(stamp_ns, ""), status=[status])
    out.write(TOPIC, "diagnostic_msgs/msg/DiagnosticArray", stamp_ns, msg)
