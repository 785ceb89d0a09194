"""The maps the perception stage feeds: what it needs of a map, and a further map placed with another pose.

:class:`PointMap` is the one method a map needs (``insert``); :class:`MapLayer` is a map that
:class:`robchair.perception.Perception` feeds with the same frames as its main map, each placed with the
layer's own ``T_world_base`` (e.g. the simulation's ground truth beside odometry). The evidence
parameters of a run's probabilistic maps (:func:`run_evidence_params`) and :func:`load_kernels`, which
loads the compiled mapping kernels before a loop's clock starts, live here too.

The map-layer workers live here as well: :class:`FrameInserter`, the part of the perception stage that
runs on its mapping threads (a delivered depth frame into the main map and the zoom on the first, the
maps beside it, i.e. the pose maps and the layers, on the second; the matching; the zoom's state the
loop sees after the frame), and :class:`_Placer`, one frame placed once per distinct pose and shared by
the maps.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from hw.interfaces import DepthFrame
from robchair.perception_depth import no_return_points
from robchair.perception_queries import Corridor
from robchair.platform.frames import transform_points
from robchair.platform.kinematics import Pose2D

# Probabilistic maps: a hit where free space was seen (a person walking in) is dynamic and forgotten this
# long after its last hit, so a walker leaving the camera's view leaves no trail; "seen free" asks for
# about five passes of free space (p < 0.15), so range noise at a static surface's edge does not count.
# Only what was hit for at most DYNAMIC_MAX_DWELL_S decays (a person passes a cell within a second or
# two): a wall first seen free at grazing incidence keeps being hit as long as it is in view.
DYNAMIC_DECAY_S = 0.5
DYNAMIC_VOID_PROBABILITY = 0.15
DYNAMIC_MAX_DWELL_S = 2.0
NO_RETURN_MIN_HEIGHT_M = 0.5  # a no-return pixel clears its ray only if this high (world z) at the range
#: Frames the maps beside the main one (odometry, ground truth, layers) may be behind it on their thread:
#: the mapping thread does not wait for them after each frame, so the two threads overlap across frames.
LAYER_LAG = 3
#: Niceness the layer thread adds to the process's (:func:`_lower_layer_priority`). office_corridor,
#: 2 CPUs, 3 sim s, load 1.4: RTF 0.98 waiting for the layers after every frame, 1.04 with the layer lag,
#: 1.11 with the lag and this priority (medians of 3, session 9).
LAYER_NICE = 5


def run_evidence_params() -> Any:
    """The :class:`mapping.probabilistic.EvidenceParams` of a run's probabilistic maps (the dynamic-hit
    decay above)."""
    from mapping.probabilistic import EvidenceParams

    return EvidenceParams(
        dynamic_decay_s=DYNAMIC_DECAY_S,
        dynamic_void_probability=DYNAMIC_VOID_PROBABILITY,
        dynamic_max_dwell_s=DYNAMIC_MAX_DWELL_S,
    )


def _lower_layer_priority() -> None:
    """Give the calling thread (the layer thread) :data:`LAYER_NICE` more niceness than the process.

    Its maps are the evaluation's (odometry, ground truth): on a busy machine the loop, the capture
    and the main map come first, and the layer thread catches up in their idle time (up to
    :data:`LAYER_LAG` frames behind). Linux threads have their own nice
    value; elsewhere nothing changes."""
    import os

    if not hasattr(os, "setpriority") or not sys.platform.startswith("linux"):
        return
    try:
        base = os.getpriority(os.PRIO_PROCESS, os.getpid())
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), min(base + LAYER_NICE, 19))
    except OSError:  # not permitted here: the thread keeps the process's priority
        pass


def layer_pool() -> ThreadPoolExecutor:
    """The layer thread: one worker at :func:`_lower_layer_priority`."""
    return ThreadPoolExecutor(1, thread_name_prefix="perception-layers", initializer=_lower_layer_priority)


class _Done:
    """A finished future (a camera without background capture)."""

    def __init__(self, value: Any) -> None:
        self.value = value

    def result(self) -> Any:
        return self.value


def load_kernels(scratch: Any, outer_sonar_deg: float, sonar_free_range_m: float) -> None:
    """Insert one sonar reading and two points, as float64 and as a placed depth frame, into ``scratch``.

    The first insertion imports and loads the compiled mapping kernels (seconds on a cold start); the
    runtime has this done before its clock starts, so that its first cycle keeps its deadline. numba
    compiles a kernel once per argument type: the depth frames arrive placed by :class:`_Placer`
    (float32, read-only) with no-return rays, so those types are loaded here too (on a cold cache
    the first frame compiled them, some 20 s inside the run).
    """
    from mapping.sonar import array_points, zone_tables

    fusion, _ = array_points((1.0, 1.0, 1.0), tables=zone_tables(outer_sonar_deg))
    t = np.eye(4)
    t[2, 3] = 0.5
    insert_sonar = getattr(scratch, "insert_sonar", None)
    if insert_sonar is not None:
        insert_sonar(fusion, t, max_range_m=sonar_free_range_m)
    pts = np.array([[1.0, 0.0, 0.3], [1.5, 0.2, 0.8]])
    scratch.insert(pts, sensor_origin=t[:3, 3])
    placed = _Placer(pts.astype(np.float32), np.array([[2.0, 0.0, 1.0]], np.float32))
    far = placed.far_points(t)
    insert_frame = getattr(scratch, "insert_frame", None)
    if insert_frame is not None and far is not None:
        insert_frame(placed.points(t), t[:3, 3], no_return_ends=far)
    else:
        scratch.insert(placed.points(t), sensor_origin=t[:3, 3])


class PointMap(Protocol):
    """What the perception stage needs of a map."""

    def insert(self, points: Any, sensor_origin: Any = None) -> Any: ...


@dataclass
class MapLayer:
    """A further map fed with the same frames, placed with another pose source.

    ``t_world_base()`` is called when a frame is taken (on the loop's thread) and returns the
    (4, 4) ``T_world_base`` to place that frame with (e.g. the physics' ground truth).
    """

    name: str
    map: PointMap
    t_world_base: Callable[[], np.ndarray]


class FrameInserter:
    """The map-layer workers of :class:`robchair.perception.Perception`: one depth frame into its maps.

    A mixin of the stage: :meth:`_insert_frame` runs on the stage's mapping thread (or inline, serial)
    and hands the maps beside the main one to the second mapping thread (``_layer_pool``); the
    attributes below are the stage's (set in its ``__init__``).
    """

    matcher: Any
    match_every: int
    evaluation_every: int
    pose: str
    map: PointMap
    pose_maps: dict[str, PointMap]
    layers: list[MapLayer]
    zoom: Any
    zoom_half_width: float | None
    band: tuple[float, float]
    corridor: Corridor
    clear_no_return: bool
    camera_stride: int
    _camera_range: float | None
    _rays: dict[tuple[str, int, int], np.ndarray]
    _layer_pool: ThreadPoolExecutor | None
    _layer_futs: deque[Future[None]]
    _lock: threading.Lock
    _after_frame: dict[int, tuple[np.ndarray, float | None, Pose2D, np.ndarray | None]]
    layer_s: dict[str, float]
    match_ms: list[float]
    map_ms: list[float]
    stats: dict[str, int]

    def _insert_frame(self, frame: DepthFrame, t_world_base: dict[str, np.ndarray], t_base_sensor: np.ndarray,
                      placed: list[tuple[PointMap, np.ndarray, bool]], pose: Pose2D,
                      seq: int) -> None:  # fmt: skip
        from mapping.vhv import VHVMap

        pts = np.asarray(frame.points).reshape(-1, 3)
        t_odom_sensor = t_world_base["odometry"] @ t_base_sensor
        poses = {k: t @ t_base_sensor for k, t in t_world_base.items()}
        r = self._camera_range if self.clear_no_return else None
        far = no_return_points(frame, r, self.camera_stride, self._rays) if r else None
        placer = _Placer(pts, far)
        if self.matcher is not None and seq % self.match_every:
            poses["matched"] = self.matcher.t_map_odom @ t_odom_sensor  # between matches: odometry
        elif self.matcher is not None:
            # the frame, placed by odometry in odom, is registered against the matched map first (the
            # odometry map takes the same placed points)
            t0 = time.perf_counter()
            res = self.matcher.match(placer.points(t_odom_sensor), self.pose_maps["matched"], t_odom_sensor)
            poses["matched"] = self.matcher.t_map_odom @ t_odom_sensor
            with self._lock:
                self.layer_s["matching"] = self.layer_s.get("matching", 0.0) + time.perf_counter() - t0
                self.match_ms.append(res.ms)
                self.stats["matches_accepted" if res.accepted else "matches_rejected"] += 1
        zoom = self.zoom
        main: list[tuple[str, Any, np.ndarray, str]] = []
        if zoom is not None:
            t_main_base = poses[self.pose] @ np.linalg.inv(t_base_sensor)
            zoom.follow(t_main_base[0, 3], t_main_base[1, 3], self.zoom_half_width)
        if zoom is not None and zoom.coarse is self.map and isinstance(self.map, VHVMap):
            main.append((self.pose, zoom, poses[self.pose], "main"))  # one insert feeds both levels
        else:
            main.append((self.pose, self.map, poses[self.pose], "main"))
            if zoom is not None:  # the main map is the zoom's coarse level: only the fine one is fed here
                main.append(("zoom", zoom, poses[self.pose], "fine" if zoom.coarse is self.map else "layer"))
        evaluate = seq % self.evaluation_every == 0  # the evaluation maps take every k-th frame
        # the odometry map takes every frame: it is what a recorded bag of the run maps back to
        fed = [k for k, m in self.pose_maps.items() if m is not self.map and (evaluate or k == "odometry")]
        others = [(k, self.pose_maps[k], poses[k], "layer") for k in fed]
        if evaluate:
            others += [(ly.name, m, t, "layer") for ly, (m, t, _) in zip(self.layers, placed, strict=True)]
        stamp = frame.stamp_ns * 1e-9
        # the maps beside the main one go in on a second thread (the kernels release the GIL) and are
        # waited for before the frame is done: each map takes its frames in the same order, threaded or not
        pool = self._layer_pool
        fut = pool.submit(self._insert_each, others, placer, stamp) if pool is not None and others else None
        self._insert_each(main, placer, stamp)
        if fut is not None:
            self._layers_behind(fut)
        elif others:
            self._insert_each(others, placer, stamp)
        if self.matcher is not None or self.zoom is not None:
            xy = self._zoom_band_xy(poses[self.pose] @ np.linalg.inv(t_base_sensor))
            d = self.corridor.distance_ahead(xy) if xy is not None else None
            t = np.array(self.matcher.t_map_odom) if self.matcher is not None else np.eye(4)
            with self._lock:
                self._after_frame[seq] = (t, d, pose, xy)

    def _layers_behind(self, fut: Future[None]) -> None:
        """Keep the layer thread's frame ``fut`` without waiting for it, up to :data:`LAYER_LAG` frames.

        Only the mapping thread calls this (it is the one that submits): the frame is done when the main
        map and the zoom are, and the maps beside them catch up on their own thread, in order. The
        readers of those maps wait for them first (:meth:`_drain_layers`)."""
        self._layer_futs.append(fut)
        while len(self._layer_futs) > LAYER_LAG:
            self._layer_futs.popleft().result()  # an error of a layer's insert surfaces with this frame

    def _drain_layers(self) -> None:
        """Wait for every frame handed to the layer thread (the maps beside the main one are complete).

        Called where no frame is being submitted: on the mapping thread, or once its queue is empty."""
        while self._layer_futs:
            self._layer_futs.popleft().result()

    def _insert_each(
        self, jobs: list[tuple[str, Any, np.ndarray, str]], placer: _Placer, stamp: float
    ) -> None:
        """Insert one frame into each ``(name, map, T_world_sensor, role)`` of ``jobs``, in order.

        ``role``: ``"main"`` (its stats are the stage's), ``"layer"``, or ``"fine"`` (the zoom's fine level
        only). Probabilistic maps take the capture ``stamp`` (s) and the no-return rays' free space.
        """
        from mapping.probabilistic import ProbabilisticVHV

        for name, m, t, role in jobs:
            t0 = time.perf_counter()
            origin = t[:3, 3]
            if role == "fine":
                m.insert_fine(placer.points(t), sensor_origin=origin)
                with self._lock:
                    self.layer_s[name] = self.layer_s.get(name, 0.0) + time.perf_counter() - t0
                continue
            probabilistic = isinstance(m, ProbabilisticVHV)
            kw = {"stamp": stamp} if probabilistic and m.now <= stamp else {}
            insert_free = getattr(m, "insert_free", None)  # maps that keep free space
            # no-return pixels: free space along their rays up to the range (OctoMap's max-range rays)
            fw = placer.far_points(t) if insert_free is not None else None
            free_ms = 0.0
            if probabilistic and fw is not None and len(fw):
                # one evidence pass for the frame: the rays' fans and the returns' fans merged on one table
                # (one miss per cell and frame; the frame's own hits cut out of both), one update
                s = m.insert_frame(placer.points(t), origin, no_return_ends=fw, **kw)
            else:
                s = m.insert(placer.points(t), sensor_origin=origin, **kw)
                if insert_free is not None and fw is not None and len(fw):
                    f = insert_free(fw, sensor_origin=origin, **kw)
                    free_ms = float(getattr(f, "build_ms", 0.0))
            if isinstance(s, tuple):  # a ZoomMap: (coarse stats, fine stats)
                s = s[0]
            with self._lock:
                self.layer_s[name] = self.layer_s.get(name, 0.0) + time.perf_counter() - t0
                if role == "main" and s is not None:
                    self.map_ms.append(float(getattr(s, "build_ms", math.nan)) + free_ms)
                    st = self.stats
                    st["depth_frames"] += 1
                    st["points_in"] += int(getattr(s, "points_in", 0))
                    st["points_dropped_nonfinite"] += int(getattr(s, "points_dropped_nonfinite", 0))
                    st["points_outside_grid"] += int(getattr(s, "points_outside_grid", 0))

    def _zoom_band_xy(self, t_world_base: np.ndarray) -> np.ndarray | None:
        """The zoom's fine cells whose structures overlap the band: (N, 2) in ``base_link``, m (None: none).

        ``t_world_base`` (4, 4): the chair's pose in the main map's frame (the zoom's)."""
        fine = self.zoom.fine if self.zoom is not None else None
        if fine is None:
            return None
        s = fine.structures()
        z0, z1 = self.band
        hit = (s.top >= z0) & (s.bottom <= z1)
        if not hit.any():
            return None
        x, y = fine.spec.index_to_world(s.i[hit], s.j[hit])
        rot = t_world_base[:2, :2]
        return (np.column_stack([x, y]) - t_world_base[:2, 3]) @ rot  # type: ignore[no-any-return]


class _Placer:
    """One depth frame placed in the world once per distinct ``T_world_sensor``, shared by its maps.

    ``points`` (N, 3) float32 camera-frame points; ``far`` (M, 3) camera-frame no-return ray ends (or
    None). The placed arrays are read-only: maps placed with the same transform take the same array.
    """

    def __init__(self, points: np.ndarray, far: np.ndarray | None) -> None:
        self._pts, self._far = points, far
        self._placed: dict[tuple[str, bytes], np.ndarray] = {}
        self._lock = threading.Lock()

    def _get(self, which: str, t: np.ndarray, make: Callable[[], np.ndarray]) -> np.ndarray:
        key = (which, np.ascontiguousarray(t, dtype=np.float64).tobytes())
        with self._lock:
            got = self._placed.get(key)
        if got is None:
            got = make()
            got.setflags(write=False)
            with self._lock:
                got = self._placed.setdefault(key, got)
        return got

    def points(self, t: np.ndarray) -> np.ndarray:
        """The frame's points in the world, (N, 3) float32, placed with ``t`` (4, 4)."""
        return self._get("points", t, lambda: transform_points(t, self._pts, np.float32))

    def far_points(self, t: np.ndarray) -> np.ndarray | None:
        """The no-return rays' ends placed with ``t``, only those at least
        :data:`NO_RETURN_MIN_HEIGHT_M` high (world z) there (None: no such rays).

        A ray that would have met the floor within the range lost its return on something (or grazing
        the floor), not in air: it clears nothing.
        """
        far = self._far
        if far is None or not len(far):
            return None

        def make() -> np.ndarray:
            fw = transform_points(t, far, np.float32)
            return np.ascontiguousarray(fw[fw[:, 2] >= NO_RETURN_MIN_HEIGHT_M])

        return self._get("far", t, make)
