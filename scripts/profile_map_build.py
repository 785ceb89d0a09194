"""Per-frame cost of `robchair map --map-kind probabilistic` on a bag, stage by stage (CPU ms per frame).

Usage: ``python scripts/profile_map_build.py BAG [--frames N]``. Stages: read (decode a message), place
(TF), measure (``--min-range`` pass), build (the frame's VHV structures), targets (structures of the
no-return ends), fan_bits, extract_free, store (decay + update). Prints the median and the mean per
frame, and the total CPU seconds; the map it builds equals the command's (same calls, in order).
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("bag")
    ap.add_argument("--frames", type=int, default=0, help="first N frames only (0: all)")
    a = ap.parse_args()
    from mapping import _evidence_kernels as E
    from mapping._frame_evidence import _LATTICE_LIMIT
    from mapping.io import open_clouds
    from robchair.cli import build_parser
    from robchair.commands import map as M
    from robchair.commands import map_tf

    args = build_parser().parse_args(["map", a.bag, "--map-kind", "probabilistic"])
    source = open_clouds(a.bag)
    placement = map_tf.open_placement(source, args, M._fail)
    assert placement is not None, "a bag with TF"
    frames = []
    it = iter(source)
    t: dict[str, list[float]] = {k: [] for k in ("read", "place", "measure", "build", "targets", "fan_bits",
                                                  "extract_free", "store")}  # fmt: skip
    c = time.process_time
    while True:
        t0 = c()
        f = next(it, None)
        if f is None:
            break
        t["read"].append(c() - t0)
        frames.append(f)
        if a.frames and len(frames) >= a.frames:
            break
    # the grid as the command chooses it (extent pass)
    extent = M._Extent(args.axis)
    placed = []
    for f in frames:
        t0 = c()
        p = placement.place(f, None)
        t["place"].append(c() - t0)
        if p is None:
            continue
        t0 = c()
        pts, _, meas = M._measure(p[0].points, p[1], args.min_range, args.axis, M._band(args))
        t["measure"].append(c() - t0)
        extent.add(pts, p[1], meas)
        placed.append((p[0], p[1], pts))
    spec, _ = extent.grid(args)
    m = map_tf.make_map(spec, args)
    no_return = map_tf.NoReturn(spec.columns[2], getattr(source, "no_return_topic", None))
    M._warm_up(spec, args, placed[0][2], placed[0][1])
    m2 = map_tf.make_map(spec, args)  # the reference: the command's own insert
    for frame, origin, pts in placed:
        stamp = frame.stamp_ns * 1e-9
        ends = no_return.ends(m, frame.no_return, origin) if frame.no_return is not None else None
        m._advance(stamp)
        t0 = c()
        built = m._build(pts, "auto")
        t["build"].append(c() - t0)
        key, bot, top = built[0], built[1], built[2]
        r = m._r
        okey, olo, ohi = E.occupied_evidence(key, bot, top, 1.0 / r, m._half, -_LATTICE_LIMIT, _LATTICE_LIMIT)
        t0 = c()
        tkey, tbot, ttop = key, bot, top
        if ends is not None and ends.shape[0]:
            k2, b2, t2 = m._build(ends, "auto")[:3]
            tkey, tbot, ttop = np.concatenate([key, k2]), np.concatenate([bot, b2]), np.concatenate([top, t2])
        t["targets"].append(c() - t0)
        fk, fl, fh = _fans(m, tkey, tbot, ttop, origin, okey, olo, ohi, t)
        t0 = c()
        m._decay()
        m._update(okey, olo, ohi, fk, fl, fh)
        m._cache.clear()
        t["store"].append(c() - t0)
        if ends is not None:
            m2.insert_frame(pts, origin, no_return_ends=ends, stamp=stamp)
        else:
            m2.insert(pts, sensor_origin=origin, stamp=stamp)
    same = np.array_equal(m.occupancy_2d((0.1, 1.5)), m2.occupancy_2d((0.1, 1.5)))
    print(f"{len(placed)} frames, grid {spec.shape}, profile's map == command's map: {same}")
    total = 0.0
    for k, v in t.items():
        total += sum(v)
        print(f"{k:14s} median {1e3 * statistics.median(v):6.2f} ms  mean {1e3 * sum(v) / len(v):6.2f} ms  "
              f"total {sum(v):6.2f} s")  # fmt: skip
    print(f"{'all':14s} total {total:6.2f} s CPU")


def _fans(m: Any, key: Any, bot: Any, top: Any, origin: Any, okey: Any, olo: Any, ohi: Any, t: Any) -> Any:
    """The frame's merged free intervals through the map's own fan job, its two kernels timed."""
    c = time.process_time
    job = m._fan_job(key, bot, top, origin, okey, olo, ohi)
    t0 = c()
    job.mark()
    t["fan_bits"].append(c() - t0)
    t0 = c()
    fk, fl, fh, _ = job.extract()
    t["extract_free"].append(c() - t0)
    return fk, fl, fh


if __name__ == "__main__":
    main()
