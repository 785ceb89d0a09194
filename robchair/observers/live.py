"""The live view of a run: the bag's topics, the map and the safety decisions, sent while the chair drives.

:class:`LiveObserver` is an observer of the one runtime, on any backend. On the loop's thread it only
takes references to the cycle's data (:class:`robchair.observers.recorder.CycleSnapshot`, plus a
copy of the thinned cloud when someone wants it) and puts them on a bounded queue; when the queue is
full the oldest item is dropped and counted. A publisher thread builds the messages with the
recorder's builder (:class:`robchair.observers.recorder.RunTopics`, so the topics, types and frame
ids are those of the bag) and hands them to the sinks. Odometry and TF go at most at ``rate_hz``
(20 Hz); a cycle with a sensor reading, a stop or a change of the safety decision always goes. The
sinks:

- :class:`robchair.viz.foxglove_live.FoxgloveSink`: a Foxglove WebSocket server (Foxglove, Lichtblick);
  ROS 2 CDR with ``ros2msg`` schemas; nothing is queued or serialised while no client subscribes;
- :class:`robchair.viz.rerun_live.RerunSink`: a Rerun recording stream (a viewer it connects to, or
  one it serves), with the entity paths of ``recording.rrd``.

Topics beyond the bag's (the bag's are listed in :mod:`robchair.observers.recorder`):

=====================  ===============================  ================================================
topic                  type                             content
=====================  ===============================  ================================================
``/map``               nav_msgs/OccupancyGrid           the run's main map in the safety height band
                                                        (100 occupied, 0 free, -1 unknown), frame
                                                        ``odom`` (odometry pose) or ``map``, every
                                                        ``map_period_s`` (1 s) and at the end
``/vhv/markers``       visualization_msgs/MarkerArray   the main map's VHV structures as boxes (one
                                                        CUBE_LIST per box size, namespace ``odometry``
                                                        / ``matched`` / ``ground-truth``), every
                                                        ``boxes_period_s`` (10 s) and at the end
``/sonar/cones``       visualization_msgs/MarkerArray   each sonar's cone section at its range (one
                                                        LINE_LIST per array, in the array's frame; no
                                                        echo: grey, at the maximum range)
``/rosout``            rcl_interfaces/Log               the safety layer's decisions: each stop (WARN)
                                                        and the start and end of a limited twist (INFO)
``/diagnostics``       diagnostic_msgs/DiagnosticArray  the samples the bag gets (1 Hz)
=====================  ===============================  ================================================

The maps are read on the mapping thread (:meth:`robchair.perception.Perception.call_with_maps`), or on
the loop's thread when the perception has none, only when a sink wants them.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from robchair.loop_types import CycleResult, LoopView, Observer, RunResult
from robchair.observers.bag_writer import RosMessages
from robchair.observers.recorder import CLOUD_TOPIC, RunTopics
from robchair.platform.frames import MAP, ODOM

log = logging.getLogger(__name__)

MAP_TOPIC = "/map"
MARKERS_TOPIC = "/vhv/markers"
CONES_TOPIC = "/sonar/cones"
SAFETY_TOPIC = "/rosout"
DIAGNOSTICS_TOPIC = "/diagnostics"
#: the topics of the live view beyond the bag's
LIVE_TOPICS = {
    MAP_TOPIC: "nav_msgs/msg/OccupancyGrid",
    MARKERS_TOPIC: "visualization_msgs/msg/MarkerArray",
    CONES_TOPIC: "visualization_msgs/msg/MarkerArray",
    SAFETY_TOPIC: "rcl_interfaces/msg/Log",
    DIAGNOSTICS_TOPIC: "diagnostic_msgs/msg/DiagnosticArray",
}
QUEUE_SIZE = 32
#: odometry and TF at most this often (a cycle with a sensor reading, a stop or a change of the
#: safety decision always goes)
RATE_HZ = 20.0
MAP_PERIOD_S = 1.0
#: the VHV boxes change slowly and cost most to build (one message object per box)
BOXES_PERIOD_S = 10.0
#: VHV boxes sent per map at most (an even subsample beyond)
MAX_BOXES = 4000
#: how long the end of a run waits for the queue to drain, s
DRAIN_TIMEOUT_S = 10.0
#: the types of the bag's topics (robchair.observers.recorder)
LIVE_TYPES = ("nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage", "sensor_msgs/msg/Range",
              "sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/LaserScan")  # fmt: skip
INFO, WARN = 20, 30  # rcl_interfaces/msg/Log levels


class LiveSink:
    """Where the live messages go (base class; the methods but :meth:`send` are optional)."""

    def open(self, topics: dict[str, str], parents: dict[str, str], t0_ns: int, store: Any) -> None:
        """Before the first message: topic -> type, the TF tree (child -> parent), the run's start time,
        the ``rosbags`` type store the messages come from."""

    def wants(self, topic: str) -> bool:
        """Whether a message on ``topic`` would be used now (called on the loop's thread: cheap)."""
        return True

    def active(self) -> bool:
        """Whether any topic is wanted now."""
        return True

    def resend_static(self) -> bool:
        """True once after a client arrived that needs the static transforms again."""
        return False

    def send(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        """One message (publisher thread)."""
        raise NotImplementedError

    def close(self) -> None:
        """After the last message."""


class _Fanout(RosMessages):
    """The builder's output, to every sink that wants the topic."""

    def __init__(self, sinks: list[LiveSink]) -> None:
        super().__init__()
        self.sinks = sinks
        self.sent: dict[str, int] = {}

    def write(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        n = 0
        for s in self.sinks:
            if s.wants(topic):
                s.send(topic, msgtype, stamp_ns, msg)
                n = 1
        self.sent[topic] = self.sent.get(topic, 0) + n


class LiveObserver(Observer):
    """Sends a run to live sinks without slowing the loop (module docstring).

    Args:
        sinks: where the messages go (opened at the episode's start, closed by :meth:`close`).
        queue_size: cycles waiting for the publisher thread at most (the oldest is dropped beyond).
        rate_hz: odometry and TF at most this often, Hz (:data:`RATE_HZ`).
        map_period_s: time between 2D maps on the run's clock, s.
        boxes_period_s: time between VHV box sets on the run's clock, s.
        max_boxes: VHV boxes per map at most.

    After the run, ``result.extra["live"]`` holds the counts: cycles queued, cycles skipped because no
    one listened, cycles thinned out by ``rate_hz``, items dropped from a full queue, messages sent per
    topic, publisher errors.
    """

    def __init__(self, sinks: list[LiveSink], queue_size: int = QUEUE_SIZE, rate_hz: float = RATE_HZ,
                 map_period_s: float = MAP_PERIOD_S, boxes_period_s: float = BOXES_PERIOD_S,
                 max_boxes: int = MAX_BOXES) -> None:  # fmt: skip
        from mapping.export.meshes import height_colors  # matplotlib: imported here, not during the run

        self.sinks = list(sinks)
        self.scheme = RunTopics()
        self.period_ns = round(1e9 / float(rate_hz))
        self.map_period_ns = round(float(map_period_s) * 1e9)
        self.boxes_period_ns = round(float(boxes_period_s) * 1e9)
        self.max_boxes = int(max_boxes)
        #: the box colours by height, as the recording's and the report's (viridis over the boxes' range)
        self._lut = np.round(height_colors(np.linspace(0.0, 1.0, 256))[:, :3] * 255).astype(np.uint8)
        self.queued = self.skipped = self.thinned = self.dropped = self.errors = 0
        self.publisher_cpu_s = 0.0  # CPU time of the publisher thread (set when it ends)
        self._out = _Fanout(self.sinks)
        self._out.precompile(sorted({*LIVE_TYPES, *LIVE_TOPICS.values()}))
        self._queue: deque[Any] = deque()
        self._size = int(queue_size)
        self._ready = threading.Condition()
        self._thread: threading.Thread | None = None
        self._diag: Any = None
        self._last_diag: Any = None
        self._next_map_ns = self._next_boxes_ns = self._next_ns = 0
        self._limited = self._limited_seen = False
        self._t0_ns = 0

    # --- loop thread ----------------------------------------------------------------------------
    def episode_start(self, runtime: LoopView) -> None:
        from robchair.observers.diagnostics import DiagnosticsObserver

        self.scheme.start(runtime)
        self._t0_ns = self._next_map_ns = self._next_boxes_ns = self._next_ns = runtime.t0_ns
        self._out.sinks = self.sinks
        topics = {**self.scheme.topics(), **LIVE_TOPICS}
        for s in self.sinks:
            s.open(topics, self.scheme.parents(), runtime.t0_ns, self._out.store)
        self._diag = next((ob for ob in runtime.observers if isinstance(ob, DiagnosticsObserver)), None)
        self._thread = threading.Thread(target=self._publish, name="robchair-live", daemon=True)
        self._thread.start()
        self._put(("static", runtime.t0_ns))

    def after_cycle(self, runtime: LoopView, cycle: CycleResult) -> None:
        if not any(s.active() for s in self.sinks):
            self.skipped += 1
            return
        snap = self.scheme.snapshot(runtime, cycle, cloud=self._wants(CLOUD_TOPIC))
        diag = self._diag.last_record if self._diag is not None else None
        if diag is self._last_diag:
            diag = None
        else:
            self._last_diag = diag
        limited = bool(cycle.decision.limited)
        due = cycle.stamp_ns >= self._next_ns
        if due:
            self._next_ns = cycle.stamp_ns + self.period_ns
        fresh = snap.sonars or snap.scan is not None or snap.cloud is not None or cycle.stops
        if due or fresh or diag is not None or limited != self._limited_seen:
            self._limited_seen = limited
            self._put(("cycle", snap, cycle.stops, cycle.decision, diag))
            self.queued += 1
        else:
            self.thinned += 1
        if cycle.stamp_ns >= self._next_map_ns and (self._wants(MAP_TOPIC) or self._wants(MARKERS_TOPIC)):
            self._next_map_ns = cycle.stamp_ns + self.map_period_ns
            p, stamp = runtime.perception, cycle.stamp_ns
            boxes = stamp >= self._next_boxes_ns and self._wants(MARKERS_TOPIC)
            if boxes:
                self._next_boxes_ns = stamp + self.boxes_period_ns
            p.call_with_maps(lambda: self._grab_map(p, stamp, boxes))

    def episode_end(self, runtime: LoopView, result: RunResult) -> None:
        if self._thread is None:
            return
        if any(s.active() for s in self.sinks):  # the final maps (the perception is closed)
            self._grab_map(runtime.perception, runtime.backend.clock.now_ns(), True)
        self._put(None)
        self._thread.join(DRAIN_TIMEOUT_S)
        if self._thread.is_alive():
            log.warning("live view: the publisher did not drain its queue in %.0f s", DRAIN_TIMEOUT_S)
        result.extra["live"] = self.stats()

    def stats(self) -> dict[str, Any]:
        """Counts of the live view so far (``result.extra["live"]``)."""
        sent = dict(sorted(self._out.sent.items()))
        return {"cycles_queued": self.queued, "cycles_skipped_no_client": self.skipped,
                "cycles_thinned": self.thinned, "dropped_queue_full": self.dropped, "messages_sent": sent,
                "publisher_errors": self.errors,
                "publisher_cpu_s": round(self.publisher_cpu_s, 3)}  # fmt: skip

    def close(self) -> None:
        """Close the sinks (stops a server)."""
        for s in self.sinks:
            try:
                s.close()
            except Exception as exc:  # a sink failing at the end does not hide the run's outcome
                log.warning("live view: closing %s failed: %s", type(s).__name__, exc)

    def __enter__(self) -> LiveObserver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _wants(self, topic: str) -> bool:
        return any(s.wants(topic) for s in self.sinks)

    def _put(self, item: Any) -> None:
        with self._ready:
            if item is not None and len(self._queue) >= self._size:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(item)
            self._ready.notify()

    def _grab_map(self, p: Any, stamp_ns: int, boxes: bool) -> None:
        """Copy the main map's 2D codes and (``boxes``) structures where the maps may be read; queue them."""
        from mapping.derived import occupancy_codes

        try:
            m = p.map
            codes = np.array(occupancy_codes(m, p.band))
            cols = None
            if boxes:
                s = m.structures()
                cols = (np.array(s.i), np.array(s.j), np.array(s.bottom), np.array(s.top))
        except Exception as exc:
            self.errors += 1
            log.warning("live view: reading the map failed: %s", exc)
            return
        pose = str(getattr(p, "pose", "odometry"))
        self._put(("map", stamp_ns, pose, m.spec, codes, cols))

    # --- publisher thread -----------------------------------------------------------------------
    def _publish(self) -> None:
        t0 = time.thread_time()
        try:
            self._drain()
        finally:
            self.publisher_cpu_s = time.thread_time() - t0

    def _drain(self) -> None:
        while True:
            with self._ready:
                while not self._queue:
                    self._ready.wait()
                item = self._queue.popleft()
            if item is None:
                return
            try:
                self._send(item)
            except Exception as exc:  # a client that went away mid-message does not touch the run
                self.errors += 1
                (log.warning if self.errors == 1 else log.debug)("live view: %s: %s", type(exc).__name__, exc)

    def _send(self, item: tuple[Any, ...]) -> None:
        out = self._out
        if item[0] == "static" or any(s.resend_static() for s in self.sinks):
            self.scheme.write_static(out, item[1] if item[0] == "static" else self._t0_ns)
        if item[0] == "cycle":
            _, snap, stops, decision, diag = item
            self.scheme.write_cycle(out, snap)
            if snap.sonars and self._wants(CONES_TOPIC):
                self._send_cones(out, snap)
            for st in stops:
                out.log(
                    SAFETY_TOPIC, st.stamp_ns, WARN, "safety", f"stop: {st.reason.value} {st.detail}".strip()
                )
            if bool(decision.limited) != self._limited:
                self._limited = bool(decision.limited)
                text = "twist limited" if self._limited else "twist no longer limited"
                out.log(SAFETY_TOPIC, snap.stamp_ns, INFO, "safety", f"{text} (v {decision.v:.2f} m/s, "
                        f"w {decision.w:.2f} rad/s)")  # fmt: skip
            if diag is not None:
                from robchair.observers.diagnostics import write_diagnostics

                write_diagnostics(out, *diag)
        elif item[0] == "map":
            self._send_map(out, *item[1:])

    def _send_cones(self, out: RosMessages, snap: Any) -> None:
        from robchair.observers.recorder import sonar_frame
        from robchair.viz.rerun_recording import ECHO_COLOR, NO_ECHO_COLOR, cone_strip

        statics = {child: t for _, child, t in self.scheme.statics}
        lines: list[tuple[str, str, int, np.ndarray, np.ndarray]] = []
        for mid, (name, reading) in enumerate(snap.sonars):  # one LINE_LIST per array, in its frame
            lo, hi, fov = self.scheme.sonar_limits.get(name, (0.0, 6.0, 1.0))
            pts, rgba = [], []
            for k, r in enumerate(reading.ranges_m, 1):
                echo = bool(np.isfinite(r)) and lo <= r <= hi
                strip = cone_strip(r if echo else hi, fov)
                seg = np.repeat(strip, 2, axis=0)[1:-1]  # the polyline as segments
                t = statics.get(sonar_frame(name, k), np.eye(4))
                pts.append(seg @ t[:3, :3].T + t[:3, 3])
                rgb = np.asarray(ECHO_COLOR if echo else NO_ECHO_COLOR, dtype=np.float64) / 255
                rgba.append(np.tile(np.append(rgb, 1.0), (len(seg), 1)))
            lines.append((name, "sonar_cones", mid, np.vstack(pts), np.vstack(rgba)))
        out.line_markers(CONES_TOPIC, snap.stamp_ns, lines)

    def _send_map(self, out: RosMessages, stamp_ns: int, pose: str, grid: Any, codes: np.ndarray,
                  cols: tuple[np.ndarray, ...] | None) -> None:  # fmt: skip
        frame = ODOM if pose == "odometry" else MAP
        (ou, ov), cs = grid.origin, float(grid.cell_size)
        x0, _, y0, _ = grid.extent
        out.occupancy_grid(MAP_TOPIC, stamp_ns, frame, codes, cs, (x0, y0))
        if cols is None:
            return
        i, j, bottom, top = cols
        if i.size > self.max_boxes:
            keep = np.unique(np.linspace(0, i.size - 1, self.max_boxes).round().astype(np.int64))
            i, j, bottom, top = i[keep], j[keep], bottom[keep], top[keep]
        x, y = (ou + i.astype(np.float64)) * cs, (ov + j.astype(np.float64)) * cs
        mins = np.column_stack([x, y, bottom.astype(np.float64)])
        maxs = np.column_stack([x + cs, y + cs, top.astype(np.float64)])
        z = maxs[:, 2]
        span = float(np.ptp(z)) if z.size else 0.0
        rgb = self._lut[np.round((z - (z.min() if z.size else 0.0)) / (span or 1.0) * 255).astype(np.int64)]
        out.box_markers(MARKERS_TOPIC, stamp_ns, frame, pose, mins, maxs, rgb)
