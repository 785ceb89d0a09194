"""The Rerun recording of a run folder, read back through the Rerun SDK: entities, row counts, times,
geometry; and `robchair view` without a display."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("rerun", reason="the viz extra (rerun-sdk) is not installed")

from rerun.chunk import RrdReader

from robchair.cli import main
from robchair.run_folder import RunFolderError
from robchair.viz.rerun_recording import (
    RECORDING_NAME,
    TIMELINE,
    cone_strip,
    entity_counts,
    frame_entities,
    write_recording,
)
from tests.robchair.synthetic_run import (
    CLOUD_SHAPE,
    RATE_HZ,
    SONAR_ARRAYS,
    write_synthetic_run,
    write_timeseries,
)

BASE = "/world/odom/base_link"
CAMERA = f"{BASE}/kinect_link/kinect_depth_optical_frame"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    r = write_synthetic_run(tmp_path_factory.mktemp("rrd") / "run", 1.0)
    write_timeseries(r.path, r.cycles)
    return r


@pytest.fixture(scope="module")
def rrd(run):
    return write_recording(run.path)


def _columns(path, entity: str, column: str) -> list:
    """``(run time s or None, value)`` of every row of one column of one entity, in time order (static
    rows first)."""
    import pyarrow as pa

    rows = []
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if TIMELINE in names:
            t = [ns / 1e9 for ns in batch.column(names.index(TIMELINE)).cast(pa.int64()).to_pylist()]
        else:
            t = [None] * batch.num_rows
        rows += zip(t, batch.column(names.index(column)).to_pylist(), strict=True)
    rows.sort(key=lambda r: -1.0 if r[0] is None else r[0])
    return rows


def test_recording_has_the_chair_sensors_maps_and_plots_with_one_row_per_message(run, rrd):
    assert rrd == run.path / RECORDING_NAME
    counts = entity_counts(rrd)
    sonar_readings = run.counts["/sonar/sonar_array_left/1"]
    expected = {
        "/world": 1,  # ViewCoordinates
        BASE: run.counts["/odom"],  # odom -> base_link from every /tf message
        f"{BASE}/kinect_link": 1,
        CAMERA: 1,
        f"{CAMERA}/points": run.counts["/kinect/points"],
        f"{BASE}/laser_link/scan": run.counts["/scan"],
        "/world/map/vhv/odometry": 1,
        "/world/map/vhv/ground_truth": 1,
        "/world/map/path/odometry": 1,
        "/world/map/occupancy": 1,
        "/map_2d": 1,
        "/plots/v": run.counts["/odom"],
        "/plots/w": run.counts["/odom"],
        "/plots/v_cmd": run.cycles,
        "/plots/mapping_ms": run.cycles // 6,
        "/run/safety": len(run.stops),
        "/run/metrics": 1,
    }
    for name in SONAR_ARRAYS:
        expected[f"{BASE}/{name}"] = sonar_readings  # the servo angle with each reading
        for k in (1, 2, 3):
            expected[f"{BASE}/{name}/{name}_{k}"] = 1
            expected[f"{BASE}/{name}/{name}_{k}/cone"] = run.counts[f"/sonar/{name}/{k}"]
    for entity, n in expected.items():
        assert counts.get(entity) == n, entity
    # the driven path grows at 10 Hz and ends with every /odom position
    path = _columns(rrd, "/world/odom/driven_path", "LineStrips3D:strips")
    assert len(path) == math.ceil(run.cycles / (RATE_HZ / 10)) + 1
    assert len(path[-1][1][0]) == run.counts["/odom"]


def test_recording_rows_sit_at_the_run_time_of_their_messages(run, rrd):
    times = [t for t, _ in _columns(rrd, BASE, "Transform3D:translation")]
    np.testing.assert_allclose(times, np.arange(1, run.cycles + 1) / RATE_HZ, atol=1e-9)
    stops = [t for t, _ in _columns(rrd, "/run/safety", "TextLog:text")]
    assert stops == pytest.approx([s["t_s"] for s in run.stops])
    # the pose at t = 1 s: a quarter circle of radius 2 m at 0.5 m/s
    last = _columns(rrd, BASE, "Transform3D:translation")[-1][1]
    np.testing.assert_allclose(last, [[2 * math.sin(0.25), 2 * (1 - math.cos(0.25)), 0.0]], atol=1e-6)


def test_recording_geometry_boxes_clouds_and_cones(run, rrd):
    ((_, half),) = _columns(rrd, "/world/map/vhv/odometry", "Boxes3D:half_sizes")
    assert len(half) == run.n_structures
    np.testing.assert_allclose(np.asarray(half)[:, :2], 0.025, atol=1e-6)  # half a 5 cm cell
    clouds = _columns(rrd, f"{CAMERA}/points", "Points3D:positions")
    assert {len(p) for _, p in clouds} == {CLOUD_SHAPE[0] * CLOUD_SHAPE[1] - 4}  # NaN points dropped
    # a sonar without an echo shows its cone at max range (6 m), one with an echo at its range
    no_echo = _columns(rrd, f"{BASE}/sonar_array_right/sonar_array_right_3/cone", "LineStrips3D:strips")
    arc = np.asarray(no_echo[0][1][0])[1:-1]
    np.testing.assert_allclose(np.hypot(arc[:, 0], arc[:, 1]), 6.0, rtol=1e-6)
    echo = np.asarray(
        _columns(rrd, f"{BASE}/sonar_array_left/sonar_array_left_2/cone", "LineStrips3D:strips")[0][1][0]
    )
    assert 0.5 <= np.hypot(*echo[1, :2]) <= 3.0


def test_depth_clouds_are_thinned_to_the_point_budget(run, tmp_path):
    out = write_recording(run.path, tmp_path / "thin.rrd", max_cloud_points=50)
    sizes = {len(p) for _, p in _columns(out, f"{CAMERA}/points", "Points3D:positions")}
    assert sizes and max(sizes) <= 50 and min(sizes) >= 25


def test_laser_scan_and_cone_shapes():
    strip = cone_strip(2.0, math.radians(60), segments=4)
    assert strip.shape == (7, 3) and np.allclose(strip[0], 0) and np.allclose(strip[-1], 0)
    np.testing.assert_allclose(np.degrees(np.arctan2(strip[1:-1, 1], strip[1:-1, 0])), [-30, -15, 0, 15, 30])


def test_frames_nest_as_in_the_tf_tree_and_a_cycle_is_refused():
    ent = frame_entities({"base_link": "odom", "laser_link": "base_link", "odom": "map"})
    assert ent["laser_link"] == "world/map/odom/base_link/laser_link"
    assert ent["map"] == "world/map"
    with pytest.raises(RunFolderError, match="cycle"):
        frame_entities({"a": "b", "b": "a"})


def test_a_damaged_bag_leaves_no_recording(tmp_path):
    run = write_synthetic_run(tmp_path / "run", 0.3)
    mcap = next((run.path / "bag").glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    with pytest.raises(RunFolderError, match="bag"):
        write_recording(run.path)
    assert sorted(p.name for p in run.path.iterdir()) == [
        "bag",
        "map",
        "maps.npz",
        "metrics.json",
        "scene.png",
    ]


def test_view_without_a_display_writes_the_recording_and_says_how_to_open_it(tmp_path, monkeypatch, capsys):
    run = write_synthetic_run(tmp_path / "run", 0.3)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    assert main(["view", str(run.path)]) == 0
    out = capsys.readouterr().out
    rrd = run.path / RECORDING_NAME
    assert rrd.is_file()
    assert f"recording: {rrd} (no display here)" in out and f"rerun {rrd}" in out
    assert entity_counts(rrd)[BASE] == run.counts["/odom"]


def test_view_of_a_missing_folder_is_one_line_and_exit_code_2(tmp_path, capsys):
    assert main(["view", str(tmp_path / "nope"), "--no-viewer"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope: not a run folder or a .rrd recording" in err


def test_2d_map_cells_land_on_the_grid_cells_they_came_from(tmp_path):
    from mapping.export import map_codes, write_map_outputs
    from mapping.export.rosmap import FREE, OCCUPIED
    from mapping.grid import GridSpec
    from mapping.vhv import VHVMap

    rng = np.random.default_rng(5)
    spec = GridSpec(cell_size=0.1, size_x=3.0, size_y=2.0, centre=(0.9, -0.4))
    m = VHVMap(spec, tolerance=0.05)
    m.insert(rng.uniform((-0.5, -1.3, 0.0), (2.3, 0.5, 1.2), (300, 3)))
    (tmp_path / "map").mkdir()
    write_map_outputs(m, tmp_path / "map", band=(0.3, 1.0))
    codes = map_codes(m, (0.3, 1.0))
    rrd = write_recording(tmp_path)
    ((_, verts),) = _columns(rrd, "/world/map/occupancy", "Mesh3D:vertex_positions")
    ((_, colors),) = _columns(rrd, "/world/map/occupancy", "Mesh3D:vertex_colors")
    quads = np.asarray(verts).reshape(-1, 4, 3)
    centres = quads.mean(axis=1)
    i, j = spec.world_to_index(centres[:, 0], centres[:, 1])
    dark = (np.asarray(colors, dtype=np.uint64)[::4] >> 24) < 128  # RGBA packed as 0xRRGGBBAA
    assert sorted(zip(i[dark], j[dark])) == sorted(zip(*np.nonzero(codes == OCCUPIED)))
    assert sorted(zip(i[~dark], j[~dark])) == sorted(zip(*np.nonzero(codes == FREE)))
    np.testing.assert_allclose(quads[:, 2, :2] - quads[:, 0, :2], 0.1, atol=1e-6)  # one cell each
