"""A frame prepared ahead (``prepare_frame``) and inserted later (``insert_prepared``) gives the map that
``insert`` / ``insert_frame`` give, bit for bit: what lets `robchair map` prepare frames on another thread."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mapping.errors import MappingError
from mapping.grid import GridSpec
from mapping.probabilistic import EvidenceParams, ProbabilisticVHV
from mapping.synthetic import render_boxes

WALL = [3.0, -3.0, 0.0, 3.1, 3.0, 2.0]
BEHIND = [-3.1, -3.0, 0.0, -3.0, 3.0, 2.0]
TABLE = [2.0, 0.8, 0.7, 2.6, 1.4, 0.75]
HZ = 30.0


def _map() -> ProbabilisticVHV:
    # the dynamic decay of a run's maps: walkers are dropped half a second after their last hit
    spec = GridSpec(cell_size=0.05, size_x=8.0, size_y=8.0)
    return ProbabilisticVHV(spec, params=EvidenceParams(dynamic_decay_s=0.5, dynamic_max_dwell_s=2.0))


def _frames() -> list[dict]:
    """A sequence of rendered depth frames (120 x 160, noisy) with stamps: the empty room seen free, a
    walker crossing it, the camera turning away (the walker's trail decays), frames with no-return ends
    and with a range limit, and a free-only frame."""
    rng = np.random.default_rng(3)
    out: list[dict] = []
    k = 0
    for step in range(34):
        x = 0.0 + 0.02 * step
        o = (x, 0.0, 1.0)
        yaw = 0.0 if step < 24 else 180.0
        boxes = [WALL, BEHIND, TABLE]
        if 8 <= step < 20:
            y = -1.0 + 0.12 * (step - 8)
            boxes.append([1.5, y - 0.2, 0.0, 1.9, y + 0.2, 1.7])
        pts = render_boxes(rng, np.array(boxes), o, 120, 160, yaw, 10.0, max_range=4.5)
        frame: dict = {"points": pts, "sensor_origin": o, "stamp": k / HZ}
        if step % 5 == 3:
            frame["max_range"] = 2.5
        if step % 7 == 2:
            dirs = pts.reshape(-1, 3).astype(np.float64) - o
            dirs = dirs[np.isfinite(dirs).all(axis=1)][::13]
            frame["no_return_ends"] = o + 4.0 * dirs / np.linalg.norm(dirs, axis=1)[:, None]
        if step == 30:
            frame["stamp"] = out[-1]["stamp"]  # the same clock twice: the decay pass is skipped
        out.append(frame)
        k += 1
    return out


def _insert(m: ProbabilisticVHV, f: dict):  # type: ignore[no-untyped-def]
    kw = {k: f[k] for k in ("max_range",) if k in f}
    if "no_return_ends" in f:
        return m.insert_frame(f["points"], f["sensor_origin"], no_return_ends=f["no_return_ends"],
                              stamp=f["stamp"], **kw)  # fmt: skip
    return m.insert(f["points"], sensor_origin=f["sensor_origin"], stamp=f["stamp"], **kw)


def _prepare(m: ProbabilisticVHV, f: dict):  # type: ignore[no-untyped-def]
    kw = {k: f[k] for k in ("max_range", "no_return_ends") if k in f}
    return m.prepare_frame(f["points"], sensor_origin=f["sensor_origin"], **kw)


def _state(m: ProbabilisticVHV) -> dict:
    used = m._used
    # the live slots of the pool (dead ones hold whatever was there), cell by cell
    runs = [np.arange(s, s + c) for s, c in zip(m._cstart, m._ccount) if c]
    live = np.concatenate(runs or [np.empty(0, np.int64)])
    return {
        "cstart": m._cstart, "ccount": m._ccount, "ccap": m._ccap,
        "plo": m._plo[live], "phi": m._phi[live], "pl": m._pl[live], "pt": m._pt[live],
        "dyn_cells": np.sort(m._dyn_cells[: m._n_dyn]), "dyn_flag": m._dyn_flag, "dyn_due": m._dyn_due,
        "scalars": np.array([used, m._garbage, m._n_intervals, m._n_dyn, m.frames, m.points_inserted,
                             m.points_dropped_nonfinite, m.points_outside_grid, m._now]),
        "origins": np.array(m.sensor_origins),
    }  # fmt: skip


def _assert_same(a: ProbabilisticVHV, b: ProbabilisticVHV) -> None:
    sa, sb = _state(a), _state(b)
    for name in sa:
        np.testing.assert_array_equal(sa[name], sb[name], err_msg=name, strict=True)


def _stats(s):  # type: ignore[no-untyped-def]
    return dataclasses.replace(s, build_ms=0.0)


def test_frames_prepared_ahead_and_inserted_in_order_give_the_inserted_map_bit_for_bit():
    frames = _frames()
    serial, ahead = _map(), _map()
    serial_stats = [_insert(serial, f) for f in frames]
    # every frame prepared before any is inserted: the preparation reads nothing of the stored map
    prepared = [_prepare(ahead, f) for f in frames]
    ahead_stats = [ahead.insert_prepared(p, stamp=f["stamp"]) for p, f in zip(prepared, frames)]
    assert sum(s.decayed for s in serial_stats) > 0  # the walker's trail decayed on the way
    assert any(s.truncated_points for s in serial_stats)
    assert [_stats(s) for s in ahead_stats] == [_stats(s) for s in serial_stats]
    assert all(s.build_ms >= p.prepare_ms for s, p in zip(ahead_stats, prepared))
    _assert_same(serial, ahead)
    np.testing.assert_array_equal(serial.occupancy_2d((0.1, 1.5)), ahead.occupancy_2d((0.1, 1.5)))


def test_insert_prepared_checks_the_map_and_the_stamp():
    frames = _frames()[:2]
    m = _map()
    p = _prepare(m, frames[0])
    other = ProbabilisticVHV(GridSpec(cell_size=0.1, size_x=8.0, size_y=8.0))
    with pytest.raises(MappingError, match="prepared for another grid"):
        other.insert_prepared(p)
    m.insert_prepared(p, stamp=1.0)
    with pytest.raises(MappingError, match="earlier than the map's clock"):
        m.insert_prepared(_prepare(m, frames[1]), stamp=0.5)
    with pytest.raises(MappingError, match="needs the sensor_origin"):
        m.prepare_frame(frames[0]["points"], no_return_ends=np.zeros((1, 3)))


def test_frames_whose_fans_are_deferred_give_the_same_map_whichever_phase_is_left_to_the_insert():
    frames = _frames()
    serial, deferred = _map(), _map()
    for f in frames:
        _insert(serial, f)
    kw = [{k: f[k] for k in ("max_range", "no_return_ends") if k in f} for f in frames]
    prepared = [deferred.prepare_frame(f["points"], f["sensor_origin"], defer_fans=True, **k)
                for f, k in zip(frames, kw)]  # fmt: skip
    assert not any(p.complete for p in prepared)
    for k, p in enumerate(prepared):
        if k % 3 >= 1:
            p.mark_fans()  # on the pipeline's third stage
        if k % 3 == 2:
            p.extract_free()
            assert p.complete
    for p, f in zip(prepared, frames):
        deferred.insert_prepared(p, stamp=f["stamp"])
    _assert_same(serial, deferred)
