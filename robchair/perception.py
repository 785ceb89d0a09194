"""The perception stage: sensor data x mount x pose -> world -> map, and what the safety layer asks of it.

This is the one place that places sensor data in the world: ``T_world_sensor = T_world_base(pose) x
T_base_sensor(mount)`` (:mod:`robchair.platform.frames`), then ``map.insert(points_world, sensor_origin)``.

* depth frames (:class:`hw.interfaces.DepthFrame`, organized (H, W, 3) in the camera frame): into the
  map; the points of the frame that stand in the chair's height band inside its corridor ahead give
  the *map distance* the safety layer checks;
* sonar array readings: five-zone fusion and the cone -> points algorithm (:mod:`mapping.sonar`) into
  a sonar map; the fused arc, clipped to the surfaces the laser and the zoom map locate in its cone
  at its range, gives the *sonar distance*; the servo is turned toward the nearest echo;
* laser scans: points (N, 3) in the scanner's frame, into the map.

The map is pluggable: any object with ``insert(points_world (N, 3), sensor_origin=(3,))``. By default
it is a :class:`mapping.probabilistic.ProbabilisticVHV` (``map_kind="probabilistic"``: occupied and free
evidence per vertical interval, so people who walk past are cleared and unknown is told apart from
free); ``map_kind="thesis"`` gives the thesis's accumulate-only :class:`mapping.vhv.VHVMap`. Sonar
readings go into a probabilistic map through its ``insert_sonar`` (free inside the zone's cone up to
the fused range, occupied at the range; a reading with no echo gives free space up to
:data:`SONAR_FREE_RANGE_M`), into a thesis map as the cone points only. Further *layers* (e.g. the
simulation's map placed with ground-truth poses) receive the same frames placed with their own pose
source; :meth:`Perception.new_map` makes them of the same kind.

Scan-to-map matching (REP-105). With a :class:`mapping.matching.ScanMatcher`, each depth frame placed
by odometry in ``odom`` is registered against the *matched* map before it is inserted; the matcher keeps
``map -> odom`` (a rejected match keeps the previous one, i.e. odometry, and is counted by reason) and
the frame goes into the matched map at ``T_map_odom x T_odom_sensor``. ``pose`` chooses which map is
the main one (``odometry``, ``matched`` or ``ground-truth``); the others are kept beside it in
:attr:`Perception.pose_maps`, so a run can compare them. ``match_every`` registers only every k-th frame
(odometry from the last match between) and ``evaluation_every`` feeds the maps beside the main one every
k-th frame.

Zoom. With ``zoom_half_width``, a :class:`mapping.zoom.ZoomMap` square of that half-width around the
chair (moving with it) is mapped ``zoom_factor`` times finer, fed by the same placed points as the main
map, which is its coarse level (a thesis main map is fed through the zoom's insert; a probabilistic one
is inserted itself and only the fine level beside it); the corridor distance of the safety layer also
asks it (:meth:`Perception.zoom_distance_m`), at the fine resolution. Maps placed with the same pose
share one transformed copy of the frame (the odometry map and the matching take the same one).

Depth frames go through a small pipeline so that capturing and mapping overlap the rest of the loop:
a camera offering ``submit_read()`` (the simulated Kinect) captures up to ``camera.max_inflight``
frames ahead on background threads; frames are delivered in order, and their map insertion runs on one
mapping thread (the matching, the main map and the zoom) and a second one for the maps beside it (the
odometry map, the ground-truth map, the layers), which the frame waits for. Delivery waits for the same
number of frames whether threads are used or not, so a threaded run and a serial one give the same maps
and decisions bit for bit.

This module owns the stage (:class:`Perception`: intake of every sensor, the pose layers, the safety
queries) and its constants; the sonar arc helpers are in :mod:`robchair.perception_sonar`, the map
protocol, the pose layers and the map-layer workers (a frame into its maps on the mapping threads:
:class:`robchair.perception_layers.FrameInserter`) in :mod:`robchair.perception_layers`, the corridor
and its distance bookkeeping in :mod:`robchair.perception_queries`, the pixel rays of a depth camera in
:mod:`robchair.perception_depth`.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any

import numpy as np

from hw.interfaces import DepthFrame, SonarArrayReading
from robchair.perception_kernels import all_finite, band_xy, obstacle_points
from robchair.perception_layers import (
    FrameInserter,
    MapLayer,
    PointMap,
    _Done,
    layer_pool,
    load_kernels,
    run_evidence_params,
)
from robchair.perception_queries import Corridor, _min_opt, _travelled
from robchair.perception_sonar import (
    _zone_tables,
    explained_arc_fast,
    fuse_array,
    fusion_points,
    load_sonar_kernels,
    mount_geometry,
    pose_transform,
    servo_command_deg,
)
from robchair.platform.frames import se3_planar, transform_points
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import RobChairSpec

POSE_SOURCES = ("odometry", "matched", "ground-truth")
STAT_KEYS = ("depth_frames", "points_in", "points_dropped_nonfinite", "points_outside_grid", "sonar_readings",
             "sonar_fusions_with_obstacle", "sonar_points", "laser_scans", "matches_accepted",
             "matches_rejected")  # fmt: skip
SNAPSHOT_LAG = 2  # frames: the loop sees the matching and zoom state this many frames back
DEFAULT_BAND_MIN_M = 0.10  # occupancy band starts above the floor's noise
MAP_KINDS = ("probabilistic", "thesis")  # mapping.probabilistic.make_map kinds; the first is the default
SONAR_FREE_RANGE_M = 1.0  # the thesis trusts SRF08 readings under 1 m: free up to here without an echo
_WARMED: set[str] = set()  # map kinds whose kernels this process has loaded


class Perception(FrameInserter):
    """Owns the maps and the obstacle distances of one run.

    Args:
        spec: platform spec (mounts, body size).
        map: the map depth frames and laser scans go into (``insert(points_world, sensor_origin)``);
            default a :class:`mapping.vhv.VHVMap` on ``grid``.
        grid: grid of the default maps (default 20 m x 20 m at 5 cm around the origin).
        sonar_map: map of the sonar points (default another VHV map on ``grid``; None: the main map).
        band: (z_min, z_max) m of the chair's height band; z_max None = the chair's height.
        camera_stride: pixel stride of the depth points used for the corridor distance.
        threaded: insert frames into the maps on background threads (the main map, and the maps beside it).
        frames: extra sensor frames ``{frame_id: T_base_frame (4, 4)}`` beyond the spec's mounts.
        tolerance: merge tolerance of the default VHV maps, m.
        matcher: a :class:`mapping.matching.ScanMatcher` to correct depth frames by scan-to-map matching
            (None: no matching; ``pose="matched"`` makes a default one).
        pose: the pose the main map is built with: ``"odometry"``, ``"matched"`` or ``"ground-truth"``.
        ground_truth: ``() -> T_world_base`` (4, 4), the pose source of ``pose="ground-truth"``.
        zoom_half_width: half-width, m, of the fine square around the chair (None: no zoom).
        zoom_factor: refinement of the zoom (fine cell = grid cell / factor).
        clear_no_return: a depth pixel without a return gives free space along its ray up to the
            camera's ``max_range_m`` in maps that keep free space (OctoMap's max-range rays): open
            space above the horizon and beyond the range clears people who walked there. A return
            lost on a surface too close or too dark is cleared through too (the sonars cover the
            close range; the safety layer's distances come from the frames' points, not the map).
        depth_max_range_m: the depth camera's maximum range, m (None: its ``max_range_m`` attribute,
            if it has one; without a range, no-return pixels give nothing).
        map_kind: kind of the default maps (and of :meth:`new_map`): ``"probabilistic"`` (default) or
            ``"thesis"`` (accumulate only); see :data:`MAP_KINDS`.
        evidence_params: :class:`mapping.probabilistic.EvidenceParams` of the probabilistic maps
            (default: :func:`robchair.perception_layers.run_evidence_params`, dynamic decay on;
            depth frames carry their capture stamps as its clock).
        evaluation_every: the evaluation maps (the pose maps other than the main one and the
            odometry map, and the :meth:`add_layer` layers) take every ``evaluation_every``-th depth
            frame (the 0th, k-th, ...); the main map, the odometry map (what a recorded bag of the run
            maps back to) and the zoom take every frame. 1 (default): every frame.
        match_every: with a matcher, every ``match_every``-th depth frame (the 0th, k-th, ...) is
            registered; the frames between are placed with the last ``map -> odom``, i.e. by odometry
            from the last match. 1 (default): every frame.

    Raises:
        ConfigError: an unknown ``pose`` or ``map_kind``, ``"ground-truth"`` without ``ground_truth``,
            or ``evaluation_every`` or ``match_every`` < 1.
    """

    def __init__(
        self,
        spec: RobChairSpec,
        *,
        map: PointMap | None = None,
        grid: Any = None,
        sonar_map: PointMap | str | None = "default",
        band: tuple[float, float | None] = (DEFAULT_BAND_MIN_M, None),
        camera_stride: int = 4,
        threaded: bool = False,
        frames: dict[str, np.ndarray] | None = None,
        tolerance: float = 0.05,
        matcher: Any = None,
        pose: str = "odometry",
        ground_truth: Callable[[], np.ndarray] | None = None,
        zoom_half_width: float | None = None,
        zoom_factor: int = 5,
        map_kind: str = MAP_KINDS[0],
        evidence_params: Any = None,
        clear_no_return: bool = True,
        depth_max_range_m: float | None = None,
        evaluation_every: int = 1,
        match_every: int = 1,
    ) -> None:
        from mapping.grid import GridSpec
        from mapping.vhv import VHVMap
        from robchair.platform.errors import ConfigError

        if pose not in POSE_SOURCES:
            raise ConfigError(f"pose = {pose!r}: expected one of {', '.join(POSE_SOURCES)}")
        if pose == "ground-truth" and ground_truth is None:
            raise ConfigError("pose = 'ground-truth' needs a ground-truth pose source (a simulated chair)")
        if map_kind not in MAP_KINDS:
            raise ConfigError(f"map kind {map_kind!r}: expected one of {', '.join(MAP_KINDS)}")
        for name, every in (("evaluation_every", evaluation_every), ("match_every", match_every)):
            if int(every) < 1:
                raise ConfigError(f"{name} = {every!r}: expected an integer >= 1")
        self.evaluation_every, self.match_every = int(evaluation_every), int(match_every)
        self.spec = spec
        self.map_kind = map_kind
        self.tolerance = float(tolerance)
        if evidence_params is None and map_kind == "probabilistic":
            evidence_params = run_evidence_params()
        self.evidence_params = evidence_params
        self.clear_no_return = bool(clear_no_return)
        self.depth_max_range_m = depth_max_range_m
        self._camera_range: float | None = None
        self._rays: dict[tuple[str, int, int], np.ndarray] = {}
        self.grid = grid if grid is not None else GridSpec(cell_size=0.05, size_x=20.0, size_y=20.0)
        self.map: PointMap = map if map is not None else self.new_map()
        if isinstance(sonar_map, str):
            sonar_map = self.new_map()
        self.sonar_map: PointMap = sonar_map if sonar_map is not None else self.map
        if matcher is None and pose == "matched":
            from mapping.matching import ScanMatcher

            matcher = ScanMatcher()
        self.matcher = matcher
        self.pose = pose
        self.ground_truth = ground_truth
        # the maps of each pose source; the main one is self.map
        self.pose_maps: dict[str, PointMap] = {pose: self.map}
        if matcher is not None and "matched" not in self.pose_maps:
            self.pose_maps["matched"] = VHVMap(self.grid, tolerance)
        if pose != "odometry":
            self.pose_maps["odometry"] = self.new_map()
        if matcher is not None and not hasattr(self.pose_maps["matched"], "structures"):
            raise ConfigError(f"scan-to-map matching needs a VHV map; got {type(self.pose_maps['matched'])}")
        self.match_ms: list[float] = []
        self.zoom: Any = None
        self.zoom_half_width = zoom_half_width
        if zoom_half_width is not None:
            from mapping.zoom import ZoomMap

            if not (math.isfinite(zoom_half_width) and zoom_half_width > 0):
                raise ConfigError(f"zoom_half_width = {zoom_half_width!r}: expected metres > 0")
            self.zoom = ZoomMap(self.grid, tolerance, factor=zoom_factor)
            if getattr(self.map, "spec", None) == self.grid and hasattr(self.map, "structures_at"):
                self.zoom.coarse = self.map  # the main map is the coarse level: one transform feeds both
        self.band = (float(band[0]), float(band[1]) if band[1] is not None else float(spec.body.height))
        self.corridor = Corridor.from_spec(spec)
        self.camera_stride = int(camera_stride)
        self.layers: list[MapLayer] = []
        self._frames: dict[str, np.ndarray] = {n: m.transform() for n, m in spec.mounts.items()}
        self._frames.update(frames or {})
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="perception-map") if threaded else None
        # the maps beside the main one (odometry, ground truth, layers) on a second mapping thread
        self._layer_pool = layer_pool() if threaded else None
        self._pending: deque[Future[None]] = deque()
        self._layer_futs: deque[Future[None]] = deque()  # frames on the layer thread (perception_layers)
        self._inflight: deque[tuple[Any, dict[str, np.ndarray], list[np.ndarray], Pose2D]] = deque()
        self._lock = threading.Lock()
        self._depth: tuple[float | None, Pose2D] | None = None  # (distance at capture, pose at capture)
        self._zoom_depth: tuple[float | None, Pose2D] | None = None  # the same from the zoom's fine cells
        # what the loop sees of the mapping thread's work: the state after frame k - SNAPSHOT_LAG when
        # frame k is delivered, threaded or not (so both runs decide the same, bit for bit)
        self._seq = 0
        self._after_frame: dict[int, tuple[np.ndarray, float | None, Pose2D, np.ndarray | None]] = {}
        # the zoom's fine cells in the band, (N, 2) in base_link at the pose of that frame (sonar echoes)
        self._zoom_xy: tuple[np.ndarray, Pose2D] | None = None
        self._frame_futs: dict[int, Future[None]] = {}
        self._t_map_odom = np.eye(4)
        self._sonar: dict[str, float | None] = {}
        self._sonar_arc: dict[str, tuple[np.ndarray, Pose2D]] = {}  # per array: (arc (N, 2) base_link, pose)
        self._scan_world: np.ndarray | None = None  # (M, 2) the last laser scan's returns placed at its pose
        self._servo: dict[str, float] = {}
        self._t_mount: dict[str, tuple[float, np.ndarray]] = {}  # per sonar array: (joint, T_base_array)
        self.map_ms: list[float] = []
        #: CPU-side seconds spent in each map's inserts (``{layer: s}``; "matching" for registration)
        self.layer_s: dict[str, float] = {}
        self.stats = dict.fromkeys(STAT_KEYS, 0)
        self.last_depth_stamp_ns: int | None = None

    def new_map(self) -> PointMap:
        """An empty map of this stage's kind on its grid (``map_kind``, ``tolerance``, evidence params)."""
        from mapping.probabilistic import make_map

        params = self.evidence_params if self.map_kind == "probabilistic" else None
        return make_map(self.grid, self.tolerance, self.map_kind, params)  # type: ignore[arg-type]

    def warm_up(self) -> None:
        """Insert one sonar reading and two points into a scratch map of this kind, once per process.

        The first insertion imports and loads the compiled mapping kernels (seconds on a cold start):
        the runtime calls this before its clock starts, so that its first cycle keeps its deadline.
        """
        if self.map_kind not in _WARMED:
            load_kernels(self.new_map(), self.spec.sonar_arrays.outer_sonar_deg, SONAR_FREE_RANGE_M)
            load_sonar_kernels(self.new_map())
            _WARMED.add(self.map_kind)

    # --- frames -----------------------------------------------------------------------------------

    def t_base_sensor(self, frame_id: str) -> np.ndarray:
        """``T_base_sensor`` (4, 4) of a sensor frame (the spec's mounts plus ``frames``)."""
        try:
            return self._frames[frame_id]
        except KeyError:
            from robchair.platform.errors import ConfigError

            raise ConfigError(
                f"sensor frame {frame_id!r} has no mount; known: {', '.join(sorted(self._frames))}"
            ) from None

    def add_layer(self, name: str, map: PointMap, t_world_base: Callable[[], np.ndarray]) -> MapLayer:
        """Feed ``map`` with the same frames placed with ``t_world_base()`` (see :class:`MapLayer`)."""
        layer = MapLayer(name, map, t_world_base)
        self.layers.append(layer)
        return layer

    # --- depth camera -----------------------------------------------------------------------------

    def take_depth(self, camera: Any, pose: Pose2D) -> DepthFrame | None:
        """Take a frame from ``camera`` at odometry ``pose``; returns the frame delivered now, if any.

        With a camera that captures in the background (``submit_read``), the frame delivered is the
        one taken ``camera.max_inflight`` calls earlier.
        """
        t_world_base = {"odometry": se3_planar(pose.x, pose.y, pose.theta)}
        if self.ground_truth is not None and "ground-truth" in self.pose_maps:
            t_world_base["ground-truth"] = np.asarray(self.ground_truth(), dtype=float)
        layer_poses = [layer.t_world_base() for layer in self.layers]
        self._camera_range = self.depth_max_range_m or getattr(camera, "max_range_m", None)
        submit = getattr(camera, "submit_read", None)
        depth = int(getattr(camera, "max_inflight", 0)) if submit is not None else 0
        fut: Any = submit() if submit is not None else _Done(camera.read())
        self._inflight.append((fut, t_world_base, layer_poses, pose))
        out = None
        while len(self._inflight) > depth:
            out = self._deliver()
        return out

    def _deliver(self) -> DepthFrame:
        fut, t_world_base, layer_poses, pose = self._inflight.popleft()
        frame: DepthFrame = fut.result()
        t_base_sensor = self.t_base_sensor(frame.frame_id)
        s = self.camera_stride
        pts = np.asarray(frame.points)
        sub = pts[::s, ::s].reshape(-1, 3) if pts.ndim == 3 else pts[::s].reshape(-1, 3)
        sub = transform_points(t_base_sensor, sub[np.isfinite(sub).all(axis=1)], np.float32)
        z0, z1 = self.band
        band = sub[(sub[:, 2] >= z0) & (sub[:, 2] <= z1)]
        self._depth = (self.corridor.distance_ahead(band[:, :2]), pose)
        self.last_depth_stamp_ns = frame.stamp_ns
        placed = [(ly.map, tw @ t_base_sensor, False) for ly, tw in zip(self.layers, layer_poses)]
        self._take_snapshot()
        fut = self._submit(self._insert_frame, frame, t_world_base, t_base_sensor, placed, pose, self._seq)
        if fut is not None:
            self._frame_futs[self._seq] = fut
        self._seq += 1
        return frame

    def _take_snapshot(self) -> None:
        """Make the mapping state after frame ``seq - SNAPSHOT_LAG`` the one the loop sees."""
        if self.matcher is None and self.zoom is None:
            return
        k = self._seq - SNAPSHOT_LAG
        fut = self._frame_futs.pop(k, None)
        if fut is not None:
            fut.result()
        snap = self._after_frame.pop(k, None)
        if snap is not None:
            self._t_map_odom, d, pose, xy = snap
            self._zoom_depth = (d, pose) if self.zoom is not None else None
            self._zoom_xy = (xy, pose) if self.zoom is not None and xy is not None else None

    def _submit(self, fn: Callable[..., None], *args: Any) -> Future[None] | None:
        if self._pool is None:
            fn(*args)
            return None
        while self._pending and self._pending[0].done():
            self._pending.popleft().result()  # a mapping error surfaces here, in the loop
        while len(self._pending) >= 3:
            self._pending.popleft().result()
        fut = self._pool.submit(fn, *args)
        self._pending.append(fut)
        return fut

    def call_with_maps(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` where it may read the maps: on the mapping thread after the insertions submitted so
        far (at once, on the caller's thread, without one or after :meth:`close`). Not waited for; ``fn``
        handles its own exceptions (on the mapping thread they would be lost)."""
        pool = self._pool
        if pool is not None:

            def after_layers() -> None:
                wait(list(self._layer_futs))  # the maps beside the main one catch up first (not popped:
                fn()  # their errors surface in the loop as before)

            try:
                pool.submit(after_layers)
                return
            except RuntimeError:  # shut down meanwhile: the maps are final
                pass
        fn()

    def depth_distance_m(self, pose: Pose2D) -> float | None:
        """Nearest depth point in the band inside the corridor ahead, from the front edge, m.

        Measured at the pose of its frame; the forward travel since then is taken off. With a zoom,
        the nearer of this and :meth:`zoom_distance_m` (the map remembers what the camera no longer
        sees, e.g. closer than its minimum range).
        """
        return _min_opt(_travelled(self._depth, pose), self.zoom_distance_m(pose))

    def zoom_distance_m(self, pose: Pose2D) -> float | None:
        """Nearest fine zoom cell in the band inside the corridor ahead, from the front edge, m.

        Answered at the zoom's fine resolution (None: no zoom, or nothing ahead in it), measured
        when the last frame was inserted; the forward travel since then is taken off.
        """
        return _travelled(self._zoom_depth, pose)

    def obstacle_points_base(self, pose: Pose2D) -> np.ndarray:
        """Obstacle points (N, 2) in ``base_link`` at odometry ``pose`` all around the chair, m.

        For the safety layer's swept-footprint check (:func:`robchair.platform.safety.swept_distances`):
        the zoom's fine cells in the height band (the local map: walls seen earlier, beside and behind
        the chair too; as of the frame the loop sees, :data:`SNAPSHOT_LAG`), the last laser scan's
        returns in the band, and each sonar array's last fused arc (placed at the pose of its reading).
        Empty (0, 2) when there is none.
        """
        arcs = list(self._sonar_arc.values())
        if self._zoom_xy is not None:
            arcs.append(self._zoom_xy)  # (N, 2) in base_link at the pose of the frame that placed them
        return obstacle_points(pose, self._scan_world, arcs)  # compiled points_in_base

    def _t_main_base(self, pose: Pose2D) -> np.ndarray:
        """``T_world_base`` (4, 4) in the main map's frame for the odometry ``pose``."""
        if self.pose == "ground-truth" and self.ground_truth is not None:
            return np.asarray(self.ground_truth(), dtype=float)
        t = se3_planar(pose.x, pose.y, pose.theta)
        return self.t_map_odom @ t if self.pose == "matched" else t

    @property
    def t_map_odom(self) -> np.ndarray:
        """(4, 4) ``map -> odom`` of the scan-to-map matching (identity without a matcher).

        As the loop sees it: the matcher's transform after the frame delivered :data:`SNAPSHOT_LAG`
        frames ago (the mapping thread may be further), the same threaded or not.
        """
        return np.array(self._t_map_odom)

    # --- sonars -----------------------------------------------------------------------------------

    def add_sonar(self, name: str, reading: SonarArrayReading, pose: Pose2D) -> float | None:
        """Fuse one array reading, map its points, and return the servo angle to turn to (deg; None: none).

        ``name`` is the array's mount (``sonar_array_left``...). The fused arc (where the echo may lie) is
        clipped to the known surfaces at its range inside its cone (the last laser scan's returns and
        the zoom's fine cells in the band, moved to ``pose``: :func:`robchair.perception_sonar.
        explained_arc_at`) before its distance ahead is taken: at 31 cm and under, three agreeing sonars
        give a 120 deg arc (zone 3 is empty there), which reaches from a door post beside the chair
        into the corridor ahead.
        """
        mount = self.spec.mounts.get(name)
        self.stats["sonar_readings"] += 1
        if mount is None:
            self._sonar[name] = None
            self._sonar_arc.pop(name, None)
            return None
        fin, nan = math.isfinite, math.nan
        r1, r2, r3 = reading.ranges_m
        arrays = self.spec.sonar_arrays
        fusion = fuse_array(
            float(r1) if fin(r1) else nan, float(r2) if fin(r2) else nan, float(r3) if fin(r3) else nan,
            tables=_zone_tables(arrays.outer_sonar_deg),
        )  # fmt: skip
        pts = fusion_points(fusion)
        geo = mount_geometry(mount)
        joint = arrays.joint_angle(reading.servo_angle_deg)
        if fusion.has_obstacle:  # the arc; the laser and the zoom map locate the echo's surface if known
            arc, self._sonar[name] = explained_arc_fast(
                fusion, geo, joint, pose, self._scan_world, self._zoom_xy, self.corridor
            )
            self._sonar_arc[name] = (np.asarray(arc, dtype=float)[:, :2], pose)
            self.stats["sonar_fusions_with_obstacle"] += 1
        else:
            self._sonar[name] = None
            self._sonar_arc.pop(name, None)
        sonar_map = self.sonar_map
        insert_sonar = getattr(sonar_map, "insert_sonar", None)
        t0 = time.perf_counter()
        if insert_sonar is not None or len(pts):
            t = pose_transform(pose) @ self._t_base_array(name, mount, joint)
            if insert_sonar is not None:  # evidence: free cone up to the range, occupied at it (or to max)
                insert_sonar(fusion, t, max_range_m=SONAR_FREE_RANGE_M)
            else:  # the cone's points (pts @ R.T + t, as transform_points)
                insert = getattr(sonar_map, "insert_few", None) or sonar_map.insert
                insert(pts @ t[:3, :3].T + t[:3, 3], sensor_origin=t[:3, 3])
            self.stats["sonar_points"] += len(pts)
        with self._lock:
            self.layer_s["sonar"] = self.layer_s.get("sonar", 0.0) + time.perf_counter() - t0
        if mount.joint is None:
            return None
        cmd = servo_command_deg(
            fusion, self._servo.get(name, reading.servo_angle_deg), gain=0.5, max_step_deg=15.0
        )
        self._servo[name] = cmd
        return float(cmd)

    def _t_base_array(self, name: str, mount: Any, joint: float) -> np.ndarray:
        """``T_base_array`` (4, 4) of sonar array ``name`` with its servo at ``joint`` rad (read-only).

        ``mount.transform(joint)``, kept per array for its last servo angle: the servo turns in steps
        and holds still between echoes, so most readings come at the angle of the one before."""
        kept = self._t_mount.get(name)
        if kept is not None and kept[0] == joint:
            return kept[1]
        t = mount_geometry(mount).t_base_array(joint)  # mount.transform(joint), bit for bit
        t.setflags(write=False)
        self._t_mount[name] = (joint, t)
        return t

    def sonar_distance_m(self) -> float | None:
        """Nearest fused sonar obstacle ahead over the arrays' latest readings, from the front edge, m."""
        ds = [d for d in self._sonar.values() if d is not None]
        return min(ds) if ds else None

    # --- laser scanner ----------------------------------------------------------------------------

    def add_scan(self, frame_id: str, points: Any, pose: Pose2D) -> None:
        """Insert a laser scan: ``points`` (N, 3) in ``frame_id`` (NaN rows = no return), at ``pose``."""
        t = self._t_main_base(pose) @ self.t_base_sensor(frame_id)
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        if self.pose == "odometry" and all_finite(p):  # the map's placement is odometry's: one product
            placed = w = transform_points(t, p)
        else:
            t_odom = se3_planar(pose.x, pose.y, pose.theta) @ self.t_base_sensor(frame_id)
            w, placed = transform_points(t_odom, p[np.isfinite(p).all(axis=1)]), transform_points(t, p)
        self._scan_world = band_xy(w, self.band)
        self._submit(lambda: self.map.insert(placed, sensor_origin=t[:3, 3]))
        self.stats["laser_scans"] += 1

    def scan_points_odom(self) -> np.ndarray | None:
        """The last laser scan's returns in the height band: (M, 2) in ``odom``, m (None: no scan yet)."""
        return self._scan_world

    # --- maps -------------------------------------------------------------------------------------

    def flush(self) -> None:
        """Deliver the frames still being captured and wait for every map insertion."""
        while self._inflight:
            self._deliver()
        self.wait_for_maps()

    def wait_for_maps(self) -> None:
        """Wait for the map insertions already submitted (frames still being captured stay in flight),
        those of the maps beside the main one too."""
        while self._pending:
            self._pending.popleft().result()
        self._drain_layers()  # the mapping thread is idle now: nothing is appended meanwhile

    def occupancy_2d(self, which: PointMap | None = None, unknown: int = -1) -> np.ndarray:
        """Three-valued 2D map (int8, grid shape) of the height band in a map (default the main one).

        ``nav_msgs/OccupancyGrid`` codes: 100 occupied, 0 free, ``unknown`` (default -1) where nothing
        is known; pass ``unknown=100`` to treat unknown as blocked or 0 as free. A probabilistic map
        answers from its evidence (occupied above its occupancy threshold, remembered free space); the
        thesis map knows no free space: a cell is 100 when a structure overlaps the band, 0 when it
        holds only structures outside the band (seen, nothing in the band), unknown otherwise.

        Raises:
            MappingError: ``unknown`` not one of -1, 0, 100.
        """
        from mapping.derived import occupancy_codes

        self.flush()
        return occupancy_codes(which if which is not None else self.map, self.band, unknown=unknown)

    def occupied_2d(self, which: PointMap | None = None) -> np.ndarray:
        """2D occupancy (bool, grid shape) of the height band: True where the map is occupied.

        Unknown is not occupied (for a probabilistic map: an interval overlapping the band at or above
        the occupancy threshold; for the thesis map: a structure overlapping the band).
        """
        from mapping.derived import occupancy_2d
        from mapping.vhv import VHVMap

        m = which if which is not None else self.map
        if isinstance(m, VHVMap) and getattr(m, "occupancy_2d", None) is None:  # the thesis map: its
            self.flush()  # codes are 100 exactly where a structure overlaps the band; that grid itself
            return occupancy_2d(m, self.band[0], self.band[1])
        return np.asarray(self.occupancy_2d(which) == 100)

    def free_2d(self, which: PointMap | None = None, unknown_is_free: bool = False) -> np.ndarray:
        """Cells (bool, grid shape) where the height band is free; unknown counts as free only if asked."""
        return np.asarray(self.occupancy_2d(which, unknown=0 if unknown_is_free else 100) == 0)

    def close(self) -> None:
        """Finish pending work and stop the mapping thread."""
        try:
            self.flush()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None
            if self._layer_pool is not None:
                self._layer_pool.shutdown(wait=True)
                self._layer_pool = None
