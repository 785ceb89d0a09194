"""A Rerun recording (``recording.rrd``) of a run folder: the chair, its sensors and its maps on the run's
timeline, in REP-103 axes (x forward, y left, z up), built from the folder's files after the run.

Entities (``<f>`` is the entity of TF frame ``f``: ``world/<root>/.../<parent>/<f>``, the tree of the
bag's ``/tf`` and ``/tf_static``; root frames such as ``odom`` and ``map`` sit at the world origin):

===================================  ================  ==============================================
entity                               archetype         from
===================================  ================  ==============================================
``world``                            ViewCoordinates   RIGHT_HAND_Z_UP (static)
``<child>``                          Transform3D       every ``/tf`` (timed) and ``/tf_static`` (static)
                                                      transform; ``/odom`` when ``/tf`` lacks the pose
``<odom>/driven_path``               LineStrips3D      ``/odom`` positions so far (at most 10 Hz;
                                                      other Odometry topics: ``driven_path_<topic>``)
``<frame>/points``                   Points3D          ``sensor_msgs/PointCloud2`` (finite points,
                                                      thinned to ``max_cloud_points``)
``<frame>/cone``                     LineStrips3D      ``sensor_msgs/Range``: a fan over the field of
                                                      view at the range (no echo: grey, at max range)
``<frame>/scan``                     Points3D          ``sensor_msgs/LaserScan`` returns in range
``world/map/vhv/<map>``              Boxes3D           ``maps.npz`` structures, coloured by height
                                                      (static; at most ``max_boxes`` per map)
``world/map/occupancy``              Mesh3D            the map_server PGM: occupied cells dark, free
                                                      light, unknown left out (static, z = -1 cm)
``world/map/path/<name>``            LineStrips3D      ``maps.npz`` ``path_<name>`` (static)
``map_2d``                           Image             the map_server PGM as a picture (static)
``plots/<name>``                     Scalars           ``/odom`` ``v`` and ``w`` (other Odometry topics:
                                                      ``v_<topic>``...); ``timeseries.csv`` columns
``run/safety``                       TextLog           ``metrics.json`` ``safety.stops``
``run/metrics``                      TextDocument      ``metrics.json`` (static)
===================================  ================  ==============================================

The timeline ``run_time`` counts seconds from the run's start (simulated time in ``robchair sim``).

:class:`MessageLogger` logs the bag's messages; a live run (:mod:`robchair.viz.rerun_live`) goes through
it too, and there ``map_2d``, ``world/map/occupancy`` and ``world/map/vhv/<pose>`` come from the live
view's ``/map`` (nav_msgs/OccupancyGrid) and ``/vhv/markers`` (CUBE_LIST markers), and ``run/safety``
from ``/rosout``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from robchair.run_folder import RunFolder, RunFolderError

RECORDING_NAME = "recording.rrd"
APPLICATION_ID = "robchair"
TIMELINE = "run_time"
#: points kept per depth cloud at most (an even stride over the finite points)
MAX_CLOUD_POINTS = 5000
#: boxes per map at most (an even subsample beyond)
MAX_BOXES = 30000
PATH_PERIOD_S = 0.1
CONE_SEGMENTS = 12
CLOUD_COLOR = (80, 160, 255)
SCAN_COLOR = (255, 60, 60)
ECHO_COLOR = (255, 170, 0)
NO_ECHO_COLOR = (150, 150, 150)
MISSING_VIZ = "the Rerun SDK is not installed: pip install 'robchair[viz]' (rerun-sdk, about 170 MB)"


def import_rerun() -> Any:
    """``rerun``, or a :class:`RunFolderError` that says how to install it."""
    try:
        import rerun
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.split(".")[0] in ("rerun", "rerun_bindings"):
            raise RunFolderError(MISSING_VIZ) from None
        raise
    return rerun


def rerun_available() -> bool:
    """True when the Rerun SDK (the ``viz`` extra) is installed."""
    import importlib.util

    return importlib.util.find_spec("rerun") is not None


def frame_entities(parents: dict[str, str]) -> dict[str, str]:
    """Entity path of every frame of a TF tree given as child -> parent (roots under ``world``).

    Raises:
        RunFolderError: the frames form a cycle.
    """
    rr = import_rerun()
    frames = set(parents) | set(parents.values())
    out: dict[str, str] = {}
    for f in sorted(frames):
        chain = [f]
        while chain[-1] in parents:
            chain.append(parents[chain[-1]])
            if len(chain) > len(frames) + 1:
                raise RunFolderError(f"the TF frames around {f!r} form a cycle")
        out[f] = "/".join(["world", *(rr.escape_entity_path_part(c) for c in reversed(chain))])
    return out


def write_recording(
    run_dir: Path | str,
    out: Path | str | None = None,
    *,
    max_cloud_points: int = MAX_CLOUD_POINTS,
    max_boxes: int = MAX_BOXES,
    name: str | None = None,
) -> Path:
    """Write the run's Rerun recording (default ``<run_dir>/recording.rrd``) and return its path.

    The file appears complete or not at all (written beside, then renamed).

    Args:
        run_dir: a run folder of ``robchair sim`` / ``robchair run``.
        out: where to write the recording instead.
        max_cloud_points: points kept per depth cloud at most.
        max_boxes: VHV boxes logged per map at most.
        name: the recording's id in the viewer (default: the folder's name; pass the final name when
            ``run_dir`` is a staging folder).

    Raises:
        RunFolderError: the folder or one of its files cannot be read, or the Rerun SDK is missing.
    """
    rr = import_rerun()
    run = RunFolder(run_dir)
    target = Path(out) if out is not None else run.path / RECORDING_NAME
    partial = target.with_name(target.name + ".partial")
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=name or run.path.resolve().name)
    rec.save(partial)
    try:
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        _log_run_info(rr, rec, run)
        _log_maps(rr, rec, run, max_boxes)
        _log_timeseries(rr, rec, run)
        if run.bag_path is not None:
            _log_bag(rr, rec, run, max_cloud_points)
        rec.flush()
        rec.disconnect()
    except BaseException:
        rec.disconnect()
        partial.unlink(missing_ok=True)
        raise
    os.replace(partial, target)
    return target


# ---------------------------------------------------------------------- static content
def _log_run_info(rr: Any, rec: Any, run: RunFolder) -> None:
    metrics = run.metrics
    if metrics:
        text = "```json\n" + json.dumps(metrics, indent=2, default=str) + "\n```"
        rec.log("run/metrics", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
    for stop in run.safety_stops():
        rec.set_time(TIMELINE, duration=float(stop["t_s"]))
        rec.log("run/safety", rr.TextLog(f"safety stop: {stop['reason']} {stop.get('detail', '')}".strip(),
                                         level=rr.TextLogLevel.WARN))  # fmt: skip
    rec.reset_time()


def _height_rgb(z: np.ndarray) -> np.ndarray:
    from mapping.export.meshes import height_colors

    return np.round(height_colors(z)[:, :3] * 255).astype(np.uint8)


def _log_maps(rr: Any, rec: Any, run: RunFolder, max_boxes: int) -> None:
    maps = run.maps()
    grid = run.grid() if maps else None
    if grid is not None:
        for name, s in maps.items():
            mins, maxs = grid.boxes(s)
            if mins.shape[0] > max_boxes:
                keep = np.unique(np.linspace(0, mins.shape[0] - 1, max_boxes).round().astype(np.int64))
                mins, maxs = mins[keep], maxs[keep]
            rec.log(
                f"world/map/vhv/{rr.escape_entity_path_part(name)}",
                rr.Boxes3D(mins=mins, sizes=maxs - mins, colors=_height_rgb(maxs[:, 2]), fill_mode="solid"),
                static=True,
            )
    for name, p in run.paths().items():
        strip = np.column_stack([p[:, 0], p[:, 1], np.full(len(p), 0.02)])
        rec.log(f"world/map/path/{rr.escape_entity_path_part(name)}", rr.LineStrips3D([strip], radii=0.02),
                static=True)  # fmt: skip
    occupancy = _occupancy(run)
    if occupancy is not None:
        img, resolution, origin = occupancy
        rec.log("map_2d", rr.Image(img, color_model="L"), static=True)
        verts, faces, colors = _cell_mesh(img, resolution, origin)
        if len(faces):
            rec.log("world/map/occupancy",
                    rr.Mesh3D(vertex_positions=verts, triangle_indices=faces, vertex_colors=colors),
                    static=True)  # fmt: skip


def _occupancy(run: RunFolder) -> tuple[np.ndarray, float, tuple[float, float]] | None:
    """The first map_server image of the run folder with its resolution and origin, or None."""
    import yaml

    from mapping.errors import MappingError
    from mapping.export.rosmap import read_pgm

    for d in run._map_dirs():
        y = d / "map.yaml"
        if not y.is_file():
            continue
        try:
            doc = yaml.safe_load(y.read_text(encoding="utf-8"))
            img = read_pgm(d / str(doc["image"]))
            return img, float(doc["resolution"]), (float(doc["origin"][0]), float(doc["origin"][1]))
        except (yaml.YAMLError, KeyError, IndexError, TypeError, ValueError, MappingError, OSError) as exc:
            raise RunFolderError(f"{y}: cannot read the 2D map ({exc})") from None
    return None


def _cell_mesh(img: np.ndarray, res: float, origin: tuple[float, float]) -> tuple[np.ndarray, ...]:
    """Quads (4 vertices, 2 triangles) for the known cells of a map_server image (top row = highest y)."""
    h = img.shape[0]
    occupied = img < 50
    free = img > 250
    rows, cols = np.nonzero(occupied | free)
    x0 = origin[0] + cols * res
    y0 = origin[1] + (h - 1 - rows) * res
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64) * res
    xy = np.stack([x0, y0], axis=1)[:, None, :] + corners[None]
    verts = np.concatenate([xy, np.full((len(rows), 4, 1), -0.01)], axis=2).reshape(-1, 3).astype(np.float32)
    base = 4 * np.arange(len(rows), dtype=np.uint32)[:, None]
    faces = (base + np.array([0, 1, 2, 0, 2, 3], dtype=np.uint32)).reshape(-1, 3)
    cell_rgb = np.where(occupied[rows, cols][:, None], [[40, 40, 40]], [[225, 225, 225]]).astype(np.uint8)
    return verts, faces, np.repeat(cell_rgb, 4, axis=0)


def _log_timeseries(rr: Any, rec: Any, run: RunFolder) -> None:
    ts = run.timeseries()
    if ts is None:
        return
    t = ts["t_s"]
    for col, values in ts.items():
        if col == "t_s":
            continue
        ok = np.isfinite(values) & np.isfinite(t)
        if ok.any():
            rec.send_columns(
                f"plots/{rr.escape_entity_path_part(col)}",
                indexes=[rr.TimeColumn(TIMELINE, duration=t[ok])],
                columns=rr.Scalars.columns(scalars=values[ok]),
            )


# ---------------------------------------------------------------------- the bag
def _tf_tree(run: RunFolder, topics: dict[str, str]) -> tuple[dict[str, str], set[str]]:
    """Child -> parent of every frame in ``/tf``, ``/tf_static`` and the odometry topics; the frames that
    ``/tf`` moves."""
    parents: dict[str, str] = {}
    moving: set[str] = set()
    tf_topics = [t for t in ("/tf", "/tf_static") if t in topics]
    for m in run.messages(tf_topics) if tf_topics else ():
        for tr in m.msg.transforms:
            parents[str(tr.child_frame_id)] = str(tr.header.frame_id)
            if m.topic == "/tf":
                moving.add(str(tr.child_frame_id))
    for topic, kind in topics.items():
        if kind == "nav_msgs/msg/Odometry":
            for m in run.messages([topic]):
                parents.setdefault(str(m.msg.child_frame_id), str(m.msg.header.frame_id))
                break
    return parents, moving


def _log_bag(rr: Any, rec: Any, run: RunFolder, max_cloud_points: int) -> None:
    topics = run.bag_topics()
    parents, tf_dynamic = _tf_tree(run, topics)
    out = MessageLogger(rr, rec, parents, tf_dynamic, max_cloud_points)
    wanted = [t for t, kind in topics.items() if kind in _HANDLED]
    for m in run.messages(wanted):
        out.log(m.topic, topics[m.topic], m.t_s, m.msg)
    out.flush()


class MessageLogger:
    """Logs deserialised ROS messages (a bag's, or a live run's) to a recording stream at their run time.

    Args:
        rr: the ``rerun`` module.
        rec: the recording stream.
        parents: child -> parent frame of the TF tree (frames outside it are placed at the world origin).
        tf_dynamic: frames that ``/tf`` moves (an odometry message does not place those).
        max_cloud_points: points kept per depth cloud at most.
    """

    def __init__(self, rr: Any, rec: Any, parents: dict[str, str], tf_dynamic: set[str],
                 max_cloud_points: int = MAX_CLOUD_POINTS) -> None:  # fmt: skip
        self.rr, self.rec = rr, rec
        self.entities = frame_entities(parents)
        self.tf_dynamic = set(tf_dynamic)
        self.max_cloud_points = int(max_cloud_points)
        self.paths: dict[str, _Path] = {}

    def entity(self, frame: str) -> str:
        """Entity path of a TF frame."""
        if frame not in self.entities:  # a frame outside the TF tree: at the world origin
            self.entities[frame] = f"world/{self.rr.escape_entity_path_part(frame or 'unknown_frame')}"
        return self.entities[frame]

    def log(self, topic: str, kind: str, t_s: float, msg: Any) -> None:
        """One message of type ``kind`` (e.g. ``"nav_msgs/msg/Odometry"``) at ``t_s`` s of run time; other
        types than the module docstring's are ignored."""
        rr, rec, entity = self.rr, self.rec, self.entity
        if kind == "tf2_msgs/msg/TFMessage":
            static = topic == "/tf_static"
            if not static:
                rec.set_time(TIMELINE, duration=t_s)
            for tr in msg.transforms:
                _log_transform(rr, rec, entity(str(tr.child_frame_id)), tr.transform, static)
            return
        rec.set_time(TIMELINE, duration=t_s)
        if kind == "rcl_interfaces/msg/Log":
            level = rr.TextLogLevel.WARN if int(msg.level) >= 30 else rr.TextLogLevel.INFO
            rec.log("run/safety", rr.TextLog(str(msg.msg), level=level))
            return
        if kind == "visualization_msgs/msg/MarkerArray":  # no header of its own
            self._log_boxes(msg)
            return
        frame = str(msg.header.frame_id)
        if kind == "nav_msgs/msg/Odometry":
            pose = msg.pose.pose
            child = str(msg.child_frame_id)
            if child not in self.tf_dynamic:
                _log_pose(rr, rec, entity(child), pose)
            suffix = "" if topic == "/odom" else "_" + _topic_name(topic)
            track = self.paths.setdefault(topic, _Path(f"{entity(frame)}/driven_path{suffix}"))
            track.add(rr, rec, t_s, pose.position)
            rec.log(f"plots/v{suffix}", rr.Scalars(float(msg.twist.twist.linear.x)))
            rec.log(f"plots/w{suffix}", rr.Scalars(float(msg.twist.twist.angular.z)))
        elif kind == "sensor_msgs/msg/PointCloud2":
            points = _cloud_points(topic, t_s, msg, self.max_cloud_points)
            rec.log(f"{entity(frame)}/points", rr.Points3D(points, radii=0.01, colors=[CLOUD_COLOR]))
        elif kind == "sensor_msgs/msg/Range":
            rec.log(f"{entity(frame)}/cone", _cone(rr, msg))
        elif kind == "sensor_msgs/msg/LaserScan":
            points = scan_points(msg)
            rec.log(f"{entity(frame)}/scan", rr.Points3D(points, radii=0.015, colors=[SCAN_COLOR]))
        elif kind == "nav_msgs/msg/OccupancyGrid":
            self._log_grid(msg)

    def _log_grid(self, msg: Any) -> None:
        """``map_2d`` and ``world/map/occupancy`` of an OccupancyGrid, as from the map_server picture."""
        info = msg.info
        codes = np.asarray(msg.data, dtype=np.int8).reshape(int(info.height), int(info.width))
        img = np.full(codes.shape, 205, dtype=np.uint8)  # map_server: unknown 205, free 254, occupied 0
        img[codes == 0] = 254
        img[codes >= 65] = 0
        img = img[::-1]  # the picture's top row is the highest y
        p = info.origin.position
        self.rec.log("map_2d", self.rr.Image(img, color_model="L"))
        verts, faces, colors = _cell_mesh(img, float(info.resolution), (float(p.x), float(p.y)))
        if len(faces):
            self.rec.log("world/map/occupancy", self.rr.Mesh3D(vertex_positions=verts, triangle_indices=faces,
                                                               vertex_colors=colors))  # fmt: skip

    def _log_boxes(self, msg: Any) -> None:
        """``world/map/vhv/<ns>`` Boxes3D of the CUBE_LIST markers of a MarkerArray, per namespace."""
        boxes: dict[str, list[np.ndarray]] = {}
        for mk in msg.markers:
            if int(mk.type) != 6 or int(mk.action) != 0 or not mk.points:
                continue
            c = np.array([(q.x, q.y, q.z) for q in mk.points], dtype=np.float64)
            rgb = np.array([(q.r, q.g, q.b) for q in mk.colors], dtype=np.float64).reshape(-1, 3)
            half = np.array([mk.scale.x, mk.scale.y, mk.scale.z], dtype=np.float64) / 2
            rows = np.column_stack([c - half, c + half, np.round(rgb * 255) if len(rgb) == len(c) else
                                    np.tile([200.0, 200.0, 200.0], (len(c), 1))])  # fmt: skip
            boxes.setdefault(str(mk.ns), []).append(rows)
        for ns, parts in boxes.items():
            a = np.vstack(parts)
            self.rec.log(f"world/map/vhv/{self.rr.escape_entity_path_part(ns)}",
                         self.rr.Boxes3D(mins=a[:, :3], sizes=a[:, 3:6] - a[:, :3],
                                         colors=a[:, 6:9].astype(np.uint8), fill_mode="solid"))  # fmt: skip

    def flush(self) -> None:
        """Log the driven paths' last points."""
        for track in self.paths.values():
            track.flush(self.rr, self.rec)


