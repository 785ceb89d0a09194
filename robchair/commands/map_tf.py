"""`robchair map` on bags with TF: place every cloud at its header stamp in a fixed frame.

The bag's ``/tf`` and ``/tf_static`` (or, with ``--pose-topic``, a ``nav_msgs/Odometry`` topic for the
moving part of the tree) give ``T_fixed_cloud`` at each cloud's stamp (:class:`mapping.io.tf.TfBuffer`:
linear translation, slerp rotation between samples). Clouds farther from the TF samples than
``--tf-tolerance`` are left out and counted. The sensor origin of each cloud (for free space) is the
cloud frame's origin in the fixed frame, or ``--sensor-origin`` carried along with the points.

Also the height-band check of every input: when most finite points lie outside the 2D band, the 2D
map shows almost nothing, so a warning names the band and the points' height range (when at least
:data:`BAND_WARN_FRACTION` of them are outside).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT_TF_TOLERANCE_S = 0.1
DEFAULT_FIXED_FRAME = "odom"  # REP-105: the continuous odometry frame, when the bag has it
# Share of finite points outside the 2D band that makes the map warn. An indoor depth camera sees mostly
# floor and ceiling: about 57 % of a `robchair sim` bag's points are outside the band, and its 2D map is
# fine; a planar lidar under the band has them all outside.
BAND_WARN_FRACTION = 0.9


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The TF options of ``robchair map``."""
    p.add_argument(
        "--fixed-frame",
        default=None,
        metavar="FRAME",
        help="frame the bag clouds are placed in through the bag's /tf and /tf_static "
        f"(default {DEFAULT_FIXED_FRAME} when the bag has it, else the root of the cloud frame's tree)",
    )
    p.add_argument(
        "--tf-tolerance",
        type=float,
        default=DEFAULT_TF_TOLERANCE_S,
        metavar="S",
        help="largest gap in seconds between a cloud's stamp and the TF samples; clouds farther out are "
        f"left out and counted as clouds_outside_tf_range (default {DEFAULT_TF_TOLERANCE_S:g})",
    )
    p.add_argument(
        "--map-kind",
        choices=("thesis", "probabilistic"),
        default="thesis",
        help="thesis: every point accumulates (default); probabilistic: occupied and free evidence with "
        "the dynamic-hit decay of a run's maps, each cloud at its stamp (what `robchair sim` builds)",
    )
    p.add_argument(
        "--pose-topic",
        default=None,
        metavar="TOPIC",
        help="nav_msgs/Odometry topic giving the moving frame's pose (header.frame_id -> child_frame_id) "
        "instead of /tf, for bags recorded without TF for it",
    )


def make_map(spec: Any, args: argparse.Namespace) -> Any:
    """The map ``--map-kind`` asks for: ``thesis`` (accumulate only, :class:`mapping.vhv.VHVMap`) or
    ``probabilistic`` with the evidence parameters of a run's maps (``robchair.perception``)."""
    from mapping.probabilistic import make_map as make
    from robchair.perception_layers import run_evidence_params

    params = run_evidence_params() if args.map_kind == "probabilistic" else None
    return make(spec, args.tolerance, args.map_kind, params)


def check_arguments(args: argparse.Namespace, fail: Any) -> None:
    """Refuse a negative or non-finite ``--tf-tolerance``."""
    if not (math.isfinite(args.tf_tolerance) and args.tf_tolerance >= 0):
        raise fail(f"--tf-tolerance {args.tf_tolerance}: expected a number of seconds >= 0")


