"""The probabilistic VHV map: free intervals, evidence per vertical interval, clearing, unknown space."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from mapping.errors import MappingError
from mapping.grid import GridSpec
from mapping.probabilistic import EvidenceParams, ProbabilisticVHV, make_map
from mapping.synthetic import render_boxes
from mapping.vhv import VHVMap

BAND = (0.10, 1.50)
WALL = [3.0, -3.0, 0.0, 3.1, 3.0, 2.0]
BOX = [1.5, -0.5, 0.0, 1.9, -0.1, 0.9]
TABLE = [1.8, 0.4, 0.72, 2.4, 1.0, 0.76]


def _spec(size: float = 8.0) -> GridSpec:
    return GridSpec(cell_size=0.05, size_x=size, size_y=size)


def _code(codes: np.ndarray, m: ProbabilisticVHV, x: float, y: float) -> int:
    i, j = m.spec.world_to_index(x, y)
    return int(codes[int(i), int(j)])


def _check_disjoint_per_cell(i, j, bottom, top) -> None:
    assert np.all(bottom < top)
    same = (i[1:] == i[:-1]) & (j[1:] == j[:-1])
    assert np.all(top[:-1][same] <= bottom[1:][same])


# ---------------------------------------------------------------------- merged evidence of one frame
points_strategy = hnp.arrays(
    np.float64,
    st.tuples(st.integers(1, 150), st.just(3)),
    elements=st.floats(-1.5, 1.5, allow_nan=False, allow_infinity=False),
)


@settings(max_examples=60, deadline=None)
@given(
    pts=points_strategy,
    origin=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-0.5, 2.0)),
)
def test_free_intervals_never_overlap_each_other_nor_the_frames_occupied_slabs(pts, origin):
    m = ProbabilisticVHV(GridSpec(cell_size=0.1, size_x=4.0, size_y=4.0), tolerance=0.05)
    occ, free = m.frame_evidence(pts, origin)
    _check_disjoint_per_cell(free.i, free.j, free.bottom, free.top)
    _check_disjoint_per_cell(occ.i, occ.j, occ.bottom, occ.top)
    ok = occ.i.astype(np.int64) * 1000 + occ.j
    fk = free.i.astype(np.int64) * 1000 + free.j
    for k, b, t in zip(fk, free.bottom, free.top):
        sel = ok == k
        assert not np.any((occ.bottom[sel] < t) & (occ.top[sel] > b))


@settings(max_examples=25, deadline=None)
@given(
    frames=st.lists(
        st.tuples(points_strategy, st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(0, 2))),
        min_size=1,
        max_size=4,
    )
)
def test_stored_intervals_stay_sorted_disjoint_and_clamped_after_any_frames(frames):
    m = ProbabilisticVHV(GridSpec(cell_size=0.1, size_x=4.0, size_y=4.0), tolerance=0.05)
    for pts, origin in frames:
        m.insert(pts, sensor_origin=origin)
    iv = m.intervals()
    _check_disjoint_per_cell(iv.i, iv.j, iv.bottom, iv.top)
    lo = m.params.log_odds
    assert np.all(iv.log_odds >= np.float32(lo["min"])) and np.all(iv.log_odds <= np.float32(lo["max"]))
    assert len(iv) == m.n_intervals


# ---------------------------------------------------------------------- scenes
def _frames(boxes, poses, h=120, w=160):
    return [(render_boxes(None, np.array(boxes), o, h, w, yaw, pitch), o) for o, yaw, pitch in poses]


POSES = [((0.0, 0.0, 1.0), 0.0, 10.0), ((0.0, -0.5, 1.2), 15.0, 20.0), ((0.3, 0.5, 0.8), -15.0, 5.0)]


def test_a_static_scene_converges_to_the_same_occupancy_whatever_the_frame_order():
    frames = _frames([WALL, BOX, TABLE], POSES)
    maps = []
    for order in ([0, 1, 2], [2, 0, 1], [1, 2, 0], [2, 1, 0]):
        m = ProbabilisticVHV(_spec())
        for _ in range(5):
            for k in order:
                m.insert(frames[k][0], sensor_origin=frames[k][1])
        maps.append(m)
    ref = maps[0].occupancy_2d(BAND)
    assert np.count_nonzero(ref == 100) > 50 and np.count_nonzero(ref == 0) > 200
    for m in maps[1:]:
        np.testing.assert_array_equal(m.occupancy_2d(BAND), ref)
        assert m.structures().equals(maps[0].structures())


def test_a_removed_obstacle_is_cleared_and_a_surface_hit_by_every_frame_is_not():
    o = (0.0, 0.0, 1.0)
    with_box = render_boxes(None, np.array([WALL, BOX]), o, 120, 160)
    without = render_boxes(None, np.array([WALL]), o, 120, 160)
    m = ProbabilisticVHV(_spec())
    box_xy, wall_xy = (1.52, -0.3), (3.02, 0.0)
    for _ in range(20):  # long enough for the box to reach the upper clamp
        m.insert(with_box, sensor_origin=o)
        assert _code(m.occupancy_2d(BAND), m, *wall_xy) == 100
    assert _code(m.occupancy_2d(BAND), m, *box_xy) == 100
    cleared_after = None
    for k in range(1, 15):
        m.insert(without, sensor_origin=o)
        codes = m.occupancy_2d(BAND)
        assert _code(codes, m, *wall_xy) == 100  # the wall never flickers
        if cleared_after is None and _code(codes, m, *box_xy) == 0:
            cleared_after = k
    # clamped at 0.971 (log-odds 3.48), 9 misses of -0.405 bring it below 0.5
    assert cleared_after == 9
    codes = m.occupancy_2d(BAND)
    i0, i1 = m.spec.world_to_index(np.array([1.5, 1.9]), np.array([-0.5, -0.1]))
    assert np.all(codes[i0[0] : i0[1], i1[0] : i1[1]] != 100)  # no trace of the box is left


def test_unknown_stays_unknown_where_no_ray_passed():
    o = (0.0, 0.0, 1.0)
    m = ProbabilisticVHV(_spec())
    m.insert(render_boxes(None, np.array([WALL, BOX]), o, 120, 160), sensor_origin=o)
    codes = m.occupancy_2d(BAND)
    iv = m.intervals()
    u, _ = m.spec.index_to_world(iv.i, iv.j)
    assert np.all(u > -0.05)  # nothing behind the sensor (it looks along +x)
    assert np.all(u < 3.15)  # nor behind the wall
    assert _code(codes, m, -1.0, 0.0) == -1 and _code(codes, m, 3.5, 0.0) == -1
    assert _code(codes, m, 1.0, 0.0) == 0
    # the caller chooses what unknown means; the default is "not free"
    assert _code(m.occupancy_2d(BAND, unknown=100), m, -1.0, 0.0) == 100
    assert not m.free_cells(BAND)[m.spec.world_to_index(-1.0, 0.0)]
    assert m.free_cells(BAND, unknown_is_free=True)[m.spec.world_to_index(-1.0, 0.0)]
    top, _ = m.elevation()
    assert np.isnan(top[m.spec.world_to_index(-1.0, 0.0)])  # unknown: no surface
    assert top[m.spec.world_to_index(1.0, 0.0)] == pytest.approx(0.0, abs=0.05)  # the floor
    assert top[m.spec.world_to_index(3.02, 0.0)] == pytest.approx(2.0, abs=0.05)


def test_a_table_top_seen_from_above_and_from_below_is_kept():
    table = [TABLE, [1.8, 0.4, 0.0, 1.85, 0.45, 0.72], [2.35, 0.95, 0.0, 2.4, 1.0, 0.72], WALL]
    above = ((0.5, 0.7, 1.6), 0.0, 35.0)
    below = ((0.8, 0.7, 0.35), 0.0, -15.0)
    frames = _frames(table, [above, below], 90, 120)
    m = ProbabilisticVHV(_spec())
    for _ in range(10):
        for pts, o in frames:
            m.insert(pts, sensor_origin=o)
    codes = m.occupancy_2d((0.6, 0.9))
    xs, ys = np.meshgrid(np.arange(1.825, 2.4, 0.05), np.arange(0.425, 1.0, 0.05), indexing="ij")
    got = np.array([_code(codes, m, x, y) for x, y in zip(xs.ravel(), ys.ravel())])
    assert np.all(got == 100)
    # and the space under it, seen from below, is free
    assert _code(m.occupancy_2d((0.2, 0.5)), m, 2.1, 0.7) == 0


def _graze(origin, edge_x, clearance=0.005):
    """Floor points whose rays from ``origin`` pass ``clearance`` above the table's far edge."""
    o = np.asarray(origin)
    p = np.stack([np.full(40, edge_x), np.linspace(0.45, 0.95, 40), np.full(40, 0.76 + clearance)], axis=1)
    d = p - o
    return o + d * (-o[2] / d[:, 2])[:, None]


