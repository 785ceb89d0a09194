"""The probabilistic map's dynamic decay: people who walk out of the sensor's view leave no trail."""

from __future__ import annotations

import numpy as np
import pytest

from mapping.errors import MappingError
from mapping.grid import GridSpec
from mapping.probabilistic import EvidenceParams, ProbabilisticVHV
from mapping.synthetic import render_boxes

BAND = (0.10, 1.50)
WALL = [3.0, -3.0, 0.0, 3.1, 3.0, 2.0]
WALKER = [1.5, -0.2, 0.0, 1.9, 0.2, 1.7]
BEHIND = [-3.1, -3.0, 0.0, -3.0, 3.0, 2.0]  # a wall behind the sensor, seen when it turns round
HZ = 30.0
O = (0.0, 0.0, 1.0)
WALKER_XY, WALL_XY = (1.52, 0.0), (3.02, 0.0)


def _map(decay: float | None = 0.5) -> ProbabilisticVHV:
    spec = GridSpec(cell_size=0.05, size_x=8.0, size_y=8.0)
    return ProbabilisticVHV(spec, params=EvidenceParams(dynamic_decay_s=decay))


def _code(m: ProbabilisticVHV, x: float, y: float) -> int:
    return int(m.occupancy_2d(BAND)[m.spec.world_to_index(x, y)])


def _view(boxes: list[list[float]], yaw: float = 0.0) -> np.ndarray:
    return render_boxes(None, np.array(boxes), O, 120, 160, yaw, 10.0)


def _walker_then_look_away(m: ProbabilisticVHV, seen_free_first: bool) -> list[int]:
    """Frames at 30 Hz: the empty room, the walker standing, then the camera turned away (yaw 180 deg).

    Returns the walker cell's code after each frame of the last part.
    """
    k = 0
    if seen_free_first:
        for _ in range(10):
            m.insert(_view([WALL]), sensor_origin=O, stamp=k / HZ)
            k += 1
    for _ in range(10):
        m.insert(_view([WALL, WALKER]), sensor_origin=O, stamp=k / HZ)
        k += 1
    assert _code(m, *WALKER_XY) == 100
    codes = []
    away = _view([BEHIND], yaw=180.0)
    for _ in range(30):
        m.insert(away, sensor_origin=O, stamp=k / HZ)
        k += 1
        codes.append(_code(m, *WALKER_XY))
    return codes


def test_a_walker_who_leaves_the_view_where_free_space_was_seen_is_forgotten_after_the_decay():
    m = _map(0.5)
    codes = _walker_then_look_away(m, seen_free_first=True)
    # its last hit was at frame 19; 0.5 s later (15 frames) it is forgotten: unknown, not free
    assert codes[:14] == [100] * 14
    assert codes[15:] == [-1] * 15
    assert _code(m, *WALL_XY) == 100  # the wall, out of view as long, stays
    assert m.intervals().free.any()  # the free space seen around it is remembered


def test_without_decay_or_without_stamps_the_walker_stays_where_it_was_last_seen():
    assert _walker_then_look_away(_map(None), seen_free_first=True) == [100] * 30
    m = _map(0.5)
    for _ in range(10):
        m.insert(_view([WALL]), sensor_origin=O)
    for _ in range(10):
        m.insert(_view([WALL, WALKER]), sensor_origin=O)
    for _ in range(30):
        m.insert(_view([BEHIND], yaw=180.0), sensor_origin=O)
    assert _code(m, *WALKER_XY) == 100  # no clock: nothing decays


def test_a_surface_nobody_saw_free_does_not_decay_out_of_view():
    # seen occupied from the first frame (never known free): a static object, kept
    assert _walker_then_look_away(_map(0.5), seen_free_first=False) == [100] * 30


def test_something_seen_free_first_but_then_hit_longer_than_the_dwell_limit_stays_out_of_view():
    spec = GridSpec(cell_size=0.05, size_x=8.0, size_y=8.0)
    m = ProbabilisticVHV(spec, params=EvidenceParams(dynamic_decay_s=0.5, dynamic_max_dwell_s=1.0))
    k = 0
    for boxes, n in (([WALL], 10), ([WALL, WALKER], 45)):  # then hit for 1.5 s: a static object
        for _ in range(n):
            m.insert(_view(boxes), sensor_origin=O, stamp=k / HZ)
            k += 1
    for _ in range(30):
        m.insert(_view([BEHIND], yaw=180.0), sensor_origin=O, stamp=k / HZ)
        k += 1
    assert _code(m, *WALKER_XY) == 100


def test_a_surface_hit_by_every_frame_never_flickers_while_a_walker_crossing_is_cleared():
    m = _map(0.5)
    rng = np.random.default_rng(0)
    k = 0
    for _ in range(10):
        m.insert(render_boxes(rng, np.array([WALL]), O, 120, 160), sensor_origin=O, stamp=k / HZ)
        k += 1
    trail = []
    for y in np.arange(-1.0, 1.0, 1.0 / HZ):
        walker = [1.5, y - 0.2, 0.0, 1.9, y + 0.2, 1.7]
        m.insert(render_boxes(rng, np.array([WALL, walker]), O, 120, 160), sensor_origin=O, stamp=k / HZ)
        k += 1
        codes = m.occupancy_2d(BAND)
        assert codes[m.spec.world_to_index(*WALL_XY)] == 100
        trail.append(codes[m.spec.world_to_index(1.52, -0.8)])
    assert 100 in trail and trail[-1] != 100  # the walker passed there and was cleared


