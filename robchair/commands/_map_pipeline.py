"""The build loop of ``robchair map``: every placed frame of an input into its map, serially or as a
pipeline of threads.

The pipeline (the default for a map with ``prepare_frame``, :class:`mapping.probabilistic.ProbabilisticVHV`)
runs five stages in order, each on its own thread, joined by bounded queues:

1. read and decode the next message, place it through TF and measure it (``--min-range``, band); not
   a stage of its own when the frames are held in memory from the extent pass;
2. the frame's evidence: its VHV structures and occupied slabs (``prepare_frame``, which reads nothing
   of the stored map, so it runs ahead of the inserts);
3. the fans of free space marked in the frame's bit table (``PreparedFrame.mark_fans``);
4. the merged free intervals (``PreparedFrame.extract_free``, of the frame alone too);
5. in the caller's thread, frame after frame: the store update, the dynamic decay and the counters
   (``insert_prepared``), the one stage that must run in order.

The compiled kernels release the GIL, so the stages overlap on several cores. Every frame meets the same
calls in the same order as in the serial loop (``--serial-build``): the maps are identical. An error in
a stage (a bad message, say) stops the others and is raised by the caller's thread as the serial loop
raises it.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Generator, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

#: Frames a stage may run ahead of the next one.
QUEUE_DEPTH = 8
_POLL_S = 0.05  # how often a blocked stage looks whether the pipeline was stopped


@dataclass
class BuildTotals:
    """What the table row and summary.json need from the build, gathered frame by frame in order.

    Attributes:
        band: the map command's ``BandCheck`` (measures of every frame).
        no_return: its ``NoReturn`` (rays of every frame).
        sensor_origin: the origin used when it is one for every frame (None with a moving sensor).
        build_ms: the inserts' milliseconds: serially the sum of ``EvidenceStats.build_ms``; on the
            pipeline, whose stages overlap, the wall time from the first frame to the last insert
            (with a bag read on its first stage, that reading too), less the kernels' warm-up.
        dropped_close: points within ``--min-range`` of the sensor.
        frame_id: last non-empty frame id.
        stamp_ns: latest stamp, ns.
    """

    band: Any
    no_return: Any
    sensor_origin: Any
    build_ms: float = 0.0
    dropped_close: int = 0
    frame_id: str = ""
    stamp_ns: int = 0
    warmed: set[str] = field(default_factory=set)
    warm_up_s: float = 0.0


@dataclass
class _Failed:
    """An exception of a stage, carried down the pipeline to the caller's thread."""

    exc: BaseException


_END = object()


def build(
    m: Any,
    pairs: Iterable[Any],
    warm_up: Callable[[Any, Any], None],
    totals: BuildTotals,
    placed: bool,
    serial: bool,
    bar: Any,
) -> None:
    """Insert every frame of ``pairs`` into ``m`` in order, updating ``totals``.

    Args:
        m: the map (``VHVMap`` or ``ProbabilisticVHV``).
        pairs: ``(frame, origin, points (N, 3), n_close, measures)`` per frame (:func:`read_frames`);
            iterating it may read, place and measure the frames (on the pipeline's first stage).
        warm_up: ``(points, origin) -> None``, loads the kernels a dtype needs before its first timed insert.
        totals: updated in place.
        placed: frames were placed through TF (a moving sensor has no one origin).
        serial: one thread (also for a map without ``prepare_frame``).
        bar: progress bar (``update(1)`` per frame inserted).

    Raises:
        Whatever reading, placing or inserting a frame raises, as the serial loop raises it.
    """
    stamped = getattr(m, "insert_prepared", None) is not None  # evidence decays: each cloud at its stamp

    def read(item: Any) -> Any:
        return item

    def warm(points: Any, origin: Any) -> None:
        if str(points.dtype) not in totals.warmed:
            t0 = time.perf_counter()
            warm_up(points, origin)
            totals.warmed.add(str(points.dtype))
            totals.warm_up_s += time.perf_counter() - t0

    def stamp_kw(frame: Any) -> dict[str, float]:
        return {"stamp": frame.stamp_ns * 1e-9} if stamped and frame.stamp_ns >= 1e9 * m.now else {}

    def record(frame: Any, origin: Any, n_close: int, measures: Any, stats: Any, summed: bool = True) -> None:
        totals.band.add_measures(measures)
        totals.dropped_close += n_close
        if summed:
            totals.build_ms += stats.build_ms
        totals.sensor_origin = origin if not placed else None
        totals.frame_id = frame.frame_id or totals.frame_id
        totals.stamp_ns = max(totals.stamp_ns, int(frame.stamp_ns))
        bar.update(1)

    if serial or not stamped:
        for item in pairs:
            frame, origin, points, n_close, measures = read(item)
            warm(points, origin)
            if frame.no_return is not None and len(frame.no_return):
                stats = totals.no_return.insert(m, points, frame.no_return, origin, stamp_kw(frame))
            else:
                stats = m.insert(points, sensor_origin=origin, **stamp_kw(frame))
            record(frame, origin, n_close, measures, stats)
        return

    def prepare(read_item: Any) -> Any:
        frame, origin, points, _, _ = read_item
        warm(points, origin)
        ends = None
        if frame.no_return is not None and len(frame.no_return):
            ends = totals.no_return.ends(m, frame.no_return, origin)
        return read_item, m.prepare_frame(points, sensor_origin=origin, no_return_ends=ends, defer_fans=True)

    def mark(item: Any) -> Any:
        item[1].mark_fans()
        return item

    def extract(item: Any) -> Any:
        item[1].extract_free()
        return item

    # frames held in memory need no reading stage; the caller's thread only updates the store
    stages = [prepare, mark, extract] if isinstance(pairs, list) else [read, prepare, mark, extract]
    t0 = time.perf_counter()
    warm0 = totals.warm_up_s
    for (frame, origin, _, n_close, measures), prepared in run_stages(pairs, stages):
        stats = m.insert_prepared(prepared, **stamp_kw(frame))
        record(frame, origin, n_close, measures, stats, summed=False)
    totals.build_ms += (time.perf_counter() - t0 - (totals.warm_up_s - warm0)) * 1e3


