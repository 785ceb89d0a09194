"""Threaded, the maps beside the main one may fall behind it by ``LAYER_LAG`` frames, never more, and every
reader of the maps waits for them: ``wait_for_maps``, ``flush`` (``occupancy_2d``), ``call_with_maps``.

Before, the mapping thread waited for the layer thread after every frame, so one thread idled whenever
the other's map took longer; now the two overlap across frames. Bit-for-bit equality with the serial maps
is ``test_perception_matching``'s.
"""

from __future__ import annotations

import os
import sys
import threading
from typing import Any

import numpy as np
import pytest

from hw.interfaces import DepthFrame
from mapping.synthetic import render_scene
from robchair.perception import Perception
from robchair.perception_layers import LAYER_LAG, LAYER_NICE
from robchair.platform.frames import se3_planar
from robchair.platform.kinematics import Pose2D
from robchair.platform.spec import load_spec

FRAMES = {"cam": se3_planar(0.0, 0.0, 0.0) @ np.diag([1.0, 1.0, 1.0, 1.0])}


class Camera:
    def __init__(self, clouds: list[np.ndarray]) -> None:
        self.clouds = list(clouds)

    def read(self) -> DepthFrame:
        return DepthFrame(0, "cam", np.asarray(self.clouds.pop(0), np.float32))


class GatedMap:
    """A layer map whose inserts wait for ``gate``, counting the frames it took."""

    def __init__(self, inner: Any, gate: threading.Event, fail_at: int | None = None) -> None:
        self.inner, self.gate, self.fail_at = inner, gate, fail_at
        self.frames = 0

    def insert(self, points: Any, sensor_origin: Any = None, **kw: Any) -> Any:
        assert self.gate.wait(30), "the gate was never opened"
        if self.fail_at is not None and self.frames == self.fail_at:
            raise RuntimeError("layer insert failed")
        self.frames += 1
        return self.inner.insert(points, sensor_origin=sensor_origin)


@pytest.fixture(scope="module")
def clouds() -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    return [render_scene(rng, 53, 64, nan_fraction=0.05, pitch_deg=5.0) for _ in range(LAYER_LAG + 3)]


def _perception(gated: GatedMap) -> Perception:
    from mapping.grid import GridSpec
    from mapping.vhv import VHVMap

    grid = GridSpec(cell_size=0.05, size_x=16.0, size_y=16.0, centre=(3.0, 0.0))
    p = Perception(load_spec(), grid=grid, frames=FRAMES, sonar_map=None, map_kind="thesis", threaded=True,
                   pose="odometry")  # fmt: skip
    gated.inner = VHVMap(grid, p.tolerance)
    p.add_layer("gated", gated, lambda: se3_planar(0.01, 0.0, 0.0))
    p.evaluation_every = 1  # the layer takes every frame
    return p


def _take(p: Perception, cam: Camera, frames: range) -> None:
    """Frames ``frames`` of ``cam``, the chair 2 cm further along x at each."""
    for k in frames:
        p.take_depth(cam, Pose2D(0.02 * k, 0.0, 0.0))


def _blocked(fn: Any) -> threading.Thread:
    """``fn`` started on a thread, asserted still waiting after 0.3 s."""
    t = threading.Thread(target=fn, daemon=True)
    t.start()
    t.join(0.3)
    assert t.is_alive(), f"{fn.__name__} returned while a layer was behind"
    return t


def test_the_main_map_goes_on_while_a_layer_is_behind_and_readers_wait_for_it(clouds) -> None:
    gate = threading.Event()
    gated = GatedMap(None, gate)
    p = _perception(gated)
    try:
        cam = Camera(clouds)
        _take(p, cam, range(LAYER_LAG))
        # the main map took every frame while the layer took none (it waits at its gate)
        for fut in list(p._pending):
            fut.result(timeout=30)
        assert p.stats["depth_frames"] == LAYER_LAG and gated.frames == 0
        ran = threading.Event()
        p.call_with_maps(ran.set)
        assert not ran.wait(0.3), "call_with_maps ran before the layer caught up"
        waiting = _blocked(p.wait_for_maps)
        gate.set()
        waiting.join(30)
        assert ran.wait(30) and gated.frames == LAYER_LAG
        gate.clear()
        _take(p, cam, range(LAYER_LAG, LAYER_LAG + 2))
        flushing = _blocked(p.occupancy_2d)  # flush: every layer insert is done when it returns
        gate.set()
        flushing.join(30)
        assert gated.frames == LAYER_LAG + 2
    finally:
        gate.set()
        p.close()


def test_a_layer_never_falls_more_than_the_lag_behind(clouds) -> None:
    gate = threading.Event()
    gated = GatedMap(None, gate)
    p = _perception(gated)
    try:
        _take(p, Camera(clouds), range(LAYER_LAG + 1))
        # the frame after the lag waits on the mapping thread for the layer's oldest frame
        last = p._pending[-1]
        assert not last.done()
        threading.Timer(0.3, gate.set).start()
        last.result(timeout=30)
        assert gated.frames >= 1
    finally:
        gate.set()
        p.close()


def test_an_error_in_a_layer_insert_surfaces_in_the_loop(clouds) -> None:
    gate = threading.Event()
    gate.set()
    gated = GatedMap(None, gate, fail_at=1)
    p = _perception(gated)
    with pytest.raises(RuntimeError, match="layer insert failed"):
        _take(p, Camera(clouds), range(len(clouds)))
        p.flush()
    with pytest.raises(RuntimeError):
        p.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice values are Linux's")
def test_the_layer_thread_runs_at_a_lower_priority_than_the_loop(clouds) -> None:
    gated = GatedMap(None, threading.Event())
    p = _perception(gated)
    try:
        assert p._layer_pool is not None and p._pool is not None
        loop = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        layer = p._layer_pool.submit(
            lambda: os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        ).result()
        main = p._pool.submit(lambda: os.getpriority(os.PRIO_PROCESS, threading.get_native_id())).result()
        assert layer == min(loop + LAYER_NICE, 19) and main == loop
        assert LAYER_NICE > 0
    finally:
        gated.gate.set()
        p.close()