def _topic_name(topic: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in topic.strip("/"))


class _Path:
    """The driven path of one odometry topic, logged whole at most every :data:`PATH_PERIOD_S`."""

    def __init__(self, entity: str) -> None:
        self.entity = entity
        self.points: list[tuple[float, float, float]] = []
        self.logged_t = -math.inf
        self.last_t = 0.0
        self.pending = False

    def add(self, rr: Any, rec: Any, t_s: float, p: Any) -> None:
        self.points.append((float(p.x), float(p.y), float(p.z) + 0.03))
        self.last_t, self.pending = t_s, True
        if t_s - self.logged_t >= PATH_PERIOD_S - 1e-9:
            self._log(rr, rec)

    def flush(self, rr: Any, rec: Any) -> None:
        if self.pending:
            rec.set_time(TIMELINE, duration=self.last_t)
            self._log(rr, rec)

    def _log(self, rr: Any, rec: Any) -> None:
        rec.log(self.entity, rr.LineStrips3D([self.points], radii=0.02, colors=[(0, 200, 120)]))
        self.logged_t, self.pending = self.last_t, False


_HANDLED = (
    "tf2_msgs/msg/TFMessage",
    "nav_msgs/msg/Odometry",
    "sensor_msgs/msg/PointCloud2",
    "sensor_msgs/msg/Range",
    "sensor_msgs/msg/LaserScan",
)