def test_stamps_going_back_and_bad_decay_parameters_are_refused():
    m = _map(0.5)
    m.insert(_view([WALL]), sensor_origin=O, stamp=2.0)
    with pytest.raises(MappingError, match=r"stamp=1\.0: earlier than the map's clock 2\.0"):
        m.insert(_view([WALL]), sensor_origin=O, stamp=1.0)
    with pytest.raises(MappingError, match="expected a finite time"):
        m.insert_free(np.zeros((1, 3)), sensor_origin=O, stamp=float("nan"))
    with pytest.raises(MappingError, match="dynamic_decay_s=0"):
        EvidenceParams(dynamic_decay_s=0)
    with pytest.raises(MappingError, match="dynamic_max_dwell_s=-1"):
        EvidenceParams(dynamic_max_dwell_s=-1)
    with pytest.raises(MappingError, match="dynamic_void_probability"):
        EvidenceParams(dynamic_void_probability=1.5)


def _whole_grid_decay(m: ProbabilisticVHV, age: float = 0.5, dwell: float = 2.0) -> int:
    """The decay pass over every cell of the grid, at every call (the reference of the tracked pass)."""
    import math

    from mapping import _store_kernels as E

    if not math.isfinite(m._now) or m._n_intervals == 0:
        return 0
    n = int(E.decay(m._ccount, m._cstart, m._plo, m._phi, m._pl, m._pt, m._now, age, dwell, m._l_occ))
    m._n_intervals -= n
    m._garbage += n
    return n


def test_the_decay_over_the_tracked_dynamic_cells_drops_what_the_whole_grid_pass_drops(monkeypatch):
    """A walker crossing in front of the wall, then out of view, with a free-only insert and a second
    insert at the same stamp in every frame: the map whose decay visits only the cells holding dynamic
    intervals, once per clock value, equals bit for bit the map whose decay sweeps the grid at every insert
    (and some intervals were dropped)."""
    params = EvidenceParams(dynamic_decay_s=0.5, dynamic_max_dwell_s=2.0)
    spec = GridSpec(cell_size=0.05, size_x=8.0, size_y=8.0)
    tracked, whole = ProbabilisticVHV(spec, params=params), ProbabilisticVHV(spec, params=params)
    dropped = []
    monkeypatch.setattr(whole, "_decay", lambda: dropped.append(_whole_grid_decay(whole)) or dropped[-1])
    far = np.array([[4.0, y, 1.2] for y in np.linspace(-1.5, 1.5, 31)])
    for k in range(40):
        y = -1.0 + 0.05 * k
        boxes = [WALL, [1.5, y - 0.2, 0.0, 1.9, y + 0.2, 1.7]] if k < 25 else [BEHIND]
        cloud = _view(boxes, yaw=0.0 if k < 25 else 180.0)
        for m in (tracked, whole):
            m.insert(cloud, sensor_origin=O, stamp=k / HZ)
            m.insert_free(far, sensor_origin=O, stamp=k / HZ)
            m.insert(cloud[::7, ::7], sensor_origin=O, stamp=k / HZ)
    assert sum(dropped) > 0
    a, b = tracked.intervals(), whole.intervals()
    for f in ("i", "j", "bottom", "top", "log_odds"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    np.testing.assert_array_equal(tracked._flat()[0], whole._flat()[0])


@pytest.mark.parametrize("dwell", [0.1, 0.4, None])
def test_the_tracked_decay_that_skips_cells_with_nothing_due_drops_what_the_whole_grid_pass_drops(
    monkeypatch, dwell
):
    """The tracked pass skips a cell whose dynamic intervals that could drop (occupied, dwelt at most
    ``dynamic_max_dwell_s``) were all hit within ``dynamic_decay_s``, and forgets cells holding none:
    with dwell bounds that exclude some of the walker's intervals (0.1 s, 0.4 s) or none, the map still
    equals bit for bit the map whose decay sweeps the whole grid at every insert, and some intervals
    were dropped while others stayed dynamic."""
    import math

    params = EvidenceParams(dynamic_decay_s=0.3, dynamic_max_dwell_s=dwell)
    spec = GridSpec(cell_size=0.05, size_x=8.0, size_y=8.0)
    tracked, whole = ProbabilisticVHV(spec, params=params), ProbabilisticVHV(spec, params=params)
    dropped: list[int] = []
    ref = math.inf if dwell is None else dwell
    monkeypatch.setattr(
        whole, "_decay", lambda: dropped.append(_whole_grid_decay(whole, 0.3, ref)) or dropped[-1]
    )
    for k in range(45):
        y = -1.0 + 0.04 * k
        # a walker that stops for a while (long dwell in its cells), walks on, and leaves the view
        y = min(y, -0.4) if 15 <= k < 28 else y
        boxes = [WALL, [1.5, y - 0.2, 0.0, 1.9, y + 0.2, 1.7]] if k < 34 else [WALL]
        cloud = _view(boxes)
        for m in (tracked, whole):
            m.insert(cloud, sensor_origin=O, stamp=k / HZ)
            m.insert(cloud[::5, ::5], sensor_origin=O, stamp=k / HZ)
    from mapping import _store_kernels as E

    def stored(m: ProbabilisticVHV) -> tuple[np.ndarray, ...]:  # every interval with its stamps
        return tuple(E.gather(m._cstart, m._ccount, m._plo, m._phi, m._pl, m._pt, m._n_intervals))

    assert sum(dropped) > 0
    assert np.isfinite(stored(whole)[4][:, 0]).any()  # dynamic intervals that did not decay remain
    for x, y in zip(stored(tracked), stored(whole), strict=True):
        np.testing.assert_array_equal(x, y)
