"""`robchair map`: build variable-height-voxel maps from point-cloud files or bags and write their outputs.

Each INPUT (a .pcd, .ply, KITTI .bin, .npy file, a ROS 1 .bag or a ROS 2 bag) becomes one map; all
the PointCloud2 (or PointCloud) messages of a bag's topic are accumulated into that input's map. For
every input one table row compares the VHV structures with the standard voxels of the same map (the
columns of the thesis's Table 5.2). Outputs go to ``--out`` (per-input sub-folders when there are
several inputs), written all-or-nothing. Without INPUT (or with ``--sample``) a small synthetic
indoor cloud is mapped.

Outputs: occupancy.png, elevation.png, vhv_3d.png (not with --no-pictures), map.pgm + map.yaml
(map_server), vhv_boxes.ply and voxels.ply (meshes), map_bag/ (ROS 2 Humble bag: /map OccupancyGrid,
/vhv_markers MarkerArray) and summary.json (with timing_s: the seconds spent reading and building,
wall and CPU).
Bag clouds are placed at their header stamps in a fixed frame through the bag's /tf and /tf_static
(--fixed-frame, default odom; --pose-topic for a bag with nav_msgs/Odometry instead of TF); a bag
without TF is mapped in its message frame, as recorded. Without --size the grid follows the data's
extent, so a bag is read twice (once for the extent) unless its clouds fit in MAX_KEPT_POINTS points,
which are then kept from the first pass. A warning (and summary.json's band_check) says when 90 % or
more of the points lie outside the 2D band.

The build runs as a pipeline of threads (reading, placing and measuring the clouds; their structures;
their fans of free space; the map's update), frame after frame in order: the maps equal those of
--serial-build (one thread).
"""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

from robchair.commands import _map_pipeline, map_tf

if TYPE_CHECKING:
    from mapping.grid import GridSpec

SAMPLE_SEED = 7
SAMPLE_SENSOR_ORIGIN = (0.0, 0.0, 1.0)  # mapping.synthetic's camera position
DEFAULT_OUT = "runs/map-<UTC time>"  # a new folder per run
MAX_GRID_SIDE_M = 100.0  # bound of a data-derived grid side; keeps rasters (elevation, 2D map) small
MAX_KEPT_POINTS = 30_000_000  # clouds kept from the extent pass (360 MB of float32); beyond, read again


def register(subparsers: Any) -> None:
    """Add the ``map`` sub-command."""
    p = subparsers.add_parser(
        "map",
        help="map point clouds (PCD, PLY, KITTI .bin, .npy, ROS 1/2 bags) into variable-height voxels",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "inputs", nargs="*", metavar="INPUT", help="point-cloud files or bags (none: the sample cloud)"
    )
    p.add_argument("--cell", type=float, default=0.05, help="cell size in metres (default 0.05)")
    p.add_argument(
        "--tolerance", type=float, default=0.05, help="largest gap inside one structure, m (default 0.05)"
    )
    p.add_argument(
        "--axis", choices=("z", "x", "y"), default="z", help="kept (full-definition) axis (default z)"
    )
    p.add_argument(
        "--band",
        nargs=2,
        type=float,
        metavar=("ZMIN", "ZMAX"),
        default=None,
        help="kept-axis band (m) that makes a cell occupied in the 2D map (default 0.10 1.50)",
    )
    p.add_argument(
        "--topic",
        default=None,
        help="point-cloud topic of bag inputs, PointCloud2 or PointCloud (default: the only one)",
    )
    p.add_argument("--out", default=None, help=f"output folder (default {DEFAULT_OUT}); written on success")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="write into an existing non-empty --out folder (same-named entries and an earlier "
        "robchair output there are replaced; other files are kept)",
    )
    p.add_argument(
        "--size",
        nargs=2,
        type=float,
        metavar=("SX", "SY"),
        default=None,
        help="grid size in metres along the grid axes (default: the data's extent plus a margin, "
        f"each side at most {MAX_GRID_SIDE_M:g} m)",
    )
    p.add_argument(
        "--centre",
        nargs=2,
        type=float,
        metavar=("CU", "CV"),
        default=None,
        help="grid centre with --size (default 0 0)",
    )
    p.add_argument(
        "--sensor-origin",
        nargs=3,
        type=float,
        metavar=("X", "Y", "Z"),
        default=None,
        help="sensor position in the points' frame, for free space (default: a PCD VIEWPOINT if set)",
    )
    p.add_argument(
        "--min-range",
        type=float,
        default=0.0,
        metavar="M",
        help="drop points at most M metres from the sensor (the sensor origin if known, else the "
        "origin of the points' frame); default 0 drops the exact zeros lidar drivers write for "
        "'no return'; counted as points_dropped_min_range in summary.json",
    )
    p.add_argument(
        "--bin-layout",
        choices=("kitti", "nuscenes", "xyz", "xyzrgb"),
        default=None,
        help="float32 layout of .bin inputs: kitti (x y z intensity), nuscenes (x y z intensity ring), "
        "xyz, xyzrgb (default: nuscenes for *.pcd.bin, kitti when the data is plausible for it, "
        "else refused)",
    )
    p.add_argument("--sample", action="store_true", help="map the built-in synthetic sample cloud")
    p.add_argument(
        "--no-pictures", action="store_true", help="do not draw the PNG pictures (the other outputs stay)"
    )
    p.add_argument(
        "--serial-build",
        action="store_true",
        help="build each map on one thread (default: reading, the frames' evidence and the map's update "
        "run as a pipeline of threads; the maps are the same)",
    )
    map_tf.add_arguments(p)
    p.set_defaults(func=_run)