@dataclasses.dataclass
class Placement:
    """Where the clouds of one bag go: ``T_fixed_cloud`` at each stamp, and what was refused.

    Attributes:
        buffer: The bag's TF tree.
        fixed_frame: Frame the points are placed in.
        source: What gave the tree: ``/tf`` or ``/tf + <pose topic>``.
        tolerance_ns: Largest stamp gap to the TF samples.
    """

    buffer: Any
    fixed_frame: str
    source: str
    tolerance_ns: int
    placed: int = 0
    outside_range: int = 0
    largest_gap_ns: int = 0

    def place(self, frame: Any, sensor_origin: Any) -> tuple[Any, Any] | None:
        """The frame with its points in the fixed frame and the sensor origin there, or None when the
        stamp lies outside the TF range by more than the tolerance (counted)."""
        from mapping.io.tf import TfOutOfRange

        try:
            t = self.buffer.lookup(self.fixed_frame, frame.frame_id, int(frame.stamp_ns), self.tolerance_ns)
        except TfOutOfRange as exc:
            self.outside_range += 1
            self.largest_gap_ns = max(self.largest_gap_ns, exc.gap_ns)
            return None
        pts = np.asarray(frame.points).reshape(-1, 3)
        dt = pts.dtype if pts.dtype.kind == "f" else np.float64
        placed = pts @ t[:3, :3].T.astype(dt) + t[:3, 3].astype(dt)
        far = frame.no_return
        if far is not None:
            far = far @ t[:3, :3].T.astype(far.dtype) + t[:3, 3].astype(far.dtype)
        origin = (
            t[:3, 3] if sensor_origin is None else t[:3, :3] @ np.asarray(sensor_origin, float) + t[:3, 3]
        )
        self.placed += 1
        placed_frame = dataclasses.replace(frame, points=placed, frame_id=self.fixed_frame, no_return=far)
        return placed_frame, tuple(map(float, origin))

    def summary(self) -> dict[str, Any]:
        """The ``tf`` entry of summary.json."""
        return {
            "fixed_frame": self.fixed_frame,
            "source": self.source,
            "tolerance_s": self.tolerance_ns / 1e9,
            "clouds_placed": self.placed,
            "clouds_outside_tf_range": self.outside_range,
            "largest_gap_outside_s": self.largest_gap_ns / 1e9 if self.outside_range else None,
        }

    def reset(self) -> None:
        """Forget the counts (before a second pass over the same bag)."""
        self.placed = self.outside_range = self.largest_gap_ns = 0


def open_placement(source: Any, args: argparse.Namespace, fail: Any) -> Placement | None:
    """The placement of a bag source (None for plain files, and for bags without TF: :func:`no_tf_note`).

    Raises:
        RobChairError (``fail``): The bag's tree does not connect the first cloud's frame to the fixed
            frame (the message names both frames and the frames the bag has), or a TF option was given
            for an input that cannot use it.
    """
    from mapping.io.bags import read_bag_tf
    from mapping.io.tf import TfError

    is_bag = source.kind in ("ros1-bag", "ros2-bag")
    if not is_bag:
        return None
    buffer = read_bag_tf(source.path, args.pose_topic)
    if not len(buffer):
        if args.fixed_frame is not None:
            raise fail(f"{source.path}: --fixed-frame {args.fixed_frame}: the bag has no /tf or /tf_static")
        return None
    first = next(iter(source), None)
    if first is None:
        return None
    frame_id = first.frame_id.lstrip("/")
    fixed = args.fixed_frame or (
        DEFAULT_FIXED_FRAME if DEFAULT_FIXED_FRAME in buffer.frames else buffer.root(frame_id)
    )
    try:
        buffer.lookup(fixed, frame_id, int(first.stamp_ns), 2**62)  # connection only: any stamp will do
    except TfError:
        raise fail(
            f"{source.path}: the TF tree does not connect the cloud frame {frame_id!r} to the fixed frame "
            f"{fixed!r}; the bag's frames: {', '.join(buffer.frames)}"
        ) from None
    what = "/tf" + (f" + {args.pose_topic}" if args.pose_topic else "")
    return Placement(buffer, fixed, what, round(args.tf_tolerance * 1e9))


@dataclasses.dataclass
class BandCheck:
    """How many finite points fall in the 2D band, and the range of their kept-axis coordinate."""

    band: tuple[float, float]
    column: int
    finite: int = 0
    in_band: int = 0
    low: float = math.inf
    high: float = -math.inf

    def add(self, points: Any) -> None:
        """Count the finite points of one (N, 3) frame (in the map's frame)."""
        p = np.asarray(points).reshape(-1, 3)
        h = p[np.isfinite(p).all(axis=1), self.column]
        if h.size:
            self.finite += int(h.size)
            self.in_band += int(np.count_nonzero((h >= self.band[0]) & (h <= self.band[1])))
            self.low, self.high = min(self.low, float(h.min())), max(self.high, float(h.max()))

    def add_measures(self, measures: Any) -> None:
        """Count one frame from its measures (``robchair.commands._map_pass.frame_pass``'s ``out``:
        finite count, count in the band, lowest and highest height)."""
        if measures[0] > 0:
            self.finite += int(measures[0])
            self.in_band += int(measures[1])
            self.low, self.high = min(self.low, float(measures[2])), max(self.high, float(measures[3]))

    def warning(self, label: str, axis: str) -> str | None:
        """The stderr line when most points are outside the band (None otherwise)."""
        if not self.finite or self.finite - self.in_band < BAND_WARN_FRACTION * self.finite:
            return None
        out = 100.0 * (self.finite - self.in_band) / self.finite
        return (
            f"robchair map: warning: {label}: {out:.0f}% of the points lie outside the 2D band "
            f"{axis} {self.band[0]:.2f} to {self.band[1]:.2f} m (their {axis} spans {self.low:.3f} to "
            f"{self.high:.3f} m), so the 2D map shows little or nothing; choose the band with --band"
        )

    def summary(self, label: str, axis: str) -> dict[str, Any]:
        """The ``band_check`` entry of summary.json."""
        return {
            "points_finite": self.finite,
            "points_in_band": self.in_band,
            "fraction_outside_band": (self.finite - self.in_band) / self.finite if self.finite else None,
            "height_range_m": [self.low, self.high] if self.finite else None,
            "warning": self.warning(label, axis),
        }