def _log_transform(rr: Any, rec: Any, path: str, tf: Any, static: bool) -> None:
    t, q = tf.translation, tf.rotation
    rec.log(
        path,
        rr.Transform3D(translation=[t.x, t.y, t.z], quaternion=rr.Quaternion(xyzw=[q.x, q.y, q.z, q.w])),
        static=static,
    )


def _log_pose(rr: Any, rec: Any, path: str, pose: Any) -> None:
    p, q = pose.position, pose.orientation
    rec.log(
        path, rr.Transform3D(translation=[p.x, p.y, p.z], quaternion=rr.Quaternion(xyzw=[q.x, q.y, q.z, q.w]))
    )


def thin(points: np.ndarray, max_points: int) -> np.ndarray:
    """The finite rows of an (N, 3) array, every k-th so that at most ``max_points`` remain."""
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    if max_points > 0 and p.shape[0] > max_points:
        p = p[:: math.ceil(p.shape[0] / max_points)]
    return p


def _cloud_points(topic: str, t_s: float, msg: Any, max_points: int) -> np.ndarray:
    from mapping.errors import MappingError
    from mapping.pointcloud2 import decode

    try:
        return thin(decode(msg), max_points)
    except MappingError as exc:
        raise RunFolderError(f"{topic} at t = {t_s:.3f} s: {exc}") from None