def _fail(message: str) -> Exception:
    from robchair.platform.errors import RobChairError

    return RobChairError(message)


def _check_args(args: argparse.Namespace) -> None:
    for name in ("cell", "tolerance"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            raise _fail(f"--{name} {value}: expected a positive number of metres")
    if args.band is not None and not (args.band[0] <= args.band[1]):
        raise _fail(f"--band {args.band[0]} {args.band[1]}: expected ZMIN <= ZMAX")
    if args.centre is not None and args.size is None:
        raise _fail("--centre needs --size (without --size the grid is centred on the data)")
    if not (math.isfinite(args.min_range) and args.min_range >= 0):
        raise _fail(f"--min-range {args.min_range}: expected a distance >= 0 m")
    if args.sample and args.inputs:
        raise _fail("give either INPUT files or --sample, not both")
    map_tf.check_arguments(args, _fail)


class _SampleSource:
    """The synthetic sample as a one-frame source (same interface as mapping.io.CloudSource)."""

    n_frames = 1
    kind = "sample"
    topic = None
    path = Path("sample")

    def __iter__(self) -> Any:
        import numpy as np

        from mapping.io import CloudFrame
        from mapping.synthetic import small_sample_cloud

        pts = small_sample_cloud(np.random.default_rng(SAMPLE_SEED))
        yield CloudFrame(pts, 0, "map", "synthetic sample", sensor_origin=SAMPLE_SENSOR_ORIGIN)


class _Extent:
    """Running bounds of the finite points (and sensor origins) in the grid plane, one frame at a time."""

    def __init__(self, axis: str) -> None:
        from mapping.grid import AXIS_COLUMNS

        self.cols = list(AXIS_COLUMNS[axis][:2])
        self.lo = [math.inf, math.inf]
        self.hi = [-math.inf, -math.inf]
        self.medians: list[tuple[float, float, int]] = []  # per-frame median and weight, for capped grids
        self.deferred: list[Any] = []  # frames whose median is taken only if the grid is capped
        self.origins: list[tuple[float, float]] = []

    def add(self, points: Any, sensor_origin: Any, stats: Any, defer: bool = False) -> None:
        """One frame: its (N, 3) points and their measures (:func:`_measure`). ``defer`` keeps a
        reference to the points and takes their median only if a capped grid needs it (for frames held
        in memory anyway); :meth:`settle` takes the deferred ones at once."""
        import numpy as np

        p = np.asarray(points).reshape(-1, 3)
        if stats[0] > 0:
            for k in range(2):
                self.lo[k] = min(self.lo[k], float(stats[4 + 2 * k]))
                self.hi[k] = max(self.hi[k], float(stats[5 + 2 * k]))
            if defer:
                self.deferred.append(p)
            else:
                self.medians.append(self._median(p))
        if sensor_origin is not None:
            self.origins.append((float(sensor_origin[self.cols[0]]), float(sensor_origin[self.cols[1]])))

    def _median(self, p: Any) -> tuple[float, float, int]:
        """The frame's median point in the grid plane and its number of finite points."""
        import numpy as np

        uv = p[np.isfinite(p).all(axis=1)][:, self.cols].astype(np.float64)
        med = np.median(uv, axis=0)
        return float(med[0]), float(med[1]), int(uv.shape[0])

    def settle(self) -> None:
        """Take the medians of the deferred frames now (their points are about to be released)."""
        self.medians += [self._median(p) for p in self.deferred]
        self.deferred = []

    def grid(self, args: argparse.Namespace) -> tuple[GridSpec, str]:
        """GridSpec over the points and the sensor plus a margin, each side bounded; and how it was chosen."""
        import numpy as np

        from mapping.grid import GridSpec

        cell = args.cell
        if not self.medians and not self.deferred:
            n = math.ceil(1.0 / cell)
            return GridSpec(
                cell, n * cell, n * cell, (0.0, 0.0), args.axis
            ), "no finite points: 1 m grid at 0"
        lo, hi = list(self.lo), list(self.hi)
        for o in self.origins:  # the sensor belongs inside the grid too: free space is traced from it
            lo = [min(lo[k], o[k]) for k in range(2)]
            hi = [max(hi[k], o[k]) for k in range(2)]
        margins = [2 * cell + 0.05 * (hi[k] - lo[k]) for k in range(2)]
        capped = False
        for k in range(2):
            if hi[k] - lo[k] + 2 * margins[k] > MAX_GRID_SIDE_M:
                capped = True
                self.settle()
                # Far outliers should not drag a bounded grid away from the bulk of the points.
                med = np.array([(m[k], m[2]) for m in self.medians])
                order = np.argsort(med[:, 0])
                cum = np.cumsum(med[order, 1])
                mid = float(med[order[np.searchsorted(cum, cum[-1] / 2)], 0])
                # the covering grid spans at most one cell more than its box
                half = (MAX_GRID_SIDE_M - cell) / 2
                lo[k], hi[k], margins[k] = mid - half, mid + half, 0.0
        how = "data extent + margin" + (
            f" (capped at {MAX_GRID_SIDE_M:g} m per side, centred on the median)" if capped else ""
        )
        grid = GridSpec.covering((lo[0], lo[1]), (hi[0], hi[1]), cell, (margins[0], margins[1]), args.axis)
        return grid, how


def _unique_names(paths: list[Path]) -> list[str]:
    names: list[str] = []
    for p in paths:
        base = (
            re.sub(r"[^A-Za-z0-9_.-]+", "_", p.name.rsplit(".", 1)[0] if p.is_file() else p.name) or "input"
        )
        name, k = base, 2
        while name in names:
            name, k = f"{base}_{k}", k + 1
        names.append(name)
    return names


def _warm_up(spec: GridSpec, args: argparse.Namespace, points: Any, origin: Any) -> None:
    """Build a throwaway map from the first frame of each dtype, so the compiled kernels that frame
    needs are loaded (or compiled) before the timed insert: ``build ms`` then measures the build."""
    map_tf.make_map(spec, args).insert(points, sensor_origin=origin)


def _measure(points: Any, origin: Any, min_range: float, axis: str, band: tuple[float, float]) -> Any:
    """The frame's points farther than ``min_range`` from ``origin`` (None: the frame's origin) as
    (N, 3), how many were dropped, and the measures of the kept finite points (``frame_pass``'s
    ``out``: count, count in ``band``, height range, grid-plane bounds), in one pass. Non-finite
    points are kept (the map counts those itself)."""
    import numpy as np

    from mapping.grid import AXIS_COLUMNS
    from robchair.commands._map_pass import frame_pass

    pts = np.asarray(points).reshape(-1, 3)
    q = pts if pts.dtype in (np.float32, np.float64) else pts.astype(np.float64)
    ref = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64)
    cu, cv, ch = AXIS_COLUMNS[axis]
    close = np.empty(pts.shape[0], np.bool_)
    out = np.empty(8)
    n = int(frame_pass(q, ref, min_range * min_range, cu, cv, ch, band[0], band[1], close, out))
    return (pts[~close] if n else pts), n, out


