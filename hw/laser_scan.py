"""Conversions of a :class:`hw.interfaces.LaserScan`: points in the sensor frame, ``sensor_msgs/LaserScan``.

Both the real driver (:mod:`hw.hokuyo`) and the simulated laser (:mod:`sim.laser`) produce
``LaserScan``; the perception stage takes points from :func:`scan_to_points` and the recorder writes
:func:`to_ros_laser_scan`. ROS types come from ``rosbags`` (ROS 2 Humble type store by default).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import numpy.typing as npt

from hw.errors import ProtocolError
from hw.interfaces import LaserScan

LASER_SCAN_MSGTYPE = "sensor_msgs/msg/LaserScan"


def valid_mask(scan: LaserScan) -> npt.NDArray[np.bool_]:
    """(N,) True where a beam holds a measurement: finite and within ``[range_min, range_max]``."""
    r = scan.ranges
    with np.errstate(invalid="ignore"):
        return np.isfinite(r) & (r >= scan.range_min) & (r <= scan.range_max)  # type: ignore[no-any-return]


@functools.lru_cache(maxsize=8)
def beam_trig(
    angle_min: float, angle_increment: float, n_beams: int
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``(cos, sin)`` (N,) of the beam angles of :meth:`LaserScan.angles` (read-only).

    One pair per scan geometry, computed once: a scanner repeats its geometry every scan, and the
    682 cosines and sines were a fifth of :func:`scan_to_points`.
    """
    a = angle_min + angle_increment * np.arange(n_beams, dtype=np.float64)  # as LaserScan.angles
    c, s = np.cos(a), np.sin(a)
    c.flags.writeable = False
    s.flags.writeable = False
    return c, s


def scan_to_points(scan: LaserScan, *, keep_invalid: bool = False) -> npt.NDArray[np.float64]:
    """Beam end points in the scan's own frame (REP-103: x forward, y left, z = 0 in the scan plane), m.

    Args:
        scan: the scan.
        keep_invalid: False: only measurements, shape (M, 3) with M <= N. True: one row per beam,
            shape (N, 3), NaN rows where the beam holds no measurement (``+inf``, ``-inf``, NaN or out
            of range), so row i stays beam i.

    Returns:
        float64 points; to put them in the world, apply ``T_world_sensor`` (perception stage).
    """
    cos_a, sin_a = beam_trig(scan.angle_min, scan.angle_increment, scan.n_beams)
    r = scan.ranges
    if not (isinstance(r, np.ndarray) and r.ndim == 1 and r.dtype in (np.float32, np.float64)):
        return scan_to_points_reference(scan, keep_invalid=keep_invalid)
    from hw._laser_scan_kernels import beam_points

    # the limits in the ranges' own type, as numpy compares an array with a Python float (NEP 50)
    lo, hi = r.dtype.type(scan.range_min), r.dtype.type(scan.range_max)
    return beam_points(r, cos_a, sin_a, lo, hi, keep_invalid)


def scan_to_points_reference(scan: LaserScan, *, keep_invalid: bool = False) -> npt.NDArray[np.float64]:
    """:func:`scan_to_points` in numpy passes (the reference its compiled path is tested against)."""
    cos_a, sin_a = beam_trig(scan.angle_min, scan.angle_increment, scan.n_beams)
    r = scan.ranges.astype(np.float64)
    with np.errstate(invalid="ignore"):  # inf x cos(90 deg) = NaN: such beams are dropped or NaN below
        pts = np.stack([r * cos_a, r * sin_a, np.zeros_like(cos_a)], axis=-1)
    ok = valid_mask(scan)
    if keep_invalid:
        pts[~ok] = np.nan
        return pts
    return pts[ok]


def _typestore(ros2: bool) -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)


def to_ros_laser_scan(scan: LaserScan, *, ros2: bool = True, typestore: Any = None) -> Any:
    """A rosbags ``sensor_msgs/msg/LaserScan`` with the same fields (ranges float32, REP-117 values kept).

    Args:
        scan: the scan.
        ros2: ROS 2 Humble types (default) or ROS 1 Noetic (whose header has ``seq``).
        typestore: a rosbags type store to take the types from (default: the one ``ros2`` names).
    """
    store = typestore if typestore is not None else _typestore(ros2)
    t = store.types
    stamp = t["builtin_interfaces/msg/Time"](
        sec=int(scan.stamp_ns // 1_000_000_000), nanosec=int(scan.stamp_ns % 1_000_000_000)
    )
    if "seq" in t["std_msgs/msg/Header"].__dataclass_fields__:
        header = t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=scan.frame_id)
    else:
        header = t["std_msgs/msg/Header"](stamp=stamp, frame_id=scan.frame_id)
    intensities = (
        np.zeros(0, dtype=np.float32)
        if scan.intensities is None
        else np.ascontiguousarray(scan.intensities, dtype=np.float32)
    )
    return t[LASER_SCAN_MSGTYPE](
        header=header,
        angle_min=float(scan.angle_min),
        angle_max=float(scan.angle_max),
        angle_increment=float(scan.angle_increment),
        time_increment=float(scan.time_increment),
        scan_time=float(scan.scan_time),
        range_min=float(scan.range_min),
        range_max=float(scan.range_max),
        ranges=np.ascontiguousarray(scan.ranges, dtype=np.float32),
        intensities=intensities,
    )


def from_ros_laser_scan(msg: Any) -> LaserScan:
    """A :class:`LaserScan` from a ROS ``sensor_msgs/LaserScan`` (rosbags, ROS 1 or ROS 2).

    Raises:
        ProtocolError: the intensities are neither empty nor one per range.
    """
    ranges = np.asarray(msg.ranges, dtype=np.float32).copy()
    inten = np.asarray(msg.intensities, dtype=np.float32)
    if inten.size not in (0, ranges.size):
        raise ProtocolError(f"LaserScan message: {inten.size} intensities for {ranges.size} ranges")
    st = msg.header.stamp
    sec, nsec = (st.sec, st.nanosec) if hasattr(st, "nanosec") else (st.sec, st.nsec)
    return LaserScan(
        stamp_ns=int(sec) * 1_000_000_000 + int(nsec),
        angle_min=float(msg.angle_min),
        angle_max=float(msg.angle_max),
        angle_increment=float(msg.angle_increment),
        time_increment=float(msg.time_increment),
        scan_time=float(msg.scan_time),
        range_min=float(msg.range_min),
        range_max=float(msg.range_max),
        ranges=ranges,
        intensities=inten.copy() if inten.size else None,
        frame_id=str(msg.header.frame_id),
    )