@pytest.mark.parametrize(
    ("params", "erased"), [(EvidenceParams(), False), (EvidenceParams(surface_margin=0.0), True)]
)
def test_rays_grazing_a_table_top_do_not_erase_it_thanks_to_the_near_surface_margin(params, erased):
    # The table ends 2 mm into its last cell; steep rays pass just over its far edge and then, inside
    # that same cell, below its height: fans hulled over the cell would erase the edge without the margin.
    table = [1.8, 0.4, 0.72, 2.352, 1.0, 0.76]
    m = ProbabilisticVHV(_spec(), params=params)
    above = (1.0, 0.7, 1.6)
    seen = render_boxes(None, np.array([table]), above, 120, 160, 0.0, 35.0, floor=False)
    for _ in range(3):
        m.insert(seen, sensor_origin=above)
    before = m.occupancy_2d((0.6, 0.9)) == 100
    for o in [(1.0, 0.7, 1.6), (1.2, 0.8, 3.0), (1.2, 0.7, 5.0), (1.1, 0.6, 4.0)]:
        g = _graze(o, 2.352)
        for _ in range(10):
            m.insert(g, sensor_origin=o)
    lost = int(np.count_nonzero(before & (m.occupancy_2d((0.6, 0.9)) != 100)))
    assert np.count_nonzero(before) > 100
    assert (lost > 0) == erased