def scan_points(msg: Any) -> np.ndarray:
    """(N, 3) float32 points, in the scanner's frame, of the returns of a ``sensor_msgs/LaserScan`` within
    ``[range_min, range_max]``."""
    r = np.asarray(msg.ranges, dtype=np.float64)
    a = float(msg.angle_min) + float(msg.angle_increment) * np.arange(r.size)
    ok = np.isfinite(r) & (r >= float(msg.range_min)) & (r <= float(msg.range_max))
    return np.column_stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok]), np.zeros(ok.sum())]).astype(
        np.float32
    )


def cone_strip(range_m: float, fov_rad: float, segments: int = CONE_SEGMENTS) -> np.ndarray:
    """Outline of a sonar's cone section in its frame (x forward): origin, the arc at ``range_m`` over
    ``fov_rad``, back to the origin; ((segments + 3), 3)."""
    a = np.linspace(-fov_rad / 2, fov_rad / 2, segments + 1)
    arc = np.column_stack([range_m * np.cos(a), range_m * np.sin(a), np.zeros(a.size)])
    return np.vstack([[0.0, 0.0, 0.0], arc, [0.0, 0.0, 0.0]])


def _cone(rr: Any, msg: Any) -> Any:
    r = float(msg.range)
    echo = math.isfinite(r) and float(msg.min_range) <= r <= float(msg.max_range)
    reach = r if echo else float(msg.max_range)
    return rr.LineStrips3D([cone_strip(reach, float(msg.field_of_view))], radii=0.006 if echo else 0.003,
                           colors=[ECHO_COLOR if echo else NO_ECHO_COLOR])  # fmt: skip


def entity_counts(path: Path | str) -> dict[str, int]:
    """Rows logged per entity path in a recording (static rows included), read back through the SDK."""
    import_rerun()
    from rerun.chunk import RrdReader

    counts: dict[str, int] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + int(chunk.num_rows)
    return counts
