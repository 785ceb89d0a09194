"""Local-to-global matching: known offsets recovered, degenerate frames fall back to odometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapping.errors import MappingError
from mapping.grid import GridSpec
from mapping.matching import MatchParams, ScanMatcher, occupied_cell_centroids
from mapping.synthetic import render_scene
from mapping.vhv import VHVMap

SPEC = GridSpec(cell_size=0.05, size_x=16.0, size_y=16.0, centre=(3.0, 0.0))


def _rot(points: np.ndarray, dx: float, dy: float, dyaw: float) -> np.ndarray:
    c, s = math.cos(dyaw), math.sin(dyaw)
    p = points.reshape(-1, 3).astype(np.float64)
    x, y = p[:, 0] * c - p[:, 1] * s + dx, p[:, 0] * s + p[:, 1] * c + dy
    return np.column_stack([x, y, p[:, 2]])


@pytest.fixture(scope="module")
def room() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    first = render_scene(rng, 212, 256, nan_fraction=0.05, pitch_deg=5.0)
    second = render_scene(rng, 212, 256, nan_fraction=0.05, pitch_deg=5.0)  # another noisy view
    return first.reshape(-1, 3), second.reshape(-1, 3)


@pytest.mark.parametrize("offset", [(0.08, -0.05, math.radians(2.0)), (-0.1, 0.06, math.radians(-3.0))])
def test_a_known_rigid_offset_is_recovered(room, offset) -> None:
    first, second = room
    m = VHVMap(SPEC, 0.05)
    m.insert(first)
    # the odometry is off: the second view arrives displaced by the inverse of the offset
    dx, dy, dyaw = offset
    c, s = math.cos(-dyaw), math.sin(-dyaw)
    displaced = _rot(second, -(c * dx - s * dy), -(s * dx + c * dy), -dyaw)
    matcher = ScanMatcher()
    res = matcher.match(displaced, m)
    assert res.accepted, res
    # tolerance: half a degree in heading, and every point of the frame (up to 4.3 m away) within one
    # 5 cm cell of where it belongs; the map's cells are a 5 cm lattice, so this is its resolution
    assert res.dyaw == pytest.approx(dyaw, abs=math.radians(0.5))
    corrected = _rot(displaced, res.dx, res.dy, res.dyaw)
    err = np.nanmax(np.linalg.norm(corrected[:, :2] - second[:, :2].astype(np.float64), axis=1))
    assert err < 0.05
    uncorrected = np.nanmax(np.linalg.norm(displaced[:, :2] - second[:, :2].astype(np.float64), axis=1))
    assert uncorrected > 0.15
    np.testing.assert_allclose(matcher.t_map_odom[:2, 3], [res.dx, res.dy])


def test_a_frame_already_in_place_gets_almost_no_correction(room) -> None:
    first, second = room
    m = VHVMap(SPEC, 0.05)
    m.insert(first)
    res = ScanMatcher().match(second, m)
    assert res.accepted
    assert math.hypot(res.dx, res.dy) < 0.01 and abs(res.dyaw) < math.radians(0.2)


@pytest.mark.parametrize(
    ("frame", "reason"),
    [
        (np.empty((0, 3)), "too few frame cells"),
        (np.full((5000, 3), np.nan), "too few frame cells"),
        # a featureless floor: every point below the matched band
        (
            np.column_stack([np.random.default_rng(0).uniform(0, 4, (20000, 2)), np.zeros(20000)]),
            "too few frame cells",
        ),
        # one straight wall: only the offset across it is observable
        (
            np.column_stack(
                [
                    np.full(20000, 2.0),
                    np.random.default_rng(1).uniform(-2, 2, 20000),
                    np.random.default_rng(2).uniform(0, 2, 20000),
                ]
            ),
            "frame cells along one line",
        ),
    ],
)
def test_frames_with_nothing_to_match_fall_back_to_odometry_and_are_counted(room, frame, reason) -> None:
    first, _ = room
    m = VHVMap(SPEC, 0.05)
    m.insert(first)
    before = m.structures()
    matcher = ScanMatcher()
    res = matcher.match(frame, m)
    assert not res.accepted and res.reason == reason
    assert matcher.rejections[reason] == 1
    np.testing.assert_array_equal(matcher.t_map_odom, np.eye(4))
    assert m.structures().equals(before)  # matching never writes the map


def test_an_empty_map_is_a_rejection_not_an_error(room) -> None:
    _, second = room
    res = ScanMatcher().match(second, VHVMap(SPEC, 0.05))
    assert not res.accepted and res.reason == "too few map cells"


def test_a_correction_beyond_the_per_frame_bound_is_rejected(room) -> None:
    first, second = room
    m = VHVMap(SPEC, 0.05)
    m.insert(first)
    params = MatchParams(max_translation=0.03)
    res = ScanMatcher(params).match(_rot(second, 0.1, 0.0, 0.0), m)
    assert not res.accepted and res.reason == "correction too large"


def test_occupied_cells_give_the_centroid_of_their_points_in_the_band() -> None:
    pts = np.array(
        [[0.01, 0.01, 0.5], [0.02, 0.03, 0.6], [0.07, 0.01, 0.5], [0.07, 0.04, 0.05], [np.nan, 0, 1]]
    )
    got = occupied_cell_centroids(pts, 0.05, (0.15, 1.8))
    np.testing.assert_allclose(got[np.lexsort(got.T[::-1])], [[0.015, 0.02], [0.07, 0.01]])


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(MappingError, match="min_fitness"):
        MatchParams(min_fitness=1.5)


def _corridor(rng: np.random.Generator, n: int = 20000, length: float = 5.0) -> np.ndarray:
    """Two parallel walls 1.5 m apart along x (y = +-0.75 m), 2 m high, from x = 0.5 m to ``length``."""
    x = rng.uniform(0.5, length, n)
    y = np.where(rng.random(n) < 0.5, -0.75, 0.75) + rng.normal(0.0, 0.005, n)
    return np.column_stack([x, y, rng.uniform(0.0, 2.0, n)])


def test_a_corridor_whose_walls_fix_nothing_along_it_is_rejected_as_degenerate() -> None:
    rng = np.random.default_rng(3)
    m = VHVMap(SPEC, 0.05)
    m.insert(_corridor(rng))
    # the odometry is 12 cm off along the corridor: nothing in the frame can tell, so no correction
    frame = _corridor(rng) + np.array([0.12, 0.0, 0.0])
    matcher = ScanMatcher()
    res = matcher.match(frame, m)
    assert not res.accepted and res.reason == "degenerate geometry", res
    assert matcher.rejections["degenerate geometry"] == 1
    np.testing.assert_array_equal(matcher.t_map_odom, np.eye(4))


def test_walls_facing_two_ways_are_not_degenerate(room) -> None:
    first, second = room
    m = VHVMap(SPEC, 0.05)
    m.insert(first)
    res = ScanMatcher(MatchParams(min_information=0.1)).match(second, m)
    assert res.accepted, res


def _boxes(
    rng: np.random.Generator, centres: list[tuple[float, float]], side: float, n: int = 4000
) -> np.ndarray:
    """Points on the four vertical faces of square boxes of ``side`` m at ``centres``, 0-1 m high."""
    out = []
    for cx, cy in centres:
        t = rng.uniform(-side / 2, side / 2, n)
        face = rng.integers(0, 4, n)
        x = np.where(face < 2, cx + np.where(face == 0, -1, 1) * side / 2, cx + t)
        y = np.where(face < 2, cy + t, cy + np.where(face == 2, -1, 1) * side / 2)
        out.append(np.column_stack([x, y, rng.uniform(0.2, 1.0, n)]))
    return np.concatenate(out)


def test_a_heading_fixed_only_by_a_small_far_cluster_moves_little_once_the_map_is_anchored(room) -> None:
    first, second = room
    rng = np.random.default_rng(5)
    cluster = [(6.0, -0.4), (6.3, 0.3), (6.6, -0.1)]  # three 0.4 m boxes in a 1 m patch, 6 m away
    m = VHVMap(SPEC, 0.05)
    m.insert(first)
    m.insert(_boxes(rng, cluster, 0.4))
    matcher = ScanMatcher()
    assert matcher.match(second, m).accepted  # the room anchors map -> odom
    before = np.array(matcher.t_map_odom)
    # the cluster alone, seen with a heading 1.5 deg off (about the sensor at the origin)
    res = matcher.match(_rot(_boxes(rng, cluster, 0.4), 0.0, 0.0, math.radians(1.5)), m)
    assert res.accepted, res
    assert res.sd[1] > math.radians(1.0)  # three boxes 1 m across fix the heading to a degree or worse
    applied = math.atan2(matcher.t_map_odom[1, 0], matcher.t_map_odom[0, 0]) - math.atan2(
        before[1, 0], before[0, 0]
    )
    assert abs(applied) < 0.25 * abs(res.dyaw)


def test_a_map_defined_by_the_odometry_start_takes_a_sudden_jump_only_in_part(room) -> None:
    first, second = room
    m = VHVMap(SPEC, 0.05)
    m.insert(first)
    # map = odom at the start: one frame later the odometry cannot be 8 cm off, so the match is weighed
    matcher = ScanMatcher(MatchParams(initial_sd=(0.0, 0.0)))
    res = matcher.match(_rot(second, 0.08, 0.0, 0.0), m)
    assert res.accepted and res.dx == pytest.approx(-0.08, abs=0.02)
    assert 0.0 < -matcher.t_map_odom[0, 3] < 0.1 * -res.dx
    with pytest.raises(MappingError, match="initial_sd"):
        MatchParams(initial_sd=(-1.0, 0.0))


def test_matching_the_same_view_while_standing_still_does_not_walk_the_map_away(room) -> None:
    first, second = room
    m = VHVMap(SPEC, 0.05)
    m.insert(first)
    pose = np.eye(4)
    standing = ScanMatcher(MatchParams(initial_sd=(0.0, 0.0)))
    per_frame = ScanMatcher(MatchParams(initial_sd=(0.0, 0.0)))
    frame = _rot(second, 0.03, 0.0, 0.0)  # a view that matches 3 cm off, seen again and again
    for _ in range(30):
        assert standing.match(frame, m, pose).accepted
        per_frame.match(frame, m)
    # the odometry did not move: its error cannot have grown, so nothing was applied
    np.testing.assert_array_equal(standing.t_map_odom, np.eye(4))
    assert abs(per_frame.t_map_odom[0, 3]) > 0.005  # without the pose, the error grows every frame


@pytest.mark.parametrize(
    "window", [(0.5, -2.0, 4.0, 2.0), (-9.0, -9.0, 9.0, 9.0), (1.0, 0.0, 3.5, 1.5), (7.0, 7.0, 8.0, 8.0)]
)
def test_a_probabilistic_map_gives_the_map_cells_of_a_window_that_its_occupied_structures_give(
    window,
) -> None:
    """map_cell_centres reads a probabilistic map's window cells directly (band_cell_keys): the same centres,
    in the same order, as selecting on the map's occupied structures (its VHV view), for windows inside,
    across and outside the grid; occupied pieces only (a cell only free in the band gives none)."""
    from mapping.matching import map_cell_centres
    from mapping.probabilistic import ProbabilisticVHV

    rng = np.random.default_rng(2)
    m = ProbabilisticVHV(GridSpec(cell_size=0.05, size_x=12.0, size_y=12.0))
    for k in range(3):
        m.insert(
            render_scene(rng, 106, 128, nan_fraction=0.05, pitch_deg=5.0), sensor_origin=(0.0, 0.1 * k, 0.9)
        )
    band = (0.10, 1.0)
    got = map_cell_centres(m, band, window)
    want = map_cell_centres(m._occupied_view(), band, window)
    np.testing.assert_array_equal(got, want)
    if window[0] < 3.0:
        assert len(got) > 3