# ---------------------------------------------------------------------- sonar, range, modes, errors
def test_a_sonar_echo_is_occupied_at_its_range_and_free_in_front_and_no_echo_clears_up_to_range():
    from mapping.sonar import fuse_array

    t = np.eye(4)
    t[:3, 3] = (0.0, 0.0, 0.3)
    m = ProbabilisticVHV(GridSpec(cell_size=0.05, size_x=4.0, size_y=4.0))
    m.insert_sonar(fuse_array(0.6, 0.6, 0.6), t)
    # a sonar cone is thin: count a cell free as soon as free space crosses the band
    codes = m.occupancy_2d((0.1, 0.5), min_free_fraction=0.0)
    assert _code(codes, m, 0.58, 0.0) == 100
    assert _code(codes, m, 0.3, 0.0) == 0
    assert _code(codes, m, 0.9, 0.0) == -1  # behind the echo: unknown
    m2 = ProbabilisticVHV(GridSpec(cell_size=0.05, size_x=4.0, size_y=4.0))
    m2.insert_sonar(fuse_array(np.nan, np.nan, np.nan), t, max_range_m=1.0)
    codes = m2.occupancy_2d((0.1, 0.5), min_free_fraction=0.0)
    assert m2.n_structures == 0
    assert _code(codes, m2, 0.8, 0.0) == 0 and _code(codes, m2, 0.5, 0.3) == 0
    assert _code(codes, m2, 1.3, 0.0) == -1


