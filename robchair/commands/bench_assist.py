"""`robchair bench assist`: CPU time of one assistance decision per mode, against the 2 ms target.

Workload: the chair drives a 0.85 m doorway approached 8 degrees off (:func:`sim.planar.doorway`),
the person pushing straight ahead; the laser scan (URG-04LX: 683 beams over 240 degrees) of each pose
along the ``door`` passage is recorded first, then every mode decides on every recorded scan, timed
with the process CPU clock (``time.process_time_ns``). The named baseline measured in the same run is
the safety layer's :meth:`robchair.platform.safety.SafetyLayer.filter`, the stage after it. Target:
at most 2 ms of CPU per decision at 20 Hz (the Raspberry Pi beside the Roboteq, SPEC section 7).
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from typing import Any

from robchair.commands.bench_output import add_out_arguments, results_dir, write_results

TARGET_MS = 2.0


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser("assist", help="one assistance decision per mode vs the 2 ms target")
    p.add_argument(
        "--cycles", type=int, default=200, help="recorded cycles of the doorway drive (default 200)"
    )
    add_out_arguments(p, "assist")
    p.set_defaults(func=_run)


def _scans(cycles: int) -> list[tuple[Any, Any]]:
    """(pose, base_link points) of a ``door`` passage of ``cycles`` cycles at 20 Hz."""
    import numpy as np

    from robchair.assistance import AssistedSource
    from robchair.platform.kinematics import Pose2D
    from robchair.platform.spec import load_spec
    from robchair.sources import Command, Observation
    from sim.planar import doorway

    spec = load_spec()
    world = doorway(0.85)
    laser_x = float(spec.mounts["laser_link"].transform()[0, 3])
    angles = np.deg2rad(np.linspace(-120.0, 120.0, 683))
    person = _Const(Command(0.4, 0.0, deadman=True))
    holder: dict[str, Any] = {}
    stage = AssistedSource(person, spec, 0.62, 2.14, "door", obstacles=lambda obs: holder["p"])
    x, y, th, dt = -2.5, 0.0, math.radians(8.0), 0.05
    out = []
    for k in range(cycles):
        odom = world.scan(x + laser_x * math.cos(th), y + laser_x * math.sin(th), th, angles)
        c, s = math.cos(th), math.sin(th)
        d = odom - (x, y)
        holder["p"] = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)
        pose = Pose2D(x, y, th)
        out.append((pose, holder["p"]))
        cmd = stage.command(Observation(k, pose, None, (), None))
        x += cmd.v * dt * math.cos(th)
        y += cmd.v * dt * math.sin(th)
        th += cmd.w * dt
    return out


def _holder_points(holder: dict[str, Any]) -> Any:
    return lambda obs: holder["p"]


class _Const:
    def __init__(self, c: Any) -> None:
        self.c = c

    def command(self, obs: Any) -> Any:
        return self.c


def measure(cycles: int) -> dict[str, Any]:
    """Mean, median and 99th-percentile CPU ms per decision of each mode and of the safety layer."""
    from robchair.assistance import MODES, AssistedSource
    from robchair.platform.safety import SafetyInputs, SafetyLayer, SafetyLimits
    from robchair.platform.spec import load_spec
    from robchair.sources import Command, Observation

    spec = load_spec()
    scans = _scans(cycles)
    rows: dict[str, dict[str, float]] = {}
    for mode in MODES:
        holder: dict[str, Any] = {}
        stage = AssistedSource(_Const(Command(0.4, 0.0, deadman=True)), spec, 0.62, 2.14, mode,
                               obstacles=_holder_points(holder))  # fmt: skip
        ts = []
        for k, (pose, pts) in enumerate(scans):
            holder["p"] = pts
            t0 = time.process_time_ns()
            stage.command(Observation(k, pose, None, (), None))
            ts.append((time.process_time_ns() - t0) / 1e6)
        rows[mode] = _stats(ts)
    safety = SafetyLayer(SafetyLimits.from_spec(spec))
    ts = []
    for k in range(len(scans)):
        t0 = time.process_time_ns()
        safety.filter(0.4, 0.0, SafetyInputs(k, map_distance_m=2.0, deadman=True), 0.05)
        ts.append((time.process_time_ns() - t0) / 1e6)
    rows["safety layer (baseline)"] = _stats(ts)
    return {"cycles": cycles, "target_ms": TARGET_MS, "ms": rows}


def _stats(ts: list[float]) -> dict[str, float]:
    q = statistics.quantiles(ts, n=100) if len(ts) > 1 else [ts[0]] * 99
    return {"mean": statistics.fmean(ts), "median": statistics.median(ts), "p99": q[98]}


def _run(args: argparse.Namespace) -> int:
    from robchair.platform.errors import RobChairError

    if args.cycles < 2:
        raise RobChairError(f"--cycles must be >= 2, got {args.cycles}")
    out = results_dir(args, "assist")  # refused before anything is measured
    load0 = os.getloadavg()
    m = measure(args.cycles)
    load1 = os.getloadavg()
    base = m["ms"]["safety layer (baseline)"]["mean"]
    print(f"robchair bench assist: 0.85 m doorway 8 degrees off, {args.cycles} cycles, CPU ms per decision")
    head = f"{'stage':26s} {'mean':>7s} {'median':>7s} {'p99':>7s} {'x safety':>9s}"
    print(f"{head}  target {TARGET_MS:g} ms (mean)")
    for name, r in m["ms"].items():
        verdict = "" if name.startswith("safety") else ("met" if r["mean"] <= TARGET_MS else "missed")
        ratio = r["mean"] / max(base, 1e-9)
        print(f"{name:26s} {r['mean']:7.3f} {r['median']:7.3f} {r['p99']:7.3f} {ratio:9.1f}  {verdict}")
    m["met"] = {k: r["mean"] <= TARGET_MS for k, r in m["ms"].items() if not k.startswith("safety")}
    write_results(out, "assist", m, load0, load1)
    return 0
