"""`robchair bench laser`: one simulated URG-04LX scan (682 rays): the plane cut, Embree, PyBullet.

Workload: the chair stands in a scene (default ``office``) with its laser at the spec's
``laser_link`` mount; the chair turns by a small yaw between scans so every scan casts from a new
pose. The three casters are timed in the same run, interleaved, on one thread each (the default
plane-cut caster of :mod:`sim._laser_raster`, Embree with ``nthreads=1``, ``rayTestBatch`` with
``numThreads=1``), and ranges without noise are compared to show they see the same world (the plane
cut against Embree: the largest difference, m). The plane cut and Embree cast against the visual
triangles mirrored from PyBullet (:mod:`sim.raycast`; the mirror's ``sync`` is included in their
time), PyBullet against its collision
shapes (which include the chair itself, so beams that reach the chair's body are left out of the
agreement figure). Reported: median milliseconds per scan and the ratio; JSON in ``--out``.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from typing import Any

from robchair.commands.bench_output import add_out_arguments, results_dir, write_results


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "laser", help="simulated Hokuyo scan: the plane cut vs the Embree mirror vs PyBullet rayTestBatch"
    )
    p.add_argument("--scans", type=int, default=200, help="scans per caster (median; default 200)")
    p.add_argument("--scene", default="office", help="scene in assets/scenes (default office)")
    add_out_arguments(p, "laser")
    p.set_defaults(func=_run)


def measure(scene: str, scans: int) -> dict[str, Any]:
    """Time both casters on ``scans`` poses; returns medians (ms) and the agreement of their ranges."""
    import numpy as np
    import pybullet as p

    from robchair.platform.paths import ASSETS
    from sim.backend import SimChair
    from sim.laser import LaserSim
    from sim.raycast import MeshMirror

    path = ASSETS / "scenes" / f"{scene}.toml"
    chair = SimChair(scene=path, sensor=None, sonars=False, noise=False)
    try:
        c = chair.world.client
        mirror = MeshMirror(c, exclude_bodies=(chair.robot.body,), nthreads=1)
        embree = LaserSim(c, mirror=mirror, caster="embree", noise=False)
        raster = LaserSim(c, mirror=mirror, caster="raster", noise=False)
        bullet = LaserSim(c, caster="pybullet", noise=False)
        base = chair.robot.link_transform("laser_link")
        poses = []
        for k in range(scans):
            yaw = 2.0 * math.pi * k / scans
            rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
            t = base.copy()
            t[:3, :3] = rz @ base[:3, :3]
            poses.append(t)
        embree.true_ranges(poses[0])  # warm-up: builds the mirror (not timed)
        raster.true_ranges(poses[0])  # and loads the kernel
        te, tb, tr, agree, hit, worst = [], [], [], [], [], 0.0
        for t in poses:
            t0 = time.perf_counter()
            rr = raster.true_ranges(t)
            t1 = time.perf_counter()
            tr.append(t1 - t0)
            t0 = time.perf_counter()
            re = embree.true_ranges(t)
            t1 = time.perf_counter()
            same = np.isfinite(re) == np.isfinite(rr)
            fin = np.isfinite(re) & same
            worst = max(
                worst, float(np.abs(re[fin] - rr[fin]).max(initial=0.0)), 0.0 if same.all() else math.inf
            )
            hits = p.rayTestBatch(
                np.broadcast_to(t[:3, 3], (len(embree._dirs), 3)).tolist(),
                (t[:3, 3] + (embree._dirs @ t[:3, :3].T) * 4.0).tolist(),
                numThreads=1,
                physicsClientId=c,
            )
            t2 = time.perf_counter()
            rb = np.array([h[2] * 4.0 if h[0] >= 0 and h[0] != chair.robot.body else np.inf for h in hits])
            own = np.array([h[0] == chair.robot.body for h in hits])
            te.append(t1 - t0)
            tb.append(t2 - t1)
            both = ~own & (np.isfinite(re) | np.isfinite(rb))
            hit.append(float(np.mean(np.isfinite(re))))
            agree.append(
                float(np.mean(np.abs(np.nan_to_num(re[both] - rb[both], posinf=9, neginf=9)) < 0.01))
            )
        del bullet
        return {
            "raster_ms": 1e3 * statistics.median(tr),
            "raster_vs_embree_max_m": worst,
            "embree_ms": 1e3 * statistics.median(te),
            "pybullet_ms": 1e3 * statistics.median(tb),
            "agreement_1cm": statistics.median(agree),
            "beams_with_return": statistics.median(hit),
            "scans": scans,
        }
    finally:
        chair.close()


def _run(args: argparse.Namespace) -> int:
    from robchair.platform.errors import RobChairError

    if args.scans < 1:
        raise RobChairError(f"--scans must be >= 1, got {args.scans}")
    out = results_dir(args, "laser")  # refused before anything is measured
    load0 = os.getloadavg()
    m = measure(args.scene, args.scans)
    load1 = os.getloadavg()
    from sim.laser import URG_04LX

    print(
        f"robchair bench laser: {args.scene}, {URG_04LX.n_beams} rays per scan, "
        f"median of {m['scans']} scans, 1 thread"
    )
    print(f"{'caster':34s} {'ms/scan':>8s}")
    print(f"{'plane cut (default), with sync':34s} {m['raster_ms']:8.3f}")
    print(f"{'Embree mirror (Open3D), with sync':34s} {m['embree_ms']:8.3f}")
    print(f"{'PyBullet rayTestBatch':34s} {m['pybullet_ms']:8.3f}")
    faster = "Embree" if m["embree_ms"] < m["pybullet_ms"] else "PyBullet"
    ratio = max(m["embree_ms"], m["pybullet_ms"]) / max(min(m["embree_ms"], m["pybullet_ms"]), 1e-12)
    print(
        f"{faster} is {ratio:.1f}x faster; {100 * m['beams_with_return']:.0f} % of beams return, and the two "
        f"casters agree within 1 cm on {100 * m['agreement_1cm']:.1f} % of the beams not on the chair"
    )
    print(
        f"the plane cut is {m['embree_ms'] / max(m['raster_ms'], 1e-12):.1f}x Embree and differs from it by "
        f"{m['raster_vs_embree_max_m']:.1e} m at most (Embree casts in float32)"
    )
    write_results(out, "laser", {"scene": args.scene, **m, "faster": faster, "ratio": ratio}, load0, load1)
    return 0