def _measured_frames(frames: Any, placement: Any, args: argparse.Namespace) -> Any:
    """(frame, sensor origin, points, n_close, measures) of each frame (:func:`_measure`), placed in
    the fixed frame when ``placement`` is set (frames outside the TF range are left out there and
    counted); read, placed and measured on threads of their own unless ``--serial-build``."""
    sensor_origin = tuple(args.sensor_origin) if args.sensor_origin is not None else None
    band = _band(args)

    def place(frame: Any) -> Any:
        origin = sensor_origin if sensor_origin is not None else frame.sensor_origin
        return (frame, origin) if placement is None else placement.place(frame, origin)

    def measure(frame: Any, origin: Any) -> Any:
        return _measure(frame.points, origin, args.min_range, args.axis, band)

    return _map_pipeline.read_frames(frames, place, measure, args.serial_build)


def _map_one(source: Any, args: argparse.Namespace, progress: bool, placement: Any = None) -> dict[str, Any]:
    """Read one source and build its map; returns the map and what the table row needs."""
    from tqdm import tqdm

    from mapping.grid import GridSpec

    label = str(source.path) + (f" [{source.topic}]" if source.topic else "")
    bar_kw = {"total": source.n_frames, "desc": label, "unit": "frame", "disable": None if progress else True}
    import time

    import numpy as np

    t_start, cpu_start = time.perf_counter(), time.process_time()
    band_m = _band(args)
    frames: list[Any] | None = None
    if args.size is not None:
        centre = tuple(args.centre) if args.centre is not None else (0.0, 0.0)
        spec = GridSpec(args.cell, args.size[0], args.size[1], centre, args.axis)  # type: ignore[arg-type]
        how = "--size"
    else:
        # One pass to find the extent: a one-frame input is kept in memory, a bag is read twice
        # (frame summaries only are kept, so a long bag does not have to fit in memory).
        extent = _Extent(args.axis)
        kept: list[Any] | None = []
        bar = tqdm(iter(source), **{**bar_kw, "desc": f"{label} (extent)"})
        n_kept = 0
        for frame, origin, *measured in _measured_frames(bar, placement, args):
            extent.add(measured[0], origin, measured[2], defer=kept is not None)
            if kept is not None:
                kept.append((frame, origin, *measured))
                n_kept += int(np.asarray(frame.points).size // 3)
                if n_kept > MAX_KEPT_POINTS:  # a long bag is read again
                    kept = None
                    extent.settle()
        spec, how = extent.grid(args)
        frames = kept
        if placement is not None and frames is None:
            placement.reset()
    m = map_tf.make_map(spec, args)
    sensor_origin = tuple(args.sensor_origin) if args.sensor_origin is not None else None
    totals = _map_pipeline.BuildTotals(
        band=map_tf.BandCheck(band_m, spec.columns[2]),
        no_return=map_tf.NoReturn(spec.columns[2], getattr(source, "no_return_topic", None)),
        sensor_origin=sensor_origin,
    )
    pairs = frames if frames is not None else _measured_frames(iter(source), placement, args)
    with tqdm(**bar_kw) as bar:
        _map_pipeline.build(
            m,
            pairs,
            lambda points, origin: _warm_up(spec, args, points, origin),
            totals,
            placed=placement is not None,
            serial=args.serial_build,
            bar=bar,
        )
    return {
        "map": m,
        "read_and_build_s": time.perf_counter() - t_start,
        "read_and_build_cpu_s": time.process_time() - cpu_start,
        "label": label,
        "grid_size_source": how,
        "build_ms": totals.build_ms,
        "points_dropped_min_range": totals.dropped_close,
        "sensor_origin": totals.sensor_origin,
        "frame_id": totals.frame_id or "map",
        "stamp_ns": totals.stamp_ns,
        "band_check": totals.band,
        "no_return": totals.no_return,
    }


def _band(args: argparse.Namespace) -> tuple[float, float]:
    from mapping.export import DEFAULT_BAND

    return (float(args.band[0]), float(args.band[1])) if args.band is not None else DEFAULT_BAND


def _row(label: str, points: int, structures: int, voxels: int, ms: float, width: int) -> str:
    return f"{label:<{width}}  {points:>12,d}  {structures:>14,d}  {voxels:>15,d}  {ms:>9.1f}"


def _run(args: argparse.Namespace) -> int:
    from mapping.io import open_clouds
    from robchair.outdir import check_output_dir, deferred_stdout, timestamped_dir

    _check_args(args)
    # Open every input first: a bad path, extension or topic fails before any work is done.
    sources: list[Any] = (
        [_SampleSource()]
        if (args.sample or not args.inputs)
        else [open_clouds(p, topic=args.topic, bin_layout=args.bin_layout) for p in args.inputs]
    )
    placements = [map_tf.open_placement(s, args, _fail) for s in sources]
    if args.out is None:
        args.out = timestamped_dir("map")
    out_dir = check_output_dir(args.out, overwrite=args.overwrite)
    with deferred_stdout():
        return _map_all(args, sources, placements, out_dir)


def _map_all(args: argparse.Namespace, sources: list[Any], placements: list[Any], out_dir: Any) -> int:
    import json
    import sys

    from mapping.export import write_map_outputs

    band = _band(args)
    names = _unique_names([s.path for s in sources])
    progress = sys.stderr.isatty()
    width = max(12, *(len(str(s.path)) + (len(s.topic) + 3 if s.topic else 0) for s in sources))
    print(
        f"{'input':<{width}}  {'points':>12}  {'VHV structures':>14}  "
        f"{'standard voxels':>15}  {'build ms':>9}"
    )
    results = []
    notes: list[str | None] = []  # printed once every map is written (bad input stays one line)
    with out_dir.stage() as stage:
        for source, name, placement in zip(sources, names, placements):
            r = _map_one(source, args, progress, placement)
            m = r["map"]
            notes += [map_tf.no_tf_note(source) if placement is None else None]
            notes += [r["band_check"].warning(r["label"], args.axis)]
            target = stage if len(sources) == 1 else stage / name
            target.mkdir(exist_ok=True)
            summary = write_map_outputs(
                m,
                target,
                band=band,  # type: ignore[arg-type]
                sensor_origin=r["sensor_origin"],
                frame_id=r["frame_id"],
                stamp_ns=r["stamp_ns"],
                build_ms=r["build_ms"],
                points_dropped_min_range=r["points_dropped_min_range"],
                parameters={
                    "input": str(source.path),
                    "input_kind": source.kind,
                    "topic": source.topic,
                    "grid_size_source": r["grid_size_source"],
                    "min_range": args.min_range,
                    "bin_layout": source.kind if source.path.suffix == ".bin" else None,
                },
                extra={
                    "band_check": r["band_check"].summary(r["label"], args.axis),
                    "tf": placement.summary() if placement is not None else map_tf.no_tf_summary(source),
                    "no_return": r["no_return"].summary(),
                    # reading, placing and inserting every frame (the map built), and the inserts alone
                    # and the CPU time of the first (all threads of the process)
                    "timing_s": {
                        "read_and_build": r["read_and_build_s"],
                        "build": r["build_ms"] / 1e3,
                        "read_and_build_cpu": r["read_and_build_cpu_s"],
                    },
                },
                pictures=not args.no_pictures,
            )
            points = summary["points_in"]
            print(_row(r["label"], points, summary["structures"], summary["voxels"], r["build_ms"], width))
            results.append((name, summary))
        if len(sources) > 1:
            keys = (
                "points_in",
                "points_dropped_min_range",
                "points_dropped_nonfinite",
                "points_outside_grid",
                "points_inserted",
                "frames",
            )
            total: dict[str, Any] = {k: sum(s[k] for _, s in results) for k in keys}
            for k in ("cells_occupied", "structures", "voxels"):
                total[k] = sum(s[k] for _, s in results)
            total["build_ms"] = sum(s["build_ms"] or 0.0 for _, s in results)
            total["parameters"] = {
                "cell_size": args.cell,
                "tolerance": args.tolerance,
                "axis": args.axis,
                "band": list(band),
                "topic": args.topic,
                "note": "one map per input; totals are sums over the inputs",
            }
            total["inputs"] = [{"name": n, "folder": n, **s} for n, s in results]
            (stage / "summary.json").write_text(json.dumps(total, indent=2) + "\n", encoding="utf-8")
    for note in notes:
        if note:
            print(note, file=sys.stderr)
    for name, summary in results:
        p = summary["parameters"]
        where = "" if len(results) == 1 else f"{name}/: "
        print(
            f"{where}grid {p['grid_shape'][0]} x {p['grid_shape'][1]} cells of {p['cell_size']:g} m "
            f"({p['grid_size_source']}), {summary['points_dropped_min_range']:,d} within "
            f"{args.min_range:g} m of the sensor, {summary['points_dropped_nonfinite']:,d} non-finite and "
            f"{summary['points_outside_grid']:,d} out-of-grid points dropped"
        )
    print(
        f"wrote {Path(args.out)}/ ({'' if args.no_pictures else 'pictures, '}map.pgm + map.yaml, PLY meshes, "
        "ROS 2 bag map_bag/, summary.json)"
    )
    return 0