def test_points_beyond_max_range_give_free_space_up_to_the_range_and_no_hit():
    o = (0.0, 0.0, 1.0)
    pts = render_boxes(None, np.array([WALL]), o, 60, 80, pitch_deg=0.0, floor=False)
    m = ProbabilisticVHV(_spec())
    s = m.insert(pts, sensor_origin=o, max_range=2.0)
    assert s.truncated_points == np.count_nonzero(np.isfinite(pts[..., 0]))
    codes = m.occupancy_2d((0.5, 1.5))
    assert m.n_structures == 0
    assert _code(codes, m, 1.5, 0.0) == 0 and _code(codes, m, 2.5, 0.0) == -1


def test_the_pure_thesis_map_stays_selectable_and_accumulates_only():
    spec = _spec()
    thesis = make_map(spec, 0.05, "thesis")
    assert type(thesis) is VHVMap
    assert isinstance(make_map(spec), ProbabilisticVHV)
    o = (0.0, 0.0, 1.0)
    for boxes in ([WALL, BOX], [WALL]):
        thesis.insert(render_boxes(None, np.array(boxes), o, 60, 80), sensor_origin=o)
    assert len(thesis.structures_at(1.52, -0.3)) > 0  # the removed box stays in the thesis map
    with pytest.raises(MappingError, match="expected 'probabilistic' or 'thesis'"):
        make_map(spec, 0.05, "octomap")  # type: ignore[arg-type]


def test_same_inputs_as_the_accumulating_map_and_its_derived_views():
    from mapping.derived import occupancy_2d, voxels

    o = (0.0, 0.0, 1.0)
    pts = render_boxes(None, np.array([WALL, BOX]), o, 60, 80)
    m = ProbabilisticVHV(_spec())
    s = m.insert(pts.astype(np.float64), sensor_origin=np.array(o))
    assert s.points_in == 60 * 80 and s.points_inserted + s.points_dropped_nonfinite == s.points_in
    occ = occupancy_2d(m, *BAND)
    np.testing.assert_array_equal(occ, m.occupancy_2d(BAND) == 100)
    assert voxels(m).shape[0] == m.n_voxels > 0
    assert m.n_cells_occupied == np.unique(m.cell_keys).shape[0]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"prob_hit": 0.4}, "prob_hit"),
        ({"prob_miss": 0.6}, "prob_miss"),
        ({"clamp_min": 0.9, "clamp_max": 0.8}, "clamp_min"),
        ({"free_threshold": 0.7, "occupied_threshold": 0.6}, "free_threshold"),
        ({"height_resolution": 0.0}, "height_resolution"),
        ({"surface_margin": -1.0}, "surface_margin"),
    ],
)
def test_bad_evidence_parameters_are_refused_with_their_name(kwargs, match):
    with pytest.raises(MappingError, match=match):
        EvidenceParams(**kwargs)


def test_bad_queries_and_inputs_are_refused():
    m = ProbabilisticVHV(_spec())
    with pytest.raises(MappingError, match="z_min <= z_max"):
        m.occupancy_2d((1.0, 0.0))
    with pytest.raises(MappingError, match="unknown=5"):
        m.occupancy_2d(BAND, unknown=5)
    with pytest.raises(MappingError, match="sensor_origin=None"):
        m.insert_frame(np.zeros((3, 3)), None)  # type: ignore[arg-type]
    with pytest.raises(MappingError, match="needs a sensor_origin"):
        m.insert(np.zeros((3, 3)), max_range=2.0)
    with pytest.raises(MappingError, match="expected finite"):
        m.insert(np.zeros((3, 3)), sensor_origin=(0.0, np.nan, 0.0))