@dataclasses.dataclass
class NoReturn:
    """Free space along the no-return rays a bag carries next to its clouds (``<topic>/no_return``,
    :data:`mapping.io.bags.NO_RETURN_SUFFIX`), inserted as a run's odometry map inserts them: with the
    frame's cloud in one evidence pass, at its stamp, only the rays whose end lies at least
    ``robchair.perception_layers.NO_RETURN_MIN_HEIGHT_M`` high (a lower ray would have met the floor within
    the range: its return was lost on something, not in free air).

    Attributes:
        column: Column of the kept axis in the fixed frame.
        topic: The companion topic read (None: the input has none).
    """

    column: int
    topic: str | None
    clouds: int = 0
    rays: int = 0
    rays_inserted: int = 0
    unused: int = 0  # clouds with rays a map without free space (--map-kind thesis) could not take

    def ends(self, m: Any, ends: Any, origin: Any) -> Any:
        """The ray ends (fixed frame, (M, 3)) of one frame that ``m`` clears free space along, or None
        when ``m`` keeps no free space or the frame has no sensor origin (counted as not used)."""
        from robchair.perception_layers import NO_RETURN_MIN_HEIGHT_M

        self.clouds += 1
        self.rays += int(ends.shape[0])
        if getattr(m, "insert_free", None) is None or origin is None:
            self.unused += 1
            return None
        high = ends[ends[:, self.column] >= NO_RETURN_MIN_HEIGHT_M]
        self.rays_inserted += int(high.shape[0])
        return high

    def insert(self, m: Any, points: Any, ends: Any, origin: Any, kw: dict[str, Any]) -> Any:
        """Insert one frame's cloud and its no-return ray ends (both fixed frame) into ``m`` as the run's
        odometry map does: in one evidence pass (``insert_frame``) where the map has it, else the cloud
        then the rays' free space. Returns the stats of the cloud's insert (``build_ms`` covers both)."""
        high = self.ends(m, ends, origin)
        if high is None:
            return m.insert(points, sensor_origin=origin, **kw)
        insert_frame = getattr(m, "insert_frame", None)
        if insert_frame is not None:
            return insert_frame(points, origin, no_return_ends=high, **kw)
        stats = m.insert(points, sensor_origin=origin, **kw)
        free = m.insert_free(high, sensor_origin=origin, **kw)
        return dataclasses.replace(stats, build_ms=stats.build_ms + float(getattr(free, "build_ms", 0.0)))

    def summary(self) -> dict[str, Any] | None:
        """The ``no_return`` entry of summary.json (None without a companion topic)."""
        if self.topic is None:
            return None
        return {"topic": self.topic, "clouds": self.clouds, "rays": self.rays,
                "rays_inserted": self.rays_inserted, "clouds_not_used": self.unused}  # fmt: skip


def no_tf_note(source: Any) -> str | None:
    """The stderr line for a bag mapped without TF (None for plain files)."""
    if getattr(source, "kind", "") not in ("ros1-bag", "ros2-bag"):
        return None
    return (
        f"robchair map: {source.path}: no /tf or /tf_static in the bag: its clouds are mapped in their "
        "message frame, stacked as recorded (no motion between them)"
    )


def no_tf_summary(source: Any) -> dict[str, Any] | None:
    """The ``tf`` entry of summary.json for an input mapped without TF (None for plain files)."""
    if getattr(source, "kind", "") not in ("ros1-bag", "ros2-bag"):
        return None
    return {"fixed_frame": None, "source": None, "note": f"{Path(source.path).name}: no TF in the bag"}