def read_frames(
    frames: Iterable[Any],
    place: Callable[[Any], Any],
    measure: Callable[[Any, Any], tuple[Any, int, Any]],
    serial: bool,
) -> Iterator[Any]:
    """``(frame, origin, points, n_close, measures)`` of every frame that ``place`` keeps.

    Args:
        frames: the input's frames (iterating reads and decodes them).
        place: ``frame -> (frame, origin)`` in the map's frame, or None to leave the frame out.
        measure: ``(frame, origin) -> (points (N, 3), n_close, measures)``.
        serial: one thread; else reading, placing and measuring are three stages of :func:`run_stages`
            (the first thread iterates ``frames``: it reads).
    """

    def measured(p: Any) -> Any:
        return None if p is None else (p[0], p[1], *measure(p[0], p[1]))

    def read(f: Any) -> Any:
        return f

    # reading (decoding, in Python: the GIL) on a thread of its own, so that placing (numpy's matrix
    # product, without the GIL) and measuring (a compiled kernel) overlap with it
    out = (measured(place(f)) for f in frames) if serial else run_stages(frames, [read, place, measured])
    for y in out:
        if y is not None:
            yield y


def run_stages(
    items: Iterable[Any], stages: list[Callable[[Any], Any]], depth: int = QUEUE_DEPTH
) -> Generator[Any, None, None]:
    """``stages[-1](... stages[0](item))`` of every item, in order, each stage on its own thread.

    The first stage's thread also iterates ``items``. Yields in the caller's thread; an exception of a
    stage (or of the iteration) is raised there after the items before it were yielded. Closing the
    generator (or an exception in the caller's loop) stops the threads and waits for them.
    """
    stop = threading.Event()
    queues: list[queue.Queue[Any]] = [queue.Queue(depth) for _ in stages]

    def put(q: queue.Queue[Any], x: Any) -> bool:
        while not stop.is_set():
            try:
                q.put(x, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def get(q: queue.Queue[Any]) -> Any:
        while not stop.is_set():
            try:
                return q.get(timeout=_POLL_S)
            except queue.Empty:
                continue
        return _END

    def worker(k: int) -> None:
        out = queues[k]
        try:
            source = iter(items) if k == 0 else None
            while True:
                x = next(source, _END) if source is not None else get(queues[k - 1])
                if x is _END or isinstance(x, _Failed):
                    put(out, x)
                    return
                if not put(out, stages[k](x)):
                    return
        except BaseException as exc:  # carried to the caller's thread, raised there
            put(out, _Failed(exc))

    threads = [threading.Thread(target=worker, args=(k,), name=f"map-stage-{k + 1}", daemon=True)
               for k in range(len(stages))]  # fmt: skip
    for t in threads:
        t.start()
    try:
        while True:
            y = get(queues[-1])
            if y is _END:
                return
            if isinstance(y, _Failed):
                raise y.exc
            yield y
    finally:
        stop.set()
        for t in threads:
            t.join()