def test_exports_carry_three_values_and_read_back(tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from mapping.export import write_map_outputs
    from mapping.export.rosmap import PGM_FREE, PGM_OCCUPIED, PGM_UNKNOWN, pgm_image, read_pgm

    o = (0.0, 0.0, 1.0)
    m = ProbabilisticVHV(_spec())
    m.insert(render_boxes(None, np.array([WALL, BOX]), o, 120, 160), sensor_origin=o)
    codes = m.occupancy_2d(BAND)
    assert set(np.unique(codes).tolist()) == {-1, 0, 100}
    summary = write_map_outputs(m, tmp_path, band=BAND, sensor_origin=o)
    assert summary["map_kind"] == "probabilistic"
    assert summary["cells_unknown_2d"] == np.count_nonzero(codes == -1) > 0
    img = read_pgm(tmp_path / "map.pgm")
    np.testing.assert_array_equal(img, pgm_image(codes))
    assert set(np.unique(img).tolist()) == {PGM_OCCUPIED, PGM_FREE, PGM_UNKNOWN} == {0, 254, 205}
    yaml = (tmp_path / "map.yaml").read_text()
    assert "mode: trinary" in yaml and "negate: 0" in yaml and "resolution: 0.05" in yaml
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(tmp_path / "map_bag") as reader:
        msgs = [ts.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages() if c.topic == "/map"]
    grid = msgs[0]
    data = np.asarray(grid.data).reshape(grid.info.height, grid.info.width)
    np.testing.assert_array_equal(data, codes.T)  # row-major by y: -1 / 0 / 100 survive the bag
    for name in ("occupancy.png", "elevation.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_beam_points_fill_the_beam_cross_section_at_the_range():
    from mapping.sonar import beam_points

    p = beam_points(0.8, -10.0, 20.0, 5.0)
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), 0.8)
    bearing = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    elevation = np.degrees(np.arcsin(p[:, 2] / 0.8))
    assert bearing.min() == pytest.approx(-10.0) and bearing.max() == pytest.approx(10.0)
    assert elevation.min() == pytest.approx(-5.0) and elevation.max() == pytest.approx(5.0)
    assert np.any((np.abs(bearing) < 0.5) & (np.abs(elevation) < 0.5))  # the axis is sampled


def test_no_return_directions_clear_a_walker_seen_against_the_sky():
    o = (0.0, 0.0, 1.0)
    walker = render_boxes(
        None, np.array([[1.5, -0.2, 0.0, 1.9, 0.2, 1.7]]), o, 90, 120, 0.0, -5.0, floor=False
    )
    dirs = walker.reshape(-1, 3).astype(np.float64) - o
    dirs = dirs[np.isfinite(dirs).all(axis=1)]
    nothing = np.full((10, 3), np.nan)
    # the camera sees the walker from 0.15 m up; the lowest rays clear from there plus the margin
    MID = (0.3, 1.4)
    m = ProbabilisticVHV(_spec(10.0), tolerance=0.1)  # 120 pixels across: 7 cm apart at the range
    for _ in range(10):
        m.insert_frame(walker, o)
    assert _code(m.occupancy_2d(MID), m, 1.52, 0.0) == 100
    for _ in range(10):
        m.insert_frame(nothing, o)  # NaN carries no direction: nothing is cleared
    assert _code(m.occupancy_2d(MID), m, 1.52, 0.0) == 100
    for _ in range(10):
        m.insert_frame(nothing, o, no_return_ends=o + 4.0 * dirs / np.linalg.norm(dirs, axis=1)[:, None])
    codes = m.occupancy_2d(MID)
    assert _code(codes, m, 1.52, 0.0) == 0 and _code(codes, m, 3.0, 0.0) == 0
    assert _code(codes, m, 4.5, 0.0) == -1  # beyond the range: still unknown
    with pytest.raises(MappingError, match=r"expected \(M, 3\)"):
        m.insert_frame(nothing, o, no_return_ends=dirs[:, :2])
